#include "slscand/sequencer/timing.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace slscand {

TimingSummary summarize(std::string name, std::vector<double> values_us) {
  TimingSummary s;
  s.name = std::move(name);
  s.count = values_us.size();
  if (values_us.empty()) return s;
  std::sort(values_us.begin(), values_us.end());
  double sum = 0;
  for (const double v : values_us) sum += v;
  s.mean_us = sum / static_cast<double>(values_us.size());
  double sq = 0;
  for (const double v : values_us) sq += (v - s.mean_us) * (v - s.mean_us);
  s.stddev_us = values_us.size() > 1 ? std::sqrt(sq / static_cast<double>(values_us.size() - 1)) : 0;
  s.min_us = values_us.front();
  s.max_us = values_us.back();
  // Nearest-rank percentiles: a value that actually occurred.
  auto rank = [&](double p) {
    const auto k = static_cast<std::size_t>(std::ceil(p * static_cast<double>(values_us.size())));
    return values_us[std::min(values_us.size() - 1, k == 0 ? 0 : k - 1)];
  };
  s.p50_us = rank(0.50);
  s.p99_us = rank(0.99);
  return s;
}

TimingReport make_timing_report(const std::vector<FrameTiming>& frames, double nominal_period_us) {
  TimingReport r;
  r.nominal_period_us = nominal_period_us;
  std::vector<double> period, jitter, lateness, shown, exposure, delivery;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const FrameTiming& f = frames[i];
    if (f.paused_before) r.paused_frames++;
    lateness.push_back(static_cast<double>(f.trigger_ns - f.deadline_ns) * 1e-3);
    if (f.shown_ns != 0) shown.push_back(static_cast<double>(f.shown_ns - f.trigger_ns) * 1e-3);
    if (f.exposure_start_ns != 0) exposure.push_back(static_cast<double>(f.exposure_start_ns - f.trigger_ns) * 1e-3);
    if (f.exposure_end_ns != 0) delivery.push_back(static_cast<double>(f.dequeued_ns - f.exposure_end_ns) * 1e-3);
    if (i > 0) {
      const FrameTiming& p = frames[i - 1];
      const bool same_pass =
          p.view_index == f.view_index && p.projector_id == f.projector_id && p.pattern_index + 1 == f.pattern_index;
      if (same_pass && !f.paused_before) {
        const double us = static_cast<double>(f.trigger_ns - p.trigger_ns) * 1e-3;
        period.push_back(us);
        jitter.push_back(std::abs(us - nominal_period_us));
      }
    }
  }
  r.pattern_period = summarize("pattern_period", period);
  r.period_jitter = summarize("pattern_period_jitter", jitter);
  r.trigger_lateness = summarize("trigger_lateness", lateness);
  r.trigger_to_shown = summarize("trigger_to_pattern_shown", shown);
  r.trigger_to_exposure = summarize("trigger_to_exposure_start", exposure);
  r.frame_delivery = summarize("exposure_end_to_frame_dequeued", delivery);
  return r;
}

std::vector<TimingSummary> TimingReport::all() const {
  return {pattern_period, period_jitter, trigger_lateness, trigger_to_shown, trigger_to_exposure, frame_delivery};
}

std::string TimingReport::to_text() const {
  std::string out;
  char line[256];
  std::snprintf(line, sizeof line, "nominal pattern period %.1f us; %llu frames paused by back-pressure\n",
                nominal_period_us, static_cast<unsigned long long>(paused_frames));
  out += line;
  std::snprintf(line, sizeof line, "%-32s %6s %10s %9s %10s %10s %10s %10s\n", "interval (us)", "count", "mean",
                "stddev", "min", "p50", "p99", "max");
  out += line;
  for (const auto& s : all()) {
    std::snprintf(line, sizeof line, "%-32s %6llu %10.2f %9.2f %10.2f %10.2f %10.2f %10.2f\n", s.name.c_str(),
                  static_cast<unsigned long long>(s.count), s.mean_us, s.stddev_us, s.min_us, s.p50_us, s.p99_us,
                  s.max_us);
    out += line;
  }
  return out;
}

}  // namespace slscand
