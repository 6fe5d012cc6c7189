#include "hil_record.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <sstream>
#include <system_error>

#include "slproto/calibration.hpp"

namespace slscan::hil {

using slproto::Errc;
using slproto::make_error;

namespace {

std::vector<std::string> split(const std::string& line, char sep) {
  std::vector<std::string> out;
  std::string field;
  std::istringstream in(line);
  while (std::getline(in, field, sep)) out.push_back(field);
  if (!line.empty() && line.back() == sep) out.emplace_back();
  return out;
}

bool parse_i64(const std::string& text, std::int64_t& out) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(text.c_str(), &end, 10);
  if (errno != 0 || *end != '\0') return false;
  out = v;
  return true;
}

bool parse_double(const std::string& text, double& out) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  out = std::strtod(text.c_str(), &end);
  return errno == 0 && *end == '\0';
}

// Calls `row(fields, line_number)` for each data line; the first error it returns stops.
template <class Fn>
slproto::Status for_each_row(const std::string& text, const std::string& where, std::size_t columns, Fn row,
                             std::size_t max_columns = 0) {
  max_columns = std::max(columns, max_columns);
  std::istringstream in(text);
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (line.empty() || line[0] == '#') continue;
    const auto fields = split(line, ',');
    if (fields.size() < columns || fields.size() > max_columns) {
      std::string message = where + ":" + std::to_string(number) + ": expected " + std::to_string(columns);
      if (max_columns > columns) message += " or " + std::to_string(max_columns);
      message += " comma-separated fields, got " + std::to_string(fields.size());
      message += " in '" + line + "'";
      return make_error(Errc::malformed, message);
    }
    if (auto s = row(fields, number); !s) return s;
  }
  return slproto::Ok{};
}

slproto::Error bad_field(const std::string& where, int line, const std::string& what, const std::string& text) {
  return make_error(Errc::malformed, where + ":" + std::to_string(line) + ": " + what + " '" + text + "' is not valid");
}

}  // namespace

slproto::Result<std::string> read_text_file(const std::string& path) {
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr)
    return make_error(Errc::io_error, "cannot open " + path + ": " + std::generic_category().message(errno));
  std::string text;
  char buffer[65536];
  std::size_t n = 0;
  while ((n = std::fread(buffer, 1, sizeof buffer, file)) > 0) text.append(buffer, n);
  const bool failed = std::ferror(file) != 0;
  std::fclose(file);
  if (failed) return make_error(Errc::io_error, "cannot read " + path);
  return text;
}

slproto::Result<std::vector<LogEvent>> parse_timing_log(const std::string& text, const std::string& where) {
  std::vector<LogEvent> events;
  auto status = for_each_row(text, where, 3, [&](const std::vector<std::string>& f, int line) -> slproto::Status {
    LogEvent e;
    static constexpr std::string_view prefix = "TIMING_EVENT_";
    if (f[0].rfind(prefix, 0) != 0 || f[0].size() == prefix.size()) {
      return bad_field(where, line, "event kind", f[0]);
    }
    e.kind = f[0].substr(prefix.size());
    std::int64_t source = 0;
    if (!parse_i64(f[1], e.ns) || e.ns < 0) return bad_field(where, line, "timestamp", f[1]);
    if (!parse_i64(f[2], source) || source < 0 || source > UINT32_MAX) return bad_field(where, line, "source", f[2]);
    e.source = static_cast<std::uint32_t>(source);
    events.push_back(std::move(e));
    return slproto::Ok{};
  });
  if (!status) return status.error();
  return events;
}

slproto::Result<std::vector<Edge>> parse_edges(const std::string& text, const std::string& where) {
  std::vector<Edge> edges;
  auto status = for_each_row(text, where, 3, [&](const std::vector<std::string>& f, int line) -> slproto::Status {
    std::int64_t offset = 0;
    Edge e;
    if (!parse_i64(f[0], offset) || offset < 0 || offset > 100000) return bad_field(where, line, "line offset", f[0]);
    if (f[1] != "0" && f[1] != "1") return bad_field(where, line, "edge (0 or 1)", f[1]);
    if (!parse_i64(f[2], e.ns) || e.ns < 0) return bad_field(where, line, "timestamp", f[2]);
    e.offset = static_cast<unsigned>(offset);
    e.rising = f[1] == "1";
    edges.push_back(e);
    return slproto::Ok{};
  });
  if (!status) return status.error();
  return edges;
}

