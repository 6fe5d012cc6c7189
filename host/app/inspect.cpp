#include "inspect.hpp"

#include <sys/stat.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "slscan/io/mesh_file.hpp"
#include "slscan/io/ply.hpp"
#include "slscan/session/file_hash.hpp"

#ifndef SLSCAN_VERSION
#define SLSCAN_VERSION "unknown"
#endif

namespace slscan::app {

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

std::string fmt(const char* format, auto... args) {
  char buffer[600];
  std::snprintf(buffer, sizeof buffer, format, args...);
  return buffer;
}

std::string utc_text(std::time_t t) {
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof buffer, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

std::string file_time_utc(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return "";
  return utc_text(st.st_mtime);
}

core::NominalUnits parse_units(const std::string& s) {
  if (s == "auto") return core::NominalUnits::auto_detect;
  if (s == "mm") return core::NominalUnits::mm;
  if (s == "m") return core::NominalUnits::m;
  if (s == "in") return core::NominalUnits::in;
  throw std::invalid_argument("--nominal-units must be auto, mm, m or in, not '" + s + "'");
}

json isometry_json(const Eigen::Isometry3d& t) {
  json rows = json::array();
  for (int r = 0; r < 4; ++r) rows.push_back({t.matrix()(r, 0), t.matrix()(r, 1), t.matrix()(r, 2), t.matrix()(r, 3)});
  return rows;
}

std::string html_escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '&':
        out += "&amp;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

// The histogram as an inline SVG: bars coloured like the map, the tolerance band marked.
std::string histogram_svg(const core::Histogram& h, const std::optional<double>& tolerance_mm) {
  const int w = 640, hgt = 220, left = 50, bottom = 30;
  std::size_t peak = 1;
  for (auto c : h.counts) peak = std::max(peak, c);
  const double bin_w = static_cast<double>(w - left - 10) / static_cast<double>(h.counts.size());
  std::string svg = fmt("<svg xmlns='http://www.w3.org/2000/svg' width='%d' height='%d' font-size='11'>", w, hgt);
  for (std::size_t i = 0; i < h.counts.size(); ++i) {
    const double centre =
        -h.range_mm + (static_cast<double>(i) + 0.5) * 2 * h.range_mm / static_cast<double>(h.counts.size());
    const auto c = deviation_colour(static_cast<float>(centre), h.range_mm);
    const double bar = (hgt - bottom - 10.0) * static_cast<double>(h.counts[i]) / static_cast<double>(peak);
    svg += fmt("<rect x='%.1f' y='%.1f' width='%.1f' height='%.1f' fill='rgb(%d,%d,%d)'/>",
               left + static_cast<double>(i) * bin_w, hgt - bottom - bar, bin_w * 0.95, bar, c[0], c[1], c[2]);
  }
  for (int k = 0; k <= 4; ++k) {
    const double x = left + k * (w - left - 10) / 4.0;
    svg += fmt("<text x='%.1f' y='%d' text-anchor='middle'>%+.0f um</text>", x, hgt - 10,
               1e3 * h.range_mm * (k / 2.0 - 1));
  }
  if (tolerance_mm && *tolerance_mm < h.range_mm * 1.0001) {
    for (double s : {-1.0, 1.0}) {
      const double x = left + (s * *tolerance_mm + h.range_mm) / (2 * h.range_mm) * (w - left - 10);
      svg +=
          fmt("<line x1='%.1f' y1='5' x2='%.1f' y2='%d' stroke='black' stroke-dasharray='4,3'/>", x, x, hgt - bottom);
    }
  }
  svg += fmt("<text x='5' y='15'>%zu</text><text x='5' y='%d'>0</text>", peak, hgt - bottom);
  svg += "</svg>";
  return svg;
}

}  // namespace

int run_inspect(const InspectCommand& command, const Console& console) {
  const core::NominalUnits units_requested = parse_units(command.nominal_units);
  if (command.tolerance_mm && !(*command.tolerance_mm > 0))
    throw std::invalid_argument("--tolerance must be positive (mm)");
  if (!(command.pass_percent > 0 && command.pass_percent <= 100))
    throw std::invalid_argument("--pass-percent must be in (0, 100]");
  // Everything is read, checked and computed before anything is written: a refused input
  // leaves no output folder behind.
  core::PointCloud scan = io::read_ply(command.model_path);
  if (scan.points.empty()) throw std::invalid_argument(command.model_path + ": the scan has no points");
  for (std::size_t i = 0; i < scan.points.size(); ++i)
    if (!scan.points[i].allFinite())
      throw std::invalid_argument(command.model_path + ": point " + std::to_string(i) +
                                  " is not finite (NaN or infinite coordinate)");
  core::TriangleMesh mesh = io::read_mesh(command.nominal_path);
  try {
    core::check_nominal_mesh(mesh, false);  // the winding is made consistent below
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(command.nominal_path + ": " + e.what());
  }
  Eigen::AlignedBox3f box;
  for (const auto& v : mesh.vertices) box.extend(v);
  const double nominal_extent = box.diagonal().norm();
  const double scan_extent = core::robust_extent(scan.points);
  core::UnitsDecision units;
  try {
    units = core::decide_nominal_units(scan_extent, nominal_extent, units_requested);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(command.nominal_path + ": " + e.what());
  }
  if (units.scale_to_mm != 1)
    for (auto& v : mesh.vertices) v *= static_cast<float>(units.scale_to_mm);
  console.info(fmt("nominal %s: %zu triangles, unit %s (%s)", command.nominal_path.c_str(), mesh.triangles.size(),
                   units.units.c_str(), units.reason.c_str()));
  std::optional<core::NominalSurface> built;
  try {
    built.emplace(std::move(mesh));
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(command.nominal_path + ": " + e.what());
  }
  const core::NominalSurface& nominal = *built;
  if (nominal.reoriented_triangles() > 0)
    console.warn(command.nominal_path + ": " + std::to_string(nominal.reoriented_triangles()) +
                 " triangles were wound against their neighbours and have been turned");

  core::InspectOptions options;
  options.tolerance_mm = command.tolerance_mm;
  options.pass_share = command.pass_percent / 100;
  options.max_distance_mm = command.max_distance_mm;
  options.coarse_search = !command.scan_frame_only;
  core::InspectionResult result;
  try {
    result = core::inspect(scan, nominal, options);
  } catch (const std::invalid_argument&) {
    throw;
  } catch (const std::exception& e) {  // no overlap: the part is not this nominal, or not found
    console.warn(command.model_path + " against " + command.nominal_path + ": " + e.what());
    return exit_measurement;
  }
  const core::DeviationStats& s = result.stats;
  const core::Alignment& a = result.alignment;

  // The figures.
  json percentiles = json::object();
  for (const auto& [pct, value] : s.percentiles_mm) percentiles[fmt("p%g", pct)] = 1e3 * value;
  json histogram = {{"range_um", 1e3 * result.histogram.range_mm},
                    {"bin_um", 2e3 * result.histogram.range_mm / static_cast<double>(result.histogram.counts.size())},
                    {"counts", result.histogram.counts},
                    {"below_range", result.histogram.below},
                    {"above_range", result.histogram.above}};
  std::string verdict = "not judged (no --tolerance)";
  if (s.pass) verdict = *s.pass ? "PASS" : "FAIL";
  const auto now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  json provenance = {{"inspected_utc", utc_text(now)},
                     {"scan_file", command.model_path},
                     {"scan_file_utc", file_time_utc(command.model_path)},
                     {"scan_sha256", session::sha256_file(command.model_path)},
                     {"nominal_file", command.nominal_path},
                     {"nominal_sha256", session::sha256_file(command.nominal_path)},
                     {"part_id", command.part_id},
                     {"operator", command.operator_name},
                     {"software", {{"slscan", SLSCAN_VERSION}}}};
  if (!command.calibration_path.empty())
    provenance["calibration"] = {{"file", command.calibration_path},
                                 {"sha256", session::sha256_file(command.calibration_path)},
                                 {"file_utc", file_time_utc(command.calibration_path)}};
  json inspection = {
      {"procedure",
       "best fit of the scan onto the nominal (robust point-to-plane ICP on exact closest points of the mesh), then "
       "the signed distance of every scan point to the nominal surface (+ outside, along the normals); points "
       "farther than max_distance_mm are not on the part and left out of the figures"},
      {"nominal",
       {{"file", command.nominal_path},
        {"triangles", nominal.mesh().triangles.size()},
        {"units", units.units},
        {"scale_to_mm", units.scale_to_mm},
        {"units_reason", units.reason},
        {"area_mm2", nominal.area_mm2()}}},
      {"alignment",
       {{"method", a.method},
        {"candidates_tried", a.candidates_tried},
        {"nominal_from_scan", isometry_json(a.nominal_from_scan)},
        {"rotation_deg", a.rotation_deg},
        {"translation_mm", a.translation_mm},
        {"fit_rms_um", 1e3 * a.fit_rms_mm},
        {"fit_inliers", a.fit_inliers},
        {"iterations", a.iterations}}},
      {"points", s.points},
      {"matched", s.matched},
      {"unmatched", s.unmatched},
      {"max_distance_mm", command.max_distance_mm},
      {"mean_um", 1e3 * s.mean_mm},
      {"rms_um", 1e3 * s.rms_mm},
      {"std_um", 1e3 * s.std_mm},
      {"min_um", 1e3 * s.min_mm},
      {"max_um", 1e3 * s.max_mm},
      {"abs_p95_um", 1e3 * s.abs_p95_mm},
      {"abs_p99_um", 1e3 * s.abs_p99_mm},
      {"percentiles_um", percentiles},
      {"histogram", histogram},
      {"colour_range_um", 1e3 * result.display_range_mm},
      {"verdict", verdict}};
  if (command.tolerance_mm) {
    inspection["tolerance_mm"] = *command.tolerance_mm;
    inspection["pass_percent"] = command.pass_percent;
    inspection["within_tolerance_percent"] = 100 * *s.share_within;
  }
  const fs::path out(command.output_dir);
  json files = {{"deviation_ply", "deviation.ply"},
                {"deviation_png", "deviation.png"},
                {"report_json", "report.json"},
                {"report_html", "report.html"}};
  const json report = {{"inspection", inspection}, {"provenance", provenance}, {"files", files}};

  std::vector<std::string> caption{
      fmt("%s vs %s: deviation from nominal", fs::path(command.model_path).filename().c_str(),
          fs::path(command.nominal_path).filename().c_str()),
      fmt("RMS %.1f um, mean %+.1f um, |d| p99 %.1f um over %zu points", 1e3 * s.rms_mm, 1e3 * s.mean_mm,
          1e3 * s.abs_p99_mm, s.matched)};
  if (command.tolerance_mm)
    caption.push_back(fmt("tolerance +/-%.0f um: %.2f %% within, %s", 1e3 * *command.tolerance_mm,
                          100 * *s.share_within, verdict.c_str()));
  const cv::Mat picture =
      deviation_picture(result.aligned_points, result.deviation_mm, result.display_range_mm, caption);
  std::vector<unsigned char> png;
  if (!cv::imencode(".png", picture, png)) throw io::IoError("PNG encoding failed (deviation picture)");
  std::vector<std::array<std::uint8_t, 3>> colours(result.deviation_mm.size());
  for (std::size_t i = 0; i < colours.size(); ++i)
    colours[i] = deviation_colour(result.deviation_mm[i], result.display_range_mm);

  std::string html =
      "<!doctype html><html><head><meta charset='utf-8'><title>slscan inspect</title><style>"
      "body{font-family:sans-serif;margin:2em}td,th{padding:2px 10px;text-align:left}"
      ".PASS{color:#070}.FAIL{color:#b00}</style></head><body>";
  html += "<h1>Inspection: " + html_escape(fs::path(command.model_path).filename().string()) + " vs " +
          html_escape(fs::path(command.nominal_path).filename().string()) + "</h1>";
  html += "<p class='" + verdict.substr(0, 4) + "'><b>" + html_escape(verdict) + "</b></p><table>";
  auto row = [&](const std::string& k, const std::string& v) {
    html += "<tr><th>" + html_escape(k) + "</th><td>" + html_escape(v) + "</td></tr>";
  };
  if (command.tolerance_mm)
    row("within tolerance", fmt("%.2f %% within +-%.1f um (PASS needs %.1f %%)", 100 * *s.share_within,
                                1e3 * *command.tolerance_mm, command.pass_percent));
  row("RMS / mean / std", fmt("%.1f / %+.1f / %.1f um", 1e3 * s.rms_mm, 1e3 * s.mean_mm, 1e3 * s.std_mm));
  row("min / max", fmt("%+.1f / %+.1f um", 1e3 * s.min_mm, 1e3 * s.max_mm));
  row("|d| p95 / p99", fmt("%.1f / %.1f um", 1e3 * s.abs_p95_mm, 1e3 * s.abs_p99_mm));
  std::string pct_text;
  for (const auto& [pct, value] : s.percentiles_mm) pct_text += fmt("p%g %+.1f  ", pct, 1e3 * value);
  row("percentiles (um)", pct_text);
  row("points", fmt("%zu matched of %zu (%zu farther than %.2f mm: not on the part)", s.matched, s.points, s.unmatched,
                    command.max_distance_mm));
  row("alignment", fmt("%s (%d tried), moved %.3f deg / %.3f mm, fit RMS %.1f um on %zu points", a.method.c_str(),
                       a.candidates_tried, a.rotation_deg, a.translation_mm, 1e3 * a.fit_rms_mm, a.fit_inliers));
  row("nominal",
      fmt("%zu triangles, unit %s (%s)", nominal.mesh().triangles.size(), units.units.c_str(), units.reason.c_str()));
  row("part id / operator", (command.part_id.empty() ? "-" : command.part_id) + " / " +
                                (command.operator_name.empty() ? "-" : command.operator_name));
  row("inspected", provenance["inspected_utc"].get<std::string>() + ", slscan " SLSCAN_VERSION);
  if (provenance.contains("calibration"))
    row("calibration", command.calibration_path + " (sha256 " +
                           provenance["calibration"]["sha256"].get<std::string>().substr(0, 16) + "..., " +
                           provenance["calibration"]["file_utc"].get<std::string>() + ")");
  html += "</table><h2>Deviation map</h2><img src='deviation.png' alt='deviation map' style='max-width:100%'>";
  html += "<h2>Histogram</h2>" + histogram_svg(result.histogram, command.tolerance_mm);
  html +=
      "<h2>Files</h2><ul><li><a href='deviation.ply'>deviation.ply</a> (aligned scan: deviation, matched, "
      "colours)</li><li><a href='deviation.png'>deviation.png</a></li><li><a href='report.json'>report.json</a>"
      "</li></ul></body></html>\n";

  // The set is written into a staging folder and moved in by renames, report.json last (the
  // completion marker, as for scan / reprocess): a failure while writing (disk full) leaves
  // the folder's previous inspection as it was.
  fs::create_directories(out);
  const fs::path stage = out / ".slscan-inspect-staging";
  fs::remove_all(stage);
  fs::create_directories(stage);
  try {
    io::write_deviation_ply((stage / "deviation.ply").string(), result.aligned_points, result.deviation_mm, colours,
                            {"slscan inspect: scan aligned onto " + fs::path(command.nominal_path).filename().string() +
                             ", deviation in mm (+ outside), NaN where unmatched"});
    io::write_file_atomically((stage / "deviation.png").string(),
                              std::string_view(reinterpret_cast<const char*>(png.data()), png.size()));
    io::write_file_atomically((stage / "report.html").string(), html);
    io::write_file_atomically((stage / "report.json").string(), report.dump(2) + "\n");
    fs::remove(out / "report.json");  // an incomplete set never carries a completion marker
    for (const char* name : {"deviation.ply", "deviation.png", "report.html", "report.json"})
      fs::rename(stage / name, out / name);
    fs::remove_all(stage);
  } catch (const std::exception& e) {
    std::error_code ignored;
    fs::remove_all(stage, ignored);
    throw io::IoError(command.output_dir + ": writing the inspection failed (" + e.what() +
                      "); the folder's previous inspection is kept");
  }

  if (command.json) {
    std::printf("%s\n", report.dump(2).c_str());
  } else {
    std::printf("inspection: %s\n", verdict.c_str());
    if (command.tolerance_mm)
      std::printf("  %.2f %% of %zu points within +-%.1f um (PASS needs %.1f %%)\n", 100 * *s.share_within, s.matched,
                  1e3 * *command.tolerance_mm, command.pass_percent);
    std::printf("  deviation: RMS %.1f um, mean %+.1f um, min %+.1f um, max %+.1f um, |d| p99 %.1f um\n",
                1e3 * s.rms_mm, 1e3 * s.mean_mm, 1e3 * s.min_mm, 1e3 * s.max_mm, 1e3 * s.abs_p99_mm);
    std::printf("  alignment: %s, moved %.3f deg / %.3f mm; %zu points farther than %.2f mm left out\n",
                a.method.c_str(), a.rotation_deg, a.translation_mm, s.unmatched, command.max_distance_mm);
    std::printf("  wrote %s/{deviation.ply, deviation.png, report.json, report.html}\n", command.output_dir.c_str());
  }
  return (s.pass && !*s.pass) ? exit_out_of_tolerance : exit_ok;
}

}  // namespace slscan::app
