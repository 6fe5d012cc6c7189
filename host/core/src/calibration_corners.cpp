#include "slscan/core/calibration_corners.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace slscan::core {

namespace {

cv::Mat to_8bit(const cv::Mat& image) {
  if (image.type() == CV_8UC1) return image;
  if (image.type() != CV_16UC1)
    throw std::invalid_argument("checkerboard detection: image must be 8- or 16-bit single channel");
  double lo = 0, hi = 0;
  cv::minMaxLoc(image, &lo, &hi);
  cv::Mat out;
  image.convertTo(out, CV_8U, hi > 0 ? 255.0 / hi : 1.0);
  return out;
}

}  // namespace

CornerDetection detect_checkerboard(const cv::Mat& image, const CheckerboardTarget& target,
                                    const CornerDetectionOptions& options) {
  target.check();
  CornerDetection out;
  if (image.empty()) {
    out.reason = "empty image";
    return out;
  }
  const cv::Mat grey = to_8bit(image);
  const cv::Size pattern(target.inner_x(), target.inner_y());
  std::vector<cv::Point2f> corners;
  bool found = false;
  const int classic_flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE;
  const int sector_flags = cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE | cv::CALIB_CB_ACCURACY;
  auto find_sector_based = [&] {
    if (options.search_max_pixels > 0 && grey.total() > options.search_max_pixels) {
      cv::Mat half;
      cv::resize(grey, half, cv::Size(), 0.5, 0.5, cv::INTER_AREA);
      if (cv::findChessboardCornersSB(half, pattern, corners, sector_flags)) {
        // A half-size pixel's centre is the middle of its 2 x 2 full-size pixels.
        for (cv::Point2f& p : corners) p = 2.0F * p + cv::Point2f(0.5F, 0.5F);
        out.search_scale = 2;
        return true;
      }
    }
    out.search_scale = 1;
    return cv::findChessboardCornersSB(grey, pattern, corners, sector_flags);
  };
  found = find_sector_based();
  // The sector-based detector first: its corners start within a fraction of a pixel, where
  // the classic one's can be several pixels off on a foreshortened board (a board lying on
  // the turntable, seen from 27 degrees above: squares 20 x 10 px), too far for cornerSubPix's
  // window to pull them back. The classic one is the fallback.
  if (!found && !options.sector_based) found = cv::findChessboardCorners(grey, pattern, corners, classic_flags);
  if (found && static_cast<int>(corners.size()) == target.corner_count()) {
    // cornerSubPix on every result: measured on a synthetic board with 1 DN of noise, the
    // sector-based corners alone scatter by 0.25 px, refined ones by 0.07 px. Its window must
    // stay inside the squares next to the corner.
    double nearest = std::numeric_limits<double>::infinity();
    for (int id = 0; id < target.corner_count(); ++id) {
      const auto i = static_cast<std::size_t>(id);
      if ((id + 1) % target.inner_x() != 0) nearest = std::min(nearest, cv::norm(corners[i + 1] - corners[i]));
      if (id + target.inner_x() < target.corner_count())
        nearest = std::min(nearest, cv::norm(corners[i + static_cast<std::size_t>(target.inner_x())] - corners[i]));
    }
    const int w = std::clamp(static_cast<int>(0.35 * nearest), 2, options.subpixel_half_window);
    // A new buffer for the blur: `grey` may be the caller's own image.
    cv::Mat smooth;
    if (options.subpixel_smoothing_sigma > 0)
      cv::GaussianBlur(grey, smooth, cv::Size(0, 0), options.subpixel_smoothing_sigma);
    else
      smooth = grey;
    cv::cornerSubPix(smooth, corners, cv::Size(w, w), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
  }
  if (!found || static_cast<int>(corners.size()) != target.corner_count()) {
    out.reason = "no " + std::to_string(target.inner_x()) + " x " + std::to_string(target.inner_y()) +
                 " inner-corner checkerboard found (board partly outside the image, hidden, blurred or too dark?)";
    return out;
  }
  out.found = true;
  for (int id = 0; id < target.corner_count(); ++id) {
    const cv::Point2f& p = corners[static_cast<std::size_t>(id)];
    out.view.corners.push_back({id, {p.x, p.y}});
  }
  return out;
}

ProjectorCorners projector_corners(const TargetView& camera_corners, const DecodedView& columns,
                                   const DecodedView& rows, const ProjectorCornerOptions& options) {
  if (columns.width != rows.width || columns.height != rows.height)
    throw std::invalid_argument("projector corners: the column map is " + std::to_string(columns.width) + " x " +
                                std::to_string(columns.height) + " but the row map " + std::to_string(rows.width) +
                                " x " + std::to_string(rows.height));
  if (columns.axis != slproto::CodingAxis::columns || rows.axis != slproto::CodingAxis::rows)
    throw std::invalid_argument("projector corners: expected a map decoded along columns and one along rows");
  const std::size_t pixels = static_cast<std::size_t>(columns.width) * static_cast<std::size_t>(columns.height);
  if (columns.coordinate.size() != pixels || rows.coordinate.size() != pixels)
    throw std::invalid_argument("projector corners: decoded maps are smaller than their stated size");
  if (options.min_pixels < 8) throw std::invalid_argument("projector corners: min_pixels must be >= 8");

  ProjectorCorners out;
  out.view.name = camera_corners.name;
  const auto& corners = camera_corners.corners;
  double fit_sum = 0;
  std::vector<cv::Point2d> src, dst;
  std::vector<cv::Point2d> kept_src, kept_dst;
  for (std::size_t i = 0; i < corners.size(); ++i) {
    const Eigen::Vector2d corner = corners[i].pixel;
    int half = options.half_window_px;
    if (half <= 0) {
      double nearest = std::numeric_limits<double>::infinity();
      for (std::size_t j = 0; j < corners.size(); ++j)
        if (j != i) nearest = std::min(nearest, (corners[j].pixel - corner).norm());
      half = std::clamp(static_cast<int>(0.45 * nearest), 3, 60);
    }
    src.clear();
    dst.clear();
    const int u0 = std::max(0, static_cast<int>(std::lround(corner(0))) - half);
    const int u1 = std::min(columns.width - 1, static_cast<int>(std::lround(corner(0))) + half);
    const int v0 = std::max(0, static_cast<int>(std::lround(corner(1))) - half);
    const int v1 = std::min(columns.height - 1, static_cast<int>(std::lround(corner(1))) + half);
    for (int v = v0; v <= v1; ++v)
      for (int u = u0; u <= u1; ++u) {
        const std::size_t k =
            static_cast<std::size_t>(v) * static_cast<std::size_t>(columns.width) + static_cast<std::size_t>(u);
        const float x = columns.coordinate[k], y = rows.coordinate[k];
        if (std::isfinite(x) && std::isfinite(y)) {
          // Relative to the corner: the fit is better conditioned and the corner maps from (0, 0).
          src.emplace_back(u - corner(0), v - corner(1));
          dst.emplace_back(x, y);
        }
      }
    if (static_cast<int>(src.size()) < options.min_pixels) {
      ++out.rejected_few_pixels;
      continue;
    }
    cv::Mat h = cv::findHomography(src, dst, 0);
    if (h.empty()) {
      ++out.rejected_bad_fit;
      continue;
    }
    // One trimming pass: pixels far from the first fit (a wrong fringe order, a pixel that
    // mixes the target with its background) are dropped and the fit repeated.
    auto residual = [](const cv::Mat& hm, const cv::Point2d& s, const cv::Point2d& d) {
      const double* m = hm.ptr<double>();
      const double w = m[6] * s.x + m[7] * s.y + m[8];
      const double x = (m[0] * s.x + m[1] * s.y + m[2]) / w, y = (m[3] * s.x + m[4] * s.y + m[5]) / w;
      return std::hypot(x - d.x, y - d.y);
    };
    kept_src.clear();
    kept_dst.clear();
    for (std::size_t k = 0; k < src.size(); ++k)
      if (residual(h, src[k], dst[k]) <= options.max_pixel_residual_px) {
        kept_src.push_back(src[k]);
        kept_dst.push_back(dst[k]);
      }
    if (static_cast<int>(kept_src.size()) < options.min_pixels) {
      ++out.rejected_bad_fit;
      continue;
    }
    h = cv::findHomography(kept_src, kept_dst, 0);
    if (h.empty()) {
      ++out.rejected_bad_fit;
      continue;
    }
    double sum = 0;
    for (std::size_t k = 0; k < kept_src.size(); ++k) {
      const double r = residual(h, kept_src[k], kept_dst[k]);
      sum += r * r;
    }
    const double rms = std::sqrt(sum / static_cast<double>(kept_src.size()));
    if (rms > options.max_fit_rms_px) {
      ++out.rejected_bad_fit;
      continue;
    }
    const double* m = h.ptr<double>();
    out.view.corners.push_back({corners[i].id, {m[2] / m[8], m[5] / m[8]}});
    fit_sum += rms * rms;
  }
  if (!out.view.corners.empty())
    out.mean_fit_rms_px = std::sqrt(fit_sum / static_cast<double>(out.view.corners.size()));
  return out;
}

}  // namespace slscan::core
