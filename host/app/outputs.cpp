#include "outputs.hpp"

#include <oneapi/tbb/task_group.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <new>
#include <numbers>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <utility>

#include "report_html.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/io/mesh_file.hpp"
#include "slscan/io/ply.hpp"
#include "slscan/io/stl.hpp"
#include "viewer_bundle.hpp"

namespace slscan::app {

using nlohmann::json;

namespace {

json counts_json(const core::DecodeCounts& c) {
  return {
      {"valid", c.valid},
      {"saturated", c.saturated},
      {"low_contrast", c.low_contrast},
      {"low_modulation", c.low_modulation},
      {"out_of_range", c.out_of_range},
      // Pixels at the clip level in a frame of each kind, whether that invalidated them or not.
      {"clipped_by_kind",
       {{"white", c.clipped.white}, {"black", c.clipped.black}, {"gray", c.clipped.gray}, {"phase", c.clipped.phase}}}};
}

json finite_or_null(bool measured, double v) { return measured && std::isfinite(v) ? json(v) : json(nullptr); }

json checks_json(const core::DecodeChecks& c) {
  json findings = json::array();
  for (const auto& f : c.findings) findings.push_back({{"check", f.check}, {"cause", f.cause}, {"fix", f.fix}});
  json out = {{"ran", c.ran},
              {"flagged", c.flagged()},
              {"findings", findings},
              {"sampled_pixels", c.sampled_pixels},
              {"row_step", c.row_step},
              {"period_jump_rate", finite_or_null(c.ran && c.sampled_pixels > 0, c.period_jump_rate)},
              {"gray_continuity", finite_or_null(c.has_gray, c.gray_continuity)},
              {"gray_flip_rate", c.gray_flip_rate}};
  if (c.has_phase) {
    out["phase_shift_deg"] = c.phase_shift_deg;
    out["sinusoid_share"] = finite_or_null(true, c.sinusoid_share);
    out["phase_offset_rad"] = finite_or_null(c.has_offset, c.phase_offset_rad);
    out["phase_offset_consistency"] = finite_or_null(c.has_offset, c.phase_offset_consistency);
    out["phase_direction_agreement"] = finite_or_null(c.has_direction, c.phase_direction_agreement);
    out["complementary_agreement"] = finite_or_null(c.has_complementary, c.complementary_agreement);
  }
  return out;
}

json counts_json(const core::TriangulateCounts& c) {
  return {{"valid", c.valid},
          {"not_decoded", c.not_decoded},
          {"no_intersection", c.no_intersection},
          {"not_converged", c.not_converged},
          {"outside_frustum", c.outside_frustum},
          {"outside_depth", c.outside_depth}};
}

// The mesher's steps in their order (an object would sort them by name).
json step_ms_json(const core::MeshStats& stats) {
  json steps = json::array();
  for (const auto& [step, ms] : stats.step_ms) steps.push_back({{"step", step}, {"ms", ms}});
  return steps;
}

json isometry_json(const Eigen::Isometry3d& t) {
  json rows = json::array();
  for (int r = 0; r < 4; ++r) rows.push_back({t.matrix()(r, 0), t.matrix()(r, 1), t.matrix()(r, 2), t.matrix()(r, 3)});
  return rows;
}

std::vector<unsigned char> encode_png(const cv::Mat& image) {
  std::vector<unsigned char> bytes;
  if (!cv::imencode(".png", image, bytes)) throw io::IoError("PNG encoding failed");
  return bytes;
}

void write_bytes(const std::string& path, const std::vector<unsigned char>& bytes) {
  io::write_file_atomically(path, std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
}

// The 1st and 99th percentiles (nearest rank) of `values`: the range a picture's colours
// span, so a few stray points (a background speck) do not flatten the object to one shade.
std::pair<float, float> percentile_range(std::vector<float> values) {
  if (values.empty()) return {0.0f, 0.0f};
  const auto at = [&](double q) {
    const auto rank = static_cast<std::size_t>(std::floor(q * static_cast<double>(values.size() - 1) + 0.5));
    std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(rank), values.end());
    return values[rank];
  };
  const float lo = at(0.01f);
  const float hi = at(0.99f);
  return {lo, hi};
}

std::string number_text(double v, const char* unit) {
  char text[48];
  std::snprintf(text, sizeof text, std::fabs(v) >= 100 ? "%.1f %s" : "%.3g %s", v, unit);
  return text;
}

// `values` (one per sample, at pixel `slots[k]` of the width x height grid) as `colormap`
// colours over their 1st-99th percentile range (beyond it: the end colours), black where nothing
// was measured, with a colour bar below stating the range.
cv::Mat colour_picture(const std::vector<std::uint32_t>& slots, const std::vector<float>& values, int width, int height,
                       cv::ColormapTypes colormap, const std::string& title, const char* unit) {
  std::vector<float> measured;
  measured.reserve(values.size());
  for (const float value : values)
    if (std::isfinite(value)) measured.push_back(value);
  const bool any = !measured.empty();
  const auto [lo, hi] = percentile_range(std::move(measured));
  const float span = hi > lo ? hi - lo : 1.0f;
  // Fresh, hence continuous, matrices: pixel i of the row-major values is element i.
  cv::Mat grey(height, width, CV_8UC1, cv::Scalar(0));
  cv::Mat mask(height, width, CV_8UC1, cv::Scalar(0));
  auto* const grey_pixels = grey.ptr<unsigned char>();
  auto* const mask_pixels = mask.ptr<unsigned char>();
  for (std::size_t k = 0; k < values.size(); ++k) {
    if (!std::isfinite(values[k])) continue;
    const float t = std::clamp((values[k] - lo) / span, 0.0f, 1.0f);
    grey_pixels[slots[k]] = static_cast<unsigned char>(std::lround(255.0f * t));
    mask_pixels[slots[k]] = 255;
  }
  cv::Mat colour;
  cv::applyColorMap(grey, colour, colormap);
  // The bar: a strip below the picture, the scale from the 1st to the 99th percentile.
  const int panel = std::max(44, height / 9);
  cv::Mat out(height + panel, width, CV_8UC3, cv::Scalar(0, 0, 0));
  colour.copyTo(out(cv::Rect(0, 0, width, height)), mask);
  cv::Mat strip(1, 256, CV_8UC1);
  for (int i = 0; i < 256; ++i) strip.at<unsigned char>(0, i) = static_cast<unsigned char>(i);
  cv::Mat strip_colour;
  cv::applyColorMap(strip, strip_colour, colormap);
  const int margin = std::max(4, width / 40);
  const cv::Rect bar(margin, height + panel / 8, std::max(1, width - 2 * margin), std::max(4, panel * 3 / 10));
  cv::Mat bar_pixels;
  cv::resize(strip_colour, bar_pixels, bar.size(), 0, 0, cv::INTER_NEAREST);
  bar_pixels.copyTo(out(bar));
  const double scale = panel / 110.0;
  const int thickness = std::max(1, static_cast<int>(std::lround(scale * 2)));
  const int baseline_y = height + panel - panel / 8;
  const cv::Scalar white(255, 255, 255);
  const std::string left = any ? number_text(lo, unit) : "";
  const std::string right = any ? number_text(hi, unit) : "";
  const std::string middle = any ? title + ", 1st-99th percentile" : title + ": nothing measured";
  int base = 0;
  const cv::Size right_size = cv::getTextSize(right, cv::FONT_HERSHEY_SIMPLEX, scale, thickness, &base);
  const cv::Size middle_size = cv::getTextSize(middle, cv::FONT_HERSHEY_SIMPLEX, scale, thickness, &base);
  cv::putText(out, left, {margin, baseline_y}, cv::FONT_HERSHEY_SIMPLEX, scale, white, thickness, cv::LINE_AA);
  cv::putText(out, right, {width - margin - right_size.width, baseline_y}, cv::FONT_HERSHEY_SIMPLEX, scale, white,
              thickness, cv::LINE_AA);
  cv::putText(out, middle, {(width - middle_size.width) / 2, baseline_y}, cv::FONT_HERSHEY_SIMPLEX, scale, white,
              thickness, cv::LINE_AA);
  return out;
}

// Depth (camera z), turbo colours over the view's 1st-99th percentile, with its colour bar.
cv::Mat depth_map(const core::SparseOrganizedCloud& cloud) {
  std::vector<float> z(cloud.size());
  for (std::size_t k = 0; k < cloud.size(); ++k) z[k] = cloud.points[k].z();
  return colour_picture(cloud.slots, z, cloud.width, cloud.height, cv::COLORMAP_TURBO, "depth z", "mm");
}

// Decode quality (phase modulation), viridis over the view's 1st-99th percentile.
cv::Mat quality_map(const core::SparseOrganizedCloud& cloud) {
  return colour_picture(cloud.slots, cloud.quality, cloud.width, cloud.height, cv::COLORMAP_VIRIDIS,
                        "quality (modulation)", "DN");
}

// Fusion source: green both, blue left only, red right only, white rejected, black none.
cv::Mat source_map(const std::vector<core::FusionSource>& source, int width, int height) {
  cv::Mat out(height, width, CV_8UC3, cv::Scalar(0, 0, 0));
  auto* const pixels = out.ptr<cv::Vec3b>();
  for (std::size_t i = 0; i < source.size(); ++i) {
    cv::Vec3b colour(0, 0, 0);
    switch (source[i]) {
      case core::FusionSource::both:
        colour = {60, 200, 60};
        break;
      case core::FusionSource::left:
        colour = {230, 120, 40};
        break;
      case core::FusionSource::right:
        colour = {40, 60, 230};
        break;
      case core::FusionSource::rejected:
        colour = {255, 255, 255};
        break;
      case core::FusionSource::none:
        break;
    }
    pixels[i] = colour;
  }
  return out;
}

// HDR: which bracket member each pixel of a projector's decode came from, one colour per member
// (plasma, shortest exposure dark), black where it did not decode, with a legend below.
cv::Mat exposure_member_map(const std::vector<std::uint8_t>& member, const std::vector<double>& exposures_us, int width,
                            int height, const std::string& projector) {
  const std::size_t n = std::max<std::size_t>(1, exposures_us.size());
  std::vector<cv::Vec3b> palette(n);
  cv::Mat levels(1, static_cast<int>(n), CV_8UC1);
  for (std::size_t k = 0; k < n; ++k) {
    // By exposure, not by bracket order: the shortest darkest whatever order it was captured in.
    std::size_t rank = 0;
    for (const double e : exposures_us) rank += e < exposures_us[k] ? 1 : 0;
    levels.at<unsigned char>(0, static_cast<int>(k)) =
        static_cast<unsigned char>(n == 1 ? 160 : 40 + (215 * rank) / (n - 1));
  }
  cv::Mat coloured;
  cv::applyColorMap(levels, coloured, cv::COLORMAP_PLASMA);
  for (std::size_t k = 0; k < n; ++k) palette[k] = coloured.at<cv::Vec3b>(0, static_cast<int>(k));
  const int panel = std::max(44, height / 9);
  cv::Mat out(height + panel, width, CV_8UC3, cv::Scalar(0, 0, 0));
  auto* const pixels = out.ptr<cv::Vec3b>();  // the legend's rows follow the picture's
  for (std::size_t i = 0; i < member.size(); ++i)
    if (member[i] < n) pixels[i] = palette[member[i]];
  const double scale = panel / 110.0;
  const int thickness = std::max(1, static_cast<int>(std::lround(scale * 2)));
  const int margin = std::max(4, width / 40);
  const int baseline_y = height + panel - panel / 4;
  const int box = std::max(6, panel / 3);
  int x = margin;
  const cv::Scalar white(255, 255, 255);
  std::string title = projector + " exposure";
  int base = 0;
  for (std::size_t k = 0; k < exposures_us.size(); ++k) {
    cv::rectangle(out, cv::Rect(x, baseline_y - box, box, box), cv::Scalar(palette[k][0], palette[k][1], palette[k][2]),
                  cv::FILLED);
    x += box + margin / 2;
    const std::string label = number_text(exposures_us[k], "us");
    cv::putText(out, label, {x, baseline_y}, cv::FONT_HERSHEY_SIMPLEX, scale, white, thickness, cv::LINE_AA);
    x += cv::getTextSize(label, cv::FONT_HERSHEY_SIMPLEX, scale, thickness, &base).width + margin;
  }
  const cv::Size title_size = cv::getTextSize(title, cv::FONT_HERSHEY_SIMPLEX, scale, thickness, &base);
  if (x + title_size.width < width - margin)
    cv::putText(out, title, {width - margin - title_size.width, baseline_y}, cv::FONT_HERSHEY_SIMPLEX, scale, white,
                thickness, cv::LINE_AA);
  return out;
}

}  // namespace

std::vector<unsigned char> depth_picture_png(const core::SparseOrganizedCloud& cloud) {
  return encode_png(depth_map(cloud));
}
std::vector<unsigned char> quality_picture_png(const core::SparseOrganizedCloud& cloud) {
  return encode_png(quality_map(cloud));
}

std::vector<std::string> self_check_findings(const core::ScanResult& result) {
  std::vector<std::string> out;
  for (const auto& view : result.views)
    for (std::size_t side = 0; side < 2; ++side) {
      const auto& p = view.projectors[side];
      if (!p.present) continue;
      for (const auto& f : p.checks.findings)
        out.push_back("view " + std::to_string(view.view_index) + ", " + (side == 0 ? "left" : "right") +
                      " projector: " + f.message());
    }
  return out;
}

json scan_result_to_json(const core::ScanResult& result) {
  json views = json::array();
  for (const auto& view : result.views) {
    json projectors = json::array();
    for (std::size_t side = 0; side < 2; ++side) {
      const auto& p = view.projectors[side];
      projectors.push_back({{"side", side == 0 ? "left" : "right"},
                            {"present", p.present},
                            {"decode", counts_json(p.decode)},
                            {"checks", checks_json(p.checks)},
                            {"noise",
                             {{"coordinate_px", p.coordinate_noise_px},
                              {"smoothing_max_deviation_px", p.smoothing_max_deviation_px},
                              {"depth_mm", p.depth_noise_mm},
                              {"depth_second_difference_mm", p.depth_second_difference_mm}}},
                            {"triangulate", counts_json(p.triangulate)},
                            {"decode_ms", p.decode_ms},
                            {"triangulate_ms", p.triangulate_ms}});
      if (!p.exposures.empty()) {
        json exposures = json::array();
        for (const core::ExposureShare& e : p.exposures)
          exposures.push_back(
              {{"exposure_us", e.exposure_us}, {"decoded", e.decoded}, {"chosen", e.chosen}, {"clipped", e.clipped}});
        projectors.back()["exposures"] = std::move(exposures);
      }
    }
    views.push_back({{"view_index", view.view_index},
                     {"commanded_angle_deg", view.commanded_angle_deg},
                     {"reported_angle_deg", view.reported_angle_deg},
                     {"projectors", projectors},
                     {"fusion",
                      {{"both", view.fusion.both},
                       {"left_only", view.fusion.left_only},
                       {"right_only", view.fusion.right_only},
                       {"rejected", view.fusion.rejected}}},
                     {"flying_pixels_removed", view.flying_pixels.removed},
                     {"limits",
                      {{"noise_factor", view.noise_factor},
                       {"flying_pixels_max_abs_mm", view.flying_max_abs_mm},
                       {"fusion_agreement_mm", view.fusion_agreement_mm}}},
                     {"turntable_denoise",
                      {{"input", view.turntable_denoise.input},
                       {"kept", view.turntable_denoise.kept},
                       {"below_min_height", view.turntable_denoise.below_min_height},
                       {"above_max_height", view.turntable_denoise.above_max_height},
                       {"outside_radius", view.turntable_denoise.outside_radius}}},
                     {"depth_smoothing",
                      {{"window_radius_px", view.depth_smoothing.window_radius_px},
                       {"full", view.depth_smoothing.full},
                       {"partial", view.depth_smoothing.partial},
                       {"kept", view.depth_smoothing.kept},
                       {"mean_shift_um", view.depth_smoothing.mean_shift_um}}},
                     {"points", view.points},
                     {"fuse_ms", view.fuse_ms},
                     {"fuse_step_ms",
                      {{"flying_pixels", view.flying_pixels_ms},
                       {"fusion", view.fusion_ms},
                       {"denoise", view.denoise_ms},
                       {"outliers", view.outliers_ms},
                       {"depth_smoothing", view.smoothing_ms},
                       {"normals", view.normals_ms}}}});
  }
  json registration = {{"applied", result.registered}};
  if (!result.registration_error.empty()) registration["error"] = result.registration_error;
  if (result.registered) {
    json per_view = json::array();
    for (std::size_t i = 0; i < result.registration.views.size(); ++i) {
      const auto& r = result.registration.views[i];
      per_view.push_back({{"view", result.views[i].view_index},  // the capture's view number
                          {"correction_deg", r.correction_deg},
                          {"correction_mm", r.correction_mm},
                          {"angle_correction_deg", r.angle_correction_deg},
                          {"residual_rms_mm", r.residual_rms_mm},
                          {"correspondences", r.correspondences},
                          {"table_from_view", isometry_json(r.table_from_view)}});
    }
    json pairs = json::array();
    for (const auto& p : result.registration.pairs)
      pairs.push_back({{"views",
                        {result.views[static_cast<std::size_t>(p.view_a)].view_index,
                         result.views[static_cast<std::size_t>(p.view_b)].view_index}},
                       {"rms_mm", p.rms_mm},
                       {"correspondences", p.correspondences}});
    registration["views"] = per_view;
    registration["pairs"] = pairs;
    registration["iterations"] = result.registration.iterations;
    registration["mode"] = core::refinement_mode_name(result.registration.mode);
    if (result.registration.mode == core::RefinementMode::turntable) {
      registration["axis_tilt_deg"] = result.registration.axis_tilt_deg;
      registration["axis_shift_mm"] = result.registration.axis_shift_mm;
    }
  }
  json flagged = json::array();
  for (const auto& line : self_check_findings(result)) flagged.push_back(line);
  json out = {{"self_check", {{"flagged", !flagged.empty()}, {"findings", flagged}}},
              {"views", views},
              {"registration", registration},
              {"model",
               {{"merged_points", result.merged_points},
                {"steep_points", result.overlap.steep},
                {"steep_points_replaced", result.overlap.replaced},
                {"outliers_removed", result.outliers_removed},
                {"points", result.model.size()}}},
              {"stage_ms", result.stage_ms}};
  if (result.meshed) {
    const auto topology = core::mesh_topology(result.mesh.mesh);
    const core::MeshStats& st = result.mesh.stats;
    out["mesh"] = {{"mode", core::mesh_mode_name(result.mesh.mode)},
                   {"vertices", result.mesh.mesh.vertices.size()},
                   {"triangles", result.mesh.mesh.triangles.size()},
                   {"closed", topology.closed()},
                   {"cell_mm", result.mesh.cell_mm},
                   {"spacing_mm", st.spacing_mm},
                   {"mesh_ms", st.mesh_ms},
                   {"step_ms", step_ms_json(st)},
                   {"points_used", st.points_used},
                   {"isolated_points", st.isolated_points},
                   {"trimmed_triangles", result.mesh.trimmed_triangles},
                   {"dropped_piece_triangles", st.dropped_piece_triangles},
                   {"holes", st.holes},
                   {"holes_filled", st.holes_filled},
                   {"holes_left_open", st.holes_left_open},
                   {"filled_triangles", st.filled_triangles},
                   {"rejected_triangles", st.rejected_triangles},
                   {"crossing_triangles", st.crossing_triangles},
                   {"pinholes_filled", st.pinholes_filled},
                   {"pinholes_crossing", st.pinholes_crossing},
                   {"crossed_faces_removed", st.crossed_faces_removed},
                   {"holes_crossing_unrefined", st.holes_crossing_unrefined},
                   {"holes_left_plain", st.holes_left_plain},
                   {"sides_separated", st.sides_separated},
                   {"self_intersections", st.self_intersections},
                   {"triangles_before_simplify", st.triangles_before_simplify},
                   {"simplified", st.simplified},
                   {"simplify_attempts", st.simplify_attempts},
                   {"simplify_skipped", st.simplify_skipped}};
  } else if (!result.mesh_error.empty()) {
    out["mesh"] = {{"error", result.mesh_error}};
  }
  return out;
}

json ball_bar_to_json(const core::BallBarResult& b) {
  json spheres = json::array();
  for (const auto& s : b.spheres)
    spheres.push_back({{"centre_mm", {s.centre.x(), s.centre.y(), s.centre.z()}},
                       {"radius_mm", s.radius_mm},
                       {"diameter_mm", 2 * s.radius_mm},
                       {"form_error_mm", s.form_error_mm},
                       {"rms_mm", s.rms_mm},
                       {"points", s.point_count}});
  return {{"spheres", spheres}, {"centre_distance_mm", b.centre_distance_mm}};
}

std::vector<unsigned char> render_preview_png(const core::PointCloud& cloud, double azimuth_deg, double elevation_deg,
                                              int size) {
  const double az = azimuth_deg * std::numbers::pi / 180, el = elevation_deg * std::numbers::pi / 180;
  // View direction from the object toward the eye; orthographic projection onto (right, up).
  const Eigen::Vector3d eye(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
  const Eigen::Vector3d right = Eigen::Vector3d::UnitZ().cross(eye).normalized();
  const Eigen::Vector3d up = eye.cross(right);
  cv::Mat image(size, size, CV_8UC1, cv::Scalar(0));
  if (cloud.size() == 0) return encode_png(image);
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e300), hi = Eigen::Vector3d::Constant(-1e300);
  for (const auto& p : cloud.points) {
    lo = lo.cwiseMin(p.cast<double>());
    hi = hi.cwiseMax(p.cast<double>());
  }
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  const double extent = std::max(1e-6, (hi - lo).norm());
  const double scale = 0.9 * size / extent;
  cv::Mat depth(size, size, CV_64FC1, cv::Scalar(-1e300));
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3d p = cloud.points[i].cast<double>() - centre;
    const int x = static_cast<int>(std::lround(size / 2.0 + scale * p.dot(right)));
    const int y = static_cast<int>(std::lround(size / 2.0 - scale * p.dot(up)));
    if (x < 0 || y < 0 || x >= size || y >= size) continue;
    const double z = p.dot(eye);
    if (z <= depth.at<double>(y, x)) continue;
    depth.at<double>(y, x) = z;
    double shade = 0.6;
    if (cloud.has_normals()) shade = std::max(0.0, cloud.normals[i].cast<double>().dot(eye));
    image.at<unsigned char>(y, x) = static_cast<unsigned char>(40 + 215 * shade);
  }
  // Close the gaps between splats so surfaces read as surfaces.
  cv::Mat closed;
  cv::morphologyEx(image, closed, cv::MORPH_CLOSE, cv::getStructuringElement(cv::MORPH_ELLIPSE, {3, 3}));
  return encode_png(closed);
}

