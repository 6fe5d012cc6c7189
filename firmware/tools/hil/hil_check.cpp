#include "hil_check.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <set>

namespace slscan::hil {

namespace {

constexpr const char* kSideNames[2] = {"projector.left", "projector.right"};

std::string fmt(double v, int decimals = 1) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*f", decimals, v);
  return buffer;
}

std::string json_escape(const std::string& s) {
  std::string out;
  for (const char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buffer[8];
      std::snprintf(buffer, sizeof buffer, "\\u%04x", c);
      out += buffer;
    } else {
      out += c;
    }
  }
  return out;
}

std::string json_number(double v) {
  if (!std::isfinite(v)) return "null";
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.6g", v);
  return buffer;
}

// Events of one kind (and source, when given), oldest first.
std::vector<Nanos> log_times(const std::vector<LogEvent>& log, const std::string& kind, int source = -1) {
  std::vector<Nanos> out;
  for (const auto& e : log) {
    if (e.kind == kind && (source < 0 || e.source == static_cast<std::uint32_t>(source))) out.push_back(e.ns);
  }
  std::sort(out.begin(), out.end());
  return out;
}

struct LineEdges {
  std::vector<Nanos> rising, falling;
};

LineEdges edges_on(const std::vector<Edge>& edges, unsigned offset) {
  LineEdges out;
  for (const auto& e : edges) {
    if (e.offset == offset) (e.rising ? out.rising : out.falling).push_back(e.ns);
  }
  std::sort(out.rising.begin(), out.rising.end());
  std::sort(out.falling.begin(), out.falling.end());
  return out;
}

struct Pulse {
  Nanos rise = 0;
  Nanos fall = std::numeric_limits<Nanos>::max();  // never fell
};

std::vector<Pulse> pulses(const LineEdges& line) {
  std::vector<Pulse> out;
  for (const Nanos rise : line.rising) {
    Pulse p{rise};
    auto it = std::upper_bound(line.falling.begin(), line.falling.end(), rise - 1);
    if (it != line.falling.end()) p.fall = *it;
    out.push_back(p);
  }
  return out;
}

}  // namespace

Stat summarize(std::string name, std::string unit, std::vector<double> values) {
  Stat s;
  s.name = std::move(name);
  s.unit = std::move(unit);
  s.count = values.size();
  if (values.empty()) return s;
  std::sort(values.begin(), values.end());
  double sum = 0;
  for (const double v : values) sum += v;
  s.mean = sum / static_cast<double>(values.size());
  // Nearest rank: a value that occurred, as the firmware's timing report does.
  auto rank = [&](double p) {
    const auto k = static_cast<std::size_t>(std::ceil(p * static_cast<double>(values.size())));
    return values[std::min(values.size() - 1, k == 0 ? 0 : k - 1)];
  };
  s.p50 = rank(0.5);
  s.p99 = rank(0.99);
  s.max = values.back();
  return s;
}

bool HilReport::passed() const { return failures().empty(); }

std::vector<const Check*> HilReport::failures() const {
  std::vector<const Check*> out;
  for (const auto& c : checks) {
    if (!c.pass) out.push_back(&c);
  }
  return out;
}

std::string HilReport::table() const {
  std::string out;
  char line[512];
  std::snprintf(line, sizeof line, "%-40s %6s %10s %10s %10s %10s\n", "measured", "count", "mean", "p50", "p99", "max");
  out += line;
  for (const auto& s : stats) {
    const std::string name = s.name + " (" + s.unit + ")";
    std::snprintf(line, sizeof line, "%-40s %6zu %10.1f %10.1f %10.1f %10.1f\n", name.c_str(), s.count, s.mean, s.p50,
                  s.p99, s.max);
    out += line;
  }
  out += "\n";
  std::snprintf(line, sizeof line, "%-9s %-58s %14s %16s  %s\n", "group", "check", "measured", "limit", "result");
  out += line;
  for (const auto& c : checks) {
    std::snprintf(line, sizeof line, "%-9s %-58s %14s %16s  %s\n", c.group.c_str(), c.name.c_str(), c.measured.c_str(),
                  c.limit.c_str(), c.pass ? "ok" : "FAILED");
    out += line;
    if (!c.pass && !c.detail.empty()) out += "          ^ " + c.detail + "\n";
  }
  return out;
}

