// The mesh against the virtual rig's truth (issue 19, docs/mesh.md): each scene is rendered,
// reconstructed (exact calibration, 6 views), and its model meshed by slscan_mesh (raw and
// watertight). Every model point and mesh
// vertex is compared with the truth's surface samples (0.05 mm apart): distance along the
// nearest sample's normal; faces whose normal is more than 10 deg off the nearest sample's.
// Built with SLSCAN_BENCH_PEERS (and Open3D found), the same model cloud also goes through
// Open3D's screened Poisson (TriangleMesh::CreateFromPointCloudPoisson) at depths 8, 9 and 10,
// as it comes, trimmed by its densities (Open3D's way) and trimmed to the data (our raw mode's
// rule), measured by the same code (docs/mesh.md, "Against Open3D's screened Poisson").
//   bench_mesh [--size small|full] [--scenes ballbar,sphere,blade,teacup] [--modes raw,watertight] [--no-peers]
//              [--cache DIR] [--repeats N] [--dump DIR]
// --dump writes, per scene, the signed distance to the truth of every model point and of every
// measured vertex of each mesh (CSV x,y,z,distance_um, rig frame), to see where the error sits.
// --cache keeps each scene's model (PLY, rig frame) so that a second run meshes only.
// --no-peers leaves Open3D's rows out; --modes raw|watertight meshes in those modes only.
// --repeats N meshes each row N times and prints the fastest (wall; the machine is shared), with
// the CPU time of all threads of that run.
#include <sys/resource.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <numbers>
#include <span>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "slproto/pattern_plan.hpp"
#include "slrig/rig.hpp"
#include "slscan/core/huge_pages.hpp"
#include "slscan/core/mesh.hpp"
#include "slscan/core/point_index.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/io/ply.hpp"
#include "slscan/mesh/mesher.hpp"

#ifdef SLSCAN_HAVE_OPEN3D
#include <open3d/Open3DConfig.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/utility/Logging.h>

#include <thread>
#endif