namespace {

// The whole set, into `dir` (the staging folder), report.json last. Each file is a task of its
// own: a 5 MP view's three pictures take ~0.15 s to colour and compress, the meshes and clouds
// tens of ms each, so on two cores the set is written in about half the time. Which file is
// written first does not matter: the list of files, and every file's bytes, are the same.
OutputFiles write_set(const std::string& dir, const core::ScanResult& result, json report,
                      const core::MeshFormats& formats) {
  namespace fs = std::filesystem;
  fs::create_directories(fs::path(dir) / "views");
  fs::create_directories(fs::path(dir) / "pictures");
  OutputFiles files;
  tbb::task_group tasks;
  files.model_ply = (fs::path(dir) / "model.ply").string();
  tasks.run([&] {
    io::write_ply(files.model_ply, result.model,
                  {.binary = true,
                   .comments = {"slscan fused model, turntable frame, mm",
                                "confidence: decode modulation (DN, summed over fused projectors); "
                                "intensity: albedo (white - black frame), 0..1 of full scale"}});
  });
  std::vector<Eigen::Vector3i> triangles;
  const std::string mode = result.meshed ? core::mesh_mode_name(result.mesh.mode) : "";
  if (result.meshed) {
    const core::TriangleMesh& mesh = result.mesh.mesh;
    if (formats.ply || formats.stl) {
      triangles.reserve(mesh.triangles.size());
      for (const auto& t : mesh.triangles)
        triangles.emplace_back(static_cast<int>(t[0]), static_cast<int>(t[1]), static_cast<int>(t[2]));
    }
    if (formats.ply) {
      files.mesh_ply = (fs::path(dir) / "mesh.ply").string();
      tasks.run([&] {
        io::write_mesh_ply(
            files.mesh_ply, mesh.vertices, mesh.normals, triangles,
            {.binary = true,
             .comments =
                 {"slscan mesh (" + mode + "), turntable frame, mm; face property filled = 1: closes a hole",
                  "vertex intensity: albedo (white - black frame) of the points around it, 0..1 of full scale"}},
            mesh.filled, mesh.intensity);
      });
    }
    if (formats.stl) {
      files.mesh_stl = (fs::path(dir) / "mesh.stl").string();
      tasks.run([&] { io::write_stl(files.mesh_stl, mesh.vertices, triangles, "slscan mesh, turntable frame, mm"); });
    }
    if (formats.obj) {
      files.mesh_obj = (fs::path(dir) / "mesh.obj").string();
      tasks.run([&] {
        io::write_obj(files.mesh_obj, mesh,
                      {"slscan mesh (" + mode + "), turntable frame", "group filled: faces that close a hole"});
      });
    }
    if (formats.three_mf) {
      files.mesh_3mf = (fs::path(dir) / "mesh.3mf").string();
      tasks.run([&] { io::write_3mf(files.mesh_3mf, mesh, "slscan mesh (" + mode + ")"); });
    }
  }
  std::vector<std::string> view_files;
  const auto picture = [&](const std::string& file_name, auto&& make_image) {
    const std::string path = (fs::path(dir) / "pictures" / file_name).string();
    files.pictures.push_back(path);
    tasks.run([path, make_image] { write_bytes(path, encode_png(make_image())); });
  };
  for (std::size_t i = 0; i < result.view_products.size(); ++i) {
    const auto& products = result.view_products[i];
    const std::string name = "view_" + std::to_string(result.views[i].view_index);
    view_files.push_back("views/" + name + ".ply");
    tasks.run([&products, path = (fs::path(dir) / view_files.back()).string()] {
      io::write_ply(path, products.points,
                    {.binary = true, .comments = {"slscan view cloud, camera frame of this view, mm"}});
    });
    picture(name + "_depth.png", [&products] { return depth_map(products.cloud); });
    picture(name + "_quality.png", [&products] { return quality_map(products.cloud); });
    picture(name + "_fusion_source.png",
            [&products] { return source_map(products.source, products.cloud.width, products.cloud.height); });
    for (std::size_t side = 0; side < 2; ++side) {
      if (products.exposure_member[side].empty()) continue;
      std::vector<double> exposures_us;
      for (const auto& share : result.views[i].projectors[side].exposures) exposures_us.push_back(share.exposure_us);
      picture(name + (side == 0 ? "_exposure_left.png" : "_exposure_right.png"),
              [&products, side, exposures_us = std::move(exposures_us)] {
                return exposure_member_map(products.exposure_member[side], exposures_us, products.cloud.width,
                                           products.cloud.height, side == 0 ? "left" : "right");
              });
    }
  }
  for (const auto& view_angle : {std::pair{0.0, 20.0}, {90.0, 20.0}, {180.0, 20.0}, {270.0, 20.0}, {0.0, 80.0}}) {
    const double azimuth = view_angle.first, elevation = view_angle.second;
    const std::string path = (fs::path(dir) / "pictures" /
                              ("model_az" + std::to_string(static_cast<int>(azimuth)) + "_el" +
                               std::to_string(static_cast<int>(elevation)) + ".png"))
                                 .string();
    files.pictures.push_back(path);
    tasks.run([&result, path, azimuth, elevation] {
      write_bytes(path, render_preview_png(result.model, azimuth, elevation, 800));
    });
  }
  tasks.wait();  // rethrows the first failure (a full disk, out of memory) once every task is done
  report["scan"] = scan_result_to_json(result);
  json outputs = {{"model", "model.ply"}, {"views", "views/"}, {"pictures", "pictures/"}};
  for (const auto& [key, path] : {std::pair{"mesh_ply", &files.mesh_ply}, std::pair{"mesh_stl", &files.mesh_stl},
                                  std::pair{"mesh_obj", &files.mesh_obj}, std::pair{"mesh_3mf", &files.mesh_3mf}})
    if (!path->empty()) outputs[key] = fs::path(*path).filename().string();
  outputs["report_html"] = "report.html";
  std::vector<std::string> relative_pictures;
  for (const auto& path : files.pictures) relative_pictures.push_back(fs::relative(path, dir).generic_string());
  // Every file of the folder that belongs to this run, relative to it (report.html links each):
  // the capture when it is there, the model, meshes, view clouds, pictures and the reports.
  json listed = json::array();
  if (const json* capture = report.contains("capture") ? &report["capture"] : nullptr;
      capture != nullptr && capture->contains("in_folder"))
    listed.push_back((*capture)["in_folder"]);
  for (const std::string* file : {&files.model_ply, &files.mesh_ply, &files.mesh_stl, &files.mesh_obj, &files.mesh_3mf})
    if (!file->empty()) listed.push_back(fs::path(*file).filename().string());
  for (const std::string& file : view_files) listed.push_back(file);
  for (const std::string& file : relative_pictures) listed.push_back(file);
  listed.push_back("report.json");
  listed.push_back("report.html");
  report["outputs"] = outputs;
  report["files"] = listed;
  files.report_html = (fs::path(dir) / "report.html").string();
  io::write_file_atomically(files.report_html,
                            render_report_html(report, result.model, relative_pictures,
                                               {report_viewer_js(), report_viewer_missing_reason()}));
  files.report_json = (fs::path(dir) / "report.json").string();
  io::write_file_atomically(files.report_json, report.dump(2) + "\n");
  return files;
}

namespace fs = std::filesystem;

// What a run writes into its output folder; a new run replaces all of them, so nothing of an
// earlier run (a mesh, a view, a picture the new run does not make) stays beside the new set.
// report.json is not in the list: it goes out first and comes in last.
constexpr std::array<const char*, 8> set_entries = {"model.ply", "mesh.ply", "mesh.stl", "mesh.obj",
                                                    "mesh.3mf",  "views",    "pictures", "report.html"};
constexpr const char* staging_name = ".slscan-staging";
constexpr const char* previous_name = ".slscan-previous";

[[noreturn]] void fail(const fs::path& path, const std::string& what, const std::error_code& error) {
  throw io::IoError(path.string() + ": " + what + " (" + error.message() + ")");
}

bool present(const fs::path& path) {
  std::error_code error;
  return fs::symlink_status(path, error).type() != fs::file_type::not_found && !error;
}

void remove_all_or_throw(const fs::path& path) {
  std::error_code error;
  fs::remove_all(path, error);
  if (error) fail(path, "cannot remove", error);
}

void rename_or_throw(const fs::path& from, const fs::path& to) {
  std::error_code error;
  fs::rename(from, to, error);
  if (error) fail(from, "cannot rename to " + to.string(), error);
}

// Moves the staged set into `out`: the old report.json and the old set aside (renames, no
// space needed), the new set in, report.json last; then the old set is deleted. If a rename
// fails, the old set is put back.
void commit_set(const fs::path& stage, const fs::path& out) {
  const fs::path previous = out / previous_name;
  remove_all_or_throw(previous);
  std::error_code error;
  if (!fs::create_directory(previous, error) || error) fail(previous, "cannot create", error);
  std::vector<std::string> moved_aside, moved_in;
  const auto all = [&] {
    std::vector<std::string> names(set_entries.begin(), set_entries.end());
    names.insert(names.begin(), "report.json");
    return names;
  }();
  try {
    for (const auto& name : all)
      if (present(out / name)) {
        rename_or_throw(out / name, previous / name);
        moved_aside.push_back(name);
      }
    for (const auto& name : all) {
      if (name == "report.json" || !present(stage / name)) continue;
      rename_or_throw(stage / name, out / name);
      moved_in.push_back(name);
    }
    rename_or_throw(stage / "report.json", out / "report.json");
  } catch (...) {
    for (const auto& name : moved_in) fs::remove_all(out / name, error);
    for (const auto& name : moved_aside) fs::rename(previous / name, out / name, error);
    fs::remove_all(stage, error);
    fs::remove_all(previous, error);
    throw;
  }
  fs::remove_all(previous, error);
  fs::remove_all(stage, error);
}

}  // namespace

