#include "slscan/core/depth_smoothing.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace slscan::core {
namespace {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

Vector6d monomials(int du, int dv) {
  Vector6d m;
  m << 1.0, du, dv, double(du) * du, double(du) * dv, double(dv) * dv;
  return m;
}

// The weights that give the fitted depth at the centre from a complete window: the first row
// of the least-squares pseudo-inverse (a 2-D Savitzky-Golay kernel). They sum to 1.
std::vector<double> full_window_kernel(int r) {
  Matrix6d normal = Matrix6d::Zero();
  for (int dv = -r; dv <= r; ++dv)
    for (int du = -r; du <= r; ++du) normal.noalias() += monomials(du, dv) * monomials(du, dv).transpose();
  const Vector6d row = normal.ldlt().solve(Vector6d::Unit(0));
  std::vector<double> kernel;
  for (int dv = -r; dv <= r; ++dv)
    for (int du = -r; du <= r; ++du) kernel.push_back(row.dot(monomials(du, dv)));
  return kernel;
}

// The window's half-width in pixels at the cloud's median depth (a sample of it: the depth
// range of a scan is small next to the working distance).
int window_radius_px(const OrganizedCloud& cloud, double focal_px, const DepthSmoothingOptions& options) {
  std::vector<float> depths;
  const std::size_t stride = std::max<std::size_t>(1, cloud.points.size() / 4096);
  for (std::size_t i = 0; i < cloud.points.size(); i += stride)
    if (cloud.valid[i] && cloud.points[i].z() > 0) depths.push_back(cloud.points[i].z());
  if (depths.empty()) return 0;
  const auto middle = depths.begin() + static_cast<std::ptrdiff_t>(depths.size() / 2);
  std::nth_element(depths.begin(), middle, depths.end());
  const double footprint_mm = *middle / focal_px;
  return static_cast<int>(
      std::min<double>(options.max_window_radius_px, std::floor(options.window_radius_mm / footprint_mm)));
}

struct RowCounts {
  std::size_t input = 0, full = 0, partial = 0, kept = 0;
  double shift_mm = 0;
};

}  // namespace

void DepthSmoothingOptions::check() const {
  if (!(window_radius_mm > 0)) throw std::invalid_argument("depth smoothing: window_radius_mm must be > 0");
  if (max_window_radius_px < 1 || max_window_radius_px > 10)
    throw std::invalid_argument("depth smoothing: max_window_radius_px must be 1-10, not " +
                                std::to_string(max_window_radius_px));
  if (!(max_depth_slope > 0)) throw std::invalid_argument("depth smoothing: max_depth_slope must be > 0");
  if (min_neighbors < 6)
    throw std::invalid_argument("depth smoothing: min_neighbors must be >= 6 (a quadratic has 6 coefficients), not " +
                                std::to_string(min_neighbors));
}

