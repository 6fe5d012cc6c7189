#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <thread>

#include "scene_build.hpp"
#include "slrig/rig.hpp"

namespace slrig {

namespace {

using detail::Frame;
using detail::V3;

constexpr int kSamplesPerPx = 8;  // profile table resolution (sub-samples per projector pixel)

// Runs fn(row_begin, row_end) over [0, rows) on the machine's cores, handing out blocks of
// rows dynamically (the top of a view is cheap wall, the bottom busy table and objects).
template <class F>
void parallel_rows(int rows, F&& fn) {
  const unsigned hw = std::max(1u, std::thread::hardware_concurrency());
  const int threads = std::clamp(static_cast<int>(hw), 1, std::max(1, std::min(16, rows / 8)));
  constexpr int kBlock = 8;
  std::atomic<int> next{0};
  auto worker = [&] {
    for (;;) {
      const int begin = next.fetch_add(kBlock);
      if (begin >= rows) return;
      fn(begin, std::min(rows, begin + kBlock));
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(static_cast<std::size_t>(threads - 1));
  for (int t = 1; t < threads; ++t) pool.emplace_back(worker);
  worker();
  for (auto& th : pool) th.join();
}

// 32-bit finaliser (MurmurHash3 fmix32): cheap enough to vectorise in the per-frame loop.
inline std::uint32_t fmix32(std::uint32_t h) {
  h ^= h >> 16;
  h *= 0x85EBCA6Bu;
  h ^= h >> 13;
  h *= 0xC2B2AE35u;
  h ^= h >> 16;
  return h;
}

// Distortion with its Jacobian, for Newton undistortion warm-started from the neighbour pixel.
struct Undistorter {
  slproto::LensDistortion d;
  bool solve(double xd, double yd, double& x, double& y) const {
    if (d.is_zero()) {
      x = xd;
      y = yd;
      return true;
    }
    for (int iter = 0; iter < 30; ++iter) {
      const double r2 = x * x + y * y;
      const double radial = 1 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
      const double dradial = d.k1 + r2 * (2 * d.k2 + 3 * r2 * d.k3);
      const double fx = x * radial + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x) - xd;
      const double fy = y * radial + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y - yd;
      const double j00 = radial + 2 * x * x * dradial + 2 * d.p1 * y + 6 * d.p2 * x;
      const double j01 = 2 * x * y * dradial + 2 * d.p1 * x + 2 * d.p2 * y;
      const double j10 = 2 * x * y * dradial + 2 * d.p1 * x + 2 * d.p2 * y;
      const double j11 = radial + 2 * y * y * dradial + 6 * d.p1 * y + 2 * d.p2 * x;
      const double det = j00 * j11 - j01 * j10;
      if (!std::isfinite(det) || std::abs(det) < 1e-12) return false;
      const double dx = (j11 * fx - j01 * fy) / det, dy = (-j10 * fx + j00 * fy) / det;
      x -= dx;
      y -= dy;
      if (std::abs(dx) < 1e-15 && std::abs(dy) < 1e-15) return true;
    }
    return false;
  }
};

double gaussian_cdf(double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); }

// The light a projector puts out along its coding axis for one pattern, sampled at
// kSamplesPerPx points per projector pixel from coordinate -0.5 to W - 0.5: each DMD pixel
// emits its 8-bit level through the gamma curve over its whole width, and defocus blurs that
// with a Gaussian (so the blur is of the emitted light, not of the pattern values).
std::vector<float> build_profile(const slproto::PatternPlan& plan, std::size_t index, double gamma, double sigma) {
  const int W = plan.config().coded_extent();
  std::vector<double> emitted(static_cast<std::size_t>(W));
  for (int k = 0; k < W; ++k) {
    const double level = std::round(255.0 * plan.value(index, k)) / 255.0;
    emitted[static_cast<std::size_t>(k)] = std::pow(level, gamma);
  }
  const int S = kSamplesPerPx;
  std::vector<float> table(static_cast<std::size_t>(W) * S + 1);
  const int reach = sigma > 1e-9 ? static_cast<int>(std::ceil(5 * sigma)) + 1 : 0;
  // weights[r][d]: share of pixel m - d at sample s = m S + r, where x - k = d + r / S - 0.5.
  std::vector<double> weights(static_cast<std::size_t>(S * (2 * reach + 1)));
  for (int r = 0; r < S; ++r)
    for (int d = -reach; d <= reach; ++d) {
      const double offset = d + static_cast<double>(r) / S - 0.5;  // x - k
      double w;
      if (reach == 0) {
        w = (offset >= -0.5 && offset < 0.5) ? 1.0 : 0.0;
      } else {
        w = gaussian_cdf((offset + 0.5) / sigma) - gaussian_cdf((offset - 0.5) / sigma);
      }
      weights[static_cast<std::size_t>(r * (2 * reach + 1) + d + reach)] = w;
    }
  for (std::size_t s = 0; s < table.size(); ++s) {
    const int m = static_cast<int>(s) / S, r = static_cast<int>(s) % S;
    double sum = 0;
    for (int d = -reach; d <= reach; ++d) {
      const int k = m - d;
      if (k < 0 || k >= W) continue;
      sum += weights[static_cast<std::size_t>(r * (2 * reach + 1) + d + reach)] * emitted[static_cast<std::size_t>(k)];
    }
    table[s] = static_cast<float>(sum);
  }
  if (reach == 0) table.back() = static_cast<float>(emitted.back());
  return table;
}

// A projector as the shading needs it: where it is, how it projects, how bright it is.
struct ProjectorGeometry {
  Frame proj_from_cam;
  V3 centre;
  slproto::PinholeModel intrinsics;
  double reference_distance2 = 1, brightness = 1;
};

std::array<ProjectorGeometry, 2> projector_geometry(const Scene& scene) {
  std::array<ProjectorGeometry, 2> projectors;
  const V3 table_centre(scene.turntable.cam_from_table.t);
  for (std::size_t s = 0; s < 2; ++s) {
    const ProjectorModel& model = scene.projectors[s];
    projectors[s].proj_from_cam = Frame(model.cam_from_proj.inverse());
    projectors[s].centre = V3(model.cam_from_proj.t);
    projectors[s].intrinsics = model.intrinsics;
    const V3 to_centre = table_centre - projectors[s].centre;
    projectors[s].reference_distance2 = detail::dot(to_centre, to_centre);
    projectors[s].brightness = model.brightness;
  }
  return projectors;
}

}  // namespace

struct ViewRenderer::Impl {
  int width = 0, height = 0, view_index = 0;
  int bit_depth = 8;
  slproto::PatternPlan plan;
  std::array<double, 2> gamma{}, sigma{};
  bool noise = true;
  std::uint64_t seed = 1;
  float max_dn = 255, dark_dn = 0, shot_per_dn = 0, read_var = 0;
  double reference_exposure_us = 8333;
  float blooming = 0;
  AmbientLight ambient;
  ViewGroundTruth truth;
  std::vector<float> offset;                         // ambient + dark, DN, at the reference exposure
  std::array<std::vector<float>, 2> position, gain;  // profile sample position; DN per unit light
  std::array<std::vector<std::vector<float>>, 2> profiles;
  // Per row, the largest offset and gain (indirect light included): whether a frame can reach
  // full scale there, so blooming costs nothing where nothing clips.
  std::vector<float> row_max_offset;
  std::array<std::vector<float>, 2> row_max_gain;
  // One-bounce interreflection, per side: for the pixels that gather any, their samples' profile
  // positions and weights (DN per unit light), pixel-sorted; row_begin[v] indexes the first
  // pixel of row v in `pixel`.
  struct Indirect {
    std::vector<std::uint32_t> pixel, first;  // first[k] .. first[k + 1]: samples of pixel[k]
    std::vector<float> position, weight;
    std::vector<std::uint32_t> row_begin;  // height + 1 entries
    bool empty() const { return pixel.empty(); }
  };
  std::array<Indirect, 2> indirect;
  // Kept from shading for the bounce only (then released): each pixel's albedo and, per side,
  // its diffuse gain (DN per unit light, no specular).
  std::vector<float> albedo_px;
  std::array<std::vector<float>, 2> diffuse_gain;

