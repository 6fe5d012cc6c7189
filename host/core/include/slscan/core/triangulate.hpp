// Stage 2: triangulation (paper Formula 6). Each camera pixel's ray meets the set of points
// that the projector maps to the decoded coordinate. Without projector distortion that set is
// a plane; with it, it is a curved surface, so the intersection is solved exactly: along the
// ray's epipolar line in the projector's undistorted image, Newton's method on the distorted
// projector coordinate (residual checked, < 1e-3 projector px by default).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "slproto/calibration.hpp"
#include "slscan/core/decode.hpp"
#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

// Undistorted normalised ray (x, y, 1) of every camera pixel centre, computed once per
// calibration with the exact inverse of the lens model. NaN where undistortion fails.
struct CameraRayTable {
  int width = 0, height = 0;
  std::vector<float> x, y;  // row-major, index = v * width + u

  static CameraRayTable build(const slproto::PinholeModel& camera);
};

struct TriangulateOptions {
  int newton_iterations = 4;       // each one roughly squares the error; 3 reach float precision
  float max_residual_px = 1e-3f;   // |projected coordinate - decoded| after Newton, projector px
  float frustum_margin_px = 2.0f;  // the point must project this close to the projector image
  float min_depth_mm = 1.0f;       // camera z range of plausible points
  float max_depth_mm = 100000.0f;

  void check() const;  // throws std::invalid_argument naming the field
};

struct TriangulateCounts {
  std::size_t valid = 0;
  std::size_t not_decoded = 0;      // masked by the decoder
  std::size_t no_intersection = 0;  // ray parallel to the coordinate's surface, or behind a device
  std::size_t not_converged = 0;    // Newton residual above max_residual_px
  std::size_t outside_frustum = 0;  // lands outside the projector image along the other axis
  std::size_t outside_depth = 0;    // depth outside [min_depth_mm, max_depth_mm]
};

struct TriangulatedView {
  OrganizedCloud cloud;  // camera frame, mm; quality = the decoder's modulation
  TriangulateCounts counts;
};

namespace detail {

// The per-pixel solve's constants (src/triangulate_tile.cpp, dispatched per SIMD target).
struct TriangulateTileParams {
  // proj_from_cam: Xp = R d t + b for the camera point t d. Double: the per-pixel solve is
  // compute-light next to decoding, and float round-off alone reaches ~5e-4 projector px.
  double r[9] = {};
  double b[3] = {};
  double k1 = 0, k2 = 0, k3 = 0, p1 = 0, p2 = 0;  // the projector's distortion
  double fx = 0, fy = 0, cx = 0, cy = 0;
  bool distorted = false;
  int projector_width = 0, projector_height = 0;
  int newton_iterations = 0;
  double max_residual_px = 0, frustum_margin_px = 0, min_depth_mm = 0, max_depth_mm = 0;
};

// Why a pixel gave no point, in the order of TriangulateCounts.
enum class TriangulateOutcome : std::uint8_t {
  valid,
  not_decoded,
  no_intersection,
  not_converged,
  outside_frustum,
  outside_depth
};

}  // namespace detail

// Triangulates the decoded coordinates of one projector. Construct once per calibration and
// projector; triangulate() is const and thread-safe.
class ProjectorTriangulator {
 public:
  // The ray table must come from `camera`; throws std::invalid_argument on a bad calibration
  // or a table of the wrong size.
  ProjectorTriangulator(std::shared_ptr<const CameraRayTable> rays, const slproto::ProjectorCalibration& projector,
                        slproto::CodingAxis axis, const TriangulateOptions& options = {});

  TriangulatedView triangulate(const DecodedView& decoded) const;
  // Into an existing cloud whose buffers are reused.
  TriangulateCounts triangulate(const DecodedView& decoded, OrganizedCloud& out) const;

  // One pixel's ray (x, y, 1) against coordinate `coord`: the camera-frame point, or false.
  // Exposed for tests and calibration; the same arithmetic as the bulk path.
  bool intersect(float ray_x, float ray_y, float coord, Eigen::Vector3f& point) const;

  slproto::CodingAxis axis() const { return axis_; }

 private:
  std::shared_ptr<const CameraRayTable> rays_;
  slproto::PinholeModel projector_;
  slproto::CodingAxis axis_;
  TriangulateOptions options_;
  detail::TriangulateTileParams tile_{};
};

}  // namespace slscan::core