std::string HilReport::json() const {
  std::string out = "{\n  \"passed\": " + std::string(passed() ? "true" : "false") + ",\n  \"stats\": [";
  for (std::size_t i = 0; i < stats.size(); ++i) {
    const Stat& s = stats[i];
    out += std::string(i ? "," : "") + "\n    {\"name\": \"" + json_escape(s.name) + "\", \"unit\": \"" + s.unit +
           "\", \"count\": " + std::to_string(s.count) + ", \"mean\": " + json_number(s.mean) +
           ", \"p50\": " + json_number(s.p50) + ", \"p99\": " + json_number(s.p99) +
           ", \"max\": " + json_number(s.max) + "}";
  }
  out += "\n  ],\n  \"checks\": [";
  for (std::size_t i = 0; i < checks.size(); ++i) {
    const Check& c = checks[i];
    out += std::string(i ? "," : "") + "\n    {\"group\": \"" + c.group + "\", \"name\": \"" + json_escape(c.name) +
           "\", \"measured\": \"" + json_escape(c.measured) + "\", \"limit\": \"" + json_escape(c.limit) +
           "\", \"pass\": " + (c.pass ? "true" : "false") + ", \"detail\": \"" + json_escape(c.detail) + "\"}";
  }
  out += "\n  ]\n}\n";
  return out;
}

