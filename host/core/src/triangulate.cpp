#include "slscan/core/triangulate.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>

#include "slproto/number_text.hpp"

namespace slscan::core {

CameraRayTable CameraRayTable::build(const slproto::PinholeModel& camera) {
  if (auto status = camera.check("camera"); !status) throw std::invalid_argument(status.error().message);
  CameraRayTable table;
  table.width = camera.width;
  table.height = camera.height;
  const auto n = static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height);
  table.x.resize(n);
  table.y.resize(n);
  tbb::parallel_for(tbb::blocked_range<int>(0, camera.height, 8), [&](const tbb::blocked_range<int>& rows) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (int v = rows.begin(); v < rows.end(); ++v)
      for (int u = 0; u < camera.width; ++u) {
        const std::size_t i =
            static_cast<std::size_t>(v) * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(u);
        double x = 0, y = 0;
        const bool ok = camera.pixel_to_ray(u, v, x, y);
        table.x[i] = ok ? static_cast<float>(x) : nan;
        table.y[i] = ok ? static_cast<float>(y) : nan;
      }
  });
  return table;
}

void TriangulateOptions::check() const {
  auto fail = [](const std::string& msg) { throw std::invalid_argument("triangulate options: " + msg); };
  if (newton_iterations < 1 || newton_iterations > 50)
    fail("newton_iterations " + std::to_string(newton_iterations) + " outside [1, 50]");
  if (!(max_residual_px > 0) || !std::isfinite(max_residual_px)) fail("max_residual_px must be positive and finite");
  if (!(frustum_margin_px >= 0) || !std::isfinite(frustum_margin_px)) fail("frustum_margin_px must be >= 0 and finite");
  if (!(min_depth_mm >= 0) || !(max_depth_mm > min_depth_mm) || !std::isfinite(max_depth_mm))
    fail("depth range [" + slproto::short_number(min_depth_mm) + ", " + slproto::short_number(max_depth_mm) +
         "] mm is empty");
}

ProjectorTriangulator::ProjectorTriangulator(std::shared_ptr<const CameraRayTable> rays,
                                             const slproto::ProjectorCalibration& projector, slproto::CodingAxis axis,
                                             const TriangulateOptions& options)
    : rays_(std::move(rays)), projector_(projector.intrinsics), axis_(axis), options_(options) {
  options_.check();
  if (!rays_ || rays_->width <= 0 || rays_->height <= 0 ||
      rays_->x.size() != static_cast<std::size_t>(rays_->width) * static_cast<std::size_t>(rays_->height) ||
      rays_->y.size() != rays_->x.size())
    throw std::invalid_argument("triangulator: camera ray table is missing or inconsistent");
  if (auto status = projector.intrinsics.check("projector"); !status)
    throw std::invalid_argument(status.error().message);
  if (auto status = projector.cam_from_proj.check("projector cam_from_proj"); !status)
    throw std::invalid_argument(status.error().message);
  const slproto::RigidTransform proj_from_cam = projector.cam_from_proj.inverse();
  for (int i = 0; i < 9; ++i) r_[i] = proj_from_cam.R[static_cast<std::size_t>(i)];
  for (int i = 0; i < 3; ++i) b_[i] = proj_from_cam.t[static_cast<std::size_t>(i)];
  const auto& d = projector_.distortion;
  k1_ = d.k1;
  k2_ = d.k2;
  k3_ = d.k3;
  p1_ = d.p1;
  p2_ = d.p2;
  fx_ = projector_.fx;
  fy_ = projector_.fy;
  cx_ = projector_.cx;
  cy_ = projector_.cy;
  distorted_ = !d.is_zero();
}

namespace {

// Pixels per tile of a row: the tile's per-pixel doubles (12 arrays, 24 KB) stay in L1.
constexpr int kTilePixels = 256;

// Per-pixel state of one tile, structure of arrays so every pass over it vectorises.
struct Tile {
  alignas(64) double ax[kTilePixels];  // ray direction in the projector frame (az is the z part)
  alignas(64) double ay[kTilePixels];
  alignas(64) double az[kTilePixels];
  alignas(64) double q0[kTilePixels];  // epipolar line: other = q0 + q1 s
  alignas(64) double q1[kTilePixels];
  alignas(64) double target[kTilePixels];  // decoded coordinate, normalised
  alignas(64) double s[kTilePixels];       // undistorted coded coordinate being solved
  alignas(64) double residual[kTilePixels];
  alignas(64) double other[kTilePixels];    // distorted other coordinate, normalised
  alignas(64) double line_ok[kTilePixels];  // 1 where the epipolar line is not parallel to the coded axis
  alignas(64) double step[kTilePixels];     // |last Newton step|
  alignas(64) double outcome[kTilePixels];  // Outcome as a double: keeps the passes one element width
};

}  // namespace

