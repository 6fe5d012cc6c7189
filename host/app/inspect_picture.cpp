// The inspection's deviation picture and colour scale (slscan inspect).
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "inspect.hpp"

namespace slscan::app {

std::array<std::uint8_t, 3> deviation_colour(float deviation_mm, double range_mm) {
  if (!std::isfinite(deviation_mm)) return {160, 160, 160};
  const double t = std::clamp(static_cast<double>(deviation_mm) / std::max(range_mm, 1e-12), -1.0, 1.0);
  // Stops at -1, -0.5, 0, 0.5, 1.
  static constexpr double stops[5][3] = {{0, 0, 255}, {0, 220, 255}, {0, 200, 0}, {255, 230, 0}, {255, 0, 0}};
  const double x = (t + 1) * 2;  // 0..4
  const int i = std::min(3, static_cast<int>(std::floor(x)));
  const double f = x - i;
  std::array<std::uint8_t, 3> c{};
  for (int k = 0; k < 3; ++k)
    c[static_cast<std::size_t>(k)] =
        static_cast<std::uint8_t>(std::lround(stops[i][k] + f * (stops[i + 1][k] - stops[i][k])));
  return c;
}

namespace {

cv::Scalar bgr(const std::array<std::uint8_t, 3>& rgb) { return {double(rgb[2]), double(rgb[1]), double(rgb[0])}; }

void text(cv::Mat& image, const std::string& s, cv::Point at, double scale = 0.5, int thickness = 1) {
  cv::putText(image, s, at, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(20, 20, 20), thickness, cv::LINE_AA);
}

}  // namespace

cv::Mat deviation_picture(const std::vector<Eigen::Vector3f>& points, const std::vector<float>& deviation_mm,
                          double range_mm, const std::vector<std::string>& caption) {
  // Principal axes of the matched points (all points when none matched).
  std::vector<Eigen::Vector3d> used;
  for (std::size_t i = 0; i < points.size(); ++i)
    if (std::isfinite(deviation_mm[i])) used.push_back(points[i].cast<double>());
  if (used.size() < 3)
    for (const auto& p : points) used.push_back(p.cast<double>());
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : used) mean += p;
  mean /= static_cast<double>(std::max<std::size_t>(1, used.size()));
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : used) cov += (p - mean) * (p - mean).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  const Eigen::Vector3d e1 = eig.eigenvectors().col(2), e2 = eig.eigenvectors().col(1), e3 = e1.cross(e2).normalized();
  double u_lo = std::numeric_limits<double>::max(), u_hi = -u_lo, v_lo = u_lo, v_hi = -u_lo;
  for (const auto& p : used) {
    const Eigen::Vector3d q = p - mean;
    u_lo = std::min(u_lo, q.dot(e1)), u_hi = std::max(u_hi, q.dot(e1));
    v_lo = std::min(v_lo, q.dot(e2)), v_hi = std::max(v_hi, q.dot(e2));
  }
  const int panel_w = 520, margin = 20, title_h = 24 + 20 * static_cast<int>(caption.size()), bar_w = 150;
  const double span_u = std::max(u_hi - u_lo, 1e-6), span_v = std::max(v_hi - v_lo, 1e-6);
  const double scale = std::min((panel_w - 2.0 * margin) / span_u, 600.0 / span_v);
  const int panel_h = static_cast<int>(std::ceil(span_v * scale)) + 2 * margin + 20;
  const int height = std::max(title_h + panel_h, title_h + 360);
  cv::Mat image(height, 2 * panel_w + bar_w, CV_8UC3, cv::Scalar(255, 255, 255));
  int y = 22;
  for (const auto& line : caption) text(image, line, {margin, y}), y += 20;
  // Footprints as wide as the points' mean spacing (each side sees about half of them).
  const double spacing =
      std::sqrt(span_u * span_v / (0.5 * static_cast<double>(std::max<std::size_t>(used.size(), 1))));
  const int splat = std::clamp(static_cast<int>(std::lround(spacing * scale)), 1, 12);
  for (int side = 0; side < 2; ++side) {
    const double flip = side == 0 ? 1 : -1;  // the second panel: seen from the other side (mirrored u)
    cv::Mat depth(image.rows, image.cols, CV_64F, cv::Scalar(-std::numeric_limits<double>::infinity()));
    const int x0 = side * panel_w + margin, y0 = title_h + margin;
    for (std::size_t i = 0; i < points.size(); ++i) {
      const Eigen::Vector3d q = points[i].cast<double>() - mean;
      const double u = flip > 0 ? q.dot(e1) - u_lo : u_hi - q.dot(e1);
      const double z = flip * q.dot(e3);  // toward the viewer
      const int px = x0 + static_cast<int>(u * scale), py = y0 + static_cast<int>((v_hi - q.dot(e2)) * scale);
      const cv::Scalar colour = bgr(deviation_colour(deviation_mm[i], range_mm));
      for (int dy = 0; dy < splat; ++dy)
        for (int dx = 0; dx < splat; ++dx) {
          const int xx = px + dx - splat / 2, yy = py + dy - splat / 2;
          if (xx < side * panel_w || xx >= (side + 1) * panel_w || yy < title_h || yy >= image.rows) continue;
          if (z <= depth.at<double>(yy, xx)) continue;
          depth.at<double>(yy, xx) = z;
          image.at<cv::Vec3b>(yy, xx) =
              cv::Vec3b(static_cast<std::uint8_t>(colour[0]), static_cast<std::uint8_t>(colour[1]),
                        static_cast<std::uint8_t>(colour[2]));
        }
    }
    text(image, side == 0 ? "seen along -axis 3" : "seen along +axis 3", {x0, image.rows - 8}, 0.45);
  }
  // Colour bar: +range at the top, -range at the bottom, labelled in um.
  const int bx = 2 * panel_w + 10, by = title_h + 10, bh = std::min(300, image.rows - by - 60), bw = 24;
  for (int r = 0; r < bh; ++r) {
    const double d = range_mm * (1 - 2.0 * r / (bh - 1));
    cv::line(image, {bx, by + r}, {bx + bw, by + r}, bgr(deviation_colour(static_cast<float>(d), range_mm)));
  }
  cv::rectangle(image, {bx, by}, {bx + bw, by + bh}, cv::Scalar(40, 40, 40));
  for (int k = 0; k <= 4; ++k) {
    const int yy = by + k * (bh - 1) / 4;
    const double d_um = 1e3 * range_mm * (1 - k / 2.0);
    char label[32];
    std::snprintf(label, sizeof label, "%+.0f um", d_um);
    cv::line(image, {bx + bw, yy}, {bx + bw + 5, yy}, cv::Scalar(40, 40, 40));
    text(image, k == 2 ? "0 um" : label, {bx + bw + 8, yy + 5}, 0.45);
  }
  const int gy = by + bh + 14;
  cv::rectangle(image, {bx, gy}, {bx + bw, gy + 14}, bgr(deviation_colour(NAN, range_mm)), cv::FILLED);
  text(image, "unmatched", {bx + bw + 8, gy + 12}, 0.42);
  return image;
}

}  // namespace slscan::app
