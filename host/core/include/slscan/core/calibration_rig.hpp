// The whole calibration (paper step 1) from a calibration capture held in memory: the camera,
// both projectors and the turntable, with a report of every image used or skipped.
//
// The capture is an ordinary scan plan run by the firmware against a checkerboard:
//  * free poses (target held or on a stand at >= 10 varied poses): at each, every projector
//    shows the pattern plan along columns and along rows, so each corner gets both projector
//    coordinates; a camera image (ambient or flood lit) is optional, the white frames serve;
//  * turntable poses (target lying on the platform, >= 6 table angles): a camera image is
//    enough; pattern frames, if present, also feed the projector calibration.
// Images whose board is not found are reported and skipped; only too few usable poses is an
// error (std::runtime_error naming the counts and the skipped images).
#pragma once

#include <array>
#include <cstddef>
#include <functional>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "slproto/calibration.hpp"
#include "slproto/pattern_plan.hpp"
#include "slscan/core/calibration_corners.hpp"
#include "slscan/core/calibration_solve.hpp"
#include "slscan/core/decode.hpp"

namespace slscan::core {

struct CalibrationPose {
  std::string name;           // for reports; "pose <index>" when empty
  bool on_turntable = false;  // the target lies on the platform at table_angle_deg
  double table_angle_deg = 0;
};

// One camera frame of the capture. `image` is CV_8UC1 or CV_16UC1 (bit depth as in
// CalibrationCapture); it may wrap the caller's buffer (no copy is made).
struct CalibrationFrame {
  int pose = 0;  // index into CalibrationCapture::poses
  enum class Kind : std::uint8_t { camera, pattern } kind = Kind::pattern;
  slproto::ProjectorSide side = slproto::ProjectorSide::left;  // pattern frames only
  slproto::CodingAxis axis = slproto::CodingAxis::columns;     // pattern frames only
  std::size_t pattern_index = 0;                               // into the plan for `axis` (pattern frames only)
  cv::Mat image;
};

struct CalibrationCapture {
  CheckerboardTarget target;
  // The scan's pattern plan; the capture shows it along both axes (the plan for an axis is
  // this config with `axis` set). The calibration file records it.
  slproto::PatternPlanConfig pattern_plan;
  int bit_depth = 8;
  double platform_radius_mm = 150;  // not measurable from the target: from the rig's spec
  std::vector<CalibrationPose> poses;
  std::vector<CalibrationFrame> frames;
  std::string source;  // the capture it came from (path or description), written to the file

  // The plan along one axis.
  slproto::PatternPlan plan(slproto::CodingAxis axis) const;
};

// How far calibrate_rig has come, for a progress line: the poses measured (`done` of `total`,
// `step` the pose under way), then the solves (camera, each projector, the joint refinement,
// the turntable; `step` the one under way).
struct CalibrationProgress {
  enum class Phase { poses, solve } phase = Phase::poses;
  std::size_t done = 0;
  std::size_t total = 0;
  std::string step;
};

struct CalibrationOptions {
  LensModelOptions camera_lens;
  LensModelOptions projector_lens;
  CornerDetectionOptions detection;
  ProjectorCornerOptions projector_corners;
  DecodeOptions decode;  // bit_depth is taken from the capture
  int min_camera_views = 10;
  int min_projector_views = 6;
  int min_turntable_views = 3;  // 6 recommended: every scan angle
  bool turntable = true;        // false: no turntable poses expected (camera and projectors only)
  // A final bundle adjustment of camera, projectors and target poses together
  // (refine_rig_jointly); false keeps the separate solves (camera alone, then each projector
  // with the camera fixed).
  bool joint_refinement = true;
  std::string created_by = "slscan calibrate";
  std::function<void(const CalibrationProgress&)> progress;  // told as each pose and solve begins
};

struct PoseReport {
  std::string name;
  bool on_turntable = false;
  double table_angle_deg = 0;
  bool board_found = false;
  double camera_rms_px = -1;                       // -1: not used
  std::array<int, 2> projector_corners{0, 0};      // corners with projector coordinates, per side
  std::array<double, 2> projector_rms_px{-1, -1};  // -1: not used for that projector
  std::array<double, 2> local_fit_rms_px{-1, -1};  // decoded pixels about their local homographies
};

struct SkippedImage {
  std::string pose;
  std::string what;  // "camera image", "left projector", ...
  std::string reason;
};

struct TurntableStep {
  std::string pose;
  double commanded_deg = 0;    // relative to the first turntable pose
  double measured_deg = 0;     // relative to the first turntable pose
  double step_deg = 0;         // turned since the previous pose (0 for the first)
  double residual_mm = 0;      // the pose's own corners vs the fitted rotation (RMS, mm)
  double reprojection_px = 0;  // of the fitted rotation
  bool corner_order_reversed = false;
};

struct CalibrationReport {
  std::vector<PoseReport> poses;
  std::vector<SkippedImage> skipped;
  std::vector<TurntableStep> turntable;
  int camera_views = 0;
  std::array<int, 2> projector_views{0, 0};
  double camera_rms_px = 0;
  std::array<double, 2> projector_rms_px{0, 0};
  double turntable_rms_px = 0;
  double target_tilt_deg = 0;  // target normal vs the axis (a target not lying flat)