slproto::Status save_record(const HilRecord& r, const std::string& dir) {
  std::string scan;
  auto kv = [&](const char* key, const std::string& value) { scan += std::string(key) + "=" + value + "\n"; };
  char number[64];
  auto fmt = [&](double v) {
    std::snprintf(number, sizeof number, "%.17g", v);
    return std::string(number);
  };
  kv("views", std::to_string(r.scan.views));
  kv("projectors", std::to_string(r.scan.projectors));
  kv("patterns", std::to_string(r.scan.patterns));
  kv("period_us", fmt(r.scan.period_us));
  kv("exposure_us", fmt(r.scan.exposure_us));
  if (!r.scan.exposures_us.empty()) {
    std::string list;
    for (const double e : r.scan.exposures_us) {
      if (!list.empty()) list += ',';
      list += fmt(e);
    }
    kv("exposures_us", list);
  }
  kv("exposure_change_frames", std::to_string(r.scan.exposure_change_frames));
  kv("final_state", r.scan.final_state);
  kv("frames_sent", std::to_string(r.scan.frames_sent));
  kv("frames_dropped", std::to_string(r.scan.frames_dropped));
  kv("duration_ns", std::to_string(r.scan.duration_ns));
  kv("have_edges", r.have_edges ? "1" : "0");
  std::string text_line = r.scan.text;
  for (char& c : text_line) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  kv("text", text_line);

  std::string log = "# kind,monotonic_ns,source\n";
  for (const auto& e : r.log)
    log += "TIMING_EVENT_" + e.kind + "," + std::to_string(e.ns) + "," + std::to_string(e.source) + "\n";
  std::string frames =
      "# sequence,view,projector,pattern,trigger_ns,exposure_start_ns,exposure_end_ns,dequeued_ns,exposure_index\n";
  for (const auto& f : r.frames) {
    frames += std::to_string(f.sequence) + "," + std::to_string(f.view) + "," + std::to_string(f.projector) + "," +
              std::to_string(f.pattern) + "," + std::to_string(f.trigger_ns) + "," +
              std::to_string(f.exposure_start_ns) + "," + std::to_string(f.exposure_end_ns) + "," +
              std::to_string(f.dequeued_ns) + "," + std::to_string(f.exposure_index) + "\n";
  }
  std::string edges = "# offset,rising,monotonic_ns\n";
  for (const auto& e : r.edges) {
    edges += std::to_string(e.offset) + "," + (e.rising ? "1" : "0") + "," + std::to_string(e.ns) + "\n";
  }
  for (const auto& [name, text] : {std::pair{"/scan.txt", &scan}, std::pair{"/timing.csv", &log},
                                   std::pair{"/frames.csv", &frames}, std::pair{"/edges.csv", &edges}}) {
    if (auto s = slproto::write_file_atomically(dir + name, *text); !s) return s;
  }
  return slproto::Ok{};
}

