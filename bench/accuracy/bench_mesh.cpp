// The mesh against the virtual rig's truth (issue 19, docs/mesh.md): each scene is rendered,
// reconstructed (exact calibration, 6 views), and its model meshed by slscan_mesh (raw and
// watertight). Every model point and mesh
// vertex is compared with the truth's surface samples (0.05 mm apart): distance along the
// nearest sample's normal; faces whose normal is more than 10 deg off the nearest sample's.
//   bench_mesh [--size small|full] [--scenes ballbar,sphere,blade,teacup] [--cache DIR]
// --cache keeps each scene's model (PLY, rig frame) so that a second run meshes only.
#include <sys/resource.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numbers>
#include <span>
#include <sstream>
#include <string>
#include <vector>

#include "slproto/pattern_plan.hpp"
#include "slrig/rig.hpp"
#include "slscan/core/mesh.hpp"
#include "slscan/core/point_index.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/io/ply.hpp"
#include "slscan/mesh/mesher.hpp"

namespace {

using Clock = std::chrono::steady_clock;

Eigen::Isometry3d to_isometry(const slproto::RigidTransform& t) {
  Eigen::Isometry3d m = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m.linear()(r, c) = t.R[static_cast<std::size_t>(3 * r + c)];
    m.translation()(r) = t.t[static_cast<std::size_t>(r)];
  }
  return m;
}

// The scene's fused model in the rig's table frame (normals too).
slscan::core::PointCloud reconstruct(const slrig::Scene& scene) {
  const slproto::RigCalibration calibration = slrig::ground_truth_calibration(scene);
  const slproto::PatternPlan plan(calibration.pattern_plan);
  slscan::core::ReconstructionOptions options;
  options.decode.bit_depth = scene.sensor.bit_depth;
  options.build_mesh = false;
  const int width = scene.camera.width, height = scene.camera.height;
  slscan::core::ScanReconstructor reconstructor(calibration, plan, width, height, options);
  std::vector<std::uint8_t> frame;
  slproto::RigidTransform cam0_from_table{};
  for (std::size_t view = 0; view < scene.view_angles_deg.size(); ++view) {
    const double angle = scene.view_angles_deg[view];
    slrig::ViewRenderer renderer(scene, angle, static_cast<int>(view));
    frame.resize(renderer.frame_bytes());
    const int bytes_per_pixel = scene.sensor.bit_depth > 8 ? 2 : 1;
    for (int side = 0; side < 2; ++side)
      for (std::size_t p = 0; p < plan.size(); ++p) {
        renderer.render(static_cast<slproto::ProjectorSide>(side), p, frame);
        slscan::core::FrameInfo info;
        info.view_index = static_cast<int>(view);
        info.commanded_angle_deg = info.reported_angle_deg = angle;
        info.projector = side;
        info.pattern_index = p;
        info.bytes_per_pixel = bytes_per_pixel;
        info.stride_bytes = static_cast<std::size_t>(width * bytes_per_pixel);
        reconstructor.add_frame(info, std::as_bytes(std::span(frame)));
      }
    if (view == 0) cam0_from_table = renderer.ground_truth().cam_from_table;
  }
  slscan::core::ScanResult result = reconstructor.finish();
  const Eigen::Isometry3d host_table_from_cam0 =
      slscan::core::coarse_table_from_view(calibration.turntable, scene.view_angles_deg[0]);
  const Eigen::Isometry3f to_rig =
      (to_isometry(cam0_from_table).inverse() * host_table_from_cam0.inverse()).cast<float>();
  slscan::core::PointCloud model = std::move(result.model);
  for (auto& p : model.points) p = to_rig * p;
  for (auto& n : model.normals) n = to_rig.linear() * n;
  return model;
}

struct Truth {
  std::vector<Eigen::Vector3f> points, normals;
  std::unique_ptr<slscan::core::PointIndex> index;
};

struct Figures {
  double rms_um = 0, p99_um = 0;
  std::size_t compared = 0, far = 0;  // far: no truth sample within 1 mm
  double bad_face_percent = 0, flipped_face_percent = 0;
};

// Distances of `points` to the truth (along the nearest sample's normal, samples within 1 mm).
Figures distances(const std::vector<Eigen::Vector3f>& points, const Truth& truth) {
  Figures f;
  std::vector<double> d;
  d.reserve(points.size());
  for (const auto& p : points) {
    float d2 = 0;
    const std::int64_t k = truth.index->nearest_within(p, 1.0f, d2);
    if (k < 0) {
      ++f.far;
      continue;
    }
    const auto i = static_cast<std::size_t>(k);
    d.push_back(std::abs(static_cast<double>(truth.normals[i].dot(p - truth.points[i]))));
  }
  f.compared = d.size();
  if (d.empty()) return f;
  double s2 = 0;
  for (const double x : d) s2 += x * x;
  f.rms_um = 1e3 * std::sqrt(s2 / static_cast<double>(d.size()));
  std::sort(d.begin(), d.end());
  f.p99_um = 1e3 * d[d.size() * 99 / 100];
  return f;
}

