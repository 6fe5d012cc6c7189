// The triangulator's per-pixel solve, once per SIMD target (see decode_rows.cpp for the
// mechanism): Highway compiles this file for each target and dispatches to the CPU's best.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "triangulate_tile.cpp"
#include "triangulate_tile.hpp"

#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <cmath>
#include <limits>

HWY_BEFORE_NAMESPACE();
namespace slscan::core::detail {
namespace HWY_NAMESPACE {
namespace {

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
void solve_tile(const TriangulateTileParams& p, int n, const float* __restrict ray_x, const float* __restrict ray_y,
                const float* __restrict coord, const float* __restrict quality_in, Eigen::Vector3f* __restrict points,
                float* __restrict quality_out, std::uint8_t* __restrict valid, TriangulateOutcome* __restrict outcome) {
  Tile t;
  const double m0 = p.r[0], m1 = p.r[1], m2 = p.r[2], m3 = p.r[3], m4 = p.r[4], m5 = p.r[5], m6 = p.r[6], m7 = p.r[7],
               m8 = p.r[8];
  const double b0 = p.b[0], b1 = p.b[1], b2 = p.b[2];
  const double f_coded = kColumns ? p.fx : p.fy, c_coded = kColumns ? p.cx : p.cy;
  const double f_other = kColumns ? p.fy : p.fx, c_other = kColumns ? p.cy : p.cx;
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
  const double k1 = p.k1, k2 = p.k2, k3 = p.k3;
  const double p_coded = kColumns ? p.p1 : p.p2, p_other = kColumns ? p.p2 : p.p1;
  if (p.distorted) {
    for (int iter = 0; iter < p.newton_iterations; ++iter) {
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
  const double max_residual = p.max_residual_px;
  const double other_extent = static_cast<double>(kColumns ? p.projector_height : p.projector_width);
  const double margin = p.frustum_margin_px;
  const double other_lo = -0.5 - margin, other_hi = other_extent - 0.5 + margin;
  const double min_depth = p.min_depth_mm, max_depth = p.max_depth_mm;
  constexpr double kFloatMax = std::numeric_limits<float>::max();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  constexpr auto kValid = static_cast<double>(TriangulateOutcome::valid);
  constexpr auto kNotDecoded = static_cast<double>(TriangulateOutcome::not_decoded);
  constexpr auto kNoIntersection = static_cast<double>(TriangulateOutcome::no_intersection);
  constexpr auto kNotConverged = static_cast<double>(TriangulateOutcome::not_converged);
  constexpr auto kOutsideFrustum = static_cast<double>(TriangulateOutcome::outside_frustum);
  constexpr auto kOutsideDepth = static_cast<double>(TriangulateOutcome::outside_depth);
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
    outcome[i] = static_cast<TriangulateOutcome>(static_cast<int>(t.outcome[i]));
    points[i] = Eigen::Vector3f(static_cast<float>(t.ax[i]), static_cast<float>(t.ay[i]), static_cast<float>(t.az[i]));
    const float q = quality_in[i];  // loaded before the select, so GCC 12 if-converts it
    quality_out[i] = ok ? q : 0.0f;
    valid[i] = ok ? 1 : 0;
  }
}

}  // namespace

void SolveTileColumns(const TriangulateTileParams& params, const TriangulateTileIo& io) {
  solve_tile<true>(params, io.n, io.ray_x, io.ray_y, io.coord, io.quality_in, io.points, io.quality_out, io.valid,
                   io.outcome);
}

void SolveTileRows(const TriangulateTileParams& params, const TriangulateTileIo& io) {
  solve_tile<false>(params, io.n, io.ray_x, io.ray_y, io.coord, io.quality_in, io.points, io.quality_out, io.valid,
                    io.outcome);
}

}  // namespace HWY_NAMESPACE
}  // namespace slscan::core::detail
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace slscan::core::detail {

HWY_EXPORT(SolveTileColumns);
HWY_EXPORT(SolveTileRows);

void solve_tile(const TriangulateTileParams& params, bool columns, const TriangulateTileIo& io) {
  if (columns)
    HWY_DYNAMIC_DISPATCH(SolveTileColumns)(params, io);
  else
    HWY_DYNAMIC_DISPATCH(SolveTileRows)(params, io);
}

}  // namespace slscan::core::detail
#endif  // HWY_ONCE