  // A frame's exposure as multipliers of the reference: the ambient's (flicker integrated) and
  // the projector's.
  struct Scales {
    float ambient = 1, projector = 1;
    bool reference() const { return ambient == 1.0f && projector == 1.0f; }
  };

  static std::unique_ptr<Impl> create(const Scene& scene, const detail::PreparedObjects& prepared,
                                      double commanded_angle_deg, int view_index);
  void shade(const Scene& scene, const detail::World& world);
  void gather_indirect(const Scene& scene, const detail::World& world, int samples);
  slproto::Status scales_of(const Exposure& exposure, Scales& scales) const;
  void render_with(int side, const std::vector<float>* profile, std::uint64_t frame_key, Scales scales,
                   std::span<std::uint8_t> out) const;
};

void ViewRenderer::Impl::shade(const Scene& scene, const detail::World& world) {
  const slproto::PinholeModel& cam = scene.camera;
  const std::size_t n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  truth.points.assign(3 * n, nan);
  truth.normals.assign(3 * n, nan);
  truth.object_id.assign(n, -1);
  truth.part_id.assign(n, 0);
  for (int s = 0; s < 2; ++s) {
    truth.projector_coord[static_cast<std::size_t>(s)].assign(n, nan);
    truth.lit[static_cast<std::size_t>(s)].assign(n, 0);
    position[static_cast<std::size_t>(s)].assign(n, 0.0f);
    gain[static_cast<std::size_t>(s)].assign(n, 0.0f);
  }
  offset.assign(n, 0.0f);
  if (scene.interreflection) {
    albedo_px.assign(n, 0.0f);
    for (auto& d : diffuse_gain) d.assign(n, 0.0f);
  }

  const double scale = std::ldexp(1.0, bit_depth - 8);  // 8-bit DN -> frame DN
  const double white = scene.sensor.white_level_dn * scale;
  const double dark = scene.sensor.dark_level_dn * scale;
  const std::array<ProjectorGeometry, 2> projectors = projector_geometry(scene);
  const bool columns = scene.pattern_plan.axis == slproto::CodingAxis::columns;
  const Undistorter undistorter{cam.distortion};

  parallel_rows(height, [&](int row_begin, int row_end) {
    for (int v = row_begin; v < row_end; ++v) {
      double x = (0 - cam.cx) / cam.fx, y = (v - cam.cy) / cam.fy;
      for (int u = 0; u < width; ++u) {
        const std::size_t i =
            static_cast<std::size_t>(v) * static_cast<std::size_t>(width) + static_cast<std::size_t>(u);
        const double xd = (u - cam.cx) / cam.fx, yd = (v - cam.cy) / cam.fy;
        if (!undistorter.solve(xd, yd, x, y)) {
          x = xd;
          y = yd;
          offset[i] = static_cast<float>(dark);
          continue;
        }
        const V3 dir{x, y, 1.0};
        detail::Hit hit;
        if (!world.intersect({0, 0, 0}, dir, 0.0, std::numeric_limits<double>::infinity(), hit)) {
          offset[i] = static_cast<float>(dark);
          continue;
        }
        const detail::Primitive& prim = world.primitives[static_cast<std::size_t>(hit.primitive)];
        const V3 p = hit.t * dir;
        const V3 view = detail::normalized(-dir);
        V3 normal = detail::normalized(hit.normal);
        if (detail::dot(normal, view) < 0) normal = -normal;
        // A sensor pixel integrates light over its area: where a texture edge (the
        // checkerboard's squares) crosses the pixel, the albedo is the footprint's mean, so
        // edges are anti-aliased. Only textured surfaces pay for the corner rays; the
        // projector's pattern and the geometry are still sampled at the pixel centre.
        double albedo;
        if (prim.material.checker) {
          std::array<V3, 4> corners;
          constexpr double kCorner[4][2] = {{-0.5, -0.5}, {0.5, -0.5}, {0.5, 0.5}, {-0.5, 0.5}};
          bool solved = true;
          for (std::size_t k = 0; k < 4 && solved; ++k) {
            double xc = x, yc = y;
            solved =
                undistorter.solve((u + kCorner[k][0] - cam.cx) / cam.fx, (v + kCorner[k][1] - cam.cy) / cam.fy, xc, yc);
            corners[k] = {xc, yc, 1.0};
          }
          albedo = solved ? world.footprint_albedo(hit, {0, 0, 0}, corners) : world.albedo_at(hit);
        } else {
          albedo = world.albedo_at(hit);
        }
        truth.points[3 * i] = static_cast<float>(p.x);
        truth.points[3 * i + 1] = static_cast<float>(p.y);
        truth.points[3 * i + 2] = static_cast<float>(p.z);
        truth.normals[3 * i] = static_cast<float>(normal.x);
        truth.normals[3 * i + 1] = static_cast<float>(normal.y);
        truth.normals[3 * i + 2] = static_cast<float>(normal.z);
        truth.object_id[i] = prim.object_id;
        truth.part_id[i] = prim.part_id;
        offset[i] = static_cast<float>(white * albedo * scene.ambient.level + dark);
        if (!albedo_px.empty()) albedo_px[i] = static_cast<float>(albedo);
        for (std::size_t s = 0; s < 2; ++s) {
          const ProjectorGeometry& pg = projectors[s];
          const V3 q = pg.proj_from_cam.apply(p);
          double up, vp;
          if (!pg.intrinsics.project(q.arr(), up, vp)) continue;
          if (up < -0.5 || up > pg.intrinsics.width - 0.5 || vp < -0.5 || vp > pg.intrinsics.height - 0.5) continue;
          const V3 to_light = pg.centre - p;
          const double distance2 = detail::dot(to_light, to_light);
          const V3 l = (1.0 / std::sqrt(distance2)) * to_light;
          const double cos_incidence = detail::dot(normal, l);
          if (cos_incidence <= 0) continue;
          if (world.occluded(p + 2e-4 * normal, to_light, 0.0, 1.0 - 1e-9, prim.convex() ? hit.primitive : -1))
            continue;
          double reflect = albedo * cos_incidence;
          if (prim.material.specular > 0) {
            const V3 h = detail::normalized(l + view);
            reflect +=
                prim.material.specular * std::pow(std::max(0.0, detail::dot(normal, h)), prim.material.specular_power);
          }
          const double falloff = pg.reference_distance2 / distance2;
          const double coord = columns ? up : vp;
          truth.projector_coord[s][i] = static_cast<float>(coord);
          truth.lit[s][i] = 1;
          position[s][i] = static_cast<float>((coord + 0.5) * kSamplesPerPx);
          gain[s][i] = static_cast<float>(white * pg.brightness * falloff * reflect);
          if (!diffuse_gain[s].empty())
            diffuse_gain[s][i] = static_cast<float>(white * pg.brightness * falloff * albedo * cos_incidence);
        }
      }
    }
  });
}

void ViewRenderer::Impl::gather_indirect(const Scene& scene, const detail::World& world, int samples) {
  // One bounce of projector light between diffuse surfaces. A receiving pixel p (a scene
  // object or the platform) gathers m x m stratified, cosine-distributed rays; a ray that meets
  // a surface q lit by a projector adds q's diffuse radiance to p's irradiance. With cosine
  // sampling the estimate is E_p = (1 / K) sum_k albedo_q E_q, so p's signal grows by
  // white x albedo_p x E_p, each term following q's projector coordinate (the pattern q shows).
  // Specular reflections at either end are left out (docs/virtual-rig.md).
  const int m = std::max(1, static_cast<int>(std::sqrt(static_cast<double>(samples))));
  const int count = m * m;
  const slproto::PinholeModel& cam = scene.camera;
  const std::array<ProjectorGeometry, 2> projectors = projector_geometry(scene);
  const bool columns = scene.pattern_plan.axis == slproto::CodingAxis::columns;
  const auto w = static_cast<std::size_t>(width);
  struct Sample {
    float position, weight;
  };
  struct RowSamples {
    std::vector<std::uint32_t> pixel, first;  // first has one more entry than pixel
    std::vector<float> position, weight;
  };
  std::array<std::vector<RowSamples>, 2> rows;
  for (auto& r : rows) r.resize(static_cast<std::size_t>(height));
  const double kMinWeight = 1e-4;  // DN: below anything a frame can show
  parallel_rows(height, [&](int row_begin, int row_end) {
    std::array<std::vector<Sample>, 2> gathered;
    for (int v = row_begin; v < row_end; ++v) {
      for (std::size_t u = 0; u < w; ++u) {
        const std::size_t i = static_cast<std::size_t>(v) * w + u;
        const std::int16_t id = truth.object_id[i];
        if (id < 0 || id == detail::kWallId) continue;
        const V3 p{truth.points[3 * i], truth.points[3 * i + 1], truth.points[3 * i + 2]};
        const V3 n{truth.normals[3 * i], truth.normals[3 * i + 1], truth.normals[3 * i + 2]};
        const V3 helper = std::abs(n.x) < 0.9 ? V3{1, 0, 0} : V3{0, 1, 0};
        const V3 tx = detail::normalized(detail::cross(helper, n));
        const V3 ty = detail::cross(n, tx);
        const double albedo_p = albedo_px[i];
        for (auto& g : gathered) g.clear();
        for (int a = 0; a < m; ++a)
          for (int b = 0; b < m; ++b) {
            const std::uint64_t hsh = detail::mix64(
                seed ^ detail::mix64((static_cast<std::uint64_t>(view_index) << 40) ^
                                     (i * static_cast<std::uint64_t>(count) + static_cast<std::uint64_t>(a * m + b))));
            const double r1 = (a + static_cast<double>(hsh >> 40) / 16777216.0) / m;
            const double r2 = (b + static_cast<double>(hsh & 0xFFFFFF) / 16777216.0) / m;
            const double radius = std::sqrt(r1), phi = 2 * std::numbers::pi * r2;
            const V3 dir = (radius * std::cos(phi)) * tx + (radius * std::sin(phi)) * ty + std::sqrt(1 - r1) * n;
            detail::Hit hit;
            if (!world.intersect(p + 1e-3 * n, dir, 0.0, std::numeric_limits<double>::infinity(), hit)) continue;
            const detail::Primitive& prim = world.primitives[static_cast<std::size_t>(hit.primitive)];
            const V3 q = p + 1e-3 * n + hit.t * dir;
            V3 nq = detail::normalized(hit.normal);
            if (detail::dot(nq, dir) > 0) nq = -nq;  // the side facing p
            const double albedo_q = world.albedo_at(hit);
            if (albedo_q <= 0) continue;
            // Reuse the camera's own shading where the camera sees q (most of a concave
            // part's inside): its projector coordinate and diffuse gain, no shadow rays.
            double uc, vc;
            std::ptrdiff_t seen = -1;
            if (cam.project(q.arr(), uc, vc)) {
              const long ui = std::lround(uc), vi = std::lround(vc);
              if (ui >= 0 && vi >= 0 && ui < width && vi < height) {
                const auto j = static_cast<std::size_t>(vi) * w + static_cast<std::size_t>(ui);
                const V3 pj{truth.points[3 * j], truth.points[3 * j + 1], truth.points[3 * j + 2]};
                const double tolerance = 2.0 * q.z / cam.fx;  // two pixel footprints
                if (truth.object_id[j] >= 0 && detail::norm(pj - q) < tolerance) seen = static_cast<std::ptrdiff_t>(j);
              }
            }
            for (std::size_t s = 0; s < 2; ++s) {
              double coord = 0, light = 0;  // q's diffuse signal per unit pattern, as the camera would read it
              if (seen >= 0) {
                const auto j = static_cast<std::size_t>(seen);
                if (!truth.lit[s][j]) continue;
                coord = truth.projector_coord[s][j];
                light = diffuse_gain[s][j];
              } else {
                const ProjectorGeometry& pg = projectors[s];
                const V3 qp = pg.proj_from_cam.apply(q);
                double up, vp;
                if (!pg.intrinsics.project(qp.arr(), up, vp)) continue;
                if (up < -0.5 || up > pg.intrinsics.width - 0.5 || vp < -0.5 || vp > pg.intrinsics.height - 0.5)
                  continue;
                const V3 to_light = pg.centre - q;
                const double distance2 = detail::dot(to_light, to_light);
                const double cos_incidence = detail::dot(nq, (1.0 / std::sqrt(distance2)) * to_light);
                if (cos_incidence <= 0) continue;
                if (world.occluded(q + 2e-4 * nq, to_light, 0.0, 1.0 - 1e-9, prim.convex() ? hit.primitive : -1))
                  continue;
                const double scale = std::ldexp(1.0, bit_depth - 8);
                light = scene.sensor.white_level_dn * scale * pg.brightness * pg.reference_distance2 / distance2 *
                        albedo_q * cos_incidence;
                coord = columns ? up : vp;
              }
              const double weight = albedo_p * light / count;  // light includes albedo_q
              if (weight < kMinWeight) continue;
              gathered[s].push_back({static_cast<float>((coord + 0.5) * kSamplesPerPx), static_cast<float>(weight)});
            }
          }
        for (std::size_t s = 0; s < 2; ++s) {
          if (gathered[s].empty()) continue;
          RowSamples& out = rows[s][static_cast<std::size_t>(v)];
          if (out.first.empty()) out.first.push_back(0);
          out.pixel.push_back(static_cast<std::uint32_t>(i));
          for (const Sample& smp : gathered[s]) {
            out.position.push_back(smp.position);
            out.weight.push_back(smp.weight);
          }
          out.first.push_back(static_cast<std::uint32_t>(out.position.size()));
        }
      }
    }
  });
  for (std::size_t s = 0; s < 2; ++s) {
    Indirect& bounce = indirect[s];
    bounce.row_begin.assign(static_cast<std::size_t>(height) + 1, 0);
    bounce.first.push_back(0);
    for (std::size_t v = 0; v < static_cast<std::size_t>(height); ++v) {
      bounce.row_begin[v] = static_cast<std::uint32_t>(bounce.pixel.size());
      const RowSamples& r = rows[s][v];
      const auto base = static_cast<std::uint32_t>(bounce.position.size());
      for (std::size_t k = 0; k < r.pixel.size(); ++k) {
        bounce.pixel.push_back(r.pixel[k]);
        bounce.first.push_back(base + r.first[k + 1]);
      }
      bounce.position.insert(bounce.position.end(), r.position.begin(), r.position.end());
      bounce.weight.insert(bounce.weight.end(), r.weight.begin(), r.weight.end());
    }
    bounce.row_begin[static_cast<std::size_t>(height)] = static_cast<std::uint32_t>(bounce.pixel.size());
    if (bounce.pixel.empty()) bounce = Indirect{};
  }
  albedo_px = {};
  diffuse_gain = {};
}

slproto::Status ViewRenderer::Impl::scales_of(const Exposure& exposure, Scales& scales) const {
  auto fail = [](std::string message) {
    return slproto::make_error(slproto::Errc::invalid_argument, "render: " + std::move(message));
  };
  const double t = exposure.exposure_us == 0 ? reference_exposure_us : exposure.exposure_us;
  if (!(t > 0) || !std::isfinite(t) || t > 1e8)
    return fail("exposure_us " + std::to_string(exposure.exposure_us) + " is not in (0, 1e8]");
  if (!(exposure.led_current > 0 && exposure.led_current <= 1))
    return fail("led_current " + std::to_string(exposure.led_current) + " is not in (0, 1]");
  if (!(exposure.projector_us >= 0 && exposure.projector_us <= t))
    return fail("projector_us " + std::to_string(exposure.projector_us) + " is not in [0, exposure " +
                std::to_string(t) + " us]");
  if (!std::isfinite(exposure.start_s)) return fail("start_s is not a finite number");
  const double lit = exposure.projector_us == 0 ? t : exposure.projector_us;
  double ambient_scale = t / reference_exposure_us;
  if (ambient.flicker_depth > 0) {
    // The lamps' intensity 1 + m cos(w t + phi) integrated over [t0, t0 + T]: its mean is
    // 1 + m (sin(w (t0 + T) + phi) - sin(w t0 + phi)) / (w T), exactly 1 for whole periods.
    const double w = 2.0 * std::numbers::pi * 2.0 * ambient.mains_hz;
    const double phi = ambient.phase_deg * std::numbers::pi / 180.0;
    const double t0 = exposure.start_s, T = t * 1e-6;
    // The start time modulo the flicker period keeps the sine's argument small.
    const double period = 1.0 / (2.0 * ambient.mains_hz);
    const double t0r = t0 - std::floor(t0 / period) * period;
    const double mean =
        1.0 + ambient.flicker_depth * (std::sin(w * (t0r + T) + phi) - std::sin(w * t0r + phi)) / (w * T);
    ambient_scale *= mean;
  }
  scales.ambient = static_cast<float>(ambient_scale);
  scales.projector = static_cast<float>(exposure.led_current * lit / reference_exposure_us);
  return slproto::Ok{};
}

namespace {

// Pass 1 of a frame: the noise-free signal of one row. kScaled: away from the reference
// exposure (the reference keeps the original arithmetic, so its frames stay bit-identical).
template <bool kScaled>
void signal_row(std::size_t w, const float* __restrict off, const float* __restrict p, const float* __restrict gr,
                const float* __restrict table, int last, float ambient_scale, float dark_correction,
                float projector_scale, float* __restrict light) {
  if (table != nullptr) {
    for (std::size_t u = 0; u < w; ++u) {
      const int k = std::min(static_cast<int>(p[u]), last);
      const float frac = p[u] - static_cast<float>(k);
      const float pattern = table[k] + frac * (table[k + 1] - table[k]);
      if constexpr (kScaled)
        light[u] = off[u] * ambient_scale + dark_correction + gr[u] * projector_scale * pattern;
      else
        light[u] = off[u] + gr[u] * pattern;
    }
  } else {
    for (std::size_t u = 0; u < w; ++u) {
      if constexpr (kScaled)
        light[u] = off[u] * ambient_scale + dark_correction;
      else
        light[u] = off[u];
    }
  }
}

}  // namespace

void ViewRenderer::Impl::render_with(int side, const std::vector<float>* profile, std::uint64_t frame_key,
                                     Scales scales, std::span<std::uint8_t> out) const {
  const float* pos = side >= 0 ? position[static_cast<std::size_t>(side)].data() : nullptr;
  const float* g = side >= 0 ? gain[static_cast<std::size_t>(side)].data() : nullptr;
  const Indirect* bounce = side >= 0 && !indirect[static_cast<std::size_t>(side)].empty() && profile != nullptr
                               ? &indirect[static_cast<std::size_t>(side)]
                               : nullptr;
  const float* row_gain = side >= 0 ? row_max_gain[static_cast<std::size_t>(side)].data() : nullptr;
  const float* table = profile != nullptr ? profile->data() : nullptr;
  const int last = profile != nullptr ? static_cast<int>(profile->size()) - 2 : 0;
  const bool wide = bit_depth > 8;
  const bool with_noise = noise;
  const float dark = dark_dn, shot = shot_per_dn, read = read_var, max_value = max_dn;
  const auto key_a = static_cast<std::uint32_t>(frame_key), key_b = static_cast<std::uint32_t>(frame_key >> 32);
  const auto w = static_cast<std::size_t>(width);
  const int h = height;
  const float* offsets = offset.data();
  const float* row_offset_max = row_max_offset.data();
  const bool scaled = !scales.reference();
  const float ambient_scale = scales.ambient, projector_scale = scales.projector;
  const float dark_correction = dark * (1.0f - ambient_scale);
  const float bloom_share = blooming * 0.25f;
  std::uint8_t* const frame = out.data();
  // Whether a row can reach full scale in this frame (profiles never exceed 1).
  auto may_clip = [=](int v) {
    if (v < 0 || v >= h) return false;
    const float top = row_offset_max[v] * ambient_scale + dark_correction +
                      (row_gain != nullptr ? row_gain[v] * projector_scale : 0.0f);
    return top > max_value;
  };
  parallel_rows(height, [=](int row_begin, int row_end) {
    // Locals, not closure members: byte stores to the frame may alias anything in memory.
    const std::size_t n = w;
    const float max_level = max_value;
    // The block's rows and, where charge may bloom across the block's edge, one row above
    // and below: signal[(v - first_row) * w + u].
    bool bloom = false;
    if (bloom_share > 0)
      for (int v = row_begin - 1; v <= row_end && !bloom; ++v) bloom = may_clip(v);
    const int first_row = bloom ? std::max(0, row_begin - 1) : row_begin;
    const int end_row = bloom ? std::min(h, row_end + 1) : row_end;
    std::vector<float> signal_buffer(static_cast<std::size_t>(end_row - first_row) * w);
    std::vector<float> bloom_buffer(bloom ? w : 0);
    for (int v = first_row; v < end_row; ++v) {
      const std::size_t row = static_cast<std::size_t>(v) * w;
      float* light = signal_buffer.data() + static_cast<std::size_t>(v - first_row) * w;
      const float* p = pos != nullptr ? pos + row : nullptr;
      const float* gr = g != nullptr ? g + row : nullptr;
      if (scaled)
        signal_row<true>(w, offsets + row, p, gr, table, last, ambient_scale, dark_correction, projector_scale, light);
      else
        signal_row<false>(w, offsets + row, p, gr, table, last, ambient_scale, dark_correction, projector_scale, light);
      if (bounce != nullptr) {
        // One bounce: each sample is lit by this pattern at its own projector coordinate.
        for (std::uint32_t k = bounce->row_begin[static_cast<std::size_t>(v)];
             k < bounce->row_begin[static_cast<std::size_t>(v) + 1]; ++k) {
          float sum = 0;
          for (std::uint32_t j = bounce->first[k]; j < bounce->first[k + 1]; ++j) {
            const float q = bounce->position[j];
            const int i = std::min(static_cast<int>(q), last);
            const float frac = q - static_cast<float>(i);
            sum += bounce->weight[j] * (table[i] + frac * (table[i + 1] - table[i]));
          }
          light[bounce->pixel[k] - row] += projector_scale * sum;
        }
      }
    }
    for (int v = row_begin; v < row_end; ++v) {
      const std::size_t row = static_cast<std::size_t>(v) * w;
      float* light = signal_buffer.data() + static_cast<std::size_t>(v - first_row) * w;
      if (bloom && (may_clip(v - 1) || may_clip(v) || may_clip(v + 1))) {
        // Blooming: a quarter of `blooming` of each neighbour's charge above the full well
        // spills into this pixel (the sensor's full well is the ADC's full scale).
        const float* above = v > first_row ? light - w : nullptr;
        const float* below = v + 1 < end_row ? light + w : nullptr;
        float* __restrict spilled = bloom_buffer.data();
        auto excess = [max_level](float x) { return x > max_level ? x - max_level : 0.0f; };
        for (std::size_t u = 0; u < n; ++u) {
          float in = 0;
          if (above != nullptr) in += excess(above[u]);
          if (below != nullptr) in += excess(below[u]);
          if (u > 0) in += excess(light[u - 1]);
          if (u + 1 < n) in += excess(light[u + 1]);
          spilled[u] = light[u] + bloom_share * in;
        }
        light = spilled;
      }
      // Pass 2: noise, branch-free so it vectorises.
      if (with_noise) {
        constexpr float kScale = 1.7320508075688772f / 65535.0f;  // sqrt(3) / 65535
        constexpr float kMean = 2.0f * 1.7320508075688772f;
        const auto base = static_cast<std::uint32_t>(row);
        float* __restrict l = light;
        for (std::size_t u = 0; u < w; ++u) {
          const std::uint32_t index = base + static_cast<std::uint32_t>(u);
          const std::uint32_t h1 = fmix32(index * 0x9E3779B1u ^ key_a);
          const std::uint32_t h2 = fmix32(index * 0x85EBCA77u ^ key_b);
          // Sum of four 16-bit uniforms: an Irwin-Hall approximation of a standard normal
          // (exact mean and variance, tails cut at 3.46 sigma).
          const auto sum =
              static_cast<float>(static_cast<std::int32_t>((h1 & 0xFFFFu) + (h1 >> 16) + (h2 & 0xFFFFu) + (h2 >> 16)));
          const float z = sum * kScale - kMean;
          const float signal = l[u] - dark;
          const float variance = shot * (signal > 0.0f ? signal : 0.0f) + read;
          l[u] += std::sqrt(variance) * z;
        }
      }
      // Pass 3: rounding and clipping to the ADC range.
      const float* __restrict l = light;
      if (wide) {
        for (std::size_t u = 0; u < n; ++u) {
          const float clipped = std::min(std::max(l[u] + 0.5f, 0.0f), max_level);
          const auto level = static_cast<std::uint32_t>(static_cast<std::int32_t>(clipped));
          frame[2 * (row + u)] = static_cast<std::uint8_t>(level & 0xFF);
          frame[2 * (row + u) + 1] = static_cast<std::uint8_t>(level >> 8);
        }
      } else {
        std::uint8_t* __restrict dst = frame + row;
        for (std::size_t u = 0; u < n; ++u) {
          const float clipped = std::min(std::max(l[u] + 0.5f, 0.0f), max_level);
          dst[u] = static_cast<std::uint8_t>(static_cast<std::int32_t>(clipped));
        }
      }
    }
  });
}

ViewRenderer::ViewRenderer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

ViewRenderer::ViewRenderer(const Scene& scene, double commanded_angle_deg, int view_index) {
  if (auto status = check_scene(scene); !status) throw std::invalid_argument(status.error().message);
  if (!std::isfinite(commanded_angle_deg)) throw std::invalid_argument("view angle is not a finite number");
  auto prepared = detail::prepare_objects(scene);
  if (!prepared) throw std::invalid_argument(prepared.error().message);
  impl_ = Impl::create(scene, *prepared, commanded_angle_deg, view_index);
}

slproto::Result<ViewRenderer> ViewRenderer::make(const Scene& scene, double commanded_angle_deg, int view_index) {
  if (auto status = check_scene(scene); !status) return status.error();
  if (!std::isfinite(commanded_angle_deg))
    return slproto::make_error(slproto::Errc::invalid_argument, "view angle is not a finite number");
  auto prepared = detail::prepare_objects(scene);  // mesh-file errors come back as a Result
  if (!prepared) return std::move(prepared).error();
  return ViewRenderer(Impl::create(scene, *prepared, commanded_angle_deg, view_index));
}

std::unique_ptr<ViewRenderer::Impl> ViewRenderer::Impl::create(const Scene& scene,
                                                               const detail::PreparedObjects& prepared,
                                                               double commanded_angle_deg, int view_index) {
  auto impl = std::make_unique<Impl>();
  Impl& m = *impl;
  m.width = scene.camera.width;
  m.height = scene.camera.height;
  m.view_index = view_index;
  m.bit_depth = scene.sensor.bit_depth;
  m.plan = slproto::PatternPlan(scene.pattern_plan);
  m.noise = scene.sensor.noise;
  m.seed = scene.sensor.seed;
  const double scale = std::ldexp(1.0, m.bit_depth - 8);
  m.max_dn = static_cast<float>(std::ldexp(1.0, m.bit_depth) - 1);
  m.dark_dn = static_cast<float>(scene.sensor.dark_level_dn * scale);
  // Conversion gain: the full well fills the ADC range. Shot-noise variance in DN is then
  // signal / gain; read noise is given on the 8-bit scale (same electrons at any depth).
  const double electrons_per_dn = scene.sensor.full_well_electrons / m.max_dn;
  m.shot_per_dn = static_cast<float>(1.0 / electrons_per_dn);
  m.read_var = static_cast<float>(std::pow(scene.sensor.read_noise_dn * scale, 2));
  m.reference_exposure_us = scene.sensor.exposure_us;
  m.blooming = static_cast<float>(scene.sensor.blooming);
  m.ambient = scene.ambient;
  for (std::size_t s = 0; s < 2; ++s) {
    m.gamma[s] = scene.projectors[s].gamma;
    m.sigma[s] = scene.projectors[s].defocus_sigma_px;
  }

  m.truth.width = m.width;
  m.truth.height = m.height;
  m.truth.commanded_angle_deg = commanded_angle_deg;
  m.truth.cam_from_table =
      detail::actual_cam_from_table(scene, commanded_angle_deg, view_index, m.truth.actual_angle_deg);
  const detail::World world = detail::build_world(scene, prepared, m.truth.cam_from_table);
  m.shade(scene, world);
  if (scene.interreflection) m.gather_indirect(scene, world, scene.interreflection_samples);
  const auto w = static_cast<std::size_t>(m.width);
  m.row_max_offset.assign(static_cast<std::size_t>(m.height), 0.0f);
  for (std::size_t s = 0; s < 2; ++s) m.row_max_gain[s].assign(static_cast<std::size_t>(m.height), 0.0f);
  for (std::size_t v = 0; v < static_cast<std::size_t>(m.height); ++v) {
    for (std::size_t u = 0; u < w; ++u) m.row_max_offset[v] = std::max(m.row_max_offset[v], m.offset[v * w + u]);
    for (std::size_t s = 0; s < 2; ++s) {
      float top = 0;
      for (std::size_t u = 0; u < w; ++u) top = std::max(top, m.gain[s][v * w + u]);
      const Impl::Indirect& bounce = m.indirect[s];
      if (!bounce.empty()) {
        for (std::uint32_t k = bounce.row_begin[v]; k < bounce.row_begin[v + 1]; ++k) {
          float sum = 0;
          for (std::uint32_t j = bounce.first[k]; j < bounce.first[k + 1]; ++j) sum += bounce.weight[j];
          top = std::max(top, m.gain[s][bounce.pixel[k]] + sum);
        }
      }
      m.row_max_gain[s][v] = top;
    }
  }
  for (std::size_t s = 0; s < 2; ++s) {
    m.profiles[s].reserve(m.plan.size());
    for (std::size_t i = 0; i < m.plan.size(); ++i)
      m.profiles[s].push_back(build_profile(m.plan, i, m.gamma[s], m.sigma[s]));
  }
  return impl;
}

ViewRenderer::~ViewRenderer() = default;
ViewRenderer::ViewRenderer(ViewRenderer&&) noexcept = default;
ViewRenderer& ViewRenderer::operator=(ViewRenderer&&) noexcept = default;

int ViewRenderer::width() const { return impl_->width; }
int ViewRenderer::height() const { return impl_->height; }
std::size_t ViewRenderer::frame_bytes() const {
  return static_cast<std::size_t>(impl_->width) * static_cast<std::size_t>(impl_->height) *
         (impl_->bit_depth > 8 ? 2u : 1u);
}

namespace {

// The noise of a frame away from the reference exposure is independent of the reference's
// (and of every other exposure's); at the reference it is the scene's own.
std::uint64_t exposure_key(const Exposure& exposure, double reference_us) {
  const double t = exposure.exposure_us == 0 ? reference_us : exposure.exposure_us;
  const double lit = exposure.projector_us == 0 ? t : exposure.projector_us;
  if (t == reference_us && exposure.led_current == 1 && lit == t) return 0;
  std::uint64_t a, b, c;
  std::memcpy(&a, &t, sizeof a);
  std::memcpy(&b, &exposure.led_current, sizeof b);
  std::memcpy(&c, &lit, sizeof c);
  return detail::mix64(a ^ detail::mix64(b ^ detail::mix64(c)));
}

}  // namespace

slproto::Status ViewRenderer::try_render(ProjectorSide side, const slproto::PatternPlan& plan,
                                         std::size_t pattern_index, std::span<std::uint8_t> out,
                                         const Exposure& exposure) const {
  const Impl& m = *impl_;
  auto fail = [](std::string message) {
    return slproto::make_error(slproto::Errc::invalid_argument, std::move(message));
  };
  if (out.size() < frame_bytes())
    return fail("render: output buffer of " + std::to_string(out.size()) + " bytes is smaller than one frame (" +
                std::to_string(frame_bytes()) + ")");
  if (pattern_index >= plan.size())
    return fail("render: pattern index " + std::to_string(pattern_index) + " is beyond the plan's " +
                std::to_string(plan.size()) + " patterns");
  const auto s = static_cast<std::size_t>(side);
  if (s > 1) return fail("render: projector side " + std::to_string(s) + " does not exist");
  Impl::Scales scales;
  if (auto status = m.scales_of(exposure, scales); !status) return status;
  const std::uint64_t key =
      detail::mix64(detail::mix64(detail::mix64(m.seed) ^ static_cast<std::uint64_t>(m.view_index)) ^
                    ((static_cast<std::uint64_t>(s) << 32) | pattern_index)) ^
      exposure_key(exposure, m.reference_exposure_us);
  if (plan.config() == m.plan.config()) {
    m.render_with(static_cast<int>(s), &m.profiles[s][pattern_index], key, scales, out);
    return slproto::Ok{};
  }
  if (plan.config().axis != m.plan.config().axis || plan.config().coded_extent() != m.plan.config().coded_extent())
    return fail("render: the plan codes a different axis or extent than the projector the view was cast for");
  const std::vector<float> profile = build_profile(plan, pattern_index, m.gamma[s], m.sigma[s]);
  m.render_with(static_cast<int>(s), &profile, key, scales, out);
  return slproto::Ok{};
}

void ViewRenderer::render(ProjectorSide side, const slproto::PatternPlan& plan, std::size_t pattern_index,
                          std::span<std::uint8_t> out, const Exposure& exposure) const {
  if (auto status = try_render(side, plan, pattern_index, out, exposure); !status)
    throw std::invalid_argument(status.error().message);
}

void ViewRenderer::render(ProjectorSide side, std::size_t pattern_index, std::span<std::uint8_t> out) const {
  render(side, impl_->plan, pattern_index, out);
}

void ViewRenderer::render_ambient(std::span<std::uint8_t> out, const Exposure& exposure) const {
  const Impl& m = *impl_;
  if (out.size() < frame_bytes()) throw std::invalid_argument("render_ambient: output buffer smaller than one frame");
  Impl::Scales scales;
  if (auto status = m.scales_of(exposure, scales); !status) throw std::invalid_argument(status.error().message);
  const std::uint64_t key =
      detail::mix64(detail::mix64(detail::mix64(m.seed) ^ static_cast<std::uint64_t>(m.view_index)) ^ (7ull << 40)) ^
      exposure_key(exposure, m.reference_exposure_us);
  m.render_with(-1, nullptr, key, scales, out);
}

const ViewGroundTruth& ViewRenderer::ground_truth() const { return impl_->truth; }

}  // namespace slrig