slproto::Result<HilRecord> load_record(const std::string& dir) {
  HilRecord r;
  auto scan_text = read_text_file(dir + "/scan.txt");
  if (!scan_text) return std::move(scan_text).error();
  std::map<std::string, std::string> kv;
  {
    std::istringstream in(*scan_text);
    std::string line;
    while (std::getline(in, line)) {
      const auto eq = line.find('=');
      if (eq != std::string::npos) kv[line.substr(0, eq)] = line.substr(eq + 1);
    }
  }
  const std::string where = dir + "/scan.txt";
  auto need = [&](const char* key) -> slproto::Result<std::string> {
    auto it = kv.find(key);
    if (it == kv.end()) return make_error(Errc::malformed, where + ": missing '" + key + "'");
    return it->second;
  };
  auto need_int = [&](const char* key, auto& out) -> slproto::Status {
    auto v = need(key);
    if (!v) return v.error();
    std::int64_t n = 0;
    if (!parse_i64(*v, n) || n < 0) return make_error(Errc::malformed, where + ": '" + key + "' is not a count");
    out = static_cast<std::remove_reference_t<decltype(out)>>(n);
    return slproto::Ok{};
  };
  auto need_double = [&](const char* key, double& out) -> slproto::Status {
    auto v = need(key);
    if (!v) return v.error();
    if (!parse_double(*v, out)) return make_error(Errc::malformed, where + ": '" + key + "' is not a number");
    return slproto::Ok{};
  };
  int have_edges = 0;
  for (const auto& s : {need_int("views", r.scan.views), need_int("projectors", r.scan.projectors),
                        need_int("patterns", r.scan.patterns), need_double("period_us", r.scan.period_us),
                        need_double("exposure_us", r.scan.exposure_us), need_int("frames_sent", r.scan.frames_sent),
                        need_int("frames_dropped", r.scan.frames_dropped), need_int("duration_ns", r.scan.duration_ns),
                        need_int("have_edges", have_edges)}) {
    if (!s) return s.error();
  }
  r.have_edges = have_edges != 0;
  // Added with brackets: absent in older records, which had one exposure and no change.
  if (kv.count("exposure_change_frames") != 0) {
    if (auto s = need_int("exposure_change_frames", r.scan.exposure_change_frames); !s) return s.error();
  }
  if (auto it = kv.find("exposures_us"); it != kv.end()) {
    for (std::string item : split(it->second, ',')) {
      double e = 0;
      if (!parse_double(item, e) || !(e > 0))
        return make_error(Errc::malformed, where + ": 'exposures_us' holds '" + item.append("', not an exposure"));
      r.scan.exposures_us.push_back(e);
    }
  }
  if (auto v = need("final_state"); v)
    r.scan.final_state = *v;
  else
    return v.error();
  r.scan.text = kv["text"];

  auto log_text = read_text_file(dir + "/timing.csv");
  if (!log_text) return std::move(log_text).error();
  auto log = parse_timing_log(*log_text, dir + "/timing.csv");
  if (!log) return std::move(log).error();
  r.log = std::move(*log);

  auto frames_text = read_text_file(dir + "/frames.csv");
  if (!frames_text) return std::move(frames_text).error();
  const std::string frames_where = dir + "/frames.csv";
  auto status = for_each_row(
      *frames_text, frames_where, 8,
      [&](const std::vector<std::string>& f, int line) -> slproto::Status {
        std::int64_t v[9] = {};
        for (int i = 0; i < static_cast<int>(f.size()); ++i) {
          if (!parse_i64(f[static_cast<std::size_t>(i)], v[i]) || v[i] < 0) {
            return bad_field(frames_where, line, "field " + std::to_string(i + 1), f[static_cast<std::size_t>(i)]);
          }
        }
        FrameRecord fr;
        fr.sequence = static_cast<std::uint64_t>(v[0]);
        fr.view = static_cast<std::uint32_t>(v[1]);
        fr.projector = static_cast<std::uint32_t>(v[2]);
        fr.pattern = static_cast<std::uint32_t>(v[3]);
        fr.trigger_ns = v[4];
        fr.exposure_start_ns = v[5];
        fr.exposure_end_ns = v[6];
        fr.dequeued_ns = v[7];
        if (v[8] >= static_cast<std::int64_t>(r.scan.exposure_count()))
          return bad_field(frames_where, line,
                           "exposure index (the bracket has " + std::to_string(r.scan.exposure_count()) + ")", f[8]);
        fr.exposure_index = static_cast<std::uint32_t>(v[8]);
        r.frames.push_back(fr);
        return slproto::Ok{};
      },
      9);
  if (!status) return status.error();

  auto edges_text = read_text_file(dir + "/edges.csv");
  if (!edges_text) return std::move(edges_text).error();
  auto edges = parse_edges(*edges_text, dir + "/edges.csv");
  if (!edges) return std::move(edges).error();
  r.edges = std::move(*edges);
  return r;
}

}  // namespace slscan::hil
