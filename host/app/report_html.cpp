#include "report_html.hpp"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <map>
#include <optional>
#include <stdexcept>
#include <string_view>
#include <system_error>
#include <utility>

namespace slscan::app {

using nlohmann::json;

namespace {

std::string base64(const unsigned char* data, std::size_t size) {
  static constexpr char alphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((size + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < size; i += 3) {
    const std::uint32_t v = (std::uint32_t{data[i]} << 16) | (std::uint32_t{data[i + 1]} << 8) | data[i + 2];
    out += alphabet[(v >> 18) & 63];
    out += alphabet[(v >> 12) & 63];
    out += alphabet[(v >> 6) & 63];
    out += alphabet[v & 63];
  }
  if (i < size) {
    std::uint32_t v = std::uint32_t{data[i]} << 16;
    if (i + 1 < size) v |= std::uint32_t{data[i + 1]} << 8;
    out += alphabet[(v >> 18) & 63];
    out += alphabet[(v >> 12) & 63];
    out += i + 1 < size ? alphabet[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::string escape(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
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

std::string fixed(double value, int decimals) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*f", decimals, value);
  return buffer;
}

// A report value as table text: numbers with `decimals` places (integers as they are),
// missing values as a dash.
std::string cell(const json& value, int decimals = 3) {
  if (value.is_null()) return "&ndash;";
  if (value.is_boolean()) return value.get<bool>() ? "yes" : "no";
  if (value.is_number_integer()) return std::to_string(value.get<std::int64_t>());
  if (value.is_number_unsigned()) return std::to_string(value.get<std::uint64_t>());
  if (value.is_number()) return fixed(value.get<double>(), decimals);
  if (value.is_string()) return escape(value.get<std::string>());
  return escape(value.dump());
}

// report["a"]["b"]... or null when any step is missing (reports of reprocess lack the board's
// figures, a failed registration lacks residuals).
const json& at(const json& root, std::initializer_list<std::string_view> path) {
  static const json null_value;
  const json* node = &root;
  for (std::string_view key : path) {
    if (!node->is_object()) return null_value;
    const auto it = node->find(key);
    if (it == node->end()) return null_value;
    node = &*it;
  }
  return *node;
}

struct Table {
  std::string html = "<table>";
  explicit Table(std::initializer_list<std::string_view> headers) { head(headers); }
  explicit Table(const std::vector<std::string>& headers) { head(headers); }
  template <class Headers>
  void head(const Headers& headers) {
    html += "<thead><tr>";
    for (const auto& h : headers) html += "<th>" + std::string(h) + "</th>";
    html += "</tr></thead><tbody>";
  }
  void row(const std::vector<std::string>& cells) {
    html += "<tr>";
    for (const auto& c : cells) html += "<td>" + c + "</td>";
    html += "</tr>";
  }
  std::string done() { return html + "</tbody></table>\n"; }
};

std::string key_value_table(const std::vector<std::pair<std::string, std::string>>& rows) {
  std::string html = "<table class=\"kv\"><tbody>";
  for (const auto& [key, value] : rows)
    html.append("<tr><th>").append(key).append("</th><td>").append(value).append("</td></tr>");
  return html + "</tbody></table>\n";
}

std::string summary_section(const json& report) {
  const json& scan = at(report, {"scan"});
  std::size_t both = 0, left = 0, right = 0, rejected = 0;
  for (const auto& view : at(scan, {"views"})) {
    both += view["fusion"].value("both", std::size_t{0});
    left += view["fusion"].value("left_only", std::size_t{0});
    right += view["fusion"].value("right_only", std::size_t{0});
    rejected += view["fusion"].value("rejected", std::size_t{0});
  }
  std::vector<std::pair<std::string, std::string>> rows{
      {"views", std::to_string(at(scan, {"views"}).size())},
      {"model points", cell(at(scan, {"model", "points"}))},
      {"merged before outlier removal", cell(at(scan, {"model", "merged_points"}))},
      {"outliers removed", cell(at(scan, {"model", "outliers_removed"}))},
      {"fusion (all views)", std::to_string(both) + " both, " + std::to_string(left) + " left only, " +
                                 std::to_string(right) + " right only, " + std::to_string(rejected) + " rejected"},
  };
  if (!at(scan, {"mesh"}).is_null())
    rows.push_back({"mesh", cell(at(scan, {"mesh", "vertices"})) + " vertices, " +
                                cell(at(scan, {"mesh", "triangles"})) + " triangles, " +
                                (at(scan, {"mesh", "closed"}) == true ? "closed" : "open") + ", cell " +
                                cell(at(scan, {"mesh", "cell_mm"})) + " mm"});
  rows.push_back({"capture", cell(at(report, {"capture", "file"})) + ": " + cell(at(report, {"capture", "frames"})) +
                                 " frames, " +
                                 (at(report, {"capture", "complete"}) == true ? "complete" : "<b>incomplete</b>")});
  if (!at(report, {"capture", "truncated_at_byte"}).is_null())
    rows.push_back({"truncated at byte", cell(at(report, {"capture", "truncated_at_byte"}))});
  const json& missing = at(report, {"capture", "missing"});
  if (missing.is_array() && !missing.empty()) {
    std::string list = "<ul>";
    for (const auto& line : missing) list += "<li>" + cell(line) + "</li>";
    rows.push_back({"missing", list + "</ul>"});
  }
  if (!at(report, {"board", "name"}).is_null())
    rows.push_back({"board", cell(at(report, {"board", "name"})) + " (" + cell(at(report, {"board", "software"})) +
                                 "), " + cell(at(report, {"board_frames_dropped"})) + " frames dropped"});
  if (const json& link = at(report, {"camera_link"}); link.is_object())
    rows.push_back({"camera link", cell(link.value("frames_lost", json())) + " frames lost, " +
                                       cell(link.value("packets_missing", json())) + " packets missing, " +
                                       cell(link.value("packets_resent", json())) + " resent (" +
                                       cell(link.value("resend_requests", json())) + " resend requests)"});
  return "<section id=\"summary\"><h2>Summary</h2>\n" + key_value_table(rows) + "</section>\n";
}

// A judged figure ({"value_um", "mpe_um", "verdict"}) as "12.3 &micro;m PASS (MPE 20)".
std::string judged_cell(const json& figure, bool sign = false) {
  if (!figure.is_object() || !figure.contains("value_um")) return "&ndash;";
  const double v = figure["value_um"].get<double>();
  std::string out = (sign && v >= 0 ? "+" : "") + fixed(v, 1) + " &micro;m";
  if (figure.contains("mpe_um")) {
    const bool pass = figure.value("verdict", "") == "PASS";
    out += std::string(" <span class=\"") + (pass ? "pass\">PASS" : "fail\">FAIL") + "</span> (MPE " +
           fixed(figure["mpe_um"].get<double>(), 1) + " &micro;m)";
  } else {
    out += " <span class=\"note\">(no MPE given)</span>";
  }
  return out;
}

std::string measurement_section(const json& report) {
  const json& bar = at(report, {"measurement", "ball_bar"});
  if (bar.is_null()) return {};
  std::string html = "<section id=\"measurement\"><h2>Ball bar (VDI/VDE 2634-2)</h2>\n";
  if (bar.contains("error")) return html + "<p class=\"warn\">Not measured: " + cell(bar["error"]) + "</p></section>\n";
  html += "<p class=\"note\">Measured from the scan alone, as a user measures (no ground truth). " +
          (at(bar, {"region_rule", "text"}).is_null()
               ? std::string()
               : "Each sphere's region: " + cell(bar["region_rule"]["text"]) + ". ") +
          "PF = range of the radial residuals, PS = fitted minus calibrated diameter, SD = centre distance minus "
          "the calibrated reference length (docs/inspection.md).</p>\n";
  html += key_value_table({{"centre distance", cell(bar["centre_distance_mm"], 4) + " mm (reference " +
                                                   cell(at(bar, {"reference_distance_mm"}), 4) + " mm)"},
                           {"SD, sphere-spacing error", judged_cell(at(bar, {"sd"}), true)}});
  Table spheres({"sphere", "PF, probing error form", "PF with every point", "PS, probing error size",
                 "diameter / calibrated (mm)", "fit RMS (&micro;m)", "points (left out)", "joint cones",
                 "centre (mm)"});
  std::size_t i = 0;
  for (const auto& s : bar["spheres"]) {
    const json& c = s["centre_mm"];
    std::string cones;
    for (const auto& j : at(s, {"joints"}))
      cones += (cones.empty() ? "" : ", ") + fixed(j["half_angle_deg"].get<double>(), 1) + "&deg;";
    spheres.row({std::to_string(i++), judged_cell(at(s, {"pf"})), cell(at(s, {"pf_all_points_um"}), 1) + " &micro;m",
                 judged_cell(at(s, {"ps"}), true),
                 cell(s["diameter_mm"], 4) + " / " + cell(at(s, {"calibrated_diameter_mm"}), 4),
                 cell(at(s, {"rms_um"}), 1), cell(at(s, {"points"})) + " (" + cell(at(s, {"left_out"})) + ")",
                 cones.empty() ? "none" : cell(at(s, {"cone_points"})) + " points in " + cones,
                 "(" + cell(c[0], 3) + ", " + cell(c[1], 3) + ", " + cell(c[2], 3) + ")"});
  }
  return html + spheres.done() + "</section>\n";
}

std::string views_section(const json& report) {
  const json& views = at(report, {"scan", "views"});
  Table counts({"view", "angle (&deg;)", "decoded L / R", "triangulated L / R", "fusion both / L / R / rejected",
                "flying pixels removed", "turntable denoise: kept / below / above / outside", "points"});
  for (const auto& v : views) {
    std::string decoded, triangulated;
    for (const auto& p : v["projectors"]) {
      if (!decoded.empty()) {
        decoded += " / ";
        triangulated += " / ";
      }
      decoded += p["present"] == true ? cell(at(p, {"decode", "valid"})) : "&ndash;";
      triangulated += p["present"] == true ? cell(at(p, {"triangulate", "valid"})) : "&ndash;";
    }
    const json& f = v["fusion"];
    const json& d = v["turntable_denoise"];
    counts.row(
        {cell(v["view_index"]), cell(v["commanded_angle_deg"], 1), decoded, triangulated,
         cell(f["both"]) + " / " + cell(f["left_only"]) + " / " + cell(f["right_only"]) + " / " + cell(f["rejected"]),
         cell(v["flying_pixels_removed"]),
         cell(d["kept"]) + " / " + cell(d["below_min_height"]) + " / " + cell(d["above_max_height"]) + " / " +
             cell(d["outside_radius"]),
         cell(v["points"])});
  }
  return "<section id=\"views\"><h2>Counts per view and stage</h2>\n" + counts.done() + "</section>\n";
}

std::string registration_section(const json& report) {
  const json& reg = at(report, {"scan", "registration"});
  std::string html = "<section id=\"registration\"><h2>Registration (ICP)</h2>\n";
  if (reg["applied"] != true) {
    html += "<p class=\"warn\">Not applied";
    if (reg.contains("error")) html += ": " + cell(reg["error"]);
    return html + ". The views are placed by the turntable angles alone.</p></section>\n";
  }
  const bool turntable = reg.contains("axis_tilt_deg");
  html += "<p>" + cell(reg["iterations"]) + " iterations";
  if (reg.contains("mode")) html += ", mode " + cell(reg["mode"]);
  if (turntable)
    html += ": one rotation axis for every view, moved " + cell(reg["axis_tilt_deg"], 4) + "&deg; and " +
            cell(reg["axis_shift_mm"], 4) + " mm from the calibrated one, and one angle correction per view";
  html += ".</p>\n";
  std::vector<std::string> columns{"view", "correction (&deg;)", "correction (mm)"};
  if (turntable) columns.emplace_back("angle correction (&deg;)");
  columns.insert(columns.end(), {"residual RMS (mm)", "correspondences"});
  Table views(columns);
  for (const auto& v : reg["views"]) {
    std::vector<std::string> row{cell(v["view"]), cell(v["correction_deg"], 4), cell(v["correction_mm"], 4)};
    if (turntable) row.push_back(cell(v["angle_correction_deg"], 4));
    row.insert(row.end(), {cell(v["residual_rms_mm"], 4), cell(v["correspondences"])});
    views.row(row);
  }
  html += views.done();
  Table pairs({"views", "RMS (mm)", "correspondences"});
  for (const auto& p : reg["pairs"])
    pairs.row(
        {cell(p["views"][0]) + " &ndash; " + cell(p["views"][1]), cell(p["rms_mm"], 4), cell(p["correspondences"])});
  return html + "<h3>Pairs</h3>\n" + pairs.done() + "</section>\n";
}

std::string timings_section(const json& report) {
  std::string html = "<section id=\"timings\"><h2>Timings</h2>\n";
  std::vector<std::pair<std::string, std::string>> rows;
  if (!at(report, {"last_frame_to_model_s"}).is_null())
    rows.push_back({"last frame to model", cell(report["last_frame_to_model_s"], 2) + " s"});
  for (const auto& [stage, ms] : at(report, {"scan", "stage_ms"}).items())
    rows.push_back({escape(stage), cell(ms, 1) + " ms"});
  html += "<h3>Stages after the last frame</h3>\n" + key_value_table(rows);
  Table per_view({"view", "decode L / R (ms)", "triangulate L / R (ms)", "fuse (ms)"});
  for (const auto& v : at(report, {"scan", "views"})) {
    std::string decode, triangulate;
    for (const auto& p : v["projectors"]) {
      if (!decode.empty()) {
        decode += " / ";
        triangulate += " / ";
      }
      decode += cell(p["decode_ms"], 1);
      triangulate += cell(p["triangulate_ms"], 1);
    }
    per_view.row({cell(v["view_index"]), decode, triangulate, cell(v["fuse_ms"], 1)});
  }
  html += "<h3>Per view (while the next view streams in)</h3>\n" + per_view.done();
  const json& board = at(report, {"board_timing"});
  if (board.is_array() && !board.empty()) {
    Table t({"board event", "count", "mean (&micro;s)", "stddev (&micro;s)", "p99 (&micro;s)", "max (&micro;s)"});
    for (const auto& e : board)
      t.row({cell(e["name"]), cell(e["count"]), cell(e["mean_us"], 1), cell(e["stddev_us"], 1), cell(e["p99_us"], 1),
             cell(e["max_us"], 1)});
    html += "<h3>On the board</h3>\n" + t.done();
  }
  return html + "</section>\n";
}

// "view_<i>_<kind>.png" -> (i, kind); nothing for any other name.
std::optional<std::pair<int, std::string>> view_picture(const std::string& name) {
  constexpr std::string_view prefix = "view_";
  if (name.rfind(prefix, 0) != 0) return std::nullopt;
  const char* end = name.data() + name.size();
  int index = 0;
  auto [rest, error] = std::from_chars(name.data() + prefix.size(), end, index);
  if (error != std::errc{} || rest == end || *rest != '_') return std::nullopt;
  std::string kind;
  for (++rest; rest != end && ((*rest >= 'a' && *rest <= 'z') || *rest == '_'); ++rest) kind += *rest;
  if (kind.empty()) return std::nullopt;
  return std::pair{index, kind};
}

std::string pictures_section(const std::vector<std::string>& pictures) {
  // Group pictures/view_<i>_<kind>.png by view; everything else is a model preview.
  std::vector<std::string> previews;
  std::map<int, std::map<std::string, std::string>> views;
  for (const auto& path : pictures) {
    const std::string name = path.substr(path.find_last_of('/') + 1);
    if (const auto view = view_picture(name)) {
      views[view->first][view->second] = path;
    } else {
      previews.push_back(path);
    }
  }
  std::string html =
      "<section id=\"pictures\"><h2>Pictures</h2>\n<h3>Rendered previews of the model</h3>\n<div class=\"grid\">";
  for (const auto& p : previews)
    html += "<figure><a href=\"" + escape(p) + "\"><img src=\"" + escape(p) + "\" alt=\"" + escape(p) +
            "\" loading=\"lazy\"></a><figcaption>" + escape(p.substr(p.find_last_of('/') + 1)) +
            "</figcaption></figure>";
  html +=
      "</div>\n<h3>Per view: depth, quality, fusion source</h3>\n"
      "<p class=\"note\">Depth: colour over the view's own range. Quality: brighter is better. Fusion source: "
      "<span class=\"key\" style=\"background:#3cc83c\"></span>both projectors, "
      "<span class=\"key\" style=\"background:#2878e6\"></span>left only, "
      "<span class=\"key\" style=\"background:#e63c28\"></span>right only, "
      "<span class=\"key\" style=\"background:#fff\"></span>rejected, black: nothing measured.</p>\n";
  for (const auto& [index, kinds] : views) {
    html += "<h4>View " + std::to_string(index) + "</h4><div class=\"grid\">";
    for (const char* kind : {"depth", "quality", "fusion_source"}) {
      const auto it = kinds.find(kind);
      if (it == kinds.end()) continue;
      html += "<figure><a href=\"" + escape(it->second) + "\"><img src=\"" + escape(it->second) +
              "\" loading=\"lazy\" alt=\"view " + std::to_string(index) + " " + kind + "\"></a><figcaption>" + kind +
              "</figcaption></figure>";
    }
    html += "</div>\n";
  }
  return html + "</section>\n";
}

std::string provenance_section(const json& report) {
  const auto dash_if_empty = [](const json& value) {
    return value.is_string() && value.get<std::string>().empty() ? std::string("&ndash;") : cell(value);
  };
  std::vector<std::pair<std::string, std::string>> rows{
      {"run", cell(at(report, {"run", "command"})) + ", started " + cell(at(report, {"run", "started_utc"}))},
      {"part id", dash_if_empty(at(report, {"run", "part_id"}))},
      {"operator", dash_if_empty(at(report, {"run", "operator"}))},
      {"slscan", cell(at(report, {"software", "slscan"}))},
      {"protocol", cell(at(report, {"software", "protocol_version"}))},
      {"calibration", cell(at(report, {"calibration", "file"})) + " (" + cell(at(report, {"calibration", "source"})) +
                          ", " + cell(at(report, {"calibration", "created_by"})) + ")"},
      {"calibration SHA-256", "<code>" + cell(at(report, {"calibration", "sha256"})) + "</code>"},
      {"calibration file written", cell(at(report, {"calibration", "file_utc"})) + " (" +
                                       cell(at(report, {"calibration", "age_days"}), 1) + " days before the run)"},
      {"camera reprojection RMS", cell(at(report, {"calibration", "camera_reprojection_rms_px"}), 4) + " px"},
      {"capture SHA-256", "<code>" + cell(at(report, {"capture", "sha256"})) + "</code>"},
      {"capture file written", cell(at(report, {"capture", "file_utc"}))}};
  return "<section id=\"provenance\"><h2>Provenance</h2>\n" + key_value_table(rows) +
         "<details><summary>Reconstruction parameters</summary><pre>" + escape(at(report, {"parameters"}).dump(2)) +
         "</pre></details>\n</section>\n";
}

// A link to every file of the run in the folder (report.json "files").
std::string files_section(const json& report) {
  const json& files = at(report, {"files"});
  if (!files.is_array() || files.empty()) return "";
  std::string html = "<section id=\"files\"><h2>Files</h2>\n<ul class=\"files\">";
  for (const json& file : files)
    if (file.is_string()) html += "<li><a href=\"" + cell(file) + "\">" + cell(file) + "</a></li>";
  return html + "</ul>\n</section>\n";
}

constexpr std::string_view style = R"(
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1200px; padding: 0 16px 40px; color: #1d2127; }
h1 { margin: 18px 0 4px; } h2 { margin-top: 32px; border-bottom: 1px solid #d6dae0; } h4 { margin: 14px 0 4px; }
table { border-collapse: collapse; margin: 8px 0; } th, td { padding: 3px 10px; border-bottom: 1px solid #e4e7eb; text-align: right; }
th { background: #f3f5f7; } td:first-child { text-align: left; } table.kv th, table.kv td { text-align: left; } ul { margin: 0; padding-left: 18px; }
#viewer { width: 100%; height: 560px; background: #20242a; position: relative; }
#viewer canvas { display: block; }
.viewer-missing, .viewer-error { color: #f3c0b8; padding: 24px; margin: 0; }
.note { color: #5b6470; } .warn { color: #a3400e; } .pass { color: #1a7f37; font-weight: 600; } .fail { color: #b42318; font-weight: 600; }
.grid { display: flex; flex-wrap: wrap; gap: 10px; } figure { margin: 0; } figure img { width: 280px; display: block; border: 1px solid #ccd1d8; }
figcaption { font-size: 12px; color: #5b6470; } .key { display: inline-block; width: 12px; height: 12px; border: 1px solid #888; margin: 0 4px 0 10px; vertical-align: middle; }
pre { background: #f3f5f7; padding: 10px; overflow: auto; max-height: 400px; }
)";

}  // namespace

json embed_cloud(const core::PointCloud& cloud, std::size_t max_points) {
  const std::size_t total = cloud.size();
  const std::size_t count = std::min(total, max_points);
  std::vector<std::size_t> chosen(count);
  // Evenly strided in the model's own order (views one after another), so every view keeps its
  // share of the points.
  for (std::size_t i = 0; i < count; ++i) chosen[i] = count == total ? i : i * total / count;
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(0), hi = Eigen::Vector3f::Constant(0);
  if (count) lo = hi = cloud.points[chosen[0]];
  for (std::size_t i : chosen) {
    lo = lo.cwiseMin(cloud.points[i]);
    hi = hi.cwiseMax(cloud.points[i]);
  }
  Eigen::Vector3f scale;
  for (int k = 0; k < 3; ++k) scale[k] = hi[k] > lo[k] ? (hi[k] - lo[k]) / 65535.0f : 1.0f;
  std::vector<std::uint16_t> positions(3 * count);
  std::vector<std::int8_t> normals(cloud.has_normals() ? 3 * count : 0);
  for (std::size_t j = 0; j < count; ++j) {
    const std::size_t i = chosen[j];
    for (int k = 0; k < 3; ++k) {
      const float q = std::round((cloud.points[i][k] - lo[k]) / scale[k]);
      positions[3 * j + static_cast<std::size_t>(k)] = static_cast<std::uint16_t>(std::clamp(q, 0.0f, 65535.0f));
      if (!normals.empty())
        normals[3 * j + static_cast<std::size_t>(k)] =
            static_cast<std::int8_t>(std::clamp(std::round(127.0f * cloud.normals[i][k]), -127.0f, 127.0f));
    }
  }
  // The viewer reads the uint16 array in the machine's byte order; every platform slscan targets
  // and every browser that runs WebGL is little-endian.
  static_assert(std::endian::native == std::endian::little, "the embedded cloud is little-endian");
  // A point a bit wider than the mean spacing over the bounding box's surface, so the cloud reads
  // as a surface at the default zoom.
  const Eigen::Vector3f extent = hi - lo;
  const double area =
      2.0 * (double{extent.x()} * extent.y() + double{extent.y()} * extent.z() + double{extent.z()} * extent.x());
  const double point_size =
      count ? std::clamp(1.5 * std::sqrt(area / 2.0 / static_cast<double>(count)), 0.05, 5.0) : 1.0;
  return {{"count", count},
          {"total", total},
          {"origin", {lo.x(), lo.y(), lo.z()}},
          {"scale", {scale.x(), scale.y(), scale.z()}},
          {"point_size_mm", point_size},
          {"positions", base64(reinterpret_cast<const unsigned char*>(positions.data()), 2 * positions.size())},
          {"normals", base64(reinterpret_cast<const unsigned char*>(normals.data()), normals.size())}};
}

// The decoder's self-checks: the findings first (they say what is wrong and what to change),
// then the measured consistency per view and projector.
std::string self_check_section(const json& report) {
  const json& views = at(report, {"scan", "views"});
  std::string html = "<section id=\"self-check\"><h2>Self-checks of the decode</h2>\n";
  const json& findings = at(report, {"scan", "self_check", "findings"});
  if (findings.is_array() && !findings.empty()) {
    html += "<p class=\"warn\">The data contradicts its description:</p><ul>";
    for (const auto& f : findings) html += "<li class=\"warn\">" + cell(f) + "</li>";
    html += "</ul>\n";
  } else {
    html += "<p class=\"note\">Every redundant code agrees with the plan.</p>\n";
  }
  Table table({"view", "projector", "sampled px", "phase offset (rad)", "direction", "complementary", "Gray continuity",
               "period jumps", "sinusoid", "clipped white / black / Gray / phase"});
  auto share = [](const json& v) { return v.is_number() ? fixed(100 * v.get<double>(), 1) + " %" : "&ndash;"; };
  for (const auto& v : views)
    for (const auto& p : v["projectors"]) {
      if (p["present"] != true || !p.contains("checks")) continue;
      const json& c = p["checks"];
      const json& k = at(p, {"decode", "clipped_by_kind"});
      table.row({cell(v["view_index"]), cell(p["side"]), cell(c["sampled_pixels"]),
                 c.value("phase_offset_rad", json()).is_number() ? cell(c["phase_offset_rad"], 3) : "&ndash;",
                 share(c.value("phase_direction_agreement", json())), share(c.value("complementary_agreement", json())),
                 share(c["gray_continuity"]), share(c["period_jump_rate"]), share(c.value("sinusoid_share", json())),
                 k.is_null() ? "&ndash;"
                             : cell(k["white"]) + " / " + cell(k["black"]) + " / " + cell(k["gray"]) + " / " +
                                   cell(k["phase"])});
    }
  return html + table.done() + "</section>\n";
}

std::string render_report_html(const json& report, const core::PointCloud& model,
                               const std::vector<std::string>& pictures, const ReportViewer& viewer,
                               const ReportHtmlOptions& options) {
  std::string html =
      "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n<title>slscan report</title>\n";
  html += "<meta name=\"generator\" content=\"slscan " + cell(at(report, {"software", "slscan"})) + "\">\n";
  html += "<style>" + std::string(style) + "</style></head>\n<body>\n<h1>slscan report</h1>\n";
  const json& bar = at(report, {"measurement", "ball_bar"});
  std::string headline = cell(at(report, {"scan", "model", "points"})) + " points from " +
                         std::to_string(at(report, {"scan", "views"}).size()) + " views";
  if (!bar.is_null() && bar.contains("centre_distance_mm"))
    headline += "; ball bar " + cell(bar["centre_distance_mm"], 4) + " mm (error " +
                cell(at(bar, {"distance_error_um"}), 1) + " &micro;m)";
  html += "<p class=\"note\">" + headline + ". The same figures are in report.json.</p>\n";

  const bool with_viewer = !viewer.js.empty() && model.size() > 0;
  html += "<section id=\"viewer-section\"><h2>Fused point cloud</h2>\n";
  json cloud;
  if (with_viewer) {
    cloud = embed_cloud(model, options.max_points);
    html += "<div id=\"viewer\" data-status=\"loading\" data-points=\"" +
            std::to_string(cloud["count"].get<std::size_t>()) + "\"></div>\n<p class=\"note\">Showing " +
            std::to_string(cloud["count"].get<std::size_t>()) + " of " + std::to_string(model.size()) +
            " points, coloured by height and shaded by normal. Drag to rotate, scroll to zoom, right-drag to pan; "
            "<button id=\"viewer-reset\" type=\"button\">reset view</button></p>\n";
  } else {
    const std::string reason = model.size() == 0               ? std::string("the model has no points")
                               : viewer.missing_reason.empty() ? std::string("no viewer code was given")
                                                               : std::string(viewer.missing_reason);
    html += "<div id=\"viewer\" data-status=\"missing\" data-reason=\"" + escape(reason) +
            "\"><p class=\"viewer-missing\">The interactive 3D viewer is missing from this report: " + escape(reason) +
            ". The model is in model.ply; the previews below show it.</p></div>\n";
  }
  html += "</section>\n";
  html += summary_section(report) + self_check_section(report) + measurement_section(report) + views_section(report) +
          registration_section(report) + timings_section(report) + pictures_section(pictures) +
          provenance_section(report) + files_section(report);
  if (with_viewer) {
    if (viewer.js.find("</script") != std::string_view::npos)
      throw std::logic_error("the viewer bundle holds \"</script\" and cannot be inlined");
    // The cloud holds only numbers and base64, which cannot end the element early.
    html += "<script type=\"application/json\" id=\"slscan-cloud\">" + cloud.dump() + "</script>\n<script>";
    html += viewer.js;
    html += "</script>\n";
  }
  return html + "</body></html>\n";
}

}  // namespace slscan::app
