// Properties of the reconstruction under an absurd-but-valid calibration (issue 17): a
// calibration file that parses and passes check() (camera.fx = 1e20 did, and crashed the view
// selection with SIGSEGV) and a replayed scan's turntable angles, through every stage of
// core::ScanReconstructor (decode, triangulate, flying pixels, fusion, turntable cleanup,
// outliers, smoothing, normals, registration, view selection, merge). The mesh is the session
// layer's and is fuzzed on its own inputs elsewhere.
//
// Input: byte 0 picks the views (1-3), byte 1 the angle between them ((b - 128) x 3 degrees,
// also absurd ones), the rest is the calibration file's JSON. Accepted calibrations within a
// size cap (camera <= kMaxPixels pixels, a plan of <= kMaxPatterns patterns) are given the
// frames of a plane through the turntable's axis, rendered with the calibration's own models. Allowed outcomes: a
// result whose points are finite, or std::invalid_argument with a message (exit 2, "bad input"); anything else is a
// finding.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string_view>
#include <utility>
#include <vector>

#include "fuzz_checks.hpp"
#include "slproto/calibration_file.hpp"
#include "slproto/pattern_plan.hpp"
#include "slscan/core/scan_reconstruction.hpp"

namespace slproto::fuzz {

inline constexpr long kMaxPixels = 64 * 48;
inline constexpr std::size_t kMaxPatterns = 40;

// The model's points (0 when the input was set aside or refused); fuzz_fail() on a finding.
// Tests may leave a view unlit (`dark_view`: its frames all black) and take the whole result.
inline std::size_t reconstruct_checked(const std::uint8_t* bytes, std::size_t size, int dark_view = -1,
                                       slscan::core::ScanResult* result_out = nullptr) {
  if (size < 2) return 0;
  const int views = 1 + bytes[0] % 3;
  const double step_deg = (static_cast<int>(bytes[1]) - 128) * 3.0;
  const std::string_view json(reinterpret_cast<const char*>(bytes + 2), size - 2);
  const auto calibration = parse_calibration(json, "fuzz");
  if (!calibration) return 0;  // the calibration_file target's business
  const auto& camera = calibration->camera;
  if (camera.width <= 0 || camera.height <= 0 ||
      static_cast<long>(camera.width) * static_cast<long>(camera.height) > kMaxPixels)
    return 0;
  const auto plan = PatternPlan::make(calibration->pattern_plan);
  if (!plan || plan->size() > kMaxPatterns) return 0;

  slscan::core::ReconstructionOptions options;
  options.build_mesh = false;
  try {
    slscan::core::ScanReconstructor reconstructor(*calibration, *plan, camera.width, camera.height, options);
    const int w = camera.width, h = camera.height;
    const bool columns = plan->config().axis == CodingAxis::columns;
    // The scene: a plane facing the camera through the turntable's axis point, as each
    // projector lights it (the calibration's own models, however absurd): per pixel and
    // projector the coded coordinate, or none (dark) where the ray or projector misses.
    const double axis_depth = calibration->turntable.axis_point()[2];
    const double depth = std::isfinite(axis_depth) && axis_depth > 1 ? axis_depth : 500.0;
    std::array<std::vector<double>, 2> coded;
    for (std::size_t side = 0; side < 2; ++side) {
      const auto& projector = calibration->projectors[side];
      const RigidTransform proj_from_cam = projector.cam_from_proj.inverse();
      coded[side].assign(static_cast<std::size_t>(w) * static_cast<std::size_t>(h), -1);
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          double rx = 0, ry = 0, u = 0, v = 0;
          if (!camera.pixel_to_ray(x, y, rx, ry)) continue;
          const Vec3 on_plane{rx * depth, ry * depth, depth};
          if (!projector.intrinsics.project(proj_from_cam.apply(on_plane), u, v)) continue;
          const double coord = columns ? u : v;
          if (std::isfinite(coord) && coord >= 0 && coord < plan->config().coded_extent())
            coded[side][static_cast<std::size_t>(y) * w + x] = coord;
        }
      }
    }
    std::vector<std::byte> frame(static_cast<std::size_t>(w) * static_cast<std::size_t>(h));
    for (int view = 0; view < views; ++view) {
      for (int side = 0; side < 2; ++side) {
        for (std::size_t pattern = 0; pattern < plan->size(); ++pattern) {
          for (std::size_t i = 0; i < frame.size(); ++i) {
            const double coord = coded[side][i];
            const float value = coord >= 0 && view != dark_view ? plan->value(pattern, coord) : 0.0f;
            frame[i] = static_cast<std::byte>(std::lround(16 + 220 * value));
          }
          slscan::core::FrameInfo info;
          info.view_index = view;
          info.commanded_angle_deg = view * step_deg;
          info.reported_angle_deg = view * step_deg;
          info.projector = side;
          info.pattern_index = pattern;
          info.stride_bytes = static_cast<std::size_t>(w);
          info.bytes_per_pixel = 1;
          reconstructor.add_frame(info, frame);
        }
      }
    }
    auto result = reconstructor.finish();
    for (const auto& p : result.model.points)
      if (!std::isfinite(p.x()) || !std::isfinite(p.y()) || !std::isfinite(p.z()))
        fuzz_fail("a model point is not finite");
    for (const auto& n : result.model.normals)
      if (!std::isfinite(n.x()) || !std::isfinite(n.y()) || !std::isfinite(n.z())) fuzz_fail("a normal is not finite");
    const std::size_t points = result.model.points.size();
    if (result_out != nullptr) *result_out = std::move(result);
    return points;
  } catch (const std::invalid_argument& e) {
    if (std::string_view(e.what()).empty()) fuzz_fail("invalid_argument without a message");
  }
  return 0;
}

inline void check_reconstruction(const std::uint8_t* bytes, std::size_t size) {
  (void)reconstruct_checked(bytes, size);
}

}  // namespace slproto::fuzz