HilReport evaluate(const HilRecord& r, const slscand::hal::BoardConfig& board, const CheckOptions& options) {
  HilReport report;
  const slscand::hal::TimingBudget& budget = board.budget;
  const double nominal_us = r.scan.period_us;
  // Times in messages: ms since the scan's first logged event, readable next to the logs.
  Nanos origin = 0;
  if (!r.log.empty()) {
    origin = std::min_element(r.log.begin(), r.log.end(), [](const LogEvent& a, const LogEvent& b) {
               return a.ns < b.ns;
             })->ns;
  }
  auto at = [&](Nanos ns) { return fmt(static_cast<double>(ns - origin) * 1e-6, 3) + " ms"; };

  auto add = [&](std::string group, std::string name, std::string measured, std::string limit, bool pass,
                 std::string detail = {}) {
    report.checks.push_back(
        Check{std::move(group), std::move(name), std::move(measured), std::move(limit), pass, std::move(detail)});
  };
  auto budget_max = [&](const std::string& key, double measured, double limit, const std::string& unit,
                        std::string detail = {}) {
    add("budget", "timing_budget." + key, fmt(measured) + " " + unit, "<= " + fmt(limit) + " " + unit,
        measured <= limit, measured <= limit ? std::string() : std::move(detail));
  };

  // ---- frames in scan order
  std::vector<FrameRecord> frames = r.frames;
  std::stable_sort(frames.begin(), frames.end(),
                   [](const FrameRecord& a, const FrameRecord& b) { return a.sequence < b.sequence; });

  // ---- behaviour
  add("behaviour", "scan final state", r.scan.final_state, "DONE", r.scan.final_state == "DONE",
      r.scan.final_state == "DONE" ? "" : "slscand: " + r.scan.text);
  {
    std::set<std::uint64_t> distinct;
    for (const auto& f : frames) distinct.insert(f.sequence);
    const std::uint64_t expected = r.scan.expected_frames();
    const std::uint64_t lost = expected > distinct.size() ? expected - distinct.size() : 0;
    const std::uint64_t lost_total = std::max<std::uint64_t>(lost, r.scan.frames_dropped);
    std::string detail;
    if (lost_total > 0) {
      detail = std::to_string(distinct.size()) + " of " + std::to_string(expected) +
               " frames received, ScanDone says " + std::to_string(r.scan.frames_sent) + " sent and " +
               std::to_string(r.scan.frames_dropped) + " dropped";
      for (std::uint64_t s = 0; s < expected; ++s) {
        if (!distinct.count(s)) {
          detail += "; first missing: sequence " + std::to_string(s);
          break;
        }
      }
    }
    add("behaviour", "frames lost", std::to_string(lost_total), "0", lost_total == 0, detail);
    const bool extra = distinct.size() > expected || distinct.size() != frames.size();
    add("behaviour", "frames duplicated or unplanned",
        std::to_string(frames.size() - std::min<std::size_t>(frames.size(), expected)), "0", !extra,
        extra ? std::to_string(frames.size()) + " frames for a plan of " + std::to_string(expected) : "");
  }
  {
    // Scan order: view, then exposure (a bracket's member), then projector pass, then pattern;
    // sequence numbers 0, 1, 2, ...
    std::string problem;
    for (std::size_t i = 0; i < frames.size() && problem.empty(); ++i) {
      const FrameRecord& f = frames[i];
      if (f.sequence != i) problem = "frame " + std::to_string(i) + " has sequence " + std::to_string(f.sequence);
      if (problem.empty() && f.exposure_index >= r.scan.exposure_count())
        problem = "frame " + std::to_string(i) + " has exposure index " + std::to_string(f.exposure_index) +
                  "; the scan's bracket has " + std::to_string(r.scan.exposure_count());
      if (i == 0) continue;
      const FrameRecord& p = frames[i - 1];
      const bool next_pattern = f.view == p.view && f.exposure_index == p.exposure_index &&
                                f.projector == p.projector && f.pattern == p.pattern + 1;
      const bool next_pass =
          f.pattern == 0 && ((f.view > p.view && f.exposure_index == 0) ||
                             (f.view == p.view && f.exposure_index == p.exposure_index && f.projector != p.projector) ||
                             (f.view == p.view && f.exposure_index == p.exposure_index + 1));
      if (problem.empty() && !next_pattern && !next_pass) {
        auto name = [](const FrameRecord& x) {
          return "view " + std::to_string(x.view) + ", exposure " + std::to_string(x.exposure_index) + ", projector " +
                 std::to_string(x.projector) + ", pattern " + std::to_string(x.pattern);
        };
        problem = "frame " + std::to_string(i) + " (" + name(f) + ") follows " + name(p);
      }
      if (problem.empty() && f.trigger_ns <= p.trigger_ns) {
        problem = "frame " + std::to_string(i) + " was triggered at " + at(f.trigger_ns) + ", not after frame " +
                  std::to_string(i - 1) + " at " + at(p.trigger_ns);
      }
    }
    add("behaviour", "frames in scan order", problem.empty() ? "yes" : "no", "yes", problem.empty(), problem);
  }
  {
    // Each frame's own timestamps against the log the sequencer wrote: the same scan, or not.
    std::string problem;
    for (int side = 0; side < 2 && problem.empty(); ++side) {
      const auto triggers = log_times(r.log, "PROJECTOR_TRIGGER", side);
      std::vector<const FrameRecord*> mine;
      for (const auto& f : frames) {
        if (f.projector == static_cast<std::uint32_t>(side)) mine.push_back(&f);
      }
      if (mine.size() != triggers.size()) {
        problem = "the log has " + std::to_string(triggers.size()) + " PROJECTOR_TRIGGER events for " +
                  kSideNames[side] + " but " + std::to_string(mine.size()) + " of its frames arrived";
        break;
      }
      for (std::size_t k = 0; k < mine.size(); ++k) {
        if (mine[k]->trigger_ns != triggers[k]) {
          problem = std::string(kSideNames[side]) + " frame " + std::to_string(mine[k]->sequence) +
                    " says its trigger was at " + at(mine[k]->trigger_ns) + ", the log's trigger " + std::to_string(k) +
                    " is at " + at(triggers[k]);
          break;
        }
      }
    }
    if (problem.empty()) {
      const auto starts = log_times(r.log, "EXPOSURE_START");
      std::vector<Nanos> frame_starts;
      frame_starts.reserve(frames.size());
      for (const auto& f : frames) frame_starts.push_back(f.exposure_start_ns);
      std::sort(frame_starts.begin(), frame_starts.end());
      if (starts != frame_starts) {
        problem = "the log has " + std::to_string(starts.size()) + " EXPOSURE_START events, the frames " +
                  std::to_string(frame_starts.size()) + ", or their times differ";
      }
    }
    add("behaviour", "frames agree with the timing log", problem.empty() ? "yes" : "no", "yes", problem.empty(),
        problem);
  }

  // ---- timing measured from the log and the frames
  std::vector<double> period, jitter, to_exposure, exposure_error, delivery;
  std::string worst_jitter_where, worst_latency_where, worst_exposure_where, worst_delivery_where;
  double worst_jitter = -1, worst_latency = -1, worst_exposure = -1, worst_delivery = -1;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const FrameRecord& f = frames[i];
    const bool known_exposure = f.exposure_index < r.scan.exposure_count();
    const std::string where = "frame " + std::to_string(f.sequence) + " (view " + std::to_string(f.view) + ", " +
                              kSideNames[f.projector % 2] + ", pattern " + std::to_string(f.pattern) +
                              (r.scan.exposures_us.empty() || !known_exposure
                                   ? std::string()
                                   : ", exposure " + fmt(r.scan.exposure_of(f.exposure_index), 0) + " us") +
                              ")";
    if (f.exposure_start_ns != 0) {
      const double us = static_cast<double>(f.exposure_start_ns - f.trigger_ns) * 1e-3;
      to_exposure.push_back(us);
      if (us > worst_latency) worst_latency = us, worst_latency_where = where;
    }
    if (f.exposure_end_ns != 0 && f.exposure_start_ns != 0 && known_exposure) {
      const double length = static_cast<double>(f.exposure_end_ns - f.exposure_start_ns) * 1e-3;
      const double error = std::abs(length - r.scan.exposure_of(f.exposure_index));
      exposure_error.push_back(length);
      if (error > worst_exposure) worst_exposure = error, worst_exposure_where = where;
    }
    if (f.exposure_end_ns != 0 && f.dequeued_ns != 0) {
      const double us = static_cast<double>(f.dequeued_ns - f.exposure_end_ns) * 1e-3;
      delivery.push_back(us);
      if (us > worst_delivery) worst_delivery = us, worst_delivery_where = where;
    }
    if (i > 0) {
      const FrameRecord& p = frames[i - 1];
      if (p.view == f.view && p.exposure_index == f.exposure_index && p.projector == f.projector &&
          p.pattern + 1 == f.pattern) {
        const double us = static_cast<double>(f.trigger_ns - p.trigger_ns) * 1e-3;
        period.push_back(us);
        jitter.push_back(std::abs(us - nominal_us));
        if (jitter.back() > worst_jitter) worst_jitter = jitter.back(), worst_jitter_where = where;
      }
    }
  }
  std::vector<double> move_settle;
  {
    const auto starts = log_times(r.log, "TURNTABLE_MOVE_START");
    const auto settled = log_times(r.log, "SETTLE_DONE");
    for (std::size_t v = 0; v < std::min(starts.size(), settled.size()); ++v) {
      move_settle.push_back(static_cast<double>(settled[v] - starts[v]) * 1e-6);
    }
  }
  const Stat period_stat = summarize("pattern period", "us", period);
  const Stat jitter_stat = summarize("pattern period jitter |p - nominal|", "us", jitter);
  report.stats = {period_stat,
                  jitter_stat,
                  summarize("trigger -> exposure start", "us", to_exposure),
                  summarize("exposure length", "us", exposure_error),
                  summarize("exposure end -> frame dequeued", "us", delivery),
                  summarize("turntable move + settle", "ms", move_settle)};

  if (options.timing) {
    budget_max("period_mean_error_us", std::abs(period_stat.mean - nominal_us), budget.period_mean_error_us, "us",
               "mean period " + fmt(period_stat.mean) + " us against the nominal " + fmt(nominal_us) + " us");
    budget_max("period_jitter_p50_us", jitter_stat.p50, budget.period_jitter_p50_us, "us");
    budget_max("period_jitter_p99_us", jitter_stat.p99, budget.period_jitter_p99_us, "us");
    budget_max("period_jitter_max_us", jitter_stat.max, budget.period_jitter_max_us, "us",
               "worst at " + worst_jitter_where);
    budget_max("trigger_to_exposure_max_us", std::max(0.0, worst_latency), budget.trigger_to_exposure_max_us, "us",
               "worst at " + worst_latency_where);
    budget_max("exposure_error_max_us", std::max(0.0, worst_exposure), budget.exposure_error_max_us, "us",
               "worst at " + worst_exposure_where);
    const Stat delivery_stat = report.stats[4];
    budget_max("frame_delivery_p99_us", delivery_stat.p99, budget.frame_delivery_p99_us, "us");
    budget_max("frame_delivery_max_us", delivery_stat.max, budget.frame_delivery_max_us, "us",
               "worst at " + worst_delivery_where);
    const Stat move_stat = report.stats[5];
    budget_max("move_settle_max_ms", move_stat.max, budget.move_settle_max_ms, "ms");
    double ideal_ns = static_cast<double>(r.scan.capture_periods()) * nominal_us * 1e3;
    for (const double ms : move_settle) ideal_ns += ms * 1e6;
    const double ratio = ideal_ns > 0 ? static_cast<double>(r.scan.duration_ns) / ideal_ns : 0;
    add("budget", "timing_budget.scan_time_ratio_max", fmt(ratio, 3), "<= " + fmt(budget.scan_time_ratio_max, 3),
        ratio <= budget.scan_time_ratio_max,
        "scan took " + fmt(static_cast<double>(r.scan.duration_ns) * 1e-6) + " ms, ideal " + fmt(ideal_ns * 1e-6) +
            " ms (frames x period + exposure changes x exposure_change_frames x period + measured moves)");
    report.checks.back().detail = report.checks.back().pass ? "" : report.checks.back().detail;
  }

  // ---- the observer
  if (!r.have_edges) {
    add("observer", "independent edge record", "none", "present", true,
        "no observer on this run: the log was not cross-checked");
    return report;
  }
  std::vector<double> observed_jitter, observed_shown;
  double worst_disagreement = 0;
  std::string worst_disagreement_where;
  for (int side = 0; side < 2; ++side) {
    const slscand::hal::DlpLines& lines = board.projectors[side];
    const std::string name = kSideNames[side];
    const auto in1 = edges_on(r.edges, lines.trig_in_1);
    const auto in2 = edges_on(r.edges, lines.trig_in_2);
    const auto out1 = edges_on(r.edges, lines.trig_out_1);
    const auto out_pulses = pulses(out1);
    const auto run_pulses = pulses(in2);
    const auto log_triggers = log_times(r.log, "PROJECTOR_TRIGGER", side);
    const auto log_shown = log_times(r.log, "PATTERN_SHOWN", side);
    std::vector<const FrameRecord*> mine;
    for (const auto& f : frames) {
      if (f.projector == static_cast<std::uint32_t>(side)) mine.push_back(&f);
    }

    // Counts: what the sequencer says it did against what the line carried.
    const bool triggers_match = in1.rising.size() == log_triggers.size();
    add("observer", name + ".trig_in_1 rising edges (line " + std::to_string(lines.trig_in_1) + ")",
        std::to_string(in1.rising.size()), std::to_string(log_triggers.size()) + " (log)", triggers_match,
        triggers_match ? ""
                       : "the observer saw " + std::to_string(in1.rising.size()) + " triggers, the log records " +
                             std::to_string(log_triggers.size()) + " PROJECTOR_TRIGGER events");
    const bool shown_match = out1.rising.size() == log_shown.size();
    add("observer", name + ".trig_out_1 rising edges (line " + std::to_string(lines.trig_out_1) + ")",
        std::to_string(out1.rising.size()), std::to_string(log_shown.size()) + " (log)", shown_match,
        shown_match ? ""
                    : "the observer saw " + std::to_string(out1.rising.size()) + " exposures, the log records " +
                          std::to_string(log_shown.size()) + " PATTERN_SHOWN events");

    // Timestamps: each logged event against the observed edge it claims.
    if (triggers_match && shown_match) {
      for (const auto& [logged, observed, what] : {std::tuple{&log_triggers, &in1.rising, "trig_in_1 trigger"},
                                                   std::tuple{&log_shown, &out1.rising, "trig_out_1 exposure"}}) {
        for (std::size_t k = 0; k < logged->size(); ++k) {
          const double us = std::abs(static_cast<double>((*logged)[k] - (*observed)[k])) * 1e-3;
          if (us > worst_disagreement) {
            worst_disagreement = us;
            worst_disagreement_where = name + " " + what + " " + std::to_string(k) + ": log " + at((*logged)[k]) +
                                       ", observer " + at((*observed)[k]);
          }
        }
      }
    }

    // Order: every trigger inside a running sequence (TRIG_IN_2 high), answered by its own
    // exposure pulse before the next trigger; every frame exposed inside that pulse (the
    // camera's trigger), after the projector trigger that selected its pattern.
    std::string order_problem;
    for (std::size_t k = 0; k < in1.rising.size() && order_problem.empty(); ++k) {
      const Nanos t = in1.rising[k];
      const bool running =
          std::any_of(run_pulses.begin(), run_pulses.end(), [&](const Pulse& p) { return p.rise <= t && t < p.fall; });
      if (!running) {
        order_problem = "trigger " + std::to_string(k) + " at " + at(t) + " while trig_in_2 was low";
        break;
      }
      if (k >= out_pulses.size()) {
        order_problem = "trigger " + std::to_string(k) + " at " + at(t) + " has no exposure pulse on trig_out_1";
        break;
      }
      const Nanos next = k + 1 < in1.rising.size() ? in1.rising[k + 1] : std::numeric_limits<Nanos>::max();
      if (out_pulses[k].rise < t || out_pulses[k].rise >= next) {
        order_problem = "exposure pulse " + std::to_string(k) + " rose at " + at(out_pulses[k].rise) +
                        ", not between its trigger at " + at(t) + " and the next trigger";
        break;
      }
      observed_shown.push_back(static_cast<double>(out_pulses[k].rise - t) * 1e-3);
      if (k > 0) {
        const Nanos previous = in1.rising[k - 1];
        const bool same_pass = std::any_of(run_pulses.begin(), run_pulses.end(),
                                           [&](const Pulse& p) { return p.rise <= previous && t < p.fall; });
        if (same_pass) observed_jitter.push_back(std::abs(static_cast<double>(t - previous) * 1e-3 - nominal_us));
      }
    }
    add("observer", name + " trigger -> exposure pulse order", order_problem.empty() ? "ok" : "broken", "ok",
        order_problem.empty(), order_problem);

    if (board.trigger_source == slscand::hal::CameraTriggerSource::projector) {
      std::string frame_problem;
      for (std::size_t k = 0; k < mine.size() && frame_problem.empty(); ++k) {
        const FrameRecord& f = *mine[k];
        const std::string which =
            "frame " + std::to_string(f.sequence) + " (" + name + ", pattern " + std::to_string(f.pattern) + ")";
        if (k >= out_pulses.size() || k >= in1.rising.size()) {
          frame_problem = which + " has no trigger pulse on the observed lines";
        } else if (f.exposure_start_ns < out_pulses[k].rise || f.exposure_start_ns >= out_pulses[k].fall) {
          frame_problem = which + " exposure started at " + at(f.exposure_start_ns) +
                          ", outside its camera-trigger pulse " + at(out_pulses[k].rise) + " .. " +
                          (out_pulses[k].fall == std::numeric_limits<Nanos>::max() ? std::string("(never fell)")
                                                                                   : at(out_pulses[k].fall));
        } else if (f.exposure_start_ns <= in1.rising[k]) {
          frame_problem = which + " exposure started at " + at(f.exposure_start_ns) +
                          ", not after its projector trigger at " + at(in1.rising[k]);
        }
      }
      add("observer", name + " frames exposed inside their trigger pulse", frame_problem.empty() ? "ok" : "broken",
          "ok", frame_problem.empty(), frame_problem);
    }

    // Left safe: nothing lit, no sequence running, no trigger held high after the scan.
    std::string left_high;
    for (const auto& [line, what] :
         {std::pair{&in1, ".trig_in_1"}, std::pair{&in2, ".trig_in_2"}, std::pair{&out1, ".trig_out_1"}}) {
      const Nanos last_rise = line->rising.empty() ? -1 : line->rising.back();
      const Nanos last_fall = line->falling.empty() ? -1 : line->falling.back();
      if (last_rise > last_fall) left_high += (left_high.empty() ? "" : ", ") + name + what;
    }
    add("observer", name + " lines low after the scan", left_high.empty() ? "yes" : "no", "yes", left_high.empty(),
        left_high.empty() ? "" : "still high: " + left_high);
  }
  if (board.trigger_source == slscand::hal::CameraTriggerSource::gpio && board.camera_trigger_line) {
    const auto cam = edges_on(r.edges, *board.camera_trigger_line);
    const auto logged = log_times(r.log, "CAMERA_TRIGGER");
    add("observer", "camera.trigger_line rising edges (line " + std::to_string(*board.camera_trigger_line) + ")",
        std::to_string(cam.rising.size()), std::to_string(logged.size()) + " (log)",
        cam.rising.size() == logged.size());
  }
  const Stat observed_jitter_stat = summarize("observed period jitter (trig_in_1)", "us", observed_jitter);
  report.stats.push_back(observed_jitter_stat);
  report.stats.push_back(summarize("observed trig_in_1 -> trig_out_1", "us", observed_shown));
  if (options.timing) {
    add("observer", "log vs observer timestamps", fmt(worst_disagreement) + " us",
        "<= " + fmt(budget.observer_tolerance_us) + " us", worst_disagreement <= budget.observer_tolerance_us,
        worst_disagreement <= budget.observer_tolerance_us ? "" : "worst: " + worst_disagreement_where);
    // The observer's own clock, judged by the same budget as the log.
    budget_max("period_jitter_p99_us (observed)", observed_jitter_stat.p99, budget.period_jitter_p99_us, "us");
    budget_max("period_jitter_max_us (observed)", observed_jitter_stat.max, budget.period_jitter_max_us, "us");
    report.checks[report.checks.size() - 2].group = "observer";
    report.checks.back().group = "observer";
  }
  return report;
}

}  // namespace slscan::hil
