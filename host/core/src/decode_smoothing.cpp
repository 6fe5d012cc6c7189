// The decoder's smoothing of the unwrapped coordinate (docs/pipeline.md, "Smoothing"), per row,
// once per SIMD target (see decode_rows.cpp for the mechanism): its window sums are in double,
// where AVX2 / AVX-512 do 4 / 8 per instruction against SSE2's 2.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "decode_smoothing.cpp"
#include "decode_smoothing.hpp"

#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>
#include <tbb/enumerable_thread_specific.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <vector>

HWY_BEFORE_NAMESPACE();
namespace slscan::core::detail {
namespace HWY_NAMESPACE {
namespace {

// Least-squares plane c = a + gx du + gy dv over the valid pixels of the (2 r + 1)^2 window
// around (x, y), in differences from the centre value; `value` = a (the plane at the centre).
// False when the valid pixels don't pin a plane down (collinear or too few).
bool plane_fit_at_centre(const float* raw, std::size_t stride, int x, int y, int r, float& value) {
  const float c0 = raw[static_cast<std::size_t>(y) * stride + static_cast<std::size_t>(x)];
  double n = 0, su = 0, sv = 0, suu = 0, svv = 0, suv = 0, sc = 0, scu = 0, scv = 0;
  for (int dv = -r; dv <= r; ++dv) {
    const float* row = raw + static_cast<std::size_t>(y + dv) * stride;
    for (int du = -r; du <= r; ++du) {
      const float v = row[x + du];
      if (!(v == v)) continue;
      const double c = v - c0;
      n += 1;
      su += du;
      sv += dv;
      suu += du * du;
      svv += dv * dv;
      suv += du * dv;
      sc += c;
      scu += c * du;
      scv += c * dv;
    }
  }
  // Solve [n su sv; su suu suv; sv suv svv] [a gx gy]^T = [sc scu scv]^T by Cramer's rule.
  const double det = n * (suu * svv - suv * suv) - su * (su * svv - suv * sv) + sv * (su * suv - suu * sv);
  if (!(std::abs(det) > 1e-6 * n * n * n)) return false;
  const double det_a = sc * (suu * svv - suv * suv) - su * (scu * svv - suv * scv) + sv * (scu * suv - suu * scv);
  value = static_cast<float>(det_a / det);
  return std::isfinite(value);
}

// v, or +0 where v is NaN (masked), by masking the bits: a select followed by the widening to
// double is not if-converted by GCC 12, this is.
inline float zero_if_nan(float v) {
  std::uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  bits &= 0u - static_cast<std::uint32_t>(v == v);
  float out;
  std::memcpy(&out, &bits, sizeof out);
  return out;
}

// Per pixel of a row, from its window means (differences to the centre) and counts: the
// smoothed value, and a flag where the plane fit must decide instead. A free function with
// restrict pointers and scalars by value: as a lambda over captured references GCC 12 leaves
// it scalar.
template <int R>
void choose_smoothed(int w, const float* __restrict centre, const float* __restrict means_wide,
                     const float* __restrict means_narrow, const float* __restrict counts_wide,
                     const float* __restrict counts_narrow, const float* __restrict modulation, float full_count,
                     float deviation, float* __restrict result, float* __restrict needs_fit) {
  // ~2 sigma of (5 x 5 mean - 3 x 3 mean): the phase noise of a pixel scales as 1 / B, and
  // is ~0.05 px at B = 30 DN on the rig (8-bit sensor, 1.5 DN read noise plus shot noise).
  constexpr float kCurvatureToleranceDnPx = 0.8f;
  for (int x = R; x < w - R; ++x) {
    const float c = centre[x];
    const float mean_wide = means_wide[x], mean_narrow = means_narrow[x];
    const float n5 = counts_wide[x], n3 = counts_narrow[x];
    // A window mean is biased by the coordinate's curvature, in proportion to the window's
    // second moment (4 for 5 x 5, 4/3 for 3 x 3). Where the two means differ by more than
    // noise (the limb of a sphere, a fillet), extrapolate the bias away (Richardson:
    // 1.5 m3 - 0.5 m5); elsewhere the 5 x 5 mean has the least noise.
    const float b = modulation[x];
    const float tolerance = kCurvatureToleranceDnPx / (b > 1.0f ? b : 1.0f);
    const bool curved = R == 2 && std::fabs(mean_wide - mean_narrow) > tolerance;
    const float wide_value = c + (curved ? 1.5f * mean_narrow - 0.5f * mean_wide : mean_wide);
    const float narrow_value = ((n3 == 9.0f) & (std::fabs(mean_narrow) <= deviation)) ? c + mean_narrow : c;
    const float full_value = std::fabs(mean_wide) <= deviation ? wide_value : narrow_value;
    // A NaN centre leaves the window short of full, so it stays NaN here.
    const bool full = n5 == full_count;
    result[x] = full ? full_value : c;
    needs_fit[x] = (!full & (n5 >= 6.0f) & (c == c)) ? 1.0f : 0.0f;
  }
}

// One row's working buffers for quadratic_where_whole (reused across rows by each thread).
struct QuadraticRows {
  std::vector<double> sum, weighted;  // per column, over the window's rows
  std::vector<float> count, value, whole;
};

// Row y's pixels whose (2 q + 1)^2 window decoded whole get the window's quadratic value, if it
// stays within max_deviation of their own and near the value the smaller window chose
// (`result` on entry): they differ by the curvature bias the quadratic removes (below the
// Richardson threshold, 1.2 / B px, where the 5 x 5 mean was kept) plus noise, but by far more
// where the wider window reaches over a depth step the smaller one does not see (a step of D
// px in its outer column moves the quadratic by ~0.09 D).
template <int Q>
void quadratic_where_whole(const float* raw, const float* modulation, std::size_t uw, int y, float max_deviation,
                           QuadraticRows& rows, float* __restrict result) {
  constexpr int n = 2 * Q + 1;
  // 1-D: a (2 Q + 1)-point quadratic's value at its centre is sum_i w_i z_i (Savitzky-Golay).
  // 2-D, on {1, u, v, u^2, uv, v^2}: sum_ij ((w_i + w_j) / n - 1 / n^2) z_ij, which is
  // sum_i (w_i / n - 1 / n^2) S_i + sum_i T_i / n over the columns' plain sums S and
  // w-weighted sums T.
  std::array<double, n> w_rows{}, k_across{};
  for (int i = -Q; i <= Q; ++i) {
    const double wi = (3.0 * (3 * Q * Q + 3 * Q - 1) - 15.0 * i * i) / ((2 * Q + 3) * (2 * Q + 1) * (2 * Q - 1));
    const int k = i + Q;
    w_rows[static_cast<std::size_t>(k)] = wi;
    k_across[static_cast<std::size_t>(k)] = wi / n - 1.0 / (n * n);
  }
  constexpr double inv_n = 1.0 / n;
  constexpr auto full = static_cast<float>(n * n);
  constexpr float kAgreementDnPx = 1.6f;  // 2 x choose_smoothed's curvature tolerance (DN px)
  const int w = static_cast<int>(uw);
  rows.sum.assign(uw, 0.0);
  rows.weighted.assign(uw, 0.0);
  rows.count.assign(uw, 0.0f);
  rows.value.resize(uw);
  rows.whole.resize(uw);
  double* __restrict sum = rows.sum.data();
  double* __restrict weighted = rows.weighted.data();
  float* __restrict count = rows.count.data();
  for (int dy = -Q; dy <= Q; ++dy) {
    const float* __restrict row = raw + static_cast<std::size_t>(y + dy) * uw;
    const int k = dy + Q;
    const double weight = w_rows[static_cast<std::size_t>(k)];
    for (int x = 0; x < w; ++x) {
      const auto v = static_cast<double>(zero_if_nan(row[x]));
      sum[x] += v;
      weighted[x] += weight * v;
      count[x] += row[x] == row[x] ? 1.0f : 0.0f;
    }
  }
  float* __restrict value = rows.value.data();
  float* __restrict whole = rows.whole.data();
  for (int x = Q; x < w - Q; ++x) {
    double fitted = 0;
    float valid = 0;
    for (int i = 0; i < n; ++i) {
      fitted += k_across[static_cast<std::size_t>(i)] * sum[x - Q + i] + inv_n * weighted[x - Q + i];
      valid += count[x - Q + i];
    }
    value[x] = static_cast<float>(fitted);
    whole[x] = valid == full ? 1.0f : 0.0f;
  }
  const float* __restrict centre = raw + static_cast<std::size_t>(y) * uw;
  const float* __restrict row_modulation = modulation + static_cast<std::size_t>(y) * uw;
  for (int x = Q; x < w - Q; ++x) {
    const float b = row_modulation[x];
    const float agreement = kAgreementDnPx / (b > 1.0f ? b : 1.0f);
    const float v = value[x];
    const bool take =
        (whole[x] == 1.0f) & (std::fabs(v - centre[x]) <= max_deviation) & (std::fabs(v - result[x]) <= agreement);
    result[x] = take ? v : result[x];
  }
}

void quadratic_where_whole(int q, const float* raw, const float* modulation, std::size_t uw, int y, float max_deviation,
                           QuadraticRows& rows, float* result) {
  switch (q) {
    case 3:
      return quadratic_where_whole<3>(raw, modulation, uw, y, max_deviation, rows, result);
    case 4:
      return quadratic_where_whole<4>(raw, modulation, uw, y, max_deviation, rows, result);
    case 5:
      return quadratic_where_whole<5>(raw, modulation, uw, y, max_deviation, rows, result);
    case 6:
      return quadratic_where_whole<6>(raw, modulation, uw, y, max_deviation, rows, result);
    default:
      throw std::logic_error("quadratic_radius outside [3, 6] past DecodeOptions::check()");
  }
}

void smooth_block(const SmoothRowsInput& input, int row_begin, int row_end) {
  const int w = input.width, h = input.height;
  const int radius = input.radius;
  const float max_deviation = input.max_deviation;
  const float* raw = input.raw;
  const float* quality = input.quality;
  float* smoothed = input.smoothed;
  // Separable window sums: per row, the column sums over the window's rows (3 and 5), then
  // per pixel the sum of 3 or 5 column sums. Double keeps the sums of the coordinates
  // themselves (up to ~1e3 px) exact to well below 1e-9 px, so no per-window differences to
  // the centre are needed. Counts of valid pixels ride along the same way; masked (NaN)
  // pixels count as 0. Each row's sums are computed from its own window only (no running
  // sums across rows), so the result does not depend on how TBB splits the rows.
  const int q = input.quadratic_radius;
  struct Columns {
    std::vector<double> narrow, wide;
    QuadraticRows quadratic;
    std::vector<float> narrow_count, wide_count;
    std::vector<float> mean_wide, mean_narrow, window_count_wide, window_count_narrow;
    std::vector<float> needs_fit;  // 1 where the plane fit decides (float: one element width)
  };
  static tbb::enumerable_thread_specific<Columns> columns_by_thread;
  Columns& columns = columns_by_thread.local();
  const auto uw = static_cast<std::size_t>(w);
  columns.narrow.resize(uw);
  columns.wide.resize(uw);
  columns.narrow_count.resize(uw);
  columns.wide_count.resize(uw);
  columns.needs_fit.resize(uw);
  columns.mean_wide.resize(uw);
  columns.mean_narrow.resize(uw);
  columns.window_count_wide.resize(uw);
  columns.window_count_narrow.resize(uw);
  double* __restrict col_narrow = columns.narrow.data();
  double* __restrict col_wide = columns.wide.data();
  float* __restrict count_narrow = columns.narrow_count.data();
  float* __restrict count_wide = columns.wide_count.data();
  float* __restrict needs_fit = columns.needs_fit.data();
  for (int y = row_begin; y < row_end; ++y) {
    const float* __restrict centre = raw + static_cast<std::size_t>(y) * uw;
    float* __restrict result = smoothed + static_cast<std::size_t>(y) * uw;
    std::copy(centre, centre + w, result);
    if (y < 1 || y >= h - 1 || w < 3) continue;
    const int r = (y >= radius && y < h - radius) ? radius : 1;
    {
      const float* __restrict above = centre - uw;
      const float* __restrict below = centre + uw;
      for (int x = 0; x < w; ++x) {
        const float a = above[x], c = centre[x], b = below[x];
        col_narrow[x] = static_cast<double>(zero_if_nan(a)) + static_cast<double>(zero_if_nan(c)) +
                        static_cast<double>(zero_if_nan(b));
        count_narrow[x] = (a == a ? 1.0f : 0.0f) + (c == c ? 1.0f : 0.0f) + (b == b ? 1.0f : 0.0f);
      }
    }
    const double* __restrict sum_wide = col_narrow;
    const float* __restrict n_wide = count_narrow;
    if (r == 2) {
      const float* __restrict above = centre - 2 * uw;
      const float* __restrict below = centre + 2 * uw;
      for (int x = 0; x < w; ++x) {
        const float a = above[x], b = below[x];
        col_wide[x] = col_narrow[x] + (static_cast<double>(zero_if_nan(a)) + static_cast<double>(zero_if_nan(b)));
        count_wide[x] = count_narrow[x] + ((a == a ? 1.0f : 0.0f) + (b == b ? 1.0f : 0.0f));
      }
      sum_wide = col_wide;
      n_wide = count_wide;
    }
    const auto full_wide = static_cast<float>((2 * r + 1) * (2 * r + 1));
    const double inv_full_wide = 1.0 / static_cast<double>(full_wide);
    const float* __restrict row_quality = quality + static_cast<std::size_t>(y) * uw;
    // Two passes: the window means from the double sums (no selects), then the choice among
    // them in float only (GCC 12 if-converts selects of one element width).
    float* __restrict means_wide = columns.mean_wide.data();
    float* __restrict means_narrow = columns.mean_narrow.data();
    float* __restrict counts_wide = columns.window_count_wide.data();
    float* __restrict counts_narrow = columns.window_count_narrow.data();
    auto window_means = [&]<int R>() {
      for (int x = R; x < w - R; ++x) {
        const double s3 = col_narrow[x - 1] + col_narrow[x] + col_narrow[x + 1];
        double s5 = s3;
        if constexpr (R == 2) s5 = sum_wide[x - 2] + sum_wide[x - 1] + sum_wide[x] + sum_wide[x + 1] + sum_wide[x + 2];
        const auto c = static_cast<double>(centre[x]);
        means_wide[x] = static_cast<float>(s5 * inv_full_wide - c);
        means_narrow[x] = static_cast<float>(s3 * (1.0 / 9.0) - c);
      }
      for (int x = R; x < w - R; ++x) {
        const float n3 = count_narrow[x - 1] + count_narrow[x] + count_narrow[x + 1];
        float n5 = n3;
        if constexpr (R == 2) n5 = n_wide[x - 2] + n_wide[x - 1] + n_wide[x] + n_wide[x + 1] + n_wide[x + 2];
        counts_wide[x] = n5;
        counts_narrow[x] = n3;
      }
    };
    if (r == 2) {
      window_means.template operator()<2>();
      choose_smoothed<2>(w, centre, means_wide, means_narrow, counts_wide, counts_narrow, row_quality, full_wide,
                         max_deviation, result, needs_fit);
    } else {
      window_means.template operator()<1>();
      choose_smoothed<1>(w, centre, means_wide, means_narrow, counts_wide, counts_narrow, row_quality, full_wide,
                         max_deviation, result, needs_fit);
    }
    // Part of the window is masked (a shadow border, an edge): a one-sided mean would be
    // biased by the coordinate's slope, so fit a plane to the valid neighbours and take its
    // value at the centre. Only edge pixels get here.
    for (int x = r; x < w - r; ++x) {
      if (needs_fit[x] == 0.0f) continue;
      float value;
      if (plane_fit_at_centre(raw, uw, x, y, r, value) && std::fabs(value) <= max_deviation)
        result[x] = centre[x] + value;
    }
    if (q > 0 && y >= q && y < h - q && w > 2 * q)
      quadratic_where_whole(q, raw, quality, uw, y, max_deviation, columns.quadratic, result);
  }
}

}  // namespace

void SmoothRows(const SmoothRowsInput& input, int row_begin, int row_end) { smooth_block(input, row_begin, row_end); }

}  // namespace HWY_NAMESPACE
}  // namespace slscan::core::detail
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace slscan::core::detail {

HWY_EXPORT(SmoothRows);

void smooth_rows(const SmoothRowsInput& input, int row_begin, int row_end) {
  HWY_DYNAMIC_DISPATCH(SmoothRows)(input, row_begin, row_end);
}

}  // namespace slscan::core::detail
#endif  // HWY_ONCE