// The camera point t (rx, ry, 1) is Xp(t) = t a + b in the projector frame. The plane through
// the projector centre and the ray, normal l = a x b, cuts the projector's undistorted
// normalised image in the epipolar line l0 x + l1 y + l2 = 0. Along it, the coded coordinate
// s (x for columns, y for rows) fixes the other one, q = q0 + q1 s, and the distorted coded
// coordinate is a smooth 1D function of s: Newton solves it for the decoded value. Then the
// depth t follows linearly from s.
//
// A tile of n pixels is solved pass by pass (set-up, each Newton step, classification), each
// pass a branch-free loop over the tile that the compiler vectorises; masked pixels (NaN)
// ride along and are classified at the end. Newton stops when every pixel of the tile has
// taken a step below 1e-10 (normalised), or after newton_iterations: a pixel that converged
// earlier than its neighbours takes further steps of ~1e-17, which change nothing.
template <bool kColumns>
void ProjectorTriangulator::solve_tile(int n, const float* __restrict ray_x, const float* __restrict ray_y,
                                       const float* __restrict coord, const float* __restrict quality_in,
                                       Eigen::Vector3f* __restrict points, float* __restrict quality_out,
                                       std::uint8_t* __restrict valid, Outcome* __restrict outcome) const {
  Tile t;
  const double m0 = r_[0], m1 = r_[1], m2 = r_[2], m3 = r_[3], m4 = r_[4], m5 = r_[5], m6 = r_[6], m7 = r_[7],
               m8 = r_[8];
  const double b0 = b_[0], b1 = b_[1], b2 = b_[2];
  const double f_coded = kColumns ? fx_ : fy_, c_coded = kColumns ? cx_ : cy_;
  const double f_other = kColumns ? fy_ : fx_, c_other = kColumns ? cy_ : cx_;
  const double inv_f_coded = 1.0 / f_coded;
  for (int i = 0; i < n; ++i) {
    const double rx = ray_x[i], ry = ray_y[i];
    const double ax = m0 * rx + m1 * ry + m2;
    const double ay = m3 * rx + m4 * ry + m5;
    const double az = m6 * rx + m7 * ry + m8;
    const double l0 = ay * b2 - az * b1;
    const double l1 = az * b0 - ax * b2;
    const double l2 = ax * b1 - ay * b0;
    const double l_along = kColumns ? l1 : l0;  // coefficient of the dependent coordinate
    const double l_coded = kColumns ? l0 : l1;
    const double l_norm = std::abs(l0) + std::abs(l1) + std::abs(l2);
    t.line_ok[i] = std::abs(l_along) > 1e-6f * l_norm ? 1.0 : 0.0;
    const double inv_along = 1.0 / l_along;
    t.ax[i] = ax;
    t.ay[i] = ay;
    t.az[i] = az;
    t.q0[i] = -l2 * inv_along;
    t.q1[i] = -l_coded * inv_along;
    const double target = (static_cast<double>(coord[i]) - c_coded) * inv_f_coded;
    t.target[i] = target;
    t.s[i] = target;
  }
  // p_coded / p_other: the tangential coefficient that multiplies 2 x y in the coded / other
  // component (OpenCV: x gets 2 p1 x y + p2 (r2 + 2 x^2), y gets p1 (r2 + 2 y^2) + 2 p2 x y).
  const double k1 = k1_, k2 = k2_, k3 = k3_;
  const double p_coded = kColumns ? p1_ : p2_, p_other = kColumns ? p2_ : p1_;
  if (distorted_) {
    for (int iter = 0; iter < options_.newton_iterations; ++iter) {
      for (int i = 0; i < n; ++i) {
        const double sv = t.s[i], q1 = t.q1[i];
        const double q = t.q0[i] + q1 * sv;
        const double r2 = sv * sv + q * q;
        const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        const double dradial = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3);
        // Coded component: s radial + 2 p_coded s q + p_other (r2 + 2 s^2).
        const double g = sv * radial + 2.0 * p_coded * sv * q + p_other * (r2 + 2.0 * sv * sv) - t.target[i];
        const double d_ds = radial + 2.0 * sv * sv * dradial + 2.0 * p_coded * q + 6.0 * p_other * sv;
        const double d_dq = 2.0 * sv * q * dradial + 2.0 * p_coded * sv + 2.0 * p_other * q;
        const double step = g / (d_ds + d_dq * q1);
        t.s[i] = sv - step;
        t.step[i] = std::abs(step);
      }
      // NaN (masked) pixels don't hold it up. A plain loop over the n steps just set (not
      // std::none_of over a pointer range, which the analyser could not bound: issue 17 lint).
      bool moving = false;
      for (int i = 0; i < n; ++i) moving |= t.step[i] >= 1e-10;
      if (!moving) break;
    }
    for (int i = 0; i < n; ++i) {
      const double sv = t.s[i];
      const double q = t.q0[i] + t.q1[i] * sv;
      const double r2 = sv * sv + q * q;
      const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
      const double g = sv * radial + 2.0 * p_coded * sv * q + p_other * (r2 + 2.0 * sv * sv) - t.target[i];
      t.residual[i] = std::abs(g) * f_coded;
      t.other[i] = q * radial + p_coded * (r2 + 2.0 * q * q) + 2.0 * p_other * sv * q;
    }
  } else {
    for (int i = 0; i < n; ++i) {
      t.residual[i] = 0.0;
      t.other[i] = t.q0[i] + t.q1[i] * t.s[i];
    }
  }
  const double b_coded = kColumns ? b0 : b1;
  const double max_residual = options_.max_residual_px;
  const double other_extent = static_cast<double>(kColumns ? projector_.height : projector_.width);
  const double margin = options_.frustum_margin_px;
  const double other_lo = -0.5 - margin, other_hi = other_extent - 0.5 + margin;
  const double min_depth = options_.min_depth_mm, max_depth = options_.max_depth_mm;
  constexpr double kFloatMax = std::numeric_limits<float>::max();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  constexpr auto kValid = static_cast<double>(Outcome::valid);
  constexpr auto kNotDecoded = static_cast<double>(Outcome::not_decoded);
  constexpr auto kNoIntersection = static_cast<double>(Outcome::no_intersection);
  constexpr auto kNotConverged = static_cast<double>(Outcome::not_converged);
  constexpr auto kOutsideFrustum = static_cast<double>(Outcome::outside_frustum);
  constexpr auto kOutsideDepth = static_cast<double>(Outcome::outside_depth);
  // Classification in doubles only (one element width keeps GCC vectorising), then the
  // narrow outputs.
  for (int i = 0; i < n; ++i) {
    const double sv = t.s[i], az = t.az[i];
    const double a_coded = kColumns ? t.ax[i] : t.ay[i];
    const double denominator = a_coded - sv * az;
    const double numerator = sv * b2 - b_coded;
    const double depth = numerator / denominator;
    const double other_px = f_other * t.other[i] + c_other;
    const double rx = ray_x[i];
    const bool decoded = std::abs(static_cast<double>(coord[i])) <= kFloatMax;
    const bool has_ray = std::abs(rx) <= kFloatMax;
    const bool converged = t.residual[i] <= max_residual;
    const bool intersects = (std::abs(denominator) > 1e-12f) & (depth > 0.0) & (depth * az + b2 > 0.0);
    const bool in_frustum = (other_px >= other_lo) & (other_px <= other_hi);
    const bool in_depth = (depth >= min_depth) & (depth <= max_depth);
    // The first reason that applies, in the order of TriangulateCounts: selects applied from
    // the last reason to the first, so the earliest failing test wins.
    double o = kValid;
    o = in_depth ? o : kOutsideDepth;
    o = in_frustum ? o : kOutsideFrustum;
    o = intersects ? o : kNoIntersection;
    o = converged ? o : kNotConverged;
    o = t.line_ok[i] != 0.0 ? o : kNoIntersection;
    o = has_ray ? o : kNoIntersection;
    o = decoded ? o : kNotDecoded;
    t.outcome[i] = o;
    t.s[i] = depth;
  }
  // Separate from the classification: GCC 12 does not if-convert a select on the outcome
  // built by the chain above within the same loop.
  for (int i = 0; i < n; ++i) {
    const double depth = t.s[i];
    const double keep = t.outcome[i] == kValid ? depth : nan;
    t.ax[i] = keep * static_cast<double>(ray_x[i]);
    t.ay[i] = keep * static_cast<double>(ray_y[i]);
    t.az[i] = keep;
  }
  for (int i = 0; i < n; ++i) {
    const bool ok = t.outcome[i] == kValid;
    outcome[i] = static_cast<Outcome>(static_cast<int>(t.outcome[i]));
    points[i] = Eigen::Vector3f(static_cast<float>(t.ax[i]), static_cast<float>(t.ay[i]), static_cast<float>(t.az[i]));
    const float q = quality_in[i];  // loaded before the select, so GCC 12 if-converts it
    quality_out[i] = ok ? q : 0.0f;
    valid[i] = ok ? 1 : 0;
  }
}