namespace {

using Clock = std::chrono::steady_clock;

Eigen::Isometry3d to_isometry(const slproto::RigidTransform& t) {
  Eigen::Isometry3d m = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m.linear()(r, c) = t.R[3 * static_cast<std::size_t>(r) + static_cast<std::size_t>(c)];
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
        info.stride_bytes = static_cast<std::size_t>(width) * static_cast<std::size_t>(bytes_per_pixel);
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

// Signed distance to the truth along the nearest sample's normal (samples within 1 mm), NaN
// where no sample is that near.
double signed_distance(const Eigen::Vector3f& p, const Truth& truth) {
  float d2 = 0;
  const std::int64_t k = truth.index->nearest_within(p, 1.0f, d2);
  if (k < 0) return std::numeric_limits<double>::quiet_NaN();
  const auto i = static_cast<std::size_t>(k);
  return static_cast<double>(truth.normals[i].dot(p - truth.points[i]));
}

// Distances of `points` to the truth (along the nearest sample's normal, samples within 1 mm).
Figures distances(const std::vector<Eigen::Vector3f>& points, const Truth& truth) {
  Figures f;
  std::vector<double> d;
  d.reserve(points.size());
  for (const auto& p : points) {
    const double s = signed_distance(p, truth);
    if (std::isnan(s)) {
      ++f.far;
      continue;
    }
    d.push_back(std::abs(s));
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

// The vertices of the measured (not filled) faces.
std::vector<Eigen::Vector3f> measured_vertices(const slscan::core::TriangleMesh& mesh) {
  std::vector<std::uint8_t> used(mesh.vertices.size(), 0);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    if (mesh.filled.empty() || !mesh.filled[t])
      for (const auto v : mesh.triangles[t]) used[v] = 1;
  std::vector<Eigen::Vector3f> vertices;
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    if (used[i]) vertices.push_back(mesh.vertices[i]);
  return vertices;
}

void dump_distances(const std::filesystem::path& file, const std::vector<Eigen::Vector3f>& points, const Truth& truth) {
  std::FILE* out = std::fopen(file.c_str(), "w");
  if (out == nullptr) throw std::runtime_error("bench_mesh: cannot write " + file.string());
  std::fprintf(out, "x,y,z,distance_um\n");
  for (const auto& p : points)
    std::fprintf(out, "%.4f,%.4f,%.4f,%.2f\n", p.x(), p.y(), p.z(), 1e3 * signed_distance(p, truth));
  if (std::fclose(out) != 0) throw std::runtime_error("bench_mesh: cannot write " + file.string());
}

Figures mesh_figures(const slscan::core::TriangleMesh& mesh, const Truth& truth) {
  // Vertices of measured (not filled) faces only.
  std::size_t faces = 0, bad = 0, flipped = 0;
  const double cos10 = std::cos(10 * std::numbers::pi / 180);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!mesh.filled.empty() && mesh.filled[t]) continue;
    const auto& tri = mesh.triangles[t];
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
  Figures f = distances(measured_vertices(mesh), truth);
  f.bad_face_percent = faces ? 100.0 * static_cast<double>(bad) / static_cast<double>(faces) : 0;
  f.flipped_face_percent = faces ? 100.0 * static_cast<double>(flipped) / static_cast<double>(faces) : 0;
  return f;
}

// The measured faces' own surface, not only their corners: each face's centre and edge
// midpoints (weighted equally). A simplified mesh's vertices stay on the surface while its larger
// faces cut chords across curvature; these samples see the chords.
std::vector<Eigen::Vector3f> face_samples(const slscan::core::TriangleMesh& mesh) {
  std::vector<Eigen::Vector3f> samples;
  samples.reserve(4 * mesh.triangles.size());
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!mesh.filled.empty() && mesh.filled[t]) continue;
    const auto& tri = mesh.triangles[t];
    const Eigen::Vector3f a = mesh.vertices[tri[0]], b = mesh.vertices[tri[1]], c = mesh.vertices[tri[2]];
    samples.push_back((a + b + c) / 3);
    samples.push_back((a + b) / 2);
    samples.push_back((b + c) / 2);
    samples.push_back((c + a) / 2);
  }
  return samples;
}

// By area rather than by face: a simplified mesh keeps small faces where the surface curves
// (where the error is largest) and merges flat regions into few large ones, so per-face and
// per-vertex figures over-weight the curved regions. Distance at each measured face's centre and
// edge midpoints weighted by a quarter of its area; the share of measured area > 10 deg off truth.
struct AreaFigures {
  double rms_um = 0, bad_area_percent = 0;
};
AreaFigures area_weighted(const slscan::core::TriangleMesh& mesh, const Truth& truth) {
  double w_sum = 0, d2_sum = 0, area = 0, bad = 0;
  const double cos10 = std::cos(10 * std::numbers::pi / 180);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!mesh.filled.empty() && mesh.filled[t]) continue;
    const auto& tri = mesh.triangles[t];
    const Eigen::Vector3f a = mesh.vertices[tri[0]], b = mesh.vertices[tri[1]], c = mesh.vertices[tri[2]];
    const Eigen::Vector3f cross = (b - a).cross(c - a);
    const double w = 0.5 * static_cast<double>(cross.norm());
    float d2 = 0;
    const std::int64_t k = truth.index->nearest_within((a + b + c) / 3, 1.0f, d2);
    if (k < 0) continue;
    area += w;
    if (cross.normalized().dot(truth.normals[static_cast<std::size_t>(k)]) < cos10) bad += w;
    for (const Eigen::Vector3f& p : {Eigen::Vector3f((a + b + c) / 3), Eigen::Vector3f((a + b) / 2),
                                     Eigen::Vector3f((b + c) / 2), Eigen::Vector3f((c + a) / 2)}) {
      const double s = signed_distance(p, truth);
      if (std::isnan(s)) continue;
      w_sum += w / 4;
      d2_sum += w / 4 * s * s;
    }
  }
  AreaFigures f;
  if (w_sum > 0) f.rms_um = 1e3 * std::sqrt(d2_sum / w_sum);
  if (area > 0) f.bad_area_percent = 100 * bad / area;
  return f;
}

