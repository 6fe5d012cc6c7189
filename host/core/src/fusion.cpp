#include "slscan/core/fusion.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "slproto/number_text.hpp"

namespace slscan::core {

namespace {

void check_cloud(const OrganizedCloud& cloud, const char* what) {
  const std::size_t n = static_cast<std::size_t>(cloud.width) * static_cast<std::size_t>(cloud.height);
  if (cloud.width < 0 || cloud.height < 0 || cloud.points.size() != n || cloud.quality.size() != n ||
      cloud.valid.size() != n)
    throw std::invalid_argument(std::string(what) + ": organised cloud buffers do not match its " +
                                std::to_string(cloud.width) + " x " + std::to_string(cloud.height) + " size");
}

}  // namespace

void FusionOptions::check() const {
  if (!(agreement_mm > 0) || !std::isfinite(agreement_mm))
    throw std::invalid_argument("fusion options: agreement_mm must be positive and finite, got " +
                                slproto::short_number(agreement_mm));
}

void FlyingPixelOptions::check() const {
  if (!(max_abs_mm > 0) || !std::isfinite(max_abs_mm))
    throw std::invalid_argument("flying pixel options: max_abs_mm must be positive and finite");
  if (!(relative >= 0) || !std::isfinite(relative))
    throw std::invalid_argument("flying pixel options: relative must be >= 0 and finite");
}

FusionResult fuse_left_right(const OrganizedCloud& left, const OrganizedCloud& right, const FusionOptions& options,
                             OrganizedCloud storage) {
  options.check();
  check_cloud(left, "fusion (left)");
  check_cloud(right, "fusion (right)");
  if (left.width != right.width || left.height != right.height)
    throw std::invalid_argument("fusion: left cloud is " + std::to_string(left.width) + " x " +
                                std::to_string(left.height) + ", right is " + std::to_string(right.width) + " x " +
                                std::to_string(right.height));
  FusionResult result;
  result.cloud = std::move(storage);
  result.cloud.resize(left.width, left.height);
  // The albedo is fused when both sides carry it (a missing projector's empty grid does).
  const std::size_t size = left.points.size();
  const bool with_intensity = left.intensity.size() == size && right.intensity.size() == size;
  if (!with_intensity) result.cloud.intensity.clear();
  const float tolerance2 = options.agreement_mm * options.agreement_mm;
  tbb::combinable<FusionCounts> counts_by_thread;
  const auto width = static_cast<std::size_t>(left.width);
  tbb::parallel_for(tbb::blocked_range<int>(0, left.height, 16), [&](const tbb::blocked_range<int>& rows) {
    FusionCounts& counts = counts_by_thread.local();
    OrganizedCloud& out = result.cloud;
    for (int v = rows.begin(); v < rows.end(); ++v) {
      const std::size_t row = static_cast<std::size_t>(v) * width;
      for (std::size_t i = row; i < row + width; ++i) {
        const bool l = left.valid[i] != 0, r = right.valid[i] != 0;
        if (l && r) {
          if ((left.points[i] - right.points[i]).squaredNorm() <= tolerance2) {
            // Quality is the phase modulation: noise in the decoded coordinate scales as 1/B,
            // so B weights the better-lit measurement more.
            const float ql = std::max(left.quality[i], 1e-6f), qr = std::max(right.quality[i], 1e-6f);
            out.points[i] = (ql * left.points[i] + qr * right.points[i]) / (ql + qr);
            out.quality[i] = ql + qr;
            // The albedo with the points' weights: one rule for every fused channel.
            if (with_intensity) out.intensity[i] = (ql * left.intensity[i] + qr * right.intensity[i]) / (ql + qr);
            out.valid[i] = 1;
            ++counts.both;
          } else {
            ++counts.rejected;
          }
        } else if (l || r) {
          const OrganizedCloud& source = l ? left : right;
          out.points[i] = source.points[i];
          out.quality[i] = source.quality[i];
          if (with_intensity) out.intensity[i] = source.intensity[i];
          out.valid[i] = 1;
          ++(l ? counts.left_only : counts.right_only);
        }
      }
    }
  });
  counts_by_thread.combine_each([&](const FusionCounts& c) {
    result.counts.both += c.both;
    result.counts.left_only += c.left_only;
    result.counts.right_only += c.right_only;
    result.counts.rejected += c.rejected;
  });
  return result;
}

FlyingPixelResult remove_flying_pixels(OrganizedCloud cloud, const FlyingPixelOptions& options) {
  options.check();
  check_cloud(cloud, "flying pixel removal");
  FlyingPixelResult result;
  const int w = cloud.width, h = cloud.height;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  static constexpr int kDirections[8][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}, {1, 1}, {-1, -1}, {1, -1}, {-1, 1}};
  // Depths alone, NaN where invalid, with a 2-pixel NaN border: the inner loop then reads a
  // dense float image with no bounds or validity branches (a NaN fails every comparison, as a
  // missing neighbour should), 3x less memory than striding over the points.
  const int pw = w + 4;
  std::vector<float> depth(static_cast<std::size_t>(pw) * static_cast<std::size_t>(h + 4), nan);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 64), [&](const tbb::blocked_range<int>& rows) {
    for (int v = rows.begin(); v < rows.end(); ++v) {
      float* out = depth.data() + static_cast<std::size_t>(v + 2) * static_cast<std::size_t>(pw) + 2;
      const std::size_t row = static_cast<std::size_t>(v) * static_cast<std::size_t>(w);
      for (int u = 0; u < w; ++u) {
        const std::size_t i = row + static_cast<std::size_t>(u);
        out[u] = cloud.valid[i] ? cloud.points[i].z() : nan;
      }
    }
  });
  // Only the depth image is read from here on: the points become the result's (no copy when
  // the caller moves its cloud in).
  result.cloud = std::move(cloud);
  std::ptrdiff_t offsets[8];
  for (int d = 0; d < 8; ++d) offsets[d] = kDirections[d][1] * pw + kDirections[d][0];
  const float max_abs = options.max_abs_mm, relative = options.relative;
  tbb::combinable<FlyingPixelCounts> counts_by_thread;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& rows) {
    FlyingPixelCounts& counts = counts_by_thread.local();
    for (int v = rows.begin(); v < rows.end(); ++v) {
      const float* zrow = depth.data() + static_cast<std::size_t>(v + 2) * static_cast<std::size_t>(pw) + 2;
      for (int u = 0; u < w; ++u) {
        const float z = zrow[u];
        if (std::isnan(z)) continue;
        ++counts.input;
        const float* centre = zrow + u;
        // Directions are listed in opposite pairs (2 j, 2 j + 1). A point on a surface continues
        // in two independent directions; a line of mixed pixels along a straight edge is smooth
        // only along the edge, i.e. in one opposite pair. So a point stays when two pairs each
        // have a direction it continues in; on a surface the first three directions tell.
        const auto continues_along = [&](unsigned d) {
          const float z1 = centre[offsets[d]], z2 = centre[2 * offsets[d]];
          const float step = std::fabs(z1 - z2);
          return std::fabs(z - (2.0f * z1 - z2)) <= max_abs + relative * step;
        };
        unsigned pairs = 0;
        for (unsigned pair = 0; pair < 4 && pairs < 2; ++pair)
          pairs += continues_along(2 * pair) || continues_along(2 * pair + 1) ? 1 : 0;
        if (pairs < 2) {
          const std::size_t i = static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u);
          result.cloud.points[i] = Eigen::Vector3f(nan, nan, nan);
          result.cloud.quality[i] = 0.0f;
          result.cloud.valid[i] = 0;
          ++counts.removed;
        }
      }
    }
  });
  counts_by_thread.combine_each([&](const FlyingPixelCounts& c) {
    result.counts.input += c.input;
    result.counts.removed += c.removed;
  });
  return result;
}

}  // namespace slscan::core
