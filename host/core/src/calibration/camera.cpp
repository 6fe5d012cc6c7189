// Camera intrinsics from target views (OpenCV calibrateCamera).
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "pose_maths.hpp"
#include "slscan/core/calibration_solve.hpp"

namespace slscan::core {

using namespace calibration_detail;

DeviceCalibration calibrate_camera(const CheckerboardTarget& target, const std::vector<TargetView>& views, int width,
                                   int height, const LensModelOptions& lens, int min_views) {
  target.check();
  if (width <= 0 || height <= 0)
    throw std::invalid_argument("camera calibration: image size " + std::to_string(width) + " x " +
                                std::to_string(height) + " is impossible");
  if (static_cast<int>(views.size()) < min_views)
    throw std::invalid_argument("camera calibration: " + std::to_string(views.size()) +
                                " usable target views, at least " + std::to_string(min_views) + " needed");
  std::vector<std::vector<cv::Point3f>> object(views.size());
  std::vector<std::vector<cv::Point2f>> image(views.size());
  for (std::size_t i = 0; i < views.size(); ++i) {
    check_view(target, views[i], "camera view", 6);
    split_view(target, views[i], object[i], image[i]);
  }
  cv::Mat k, d;
  std::vector<cv::Mat> rvecs, tvecs;
  cv::calibrateCamera(object, image, cv::Size(width, height), k, d, rvecs, tvecs, lens_flags(lens),
                      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-12));
  DeviceCalibration out;
  out.model = model_from_cv(k, d, width, height);
  if (auto status = out.model.check("camera calibration result"); !status)
    throw std::runtime_error(status.error().message + " (are the views varied enough?)");
  double sum = 0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < views.size(); ++i) {
    out.from_target.push_back(transform_from_cv(rvecs[i], tvecs[i]));
    const double rms = view_reprojection_rms(target, out.model, out.from_target.back(), views[i]);
    out.view_rms_px.push_back(rms);
    sum += rms * rms * static_cast<double>(views[i].corners.size());
    count += views[i].corners.size();
  }
  out.rms_px = std::sqrt(sum / static_cast<double>(count));
  return out;
}

}  // namespace slscan::core