DepthSmoothingCounts smooth_depth(OrganizedCloud& cloud, double focal_px, const DepthSmoothingOptions& options) {
  options.check();
  if (!(focal_px > 0)) throw std::invalid_argument("smooth_depth: the focal length must be > 0 pixels");
  if (static_cast<std::size_t>(cloud.width) * static_cast<std::size_t>(cloud.height) != cloud.points.size() ||
      cloud.valid.size() != cloud.points.size())
    throw std::invalid_argument("smooth_depth: organised cloud is " + std::to_string(cloud.width) + "x" +
                                std::to_string(cloud.height) + " but holds " + std::to_string(cloud.points.size()) +
                                " points and " + std::to_string(cloud.valid.size()) + " validity flags");
  const int w = cloud.width, h = cloud.height;
  DepthSmoothingCounts total;
  const int r = window_radius_px(cloud, focal_px, options);
  total.window_radius_px = r;
  if (r < 1) {
    total.input = total.kept = cloud.count_valid();
    return total;
  }
  const std::vector<double> kernel = full_window_kernel(r);
  const std::size_t window_size = kernel.size();
  // The valid slots (row-major), and per slot its fitted depth (in a separate buffer: every fit
  // must see the measured depths) and what became of it. A view's object after the platform is
  // removed is ~2.5 % of its grid: nothing is kept per slot of the grid.
  std::vector<std::uint32_t> slots;
  slots.reserve(cloud.count_valid());
  for (std::size_t i = 0; i < cloud.points.size(); ++i)
    if (cloud.valid[i]) slots.push_back(static_cast<std::uint32_t>(i));
  enum class Fit : std::uint8_t { kept, full, partial };
  std::vector<float> fitted(slots.size());
  std::vector<double> offsets(slots.size(), 0.0);
  std::vector<Fit> fits(slots.size(), Fit::kept);
  const double slope_per_focal = options.max_depth_slope / focal_px;
  const auto width = static_cast<std::uint32_t>(w);

  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, slots.size(), 512), [&](const tbb::blocked_range<std::size_t>& range) {
        std::vector<double> depths(window_size);
        std::vector<std::uint8_t> usable(window_size);
        for (std::size_t slot = range.begin(); slot < range.end(); ++slot) {
          const std::size_t i = slots[slot];
          const int u = static_cast<int>(slots[slot] % width), v = static_cast<int>(slots[slot] / width);
          const double centre = cloud.points[i].z();
          fitted[slot] = static_cast<float>(centre);
          const double step = slope_per_focal * centre;  // mm of depth per pixel of grid distance
          // Gather the window's depths relative to the centre (small numbers: exact in double).
          std::size_t n = 0, k = 0;
          for (int dv = -r; dv <= r; ++dv) {
            const int vv = v + dv;
            for (int du = -r; du <= r; ++du, ++k) {
              const int uu = u + du;
              usable[k] = 0;
              if (vv < 0 || vv >= h || uu < 0 || uu >= w) continue;
              const std::size_t j =
                  static_cast<std::size_t>(vv) * static_cast<std::size_t>(w) + static_cast<std::size_t>(uu);
              if (!cloud.valid[j]) continue;
              const double d = static_cast<double>(cloud.points[j].z()) - centre;
              if (std::fabs(d) > step * std::max(std::abs(du), std::abs(dv))) continue;
              depths[k] = d;
              usable[k] = 1;
              ++n;
            }
          }
          double offset = 0;
          if (n == window_size) {
            for (std::size_t m = 0; m < window_size; ++m) offset += kernel[m] * depths[m];
            fits[slot] = Fit::full;
          } else {
            if (n < static_cast<std::size_t>(options.min_neighbors)) continue;
            Matrix6d normal = Matrix6d::Zero();
            Vector6d rhs = Vector6d::Zero();
            k = 0;
            for (int dv = -r; dv <= r; ++dv)
              for (int du = -r; du <= r; ++du, ++k) {
                if (!usable[k]) continue;
                const Vector6d m = monomials(du, dv);
                normal.noalias() += m * m.transpose();
                rhs += m * depths[k];
              }
            const Eigen::LDLT<Matrix6d> ldlt(normal);
            const auto diagonal = ldlt.vectorD();
            // A degenerate support (a strip of pixels) cannot fix a quadratic; and a one-sided
            // one can make the fitted centre noisier than the measurement itself (variance
            // factor e0' (A'A)^-1 e0 > 1): either way the point stays as measured.
            if (ldlt.info() != Eigen::Success || diagonal.minCoeff() <= 1e-9 * diagonal.maxCoeff()) continue;
            const Vector6d e0 = ldlt.solve(Vector6d::Unit(0));
            if (!(e0(0) > 0) || e0(0) > 1.0) continue;
            offset = e0.dot(rhs);
            fits[slot] = Fit::partial;
          }
          fitted[slot] = static_cast<float>(centre + offset);
          offsets[slot] = offset;
        }
      });

  // Summed row by row, then over the rows, in grid order: the same figure on any thread timing.
  std::vector<RowCounts> rows_counts(static_cast<std::size_t>(h));
  for (std::size_t slot = 0; slot < slots.size(); ++slot) {
    RowCounts& counts = rows_counts[slots[slot] / width];
    ++counts.input;
    switch (fits[slot]) {
      case Fit::kept:
        ++counts.kept;
        break;
      case Fit::full:
        ++counts.full;
        counts.shift_mm += std::fabs(offsets[slot]);
        break;
      case Fit::partial:
        ++counts.partial;
        counts.shift_mm += std::fabs(offsets[slot]);
        break;
    }
  }
  double shift_mm = 0;
  for (const RowCounts& c : rows_counts) {
    total.input += c.input;
    total.full += c.full;
    total.partial += c.partial;
    total.kept += c.kept;
    shift_mm += c.shift_mm;
  }
  const std::size_t moved = total.full + total.partial;
  total.mean_shift_um = moved ? 1000.0 * shift_mm / static_cast<double>(moved) : 0.0;
  // Slide each point along its camera ray (through the origin) to the fitted depth.
  for (std::size_t slot = 0; slot < slots.size(); ++slot) {
    Eigen::Vector3f& point = cloud.points[slots[slot]];
    const float z = point.z();
    if (z != 0.0f) point *= fitted[slot] / z;
  }
  return total;
}

}  // namespace slscan::core