  // Human-readable summary (what `slscan calibrate` prints).
  std::string summary() const;
};

struct RigCalibrationResult {
  slproto::RigCalibration calibration;
  CalibrationReport report;
};

// Stage 1 of calibrate_rig for one pose: the board's corners in the camera and each
// projector's coordinates at them. A few kilobytes where the pose's frames are tens of
// megabytes (~380 MB at full resolution): a capture measured as its poses arrive
// (session::capture_calibration) keeps these and lets the frames go.
struct CalibrationPoseMeasurement {
  bool has_image = false;     // a camera image or a white frame to look for the board in
  CornerDetection detection;  // found = false with the reason when the board was not found
  // Per side: nullopt when the projector showed nothing at this pose, or when `missing` says
  // which frame of its plan is absent.
  std::array<std::optional<ProjectorCorners>, 2> projectors;
  std::array<std::string, 2> missing;
  int width = 0, height = 0;  // of the camera images
};

// A capture reduced to its measurements: everything calibrate_rig's solves need.
struct CalibrationMeasurements {
  CheckerboardTarget target;
  slproto::PatternPlanConfig pattern_plan;
  double platform_radius_mm = 150;
  std::vector<CalibrationPose> poses;
  std::vector<CalibrationPoseMeasurement> measured;  // one per pose
  std::string source;
};

// `projectors` false: the board only (no pattern decoding), for a quick look at a pose.
// Throws std::invalid_argument on a capture that cannot be read (frames of the wrong type or
// size, a pose out of range).
CalibrationPoseMeasurement measure_calibration_pose(const CalibrationCapture& capture, int pose,
                                                    const CalibrationOptions& options = {}, bool projectors = true);
// measure_calibration_pose for the poses of one capture in turn, keeping its pair of pattern
// decoders from pose to pose: their set-up costs ~0.5 s at 5 MP, as much as a pose's four
// decodes. They are made again when a capture's plan, image size or bit depth differs.
class CalibrationPoseMeasurer {
 public:
  explicit CalibrationPoseMeasurer(CalibrationOptions options = {});
  CalibrationPoseMeasurement measure(const CalibrationCapture& capture, int pose, bool projectors = true);

 private:
  struct DecodersFor {
    slproto::PatternPlanConfig plan;
    int width = 0, height = 0, bit_depth = 0;
    bool operator==(const DecodersFor&) const = default;
  };
  CalibrationOptions options_;
  std::optional<DecodersFor> made_for_;
  std::optional<std::array<ProjectorViewDecoder, 2>> decoders_;  // columns, rows
};
// The capture's settings with no poses yet; measure_calibration_pose fills `measured`.
CalibrationMeasurements measurements_of(const CalibrationCapture& capture);

// The solves (stages 2-5: camera, projectors, joint refinement, turntable) from measured poses.
RigCalibrationResult calibrate_rig(const CalibrationMeasurements& measurements, const CalibrationOptions& options = {});
// Measures every pose (progress phase `poses`), then solves.
RigCalibrationResult calibrate_rig(const CalibrationCapture& capture, const CalibrationOptions& options = {});

// One pose of a capture as calibrate_rig sees it (the same detection and decoding), for a
// guided capture to say at once whether the pose is usable: the board found, and how many of
// its inner corners each projector lights (gives coordinates at).
struct CalibrationPoseCheck {
  bool board_found = false;
  std::string reason;  // why not, when !board_found
  int corners = 0;     // the target's inner corners
  std::array<int, 2> lit_corners{0, 0};
  TargetView camera_corners;  // the board's corners in the camera image, when found
  int width = 0, height = 0;  // of the camera image
  // "" when the board was found and each projector lights at least `min_lit_fraction` of the
  // corners; else what is wrong, in words for the user.
  std::string problem(double min_lit_fraction = 0.75) const;
};
// `projectors` false: the board only (lit_corners stay 0), for poses checked before.
CalibrationPoseCheck check_calibration_pose(const CalibrationCapture& capture, int pose,
                                            const CalibrationOptions& options = {}, bool projectors = true);
// The same check of a pose measured already.
CalibrationPoseCheck check_calibration_pose(const CalibrationPoseMeasurement& measured,
                                            const CheckerboardTarget& target);

}  // namespace slscan::core