double ms_since(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

// CPU time of the process, every thread: on a shared machine the wall time of a multi-threaded
// step depends on how often its threads get a core, the CPU time much less.
double process_cpu_ms() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const auto ms = [](const timeval& t) {
    return 1e3 * static_cast<double>(t.tv_sec) + 1e-3 * static_cast<double>(t.tv_usec);
  };
  return ms(usage.ru_utime) + ms(usage.ru_stime);
}

// Wall and CPU time of one step.
struct Timing {
  double wall_ms = 0, cpu_ms = 0;
  Timing operator+(const Timing& other) const { return {wall_ms + other.wall_ms, cpu_ms + other.cpu_ms}; }
};

struct Stopwatch {
  Clock::time_point wall = Clock::now();
  double cpu = process_cpu_ms();
  Timing elapsed() const { return {ms_since(wall), process_cpu_ms() - cpu}; }
};

// Of repeated runs, the fastest (wall) one: the others were slowed by the machine's other work.
void keep_fastest(Timing& best, const Timing& run, int repeat) {
  if (repeat == 0 || run.wall_ms < best.wall_ms) best = run;
}

long peak_rss_mb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024;
}

void row(const std::string& scene, const std::string& mesher, const Figures& f, const Timing& time,
         std::size_t triangles, const std::string& extra) {
  std::printf("| %s | %s | %.1f / %.0f | %.1f %% (%.1f %% flipped) | %zu | %zu | %.0f (CPU %.0f) | %s |\n",
              scene.c_str(), mesher.c_str(), f.rms_um, f.p99_um, f.bad_face_percent, f.flipped_face_percent, triangles,
              f.far, time.wall_ms, time.cpu_ms, extra.c_str());
  std::fflush(stdout);
}

#ifdef SLSCAN_HAVE_OPEN3D
// Open3D's tutorial trims its Poisson meshes at this density quantile
// (`densities < np.quantile(densities, 0.01)`, "Poisson surface reconstruction" in
// docs/geometry/surface_reconstruction): the vertices supported by the fewest points, i.e. the
// surface Poisson invents where there is no data.
constexpr double open3d_trim_quantile = 0.01;

// The model cloud as Open3D's (double precision is its only point type). Not timed: it is the
// bench's conversion, not Open3D's work.
open3d::geometry::PointCloud to_open3d(const slscan::core::PointCloud& model) {
  open3d::geometry::PointCloud cloud;
  cloud.points_.reserve(model.size());
  cloud.normals_.reserve(model.size());
  for (std::size_t i = 0; i < model.size(); ++i) {
    cloud.points_.push_back(model.points[i].cast<double>());
    cloud.normals_.push_back(model.normals[i].cast<double>());
  }
  return cloud;
}

// Open3D's mesh as ours, so that mesh_figures and check_mesh measure it like our rows (no face
// is flagged filled: Poisson's whole surface is counted).
slscan::core::TriangleMesh from_open3d(const open3d::geometry::TriangleMesh& mesh) {
  slscan::core::TriangleMesh ours;
  ours.vertices.reserve(mesh.vertices_.size());
  for (const auto& v : mesh.vertices_) ours.vertices.push_back(v.cast<float>());
  for (const auto& n : mesh.vertex_normals_) ours.normals.push_back(n.cast<float>().normalized());
  ours.triangles.reserve(mesh.triangles_.size());
  for (const auto& t : mesh.triangles_)
    ours.triangles.push_back(
        {static_cast<std::uint32_t>(t[0]), static_cast<std::uint32_t>(t[1]), static_cast<std::uint32_t>(t[2])});
  return ours;
}

