#include "slscan/core/calibration_coverage.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "slscan/core/calibration_solve.hpp"

namespace slscan::core {

namespace {

std::string fixed(double value, int digits) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*f", digits, value);
  return buffer;
}

}  // namespace

PoseFootprint pose_footprint(const std::string& name, const TargetView& view, const CheckerboardTarget& target) {
  const int n = target.corner_count();
  PoseFootprint out;
  out.name = name;
  out.corners.assign(static_cast<std::size_t>(n), Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN()));
  for (const CornerObservation& c : view.corners) {
    if (c.id < 0 || c.id >= n)
      throw std::invalid_argument("pose footprint " + name + ": corner id " + std::to_string(c.id) + " of " +
                                  std::to_string(n));
    out.corners[static_cast<std::size_t>(c.id)] = c.pixel;
  }
  for (int id = 0; id < n; ++id)
    if (!out.corners[static_cast<std::size_t>(id)].allFinite())
      throw std::invalid_argument("pose footprint " + name + ": corner " + std::to_string(id) +
                                  " is missing (the board must be found whole)");
  return out;
}

double footprint_distance_px(const PoseFootprint& a, const PoseFootprint& b) {
  const std::size_t n = a.corners.size();
  if (n == 0 || b.corners.size() != n)
    throw std::invalid_argument("footprint distance: " + a.name + " has " + std::to_string(n) + " corners, " + b.name +
                                " " + std::to_string(b.corners.size()));
  double same = 0, reversed = 0;
  for (std::size_t i = 0; i < n; ++i) {
    same += (a.corners[i] - b.corners[i]).norm();
    reversed += (a.corners[i] - b.corners[n - 1 - i]).norm();
  }
  return std::min(same, reversed) / static_cast<double>(n);
}

PoseNovelty closest_pose(const PoseFootprint& pose, const std::vector<PoseFootprint>& taken) {
  PoseNovelty out;
  for (std::size_t i = 0; i < taken.size(); ++i) {
    const double d = footprint_distance_px(pose, taken[i]);
    if (out.closest < 0 || d < out.distance_px) {
      out.closest = static_cast<int>(i);
      out.distance_px = d;
    }
  }
  return out;
}

double footprint_size_px(const PoseFootprint& pose) {
  if (pose.corners.empty()) return 0;
  return (pose.corners.back() - pose.corners.front()).norm();
}

std::string too_similar_problem(const PoseFootprint& pose, const std::vector<PoseFootprint>& taken,
                                double min_shift_of_board) {
  const PoseNovelty novelty = closest_pose(pose, taken);
  if (novelty.closest < 0) return "";
  const double wanted = min_shift_of_board * footprint_size_px(pose);
  if (novelty.distance_px >= wanted) return "";
  return "too similar to '" + taken[static_cast<std::size_t>(novelty.closest)].name + "' (its corners lie " +
         fixed(novelty.distance_px, 2) + " px from that pose's on average, " + fixed(wanted, 1) +
         " px wanted): it adds nothing to the calibration; tilt or move the board as the pose says";
}

std::string PoseSetCoverage::summary() const {
  const std::string image = "image " + std::to_string(cells_covered) + " of " + std::to_string(cells) + " cells (" +
                            fixed(100.0 * covered_fraction(), 0) + " %)";
  const std::string over = " over " + std::to_string(poses) + (poses == 1 ? " pose" : " poses");
  if (!has_depth) return image + over + "; depth " + depth_note;
  return image + "; depth " + fixed(nearest_mm, 0) + "-" + fixed(farthest_mm, 0) + " mm (" +
         fixed(farthest_mm - nearest_mm, 0) + " mm)" + over;
}

PoseSetCoverage pose_set_coverage(const CheckerboardTarget& target, const std::vector<PoseFootprint>& poses, int width,
                                  int height, const CoverageOptions& options) {
  if (width <= 0 || height <= 0 || options.cells_x < 1 || options.cells_y < 1)
    throw std::invalid_argument("pose set coverage: an image of " + std::to_string(width) + " x " +
                                std::to_string(height) + " px in " + std::to_string(options.cells_x) + " x " +
                                std::to_string(options.cells_y) + " cells");
  PoseSetCoverage out;
  out.poses = static_cast<int>(poses.size());
  out.cells = options.cells_x * options.cells_y;
  std::vector<std::vector<cv::Point2f>> hulls;
  for (const PoseFootprint& pose : poses) {
    std::vector<cv::Point2f> points;
    for (const Eigen::Vector2d& c : pose.corners)
      points.emplace_back(static_cast<float>(c.x()), static_cast<float>(c.y()));
    std::vector<cv::Point2f> hull;
    cv::convexHull(points, hull);
    hulls.push_back(std::move(hull));
  }
  for (int cy = 0; cy < options.cells_y; ++cy)
    for (int cx = 0; cx < options.cells_x; ++cx) {
      const cv::Point2f centre(static_cast<float>((cx + 0.5) * width / options.cells_x),
                               static_cast<float>((cy + 0.5) * height / options.cells_y));
      if (std::any_of(hulls.begin(), hulls.end(), [&](const std::vector<cv::Point2f>& hull) {
            return cv::pointPolygonTest(hull, centre, false) >= 0;
          }))
        ++out.cells_covered;
    }

  constexpr std::size_t kMinViews = 3;
  if (poses.size() < kMinViews) {
    out.depth_note = "known from " + std::to_string(kMinViews) + " poses on";
    return out;
  }
  std::vector<TargetView> views;
  for (const PoseFootprint& pose : poses) {
    TargetView view;
    view.name = pose.name;
    for (std::size_t id = 0; id < pose.corners.size(); ++id)
      view.corners.push_back({static_cast<int>(id), pose.corners[id]});
    views.push_back(std::move(view));
  }
  try {
    LensModelOptions lens;  // few views: the plainest model
    lens.tangential = false;
    lens.k2 = false;
    const DeviceCalibration camera = calibrate_camera(target, views, width, height, lens, static_cast<int>(kMinViews));
    out.nearest_mm = std::numeric_limits<double>::infinity();
    out.farthest_mm = -std::numeric_limits<double>::infinity();
    for (const slproto::RigidTransform& from_target : camera.from_target) {
      const Eigen::Vector3d c = target.centre();
      const double z = from_target.apply({c.x(), c.y(), c.z()})[2];
      out.nearest_mm = std::min(out.nearest_mm, z);
      out.farthest_mm = std::max(out.farthest_mm, z);
    }
    out.has_depth = !camera.from_target.empty();
    if (!out.has_depth) out.depth_note = "not solved";
  } catch (const std::exception& e) {
    out.depth_note = std::string("not solved yet (") + e.what() + ")";
  }
  return out;
}

}  // namespace slscan::core