OutputFiles write_scan_outputs(const std::string& dir, const core::ScanResult& result, json report,
                               const core::MeshFormats& mesh_formats) {
  const fs::path out = fs::path(dir).lexically_normal();
  std::error_code error;
  fs::create_directories(out, error);
  if (error) fail(out, "cannot create the output folder", error);
  if (!fs::is_directory(out, error)) throw io::IoError(out.string() + ": not a folder (--out names the output folder)");
  // The set is written whole into a hidden folder inside `out` (so on the same file system,
  // whatever is mounted where) and only then moved into place: a run that fails midway (a full
  // disk) leaves the previous complete set as it was.
  const fs::path stage = out / staging_name;
  remove_all_or_throw(stage);  // left by a run that was killed
  OutputFiles staged;
  try {
    staged = write_set(stage.string(), result, std::move(report), mesh_formats);
  } catch (const std::bad_alloc&) {
    fs::remove_all(stage, error);  // out of memory is the caller's to report (exit_resources)
    throw;
  } catch (const std::exception& e) {
    fs::remove_all(stage, error);
    throw io::IoError("writing the outputs into " + out.string() + " failed: " + e.what() +
                      (present(out / "report.json") ? "; the previous outputs there are as they were"
                                                    : "; nothing was written there"));
  }
  commit_set(stage, out);
  const auto moved = [&](const std::string& path) {
    return path.empty() ? path : (out / fs::path(path).lexically_relative(stage)).string();
  };
  OutputFiles files{
      moved(staged.model_ply), moved(staged.mesh_ply),    moved(staged.mesh_stl),    moved(staged.mesh_obj),
      moved(staged.mesh_3mf),  moved(staged.report_json), moved(staged.report_html), {}};
  for (const auto& p : staged.pictures) files.pictures.push_back(moved(p));
  return files;
}

}  // namespace slscan::app