// Removes the vertices (and their triangles) whose density is below the given quantile of all
// densities, as Open3D's tutorial does.
void trim_by_density(open3d::geometry::TriangleMesh& mesh, const std::vector<double>& densities, double quantile) {
  std::vector<double> sorted = densities;
  const auto at = static_cast<std::ptrdiff_t>(quantile * static_cast<double>(sorted.size() - 1));
  std::nth_element(sorted.begin(), sorted.begin() + at, sorted.end());
  const double threshold = sorted[static_cast<std::size_t>(at)];
  std::vector<bool> below(densities.size());
  for (std::size_t i = 0; i < densities.size(); ++i) below[i] = densities[i] < threshold;
  mesh.RemoveVerticesByMask(below);
}

std::string check_note(const slscan::core::TriangleMesh& mesh) {
  const auto check = slscan::mesh::check_mesh(mesh);
  char note[160];
  std::snprintf(note, sizeof note, "CGAL: %s, %zu self-intersecting pairs, %zu refused",
                check.closed ? "closed" : "open", check.self_intersections, check.rejected_triangles);
  return note;
}

// Drops the triangles with a vertex farther than `distance_mm` from every model point: our raw
// mode's trim to the data (docs/mesh.md step 6, trim_factor x cell), so that Poisson's surface
// is measured only where there are points, as our raw and watertight rows are (filled faces
// excluded).
slscan::core::TriangleMesh trim_to_data(const slscan::core::TriangleMesh& mesh, const slscan::core::PointCloud& model,
                                        double distance_mm) {
  const slscan::core::PointIndex index(model.points);
  std::vector<std::uint8_t> near(mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    float d2 = 0;
    near[i] = index.nearest_within(mesh.vertices[i], static_cast<float>(distance_mm), d2) >= 0;
  }
  slscan::core::TriangleMesh kept;
  kept.vertices = mesh.vertices;
  kept.normals = mesh.normals;
  for (const auto& t : mesh.triangles)
    if (near[t[0]] && near[t[1]] && near[t[2]]) kept.triangles.push_back(t);
  return kept;
}

// Open3D's screened Poisson on the same cloud at one depth: as it comes (closed over the unseen
// regions), trimmed by density (Open3D's own way), and trimmed to the data (our raw's rule).
// Times: the Poisson call; the trimmed rows add their trim (the conversion to our mesh, needed
// only by the bench, is not timed).
void open3d_rows(const std::string& scene, const slscan::core::PointCloud& model,
                 const open3d::geometry::PointCloud& cloud, int depth, int repeats, double data_trim_mm,
                 const Truth& truth) {
  Timing poisson_time, density_trim_time, data_trim_time;
  std::shared_ptr<open3d::geometry::TriangleMesh> poisson;
  open3d::geometry::TriangleMesh density_trimmed;
  slscan::core::TriangleMesh data_trimmed;
  for (int r = 0; r < repeats; ++r) {
    const Stopwatch call;
    // n_threads -1: Open3D's default, std::thread::hardware_concurrency().
    auto [mesh, densities] = open3d::geometry::TriangleMesh::CreateFromPointCloudPoisson(
        cloud, static_cast<std::size_t>(depth), /*width=*/0, /*scale=*/1.1f, /*linear_fit=*/false, /*n_threads=*/-1);
    keep_fastest(poisson_time, call.elapsed(), r);
    density_trimmed = *mesh;  // the copy is the bench's, not part of the trim
    const Stopwatch density_trim;
    trim_by_density(density_trimmed, densities, open3d_trim_quantile);
    keep_fastest(density_trim_time, density_trim.elapsed(), r);
    const slscan::core::TriangleMesh as_ours = from_open3d(*mesh);
    const Stopwatch data_trim;
    data_trimmed = trim_to_data(as_ours, model, data_trim_mm);
    keep_fastest(data_trim_time, data_trim.elapsed(), r);
    poisson = std::move(mesh);
  }
  const std::string name = "Open3D Poisson depth " + std::to_string(depth);
  const slscan::core::TriangleMesh as_is = from_open3d(*poisson);
  row(scene, name, mesh_figures(as_is, truth), poisson_time, as_is.triangles.size(), check_note(as_is));
  const slscan::core::TriangleMesh cut = from_open3d(density_trimmed);
  char trim_name[64];
  std::snprintf(trim_name, sizeof trim_name, " trimmed (density < %g %% quantile)", 100 * open3d_trim_quantile);
  row(scene, name + trim_name, mesh_figures(cut, truth), poisson_time + density_trim_time, cut.triangles.size(),
      check_note(cut) + "; trim alone " + std::to_string(std::lround(density_trim_time.wall_ms)) + " ms");
  char data_name[96];
  std::snprintf(data_name, sizeof data_name, " trimmed to the data (vertex > %.3f mm from every point)", data_trim_mm);
  row(scene, name + data_name, mesh_figures(data_trimmed, truth), poisson_time + data_trim_time,
      data_trimmed.triangles.size(),
      check_note(data_trimmed) + "; trim alone " + std::to_string(std::lround(data_trim_time.wall_ms)) + " ms");
}
#endif

}  // namespace

