#include "outputs.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "report_html.hpp"
#include "slscan/io/ply.hpp"
#include "viewer_bundle.hpp"

namespace slscan::app {

using nlohmann::json;

namespace {

json counts_json(const core::DecodeCounts& c) {
  return {{"valid", c.valid},
          {"saturated", c.saturated},
          {"low_contrast", c.low_contrast},
          {"low_modulation", c.low_modulation},
          {"out_of_range", c.out_of_range}};
}

json counts_json(const core::TriangulateCounts& c) {
  return {{"valid", c.valid},
          {"not_decoded", c.not_decoded},
          {"no_intersection", c.no_intersection},
          {"not_converged", c.not_converged},
          {"outside_frustum", c.outside_frustum},
          {"outside_depth", c.outside_depth}};
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

// Depth (camera z) as a colour map over the view's own range; black where nothing was measured.
cv::Mat depth_map(const core::OrganizedCloud& cloud) {
  float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (cloud.valid[i]) {
      lo = std::min(lo, cloud.points[i].z());
      hi = std::max(hi, cloud.points[i].z());
    }
  cv::Mat grey(cloud.height, cloud.width, CV_8UC1, cv::Scalar(0));
  cv::Mat mask(cloud.height, cloud.width, CV_8UC1, cv::Scalar(0));
  const float span = hi > lo ? hi - lo : 1.0f;
  for (int v = 0; v < cloud.height; ++v)
    for (int u = 0; u < cloud.width; ++u) {
      const std::size_t i =
          static_cast<std::size_t>(v) * static_cast<std::size_t>(cloud.width) + static_cast<std::size_t>(u);
      if (!cloud.valid[i]) continue;
      grey.at<unsigned char>(v, u) = static_cast<unsigned char>(1 + 254.0f * (cloud.points[i].z() - lo) / span);
      mask.at<unsigned char>(v, u) = 255;
    }
  cv::Mat colour;
  cv::applyColorMap(grey, colour, cv::COLORMAP_TURBO);
  cv::Mat out(colour.size(), colour.type(), cv::Scalar(0, 0, 0));
  colour.copyTo(out, mask);
  return out;
}

cv::Mat quality_map(const core::OrganizedCloud& cloud) {
  float hi = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (cloud.valid[i]) hi = std::max(hi, cloud.quality[i]);
  cv::Mat grey(cloud.height, cloud.width, CV_8UC1, cv::Scalar(0));
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (cloud.valid[i] && hi > 0)
      grey.at<unsigned char>(static_cast<int>(i) / cloud.width, static_cast<int>(i) % cloud.width) =
          static_cast<unsigned char>(255.0f * cloud.quality[i] / hi);
  return grey;
}

// Fusion source: green both, blue left only, red right only, white rejected, black none.
cv::Mat source_map(const std::vector<core::FusionSource>& source, int width, int height) {
  cv::Mat out(height, width, CV_8UC3, cv::Scalar(0, 0, 0));
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
    out.at<cv::Vec3b>(static_cast<int>(i) / width, static_cast<int>(i) % width) = colour;
  }
  return out;
}

}  // namespace

json scan_result_to_json(const core::ScanResult& result) {
  json views = json::array();
  for (const auto& view : result.views) {
    json projectors = json::array();
    for (std::size_t side = 0; side < 2; ++side) {
      const auto& p = view.projectors[side];
      projectors.push_back({{"side", side == 0 ? "left" : "right"},
                            {"present", p.present},
                            {"decode", counts_json(p.decode)},
                            {"triangulate", counts_json(p.triangulate)},
                            {"decode_ms", p.decode_ms},
                            {"triangulate_ms", p.triangulate_ms}});
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
                     {"fuse_ms", view.fuse_ms}});
  }
  json registration = {{"applied", result.registered}};
  if (!result.registration_error.empty()) registration["error"] = result.registration_error;
  if (result.registered) {
    json per_view = json::array();
    for (std::size_t i = 0; i < result.registration.views.size(); ++i) {
      const auto& r = result.registration.views[i];
      per_view.push_back({{"view", i},
                          {"correction_deg", r.correction_deg},
                          {"correction_mm", r.correction_mm},
                          {"residual_rms_mm", r.residual_rms_mm},
                          {"correspondences", r.correspondences},
                          {"table_from_view", isometry_json(r.table_from_view)}});
    }
    json pairs = json::array();
    for (const auto& p : result.registration.pairs)
      pairs.push_back({{"views", {p.view_a, p.view_b}}, {"rms_mm", p.rms_mm}, {"correspondences", p.correspondences}});
    registration["views"] = per_view;
    registration["pairs"] = pairs;
    registration["iterations"] = result.registration.iterations;
  }
  json out = {{"views", views},
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
    out["mesh"] = {{"vertices", result.mesh.mesh.vertices.size()},
                   {"triangles", result.mesh.mesh.triangles.size()},
                   {"closed", topology.closed()},
                   {"cell_mm", result.mesh.cell_mm},
                   {"trimmed_triangles", result.mesh.trimmed_triangles}};
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

OutputFiles write_scan_outputs(const std::string& dir, const core::ScanResult& result, json report) {
  namespace fs = std::filesystem;
  fs::create_directories(fs::path(dir) / "views");
  fs::create_directories(fs::path(dir) / "pictures");
  OutputFiles files;
  const io::PlyWriteOptions ply{.binary = true, .comments = {"slscan fused model, turntable frame, mm"}};
  files.model_ply = (fs::path(dir) / "model.ply").string();
  io::write_ply(files.model_ply, result.model, ply);
  if (result.meshed) {
    std::vector<Eigen::Vector3i> triangles;
    triangles.reserve(result.mesh.mesh.triangles.size());
    for (const auto& t : result.mesh.mesh.triangles)
      triangles.emplace_back(static_cast<int>(t[0]), static_cast<int>(t[1]), static_cast<int>(t[2]));
    files.mesh_ply = (fs::path(dir) / "mesh.ply").string();
    files.mesh_stl = (fs::path(dir) / "mesh.stl").string();
    io::write_mesh_ply(files.mesh_ply, result.mesh.mesh.vertices, result.mesh.mesh.normals, triangles,
                       {.binary = true, .comments = {"slscan mesh, turntable frame, mm"}});
    io::write_stl(files.mesh_stl, result.mesh.mesh.vertices, triangles, "slscan mesh, turntable frame, mm");
  }
  for (std::size_t i = 0; i < result.view_products.size(); ++i) {
    const auto& products = result.view_products[i];
    const std::string name = "view_" + std::to_string(result.views[i].view_index);
    io::write_ply((fs::path(dir) / "views" / (name + ".ply")).string(), products.points,
                  {.binary = true, .comments = {"slscan view cloud, camera frame of this view, mm"}});
    const auto picture = [&](const std::string& suffix, const cv::Mat& image) {
      const std::string path = (fs::path(dir) / "pictures" / (name + "_" + suffix + ".png")).string();
      write_bytes(path, encode_png(image));
      files.pictures.push_back(path);
    };
    picture("depth", depth_map(products.cloud));
    picture("quality", quality_map(products.cloud));
    picture("fusion_source", source_map(products.source, products.cloud.width, products.cloud.height));
  }
  for (const auto& [azimuth, elevation] :
       {std::pair{0.0, 20.0}, {90.0, 20.0}, {180.0, 20.0}, {270.0, 20.0}, {0.0, 80.0}}) {
    const std::string path = (fs::path(dir) / "pictures" /
                              ("model_az" + std::to_string(static_cast<int>(azimuth)) + "_el" +
                               std::to_string(static_cast<int>(elevation)) + ".png"))
                                 .string();
    write_bytes(path, render_preview_png(result.model, azimuth, elevation, 800));
    files.pictures.push_back(path);
  }
  report["scan"] = scan_result_to_json(result);
  json outputs = {{"model", "model.ply"}, {"views", "views/"}, {"pictures", "pictures/"}};
  if (result.meshed) {
    outputs["mesh_ply"] = "mesh.ply";
    outputs["mesh_stl"] = "mesh.stl";
  }
  outputs["report_html"] = "report.html";
  report["outputs"] = outputs;
  std::vector<std::string> relative_pictures;
  for (const auto& path : files.pictures) relative_pictures.push_back(fs::relative(path, dir).generic_string());
  files.report_html = (fs::path(dir) / "report.html").string();
  io::write_file_atomically(files.report_html,
                            render_report_html(report, result.model, relative_pictures,
                                               {report_viewer_js(), report_viewer_missing_reason()}));
  files.report_json = (fs::path(dir) / "report.json").string();
  io::write_file_atomically(files.report_json, report.dump(2) + "\n");
  return files;
}

}  // namespace slscan::app
