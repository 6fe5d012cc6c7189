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
#include "triangulate_tile.hpp"

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
  for (int i = 0; i < 9; ++i) tile_.r[i] = proj_from_cam.R[static_cast<std::size_t>(i)];
  for (int i = 0; i < 3; ++i) tile_.b[i] = proj_from_cam.t[static_cast<std::size_t>(i)];
  const auto& d = projector_.distortion;
  tile_.k1 = d.k1;
  tile_.k2 = d.k2;
  tile_.k3 = d.k3;
  tile_.p1 = d.p1;
  tile_.p2 = d.p2;
  tile_.fx = projector_.fx;
  tile_.fy = projector_.fy;
  tile_.cx = projector_.cx;
  tile_.cy = projector_.cy;
  tile_.distorted = !d.is_zero();
  tile_.projector_width = projector_.width;
  tile_.projector_height = projector_.height;
  tile_.newton_iterations = options_.newton_iterations;
  tile_.max_residual_px = options_.max_residual_px;
  tile_.frustum_margin_px = options_.frustum_margin_px;
  tile_.min_depth_mm = options_.min_depth_mm;
  tile_.max_depth_mm = options_.max_depth_mm;
}

bool ProjectorTriangulator::intersect(float ray_x, float ray_y, float coord, Eigen::Vector3f& point) const {
  if (!std::isfinite(ray_x) || !std::isfinite(ray_y) || !std::isfinite(coord)) return false;
  // A tile of one pixel: the bulk path's arithmetic exactly.
  const float quality_in = 1.0f;
  float quality_out = 0.0f;
  std::uint8_t valid = 0;
  auto outcome = detail::TriangulateOutcome::no_intersection;
  Eigen::Vector3f solved;
  detail::solve_tile(tile_, axis_ == slproto::CodingAxis::columns,
                     {1, &ray_x, &ray_y, &coord, &quality_in, &solved, &quality_out, &valid, &outcome});
  if (outcome != detail::TriangulateOutcome::valid) return false;
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
    alignas(64) detail::TriangulateOutcome outcome[detail::kTilePixels];
    for (int v = rows.begin(); v < rows.end(); ++v) {
      const std::size_t row = static_cast<std::size_t>(v) * static_cast<std::size_t>(width);
      for (int u0 = 0; u0 < width; u0 += detail::kTilePixels) {
        const int tile = std::min(detail::kTilePixels, width - u0);
        const std::size_t i = row + static_cast<std::size_t>(u0);
        const float* ray_x = rays_->x.data() + i;
        const float* ray_y = rays_->y.data() + i;
        const float* coord = decoded.coordinate.data() + i;
        const float* quality = decoded.quality.data() + i;
        detail::solve_tile(tile_, columns,
                           {tile, ray_x, ray_y, coord, quality, out.points.data() + i, out.quality.data() + i,
                            out.valid.data() + i, outcome});
        if (with_intensity) {
          const float* __restrict in = decoded.intensity.data() + i;
          float* __restrict albedo = out.intensity.data() + i;
          const std::uint8_t* __restrict ok = out.valid.data() + i;
          for (int k = 0; k < tile; ++k) albedo[k] = ok[k] != 0 ? in[k] : 0.0f;
        }
        // One compare-and-add pass per reason (vectorised) instead of a switch per pixel.
        auto tally = [&](detail::TriangulateOutcome reason) {
          std::uint32_t c = 0;  // 32-bit: the compare-and-add vectorises without widening to 64
          for (int k = 0; k < tile; ++k) c += outcome[k] == reason ? 1 : 0;
          return c;
        };
        counts.valid += tally(detail::TriangulateOutcome::valid);
        counts.not_decoded += tally(detail::TriangulateOutcome::not_decoded);
        counts.no_intersection += tally(detail::TriangulateOutcome::no_intersection);
        counts.not_converged += tally(detail::TriangulateOutcome::not_converged);
        counts.outside_frustum += tally(detail::TriangulateOutcome::outside_frustum);
        counts.outside_depth += tally(detail::TriangulateOutcome::outside_depth);
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