static int run_bench(int argc, char** argv) {
  std::string size_name = "small", cache, dump;
  int repeats = 1;
  std::size_t max_triangles = 0;
  double simplify_tolerance_mm = 0;
  std::vector<std::string> scenes{"ballbar", "sphere", "blade", "teacup"};
  [[maybe_unused]] bool peers = true;  // read only with Open3D
  std::vector<slscan::core::MeshMode> modes{slscan::core::MeshMode::raw, slscan::core::MeshMode::watertight};
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--size" && i + 1 < argc) {
      size_name = argv[++i];
    } else if (arg == "--cache" && i + 1 < argc) {
      cache = argv[++i];
    } else if (arg == "--dump" && i + 1 < argc) {
      dump = argv[++i];
    } else if (arg == "--repeats" && i + 1 < argc) {
      char* end = nullptr;
      const long n = std::strtol(argv[++i], &end, 10);
      if (end == argv[i] || *end != '\0' || n < 1 || n > 1000) {
        std::fprintf(stderr, "bench_mesh: --repeats wants a whole number from 1 to 1000, not '%s'\n", argv[i]);
        return 2;
      }
      repeats = static_cast<int>(n);
    } else if (arg == "--max-triangles" && i + 1 < argc) {
      char* end = nullptr;
      const long long n = std::strtoll(argv[++i], &end, 10);
      if (end == argv[i] || *end != '\0' || n < 4) {
        std::fprintf(stderr, "bench_mesh: --max-triangles wants a count >= 4, not '%s'\n", argv[i]);
        return 2;
      }
      max_triangles = static_cast<std::size_t>(n);
    } else if (arg == "--simplify-tolerance" && i + 1 < argc) {
      char* end = nullptr;
      simplify_tolerance_mm = std::strtod(argv[++i], &end);
      if (end == argv[i] || *end != '\0' || !(simplify_tolerance_mm > 0 && simplify_tolerance_mm <= 1)) {
        std::fprintf(stderr, "bench_mesh: --simplify-tolerance wants a distance in (0, 1] mm, not '%s'\n", argv[i]);
        return 2;
      }
    } else if (arg == "--no-peers") {
      peers = false;
    } else if (arg == "--modes" && i + 1 < argc) {
      modes.clear();
      std::stringstream list(argv[++i]);
      for (std::string s; std::getline(list, s, ',');) {
        if (s != "raw" && s != "watertight") {
          std::fprintf(stderr, "bench_mesh: --modes takes raw and/or watertight, not '%s'\n", s.c_str());
          return 2;
        }
        modes.push_back(s == "raw" ? slscan::core::MeshMode::raw : slscan::core::MeshMode::watertight);
      }
    } else if (arg == "--scenes" && i + 1 < argc) {
      scenes.clear();
      std::stringstream list(argv[++i]);
      for (std::string s; std::getline(list, s, ',');) scenes.push_back(s);
    } else {
      std::fprintf(stderr,
                   "usage: bench_mesh [--size small|full] [--scenes a,b] [--modes raw,watertight] [--no-peers]\n"
                   "                  [--cache DIR] [--repeats N] [--dump DIR] [--max-triangles N] "
                   "[--simplify-tolerance MM]  (adds simplified rows)\n");
      return 2;
    }
  }
  const slrig::RigSize size = size_name == "full" ? slrig::RigSize::full : slrig::RigSize::small;