bool ProjectorTriangulator::intersect(float ray_x, float ray_y, float coord, Eigen::Vector3f& point) const {
  if (!std::isfinite(ray_x) || !std::isfinite(ray_y) || !std::isfinite(coord)) return false;
  // A tile of one pixel: the bulk path's arithmetic exactly.
  const float quality_in = 1.0f;
  float quality_out = 0.0f;
  std::uint8_t valid = 0;
  Outcome outcome = Outcome::no_intersection;
  Eigen::Vector3f solved;
  if (axis_ == slproto::CodingAxis::columns)
    solve_tile<true>(1, &ray_x, &ray_y, &coord, &quality_in, &solved, &quality_out, &valid, &outcome);
  else
    solve_tile<false>(1, &ray_x, &ray_y, &coord, &quality_in, &solved, &quality_out, &valid, &outcome);
  if (outcome != Outcome::valid) return false;
  point = solved;
  return true;
}

TriangulatedView ProjectorTriangulator::triangulate(const DecodedView& decoded) const {
  TriangulatedView out;
  out.counts = triangulate(decoded, out.cloud);
  return out;
}

TriangulateCounts ProjectorTriangulator::triangulate(const DecodedView& decoded, OrganizedCloud& out) const {
  if (decoded.width != rays_->width || decoded.height != rays_->height)
    throw std::invalid_argument("triangulator: decoded view is " + std::to_string(decoded.width) + " x " +
                                std::to_string(decoded.height) + " but the camera is " + std::to_string(rays_->width) +
                                " x " + std::to_string(rays_->height));
  if (decoded.axis != axis_)
    throw std::invalid_argument(std::string("triangulator: decoded view codes ") +
                                slproto::coding_axis_name(decoded.axis) + " but the triangulator expects " +
                                slproto::coding_axis_name(axis_));
  const std::size_t n = static_cast<std::size_t>(decoded.width) * static_cast<std::size_t>(decoded.height);
  if (decoded.coordinate.size() != n || decoded.quality.size() != n)
    throw std::invalid_argument("triangulator: decoded view buffers do not match its size");
  out.width = decoded.width;
  out.height = decoded.height;
  out.points.resize(n);
  out.quality.resize(n);
  out.valid.resize(n);
  // The albedo rides along where the decoder gave one (0 where the point is invalid).
  const bool with_intensity = decoded.intensity.size() == n;
  if (with_intensity)
    out.intensity.resize(n);
  else
    out.intensity.clear();
  tbb::combinable<TriangulateCounts> counts_by_thread;
  const int width = decoded.width;
  const bool columns = axis_ == slproto::CodingAxis::columns;
  tbb::parallel_for(tbb::blocked_range<int>(0, decoded.height, 8), [&](const tbb::blocked_range<int>& rows) {
    TriangulateCounts& counts = counts_by_thread.local();
    alignas(64) Outcome outcome[kTilePixels];
    for (int v = rows.begin(); v < rows.end(); ++v) {
      const std::size_t row = static_cast<std::size_t>(v) * static_cast<std::size_t>(width);
      for (int u0 = 0; u0 < width; u0 += kTilePixels) {
        const int tile = std::min(kTilePixels, width - u0);
        const std::size_t i = row + static_cast<std::size_t>(u0);
        const float* ray_x = rays_->x.data() + i;
        const float* ray_y = rays_->y.data() + i;
        const float* coord = decoded.coordinate.data() + i;
        const float* quality = decoded.quality.data() + i;
        if (columns)
          solve_tile<true>(tile, ray_x, ray_y, coord, quality, out.points.data() + i, out.quality.data() + i,
                           out.valid.data() + i, outcome);
        else
          solve_tile<false>(tile, ray_x, ray_y, coord, quality, out.points.data() + i, out.quality.data() + i,
                            out.valid.data() + i, outcome);
        if (with_intensity) {
          const float* __restrict in = decoded.intensity.data() + i;
          float* __restrict albedo = out.intensity.data() + i;
          const std::uint8_t* __restrict ok = out.valid.data() + i;
          for (int k = 0; k < tile; ++k) albedo[k] = ok[k] != 0 ? in[k] : 0.0f;
        }
        // One compare-and-add pass per reason (vectorised) instead of a switch per pixel.
        auto tally = [&](Outcome reason) {
          std::uint32_t c = 0;  // 32-bit: the compare-and-add vectorises without widening to 64
          for (int k = 0; k < tile; ++k) c += outcome[k] == reason ? 1 : 0;
          return c;
        };
        counts.valid += tally(Outcome::valid);
        counts.not_decoded += tally(Outcome::not_decoded);
        counts.no_intersection += tally(Outcome::no_intersection);
        counts.not_converged += tally(Outcome::not_converged);
        counts.outside_frustum += tally(Outcome::outside_frustum);
        counts.outside_depth += tally(Outcome::outside_depth);
      }
    }
  });
  TriangulateCounts total;
  counts_by_thread.combine_each([&](const TriangulateCounts& c) {
    total.valid += c.valid;
    total.not_decoded += c.not_decoded;
    total.no_intersection += c.no_intersection;
    total.not_converged += c.not_converged;
    total.outside_frustum += c.outside_frustum;
    total.outside_depth += c.outside_depth;
  });
  return total;
}

}  // namespace slscan::core
