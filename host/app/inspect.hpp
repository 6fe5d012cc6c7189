// slscan inspect: a scan against its nominal shape (STL / PLY / OBJ): best-fit alignment,
// signed deviation per point, figures, PASS / FAIL, and the files that show them
// (docs/inspection.md, "Deviation from a nominal").
#pragma once

#include <array>
#include <cstdint>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "run.hpp"
#include "slscan/core/inspect.hpp"

namespace slscan::app {

struct InspectCommand {
  std::string model_path;    // the scan (PLY point cloud)
  std::string nominal_path;  // STL, PLY or OBJ
  std::string output_dir;
  std::optional<double> tolerance_mm;  // +-; unset = not judged
  double pass_percent = 99;            // PASS when this share of the matched points is within tolerance
  double max_distance_mm = 0.5;        // farther points are not on the part
  std::string nominal_units = "auto";  // auto, mm, m, in
  bool scan_frame_only = false;        // --no-coarse-search
  // Provenance, for the reports.
  std::string part_id;
  std::string operator_name;
  std::string calibration_path;  // the calibration the scan was made with: its hash and date
  bool json = false;
};
int run_inspect(const InspectCommand& command, const Console& console);

// The inspection's colour scale: blue (-range) - cyan - green (0) - yellow - red (+range),
// clamped beyond; grey where unmatched (NaN). RGB.
std::array<std::uint8_t, 3> deviation_colour(float deviation_mm, double range_mm);

// Picture of the aligned scan coloured by deviation, seen along its thinnest principal axis
// from both sides, with a colour bar in um and a caption. BGR, for cv::imencode.
cv::Mat deviation_picture(const std::vector<Eigen::Vector3f>& points, const std::vector<float>& deviation_mm,
                          double range_mm, const std::vector<std::string>& caption);

}  // namespace slscan::app