#ifdef SLSCAN_HAVE_OPEN3D
  open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Warning);
  std::printf("Open3D %s, CreateFromPointCloudPoisson n_threads -1 (= hardware_concurrency %u); ours: TBB default\n\n",
              OPEN3D_VERSION, std::thread::hardware_concurrency());
#endif
  std::printf(
      "| scene | mesher | vertex distance RMS / p99 um | faces > 10 deg off truth | triangles | vertices > 1 mm "
      "from truth | ms (CPU ms, all threads) | notes |\n|---|---|---|---|---|---|---|---|\n");
  for (const auto& name : scenes) {
    auto scene_or = slrig::scene_preset(name, size);
    if (!scene_or) {
      std::fprintf(stderr, "%s\n", scene_or.error().message.c_str());
      return 1;
    }
    const slrig::Scene& scene = *scene_or;
    slscan::core::PointCloud model;
    std::string cached;
    if (!cache.empty()) {
      std::string file_name = name;
      file_name.append("_").append(size_name).append(".ply");
      cached = (std::filesystem::path(cache) / file_name).string();
    }
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
    std::string dump_stem = name;
    dump_stem.append("_").append(size_name);
    if (!dump.empty()) {
      std::filesystem::create_directories(dump);
      dump_distances(std::filesystem::path(dump) / (dump_stem + "_points.csv"), model.points, truth);
    }
    std::printf("| %s | points (%zu) | %.1f / %.0f | | | %zu | | |\n", name.c_str(), model.size(), points.rms_um,
                points.p99_um, points.far);
    // Our raw mode's trim distance, applied to Open3D's mesh too (unused without Open3D).
    [[maybe_unused]] double raw_trim_mm = 0;
    const bool simplify = max_triangles > 0 || simplify_tolerance_mm > 0;
    for (const auto mode : modes)
      for (const bool simplified : {false, true}) {
        if (simplified && !simplify) continue;
        slscan::core::MeshOptions options;
        options.mode = mode;
        if (simplified) {
          options.max_triangles = max_triangles;
          options.simplify_tolerance_mm = simplify_tolerance_mm;
        }
        slscan::core::MeshResult result;
        Timing time;
        for (int r = 0; r < repeats; ++r) {
          const Stopwatch call;
          result = slscan::mesh::build_mesh(model, options);
          keep_fastest(time, call.elapsed(), r);
        }
        const auto check = slscan::mesh::check_mesh(result.mesh);
        const Figures faces = distances(face_samples(result.mesh), truth);
        const AreaFigures by_area = area_weighted(result.mesh, truth);
        char extra[640];
        std::snprintf(
            extra, sizeof extra,
            "cell %.3f mm; CGAL: %s, %zu self-intersecting pairs, %zu refused; holes %zu filled %zu open; "
            "%zu filled faces; %zu crossing triangles cut%s; face centres and edge midpoints RMS / p99 "
            "%.1f / %.0f um; by area: RMS %.1f um, %.1f %% > 10 deg%s%s",
            result.cell_mm, check.closed ? "closed" : "open", check.self_intersections, check.rejected_triangles,
            result.stats.holes_filled, result.stats.holes_left_open, result.stats.filled_triangles,
            result.stats.crossing_triangles, result.stats.sides_separated ? "" : "; fit over both sides (fallback)",
            faces.rms_um, faces.p99_um, by_area.rms_um, by_area.bad_area_percent,
            result.stats.simplified ? "; simplified" : "",
            result.stats.simplify_skipped.empty() ? ""
                                                  : ("; not simplified: " + result.stats.simplify_skipped).c_str());
        // trim_factor x max(cell, spacing); the cell is at least the spacing with the default options.
        if (mode == slscan::core::MeshMode::raw) raw_trim_mm = options.trim_factor * result.cell_mm;
        if (!dump.empty()) {
          std::vector<Eigen::Vector3f> crossing;
          for (const std::size_t t : slscan::mesh::self_intersecting_triangles(result.mesh)) {
            const auto& tri = result.mesh.triangles[t];
            crossing.push_back(
                (result.mesh.vertices[tri[0]] + result.mesh.vertices[tri[1]] + result.mesh.vertices[tri[2]]) / 3);
          }
          dump_distances(std::filesystem::path(dump) /
                             (dump_stem + "_" + slscan::core::mesh_mode_name(mode) + "_self_intersecting.csv"),
                         crossing, truth);
          std::map<std::pair<std::uint32_t, std::uint32_t>, int> edges;
          for (const auto& t : result.mesh.triangles)
            for (int k = 0; k < 3; ++k) {
              const std::uint32_t a = t[static_cast<std::size_t>(k)], b = t[static_cast<std::size_t>((k + 1) % 3)];
              ++edges[{std::min(a, b), std::max(a, b)}];
            }
          std::vector<Eigen::Vector3f> border;
          for (const auto& [e, n] : edges)
            if (n == 1) border.push_back((result.mesh.vertices[e.first] + result.mesh.vertices[e.second]) / 2);
          dump_distances(
              std::filesystem::path(dump) / (dump_stem + "_" + slscan::core::mesh_mode_name(mode) + "_border.csv"),
              border, truth);
        }
        if (!dump.empty())
          dump_distances(std::filesystem::path(dump) / (dump_stem + "_" + slscan::core::mesh_mode_name(mode) + ".csv"),
                         measured_vertices(result.mesh), truth);
        std::string mesher = std::string("VDB ") + slscan::core::mesh_mode_name(mode);
        if (simplified) {
          char how[96];
          std::snprintf(how, sizeof how, ", simplified (max %zu, tolerance %g mm)", max_triangles,
                        simplify_tolerance_mm);
          mesher += how;
        }
        row(name, mesher, mesh_figures(result.mesh, truth), time, result.mesh.triangles.size(), extra);
        // Where the time goes (the last repeat's steps), on stderr so the table stays a table.
        std::string steps;
        for (const auto& [step, ms] : result.stats.step_ms)
          steps.append(steps.empty() ? "" : ", ").append(step).append(" ").append(std::to_string(std::lround(ms)));
        std::fprintf(stderr, "%s %s steps (ms): %s\n", name.c_str(), slscan::core::mesh_mode_name(mode), steps.c_str());
      }
#ifdef SLSCAN_HAVE_OPEN3D
    const open3d::geometry::PointCloud open3d_cloud = to_open3d(model);
    if (peers)
      for (const int depth : {8, 9, 10}) open3d_rows(name, model, open3d_cloud, depth, repeats, raw_trim_mm, truth);
#endif
  }
  std::printf("\npeak RSS %ld MB\n", peak_rss_mb());
  return 0;
}

int main(int argc, char** argv) {
  slscan::core::run_with_huge_pages(argv);  // as slscan does: the same allocator behind the same code
  try {
    return run_bench(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_mesh: %s\n", e.what());
    return 1;
  }
}