Figures mesh_figures(const slscan::core::TriangleMesh& mesh, const Truth& truth) {
  // Vertices of measured (not filled) faces only.
  std::vector<std::uint8_t> used(mesh.vertices.size(), 0);
  std::size_t faces = 0, bad = 0, flipped = 0;
  const double cos10 = std::cos(10 * std::numbers::pi / 180);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!mesh.filled.empty() && mesh.filled[t]) continue;
    const auto& tri = mesh.triangles[t];
    for (const auto v : tri) used[v] = 1;
    const Eigen::Vector3f a = mesh.vertices[tri[0]], b = mesh.vertices[tri[1]], c = mesh.vertices[tri[2]];
    const Eigen::Vector3f n = (b - a).cross(c - a).normalized();
    float d2 = 0;
    const std::int64_t k = truth.index->nearest_within((a + b + c) / 3, 1.0f, d2);
    if (k < 0) continue;
    ++faces;
    const double cosine = n.dot(truth.normals[static_cast<std::size_t>(k)]);
    if (cosine < cos10) ++bad;
    if (cosine < 0) ++flipped;
  }
  std::vector<Eigen::Vector3f> vertices;
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    if (used[i]) vertices.push_back(mesh.vertices[i]);
  Figures f = distances(vertices, truth);
  f.bad_face_percent = faces ? 100.0 * static_cast<double>(bad) / static_cast<double>(faces) : 0;
  f.flipped_face_percent = faces ? 100.0 * static_cast<double>(flipped) / static_cast<double>(faces) : 0;
  return f;
}

double ms_since(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

long peak_rss_mb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024;
}

void row(const std::string& scene, const std::string& mesher, const Figures& f, double ms, std::size_t triangles,
         const std::string& extra) {
  std::printf("| %s | %s | %.1f / %.0f | %.1f %% (%.1f %% flipped) | %zu | %zu | %.0f | %s |\n", scene.c_str(),
              mesher.c_str(), f.rms_um, f.p99_um, f.bad_face_percent, f.flipped_face_percent, triangles, f.far, ms,
              extra.c_str());
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  std::string size_name = "small", cache;
  std::vector<std::string> scenes{"ballbar", "sphere", "blade", "teacup"};
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--size" && i + 1 < argc) {
      size_name = argv[++i];
    } else if (arg == "--cache" && i + 1 < argc) {
      cache = argv[++i];
    } else if (arg == "--scenes" && i + 1 < argc) {
      scenes.clear();
      std::stringstream list(argv[++i]);
      for (std::string s; std::getline(list, s, ',');) scenes.push_back(s);
    } else {
      std::fprintf(stderr, "usage: bench_mesh [--size small|full] [--scenes a,b] [--cache DIR]\n");
      return 2;
    }
  }
  const slrig::RigSize size = size_name == "full" ? slrig::RigSize::full : slrig::RigSize::small;
  std::printf(
      "| scene | mesher | vertex distance RMS / p99 um | faces > 10 deg off truth | triangles | vertices > 1 mm "
      "from truth | ms | notes |\n|---|---|---|---|---|---|---|---|\n");
  for (const auto& name : scenes) {
    auto scene_or = slrig::scene_preset(name, size);
    if (!scene_or) {
      std::fprintf(stderr, "%s\n", scene_or.error().message.c_str());
      return 1;
    }
    const slrig::Scene& scene = *scene_or;
    slscan::core::PointCloud model;
    const std::string cached = cache.empty() ? "" : cache + "/" + name + "_" + size_name + ".ply";
    if (!cached.empty() && std::filesystem::exists(cached)) {
      model = slscan::io::read_ply(cached);
    } else {
      model = reconstruct(scene);
      if (!cached.empty()) {
        std::filesystem::create_directories(cache);
        slscan::io::write_ply(cached, model, {.binary = true, .comments = {"bench_mesh model, rig table frame, mm"}});
      }
    }
    Truth truth;
    const slrig::SurfaceSample surface = slrig::sample_object_surfaces(scene, 0.05);
    for (std::size_t i = 0; i < surface.points.size() / 3; ++i) {
      truth.points.emplace_back(surface.points[3 * i], surface.points[3 * i + 1], surface.points[3 * i + 2]);
      truth.normals.emplace_back(surface.normals[3 * i], surface.normals[3 * i + 1], surface.normals[3 * i + 2]);
    }
    truth.index = std::make_unique<slscan::core::PointIndex>(truth.points);
    const Figures points = distances(model.points, truth);
    std::printf("| %s | points (%zu) | %.1f / %.0f | | | %zu | | |\n", name.c_str(), model.size(), points.rms_um,
                points.p99_um, points.far);
    for (const auto mode : {slscan::core::MeshMode::raw, slscan::core::MeshMode::watertight}) {
      slscan::core::MeshOptions options;
      options.mode = mode;
      const auto t0 = Clock::now();
      const auto result = slscan::mesh::build_mesh(model, options);
      const double ms = ms_since(t0);
      const auto check = slscan::mesh::check_mesh(result.mesh);
      char extra[256];
      std::snprintf(extra, sizeof extra,
                    "cell %.3f mm; CGAL: %s, %zu self-intersecting pairs, %zu refused; holes %zu filled %zu open; "
                    "%zu filled faces",
                    result.cell_mm, check.closed ? "closed" : "open", check.self_intersections,
                    check.rejected_triangles, result.stats.holes_filled, result.stats.holes_left_open,
                    result.stats.filled_triangles);
      row(name, std::string("VDB ") + slscan::core::mesh_mode_name(mode), mesh_figures(result.mesh, truth), ms,
          result.mesh.triangles.size(), extra);
    }
  }
  std::printf("\npeak RSS %ld MB\n", peak_rss_mb());
  return 0;
}
