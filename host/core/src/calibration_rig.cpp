#include "slscan/core/calibration_rig.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <sstream>
#include <stdexcept>

namespace slscan::core {

using slproto::CodingAxis;
using slproto::PatternKind;
using slproto::ProjectorSide;

slproto::PatternPlan CalibrationCapture::plan(CodingAxis axis) const {
  slproto::PatternPlanConfig config = pattern_plan;
  config.axis = axis;
  auto plan = slproto::PatternPlan::make(config);
  if (!plan.ok())
    throw std::invalid_argument("calibration capture: pattern plan along " + std::string(coding_axis_name(axis)) +
                                ": " + plan.error().message);
  return std::move(plan).value();
}

namespace {

constexpr std::array<ProjectorSide, 2> kSides{ProjectorSide::left, ProjectorSide::right};
constexpr std::array<CodingAxis, 2> kAxes{CodingAxis::columns, CodingAxis::rows};

std::string side_label(ProjectorSide side) { return std::string(slproto::projector_side_name(side)) + " projector"; }

// The frames of one pose, by role.
struct PoseFrames {
  const cv::Mat* camera = nullptr;
  // [side][axis][pattern index]
  std::array<std::array<std::vector<const cv::Mat*>, 2>, 2> patterns;
};

std::vector<PoseFrames> index_frames(const CalibrationCapture& capture,
                                     const std::array<slproto::PatternPlan, 2>& plans, int& width, int& height) {
  if (capture.poses.empty()) throw std::invalid_argument("calibration capture: no poses");
  if (capture.bit_depth != 8 && capture.bit_depth != 10 && capture.bit_depth != 12 && capture.bit_depth != 16)
    throw std::invalid_argument("calibration capture: bit depth " + std::to_string(capture.bit_depth) +
                                " is not 8, 10, 12 or 16");
  const int type = capture.bit_depth == 8 ? CV_8UC1 : CV_16UC1;
  std::vector<PoseFrames> out(capture.poses.size());
  for (auto& pose : out)
    for (auto& side : pose.patterns)
      for (std::size_t a = 0; a < 2; ++a) side[a].assign(plans[a].size(), nullptr);
  width = height = 0;
  for (std::size_t i = 0; i < capture.frames.size(); ++i) {
    const CalibrationFrame& f = capture.frames[i];
    const std::string where = "calibration capture: frame " + std::to_string(i);
    if (f.pose < 0 || f.pose >= static_cast<int>(capture.poses.size()))
      throw std::invalid_argument(where + " names pose " + std::to_string(f.pose) + " of " +
                                  std::to_string(capture.poses.size()));
    if (f.image.empty() || f.image.type() != type)
      throw std::invalid_argument(where + ": image must be a non-empty " +
                                  std::string(capture.bit_depth == 8 ? "8-bit" : "16-bit") + " single-channel image");
    if (width == 0) {
      width = f.image.cols;
      height = f.image.rows;
    } else if (f.image.cols != width || f.image.rows != height) {
      throw std::invalid_argument(where + ": " + std::to_string(f.image.cols) + " x " + std::to_string(f.image.rows) +
                                  ", but earlier frames are " + std::to_string(width) + " x " + std::to_string(height));
    }
    PoseFrames& pose = out[static_cast<std::size_t>(f.pose)];
    if (f.kind == CalibrationFrame::Kind::camera) {
      pose.camera = &f.image;
      continue;
    }
    const auto s = static_cast<std::size_t>(f.side), a = static_cast<std::size_t>(f.axis);
    if (s > 1 || a > 1) throw std::invalid_argument(where + ": unknown projector side or axis");
    if (f.pattern_index >= plans[a].size())
      throw std::invalid_argument(where + ": pattern " + std::to_string(f.pattern_index) + " beyond the " +
                                  std::to_string(plans[a].size()) + "-pattern plan along " +
                                  slproto::coding_axis_name(f.axis));
    pose.patterns[s][a][f.pattern_index] = &f.image;
  }
  if (width == 0) throw std::invalid_argument("calibration capture: no frames");
  return out;
}

// What the corner detector looks at: the camera image if there is one, else the sum of the
// projectors' white frames (the board lit from both sides, so neither casts a dark side), of
// both axes when there are both (four frames: half the noise variance of two).
cv::Mat detection_image(const PoseFrames& frames, const std::array<slproto::PatternPlan, 2>& plans) {
  if (frames.camera != nullptr) return *frames.camera;
  cv::Mat sum;
  for (std::size_t s = 0; s < 2; ++s)
    for (std::size_t a = 0; a < 2; ++a) {
      const int white = plans[a].index_of(PatternKind::white);
      if (white < 0) continue;
      const cv::Mat* image = frames.patterns[s][a][static_cast<std::size_t>(white)];
      if (image == nullptr) continue;
      if (sum.empty()) sum = cv::Mat::zeros(image->size(), CV_32F);
      cv::Mat f;
      image->convertTo(f, CV_32F);
      sum += f;  // every white frame: both projectors, both axes (less noise)
    }
  if (sum.empty()) return {};
  double hi = 0;
  cv::minMaxLoc(sum, nullptr, &hi);
  cv::Mat out;
  sum.convertTo(out, CV_8U, hi > 0 ? 255.0 / hi : 1.0);
  return out;
}

// The first pattern of `plan` with no frame, or -1 when all are there.
int first_missing(const std::vector<const cv::Mat*>& frames) {
  for (std::size_t i = 0; i < frames.size(); ++i)
    if (frames[i] == nullptr) return static_cast<int>(i);
  return -1;
}

bool any_present(const std::vector<const cv::Mat*>& frames) {
  return std::any_of(frames.begin(), frames.end(), [](const cv::Mat* m) { return m != nullptr; });
}

DecodedView decode(ProjectorViewDecoder& decoder, const std::vector<const cv::Mat*>& frames) {
  decoder.reset();
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const cv::Mat& m = *frames[i];
    if (m.depth() == CV_8U)
      decoder.add_frame(i, m.ptr<std::uint8_t>(), m.step1());
    else
      decoder.add_frame(i, m.ptr<std::uint16_t>(), m.step1());
  }
  return decoder.finish();
}

CalibrationPoseMeasurement measure_pose(const PoseFrames& frames, const std::array<slproto::PatternPlan, 2>& plans,
                                        const CheckerboardTarget& target, const CalibrationOptions& options,
                                        std::array<ProjectorViewDecoder, 2>* decoders) {
  CalibrationPoseMeasurement out;
  const cv::Mat image = detection_image(frames, plans);
  out.has_image = !image.empty();
  if (!out.has_image) return out;
  out.detection = detect_checkerboard(image, target, options.detection);
  if (!out.detection.found || decoders == nullptr) return out;  // the board only
  for (std::size_t s = 0; s < 2; ++s) {
    const auto& sets = frames.patterns[s];
    if (!any_present(sets[0]) && !any_present(sets[1])) continue;  // this projector showed nothing here
    for (std::size_t a = 0; a < 2 && out.missing[s].empty(); ++a)
      if (const int m = first_missing(sets[a]); m >= 0)
        out.missing[s] = "no frame for pattern " + std::to_string(m) + " (" +
                         slproto::pattern_kind_name(plans[a][static_cast<std::size_t>(m)].kind) + ") along " +
                         slproto::coding_axis_name(kAxes[a]);
    if (!out.missing[s].empty()) continue;
    const DecodedView columns = decode((*decoders)[0], sets[0]);
    const DecodedView rows = decode((*decoders)[1], sets[1]);
    out.projectors[s] = projector_corners(out.detection.view, columns, rows, options.projector_corners);
  }
  return out;
}

std::array<ProjectorViewDecoder, 2> make_decoders(const std::array<slproto::PatternPlan, 2>& plans, int width,
                                                  int height, const CalibrationOptions& options, int bit_depth) {
  DecodeOptions decode_options = options.decode;
  decode_options.bit_depth = bit_depth;
  return {ProjectorViewDecoder(plans[0], width, height, decode_options),
          ProjectorViewDecoder(plans[1], width, height, decode_options)};
}

std::string fixed(double value, int digits) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*f", digits, value);
  return buffer;
}

}  // namespace

CalibrationMeasurements measurements_of(const CalibrationCapture& capture) {
  CalibrationMeasurements out;
  out.target = capture.target;
  out.pattern_plan = capture.pattern_plan;
  out.platform_radius_mm = capture.platform_radius_mm;
  out.source = capture.source;
  return out;
}

RigCalibrationResult calibrate_rig(const CalibrationCapture& capture, const CalibrationOptions& options) {
  capture.target.check();
  const std::array<slproto::PatternPlan, 2> plans{capture.plan(CodingAxis::columns), capture.plan(CodingAxis::rows)};
  int width = 0, height = 0;
  const std::vector<PoseFrames> frames = index_frames(capture, plans, width, height);
  std::array<ProjectorViewDecoder, 2> decoders = make_decoders(plans, width, height, options, capture.bit_depth);
  CalibrationMeasurements measurements = measurements_of(capture);
  measurements.poses = capture.poses;
  for (std::size_t p = 0; p < capture.poses.size(); ++p) {
    if (options.progress)
      options.progress({CalibrationProgress::Phase::poses, p, capture.poses.size(),
                        capture.poses[p].name.empty() ? "pose " + std::to_string(p) : capture.poses[p].name});
    CalibrationPoseMeasurement measured = measure_pose(frames[p], plans, capture.target, options, &decoders);
    measured.width = width;
    measured.height = height;
    measurements.measured.push_back(std::move(measured));
  }
  if (options.progress)
    options.progress({CalibrationProgress::Phase::poses, capture.poses.size(), capture.poses.size(), {}});
  return calibrate_rig(measurements, options);
}

CalibrationPoseMeasurer::CalibrationPoseMeasurer(CalibrationOptions options) : options_(std::move(options)) {}

CalibrationPoseMeasurement CalibrationPoseMeasurer::measure(const CalibrationCapture& capture, int pose,
                                                            bool projectors) {
  capture.target.check();
  const std::array<slproto::PatternPlan, 2> plans{capture.plan(CodingAxis::columns), capture.plan(CodingAxis::rows)};
  int width = 0, height = 0;
  const std::vector<PoseFrames> frames = index_frames(capture, plans, width, height);
  if (pose < 0 || pose >= static_cast<int>(frames.size()))
    throw std::invalid_argument("calibration capture: pose " + std::to_string(pose) + " of " +
                                std::to_string(frames.size()));
  const DecodersFor wanted{capture.pattern_plan, width, height, capture.bit_depth};
  if (projectors && (!decoders_ || made_for_ != wanted)) {
    made_for_.reset();
    decoders_.emplace(make_decoders(plans, width, height, options_, capture.bit_depth));
    made_for_ = wanted;
  }
  CalibrationPoseMeasurement measured = measure_pose(frames[static_cast<std::size_t>(pose)], plans, capture.target,
                                                     options_, projectors ? &*decoders_ : nullptr);
  measured.width = width;
  measured.height = height;
  return measured;
}

CalibrationPoseMeasurement measure_calibration_pose(const CalibrationCapture& capture, int pose,
                                                    const CalibrationOptions& options, bool projectors) {
  return CalibrationPoseMeasurer(options).measure(capture, pose, projectors);
}

RigCalibrationResult calibrate_rig(const CalibrationMeasurements& measurements, const CalibrationOptions& options) {
  measurements.target.check();
  if (measurements.poses.empty()) throw std::invalid_argument("calibration capture: no poses");
  if (measurements.measured.size() != measurements.poses.size())
    throw std::invalid_argument("calibration: " + std::to_string(measurements.measured.size()) +
                                " measured poses for " + std::to_string(measurements.poses.size()) + " poses");
  const int width = measurements.measured.front().width;
  const int height = measurements.measured.front().height;
  for (std::size_t p = 0; p < measurements.measured.size(); ++p)
    if (measurements.measured[p].width != width || measurements.measured[p].height != height)
      throw std::invalid_argument("calibration: pose " + std::to_string(p) + " was measured in " +
                                  std::to_string(measurements.measured[p].width) + " x " +
                                  std::to_string(measurements.measured[p].height) + " images, pose 0 in " +
                                  std::to_string(width) + " x " + std::to_string(height));
  const int projector_width = measurements.pattern_plan.projector_width;
  const int projector_height = measurements.pattern_plan.projector_height;
  const CheckerboardTarget& target = measurements.target;

  RigCalibrationResult result;
  CalibrationReport& report = result.report;
  report.poses.resize(measurements.poses.size());

  // 1. Corners in the camera, and each projector's coordinates at them.
  std::vector<TargetView> camera_views;
  std::vector<std::size_t> camera_pose;  // pose index of each camera view
  std::array<std::vector<TargetView>, 2> proj_cam_views, proj_views;
  std::array<std::vector<std::size_t>, 2> proj_pose;
  std::vector<TurntableView> table_views;
  std::vector<std::size_t> table_pose;
  auto tell = [&](CalibrationProgress::Phase phase, std::size_t done, std::size_t total, std::string step) {
    if (options.progress) options.progress({phase, done, total, std::move(step)});
  };
  for (std::size_t p = 0; p < measurements.poses.size(); ++p) {
    const CalibrationPose& pose = measurements.poses[p];
    PoseReport& pr = report.poses[p];
    pr.name = pose.name.empty() ? "pose " + std::to_string(p) : pose.name;
    pr.on_turntable = pose.on_turntable;
    pr.table_angle_deg = pose.table_angle_deg;
    CalibrationPoseMeasurement measured = measurements.measured[p];
    if (!measured.has_image) {
      report.skipped.push_back({pr.name, "camera image", "no camera image and no white pattern frame"});
      continue;
    }
    CornerDetection& detection = measured.detection;
    if (!detection.found) {
      report.skipped.push_back({pr.name, "camera image", detection.reason});
      continue;
    }
    pr.board_found = true;
    detection.view.name = pr.name;
    camera_views.push_back(detection.view);
    camera_pose.push_back(p);
    if (pose.on_turntable) {
      TurntableView table_view;
      table_view.camera = detection.view;
      table_view.commanded_angle_deg = pose.table_angle_deg;
      table_views.push_back(std::move(table_view));
      table_pose.push_back(p);
    }
    for (std::size_t s = 0; s < 2; ++s) {
      if (!measured.missing[s].empty()) {
        report.skipped.push_back({pr.name, side_label(kSides[s]), measured.missing[s]});
        continue;
      }
      if (!measured.projectors[s]) continue;  // this projector showed nothing here
      ProjectorCorners& corners = *measured.projectors[s];
      corners.view.name = pr.name;
      pr.projector_corners[s] = static_cast<int>(corners.view.corners.size());
      pr.local_fit_rms_px[s] = corners.view.corners.empty() ? -1 : corners.mean_fit_rms_px;
      if (corners.view.corners.size() < 6) {
        report.skipped.push_back({pr.name, side_label(kSides[s]),
                                  std::to_string(corners.view.corners.size()) +
                                      " corners with projector coordinates (" +
                                      std::to_string(corners.rejected_few_pixels) + " with too few decoded pixels, " +
                                      std::to_string(corners.rejected_bad_fit) + " with a poor local fit); 6 needed"});
        continue;
      }
      proj_cam_views[s].push_back(detection.view);
      proj_views[s].push_back(corners.view);
      proj_pose[s].push_back(p);
      if (pose.on_turntable) table_views.back().projectors[s] = corners.view;
    }
  }

  auto skipped_text = [&] {
    std::string text;
    for (const SkippedImage& s : report.skipped) text += "\n  " + s.pose + ", " + s.what + ": " + s.reason;
    return text;
  };

  // 2. Camera.
  const std::size_t solves = 3 + (options.joint_refinement ? 1 : 0) + (options.turntable ? 1 : 0);
  std::size_t solved = 0;
  tell(CalibrationProgress::Phase::solve, solved++, solves, "camera");
  if (static_cast<int>(camera_views.size()) < options.min_camera_views)
    throw std::runtime_error("calibration: the board was found in " + std::to_string(camera_views.size()) +
                             " poses, at least " + std::to_string(options.min_camera_views) +
                             " are needed for the camera" + skipped_text());
  const DeviceCalibration camera =
      calibrate_camera(target, camera_views, width, height, options.camera_lens, options.min_camera_views);
  report.camera_views = static_cast<int>(camera_views.size());
  report.camera_rms_px = camera.rms_px;
  for (std::size_t i = 0; i < camera_views.size(); ++i)
    report.poses[camera_pose[i]].camera_rms_px = camera.view_rms_px[i];

  slproto::RigCalibration& cal = result.calibration;
  cal.camera = camera.model;
  cal.camera_reprojection_rms_px = camera.rms_px;

  // 3. Projectors.
  for (std::size_t s = 0; s < 2; ++s) {
    tell(CalibrationProgress::Phase::solve, solved++, solves, side_label(kSides[s]));
    if (static_cast<int>(proj_views[s].size()) < options.min_projector_views)
      throw std::runtime_error("calibration: the " + side_label(kSides[s]) + " has corner coordinates in " +
                               std::to_string(proj_views[s].size()) + " poses, at least " +
                               std::to_string(options.min_projector_views) + " are needed" + skipped_text());
    const ProjectorSolve solve =
        calibrate_projector(target, camera.model, proj_cam_views[s], proj_views[s], projector_width, projector_height,
                            options.projector_lens, options.min_projector_views);
    cal.projectors[s] = solve.calibration;
    report.projector_views[s] = static_cast<int>(proj_views[s].size());
    report.projector_rms_px[s] = solve.calibration.reprojection_rms_px;
    for (std::size_t i = 0; i < proj_views[s].size(); ++i)
      report.poses[proj_pose[s][i]].projector_rms_px[s] = solve.view_rms_px[i];
  }

  // 4. The whole rig at once (refine_rig_jointly): the projectors' precise corners pin the
  // target poses and through them the camera's intrinsics.
  if (options.joint_refinement) {
    tell(CalibrationProgress::Phase::solve, solved++, solves, "joint refinement");
    std::vector<std::size_t> camera_view_of_pose(measurements.poses.size(), 0);
    for (std::size_t i = 0; i < camera_pose.size(); ++i) camera_view_of_pose[camera_pose[i]] = i;
    std::array<ProjectorObservations, 2> observations;
    for (std::size_t s = 0; s < 2; ++s) {
      observations[s].views = proj_views[s];
      observations[s].start = cal.projectors[s];
      for (std::size_t p : proj_pose[s]) observations[s].camera_view.push_back(camera_view_of_pose[p]);
    }
    const RigBundle bundle =
        refine_rig_jointly(target, camera, camera_views, observations, options.camera_lens, options.projector_lens);
    cal.camera = bundle.camera.model;
    cal.camera_reprojection_rms_px = bundle.camera.rms_px;
    report.camera_rms_px = bundle.camera.rms_px;
    for (std::size_t i = 0; i < camera_views.size(); ++i)
      report.poses[camera_pose[i]].camera_rms_px = bundle.camera.view_rms_px[i];
    for (std::size_t s = 0; s < 2; ++s) {
      cal.projectors[s] = bundle.projectors[s];
      report.projector_rms_px[s] = bundle.projectors[s].reprojection_rms_px;
      for (std::size_t i = 0; i < proj_pose[s].size(); ++i)
        report.poses[proj_pose[s][i]].projector_rms_px[s] = bundle.projector_view_rms_px[s][i];
    }
  }

  // 5. Turntable.
  cal.turntable.platform_radius_mm = measurements.platform_radius_mm;
  if (options.turntable) {
    tell(CalibrationProgress::Phase::solve, solved++, solves, "turntable");
    if (static_cast<int>(table_views.size()) < options.min_turntable_views)
      throw std::runtime_error("calibration: the board was found in " + std::to_string(table_views.size()) +
                               " turntable poses, at least " + std::to_string(options.min_turntable_views) +
                               " are needed (6 recommended)" + skipped_text());
    // Projectors that saw the table poses pin their depth (the camera alone: PnP).
    std::array<TurntableProjector, 2> table_projectors;
    for (std::size_t s = 0; s < 2; ++s) {
      table_projectors[s].use = !proj_views[s].empty();
      table_projectors[s].calibration = cal.projectors[s];
      table_projectors[s].weight =
          cal.camera_reprojection_rms_px / std::max(cal.projectors[s].reprojection_rms_px, 0.005);
    }
    const TurntableSolve table =
        calibrate_turntable(target, cal.camera, table_views, measurements.platform_radius_mm, table_projectors);
    cal.turntable = table.calibration;
    report.turntable_rms_px = table.rms_px;
    report.target_tilt_deg = table.target_tilt_deg;
    for (std::size_t i = 0; i < table_views.size(); ++i)
      report.turntable.push_back({report.poses[table_pose[i]].name,
                                  table_views[i].commanded_angle_deg - table_views[0].commanded_angle_deg,
                                  table.measured_angle_deg[i], table.step_deg[i], table.pose_residual_mm[i],
                                  table.reprojection_rms_px[i], table.flipped[i]});
  }

  tell(CalibrationProgress::Phase::solve, solved, solves, {});
  cal.pattern_plan = measurements.pattern_plan;
  cal.source = measurements.source;
  cal.created_by = options.created_by;
  if (auto status = cal.check(); !status)
    throw std::runtime_error("calibration: the result is not a valid calibration: " + status.error().message);
  return result;
}

std::string CalibrationReport::summary() const {
  std::ostringstream out;
  out << "camera: " << camera_views << " views, reprojection RMS " << fixed(camera_rms_px, 3) << " px\n";
  for (std::size_t s = 0; s < 2; ++s)
    out << side_label(kSides[s]) << ": " << projector_views[s] << " views, reprojection RMS "
        << fixed(projector_rms_px[s], 3) << " projector px\n";
  if (!turntable.empty()) {
    out << "turntable: reprojection RMS " << fixed(turntable_rms_px, 3) << " px, target tilt to axis "
        << fixed(target_tilt_deg, 3) << " deg\n";
    for (const TurntableStep& step : turntable)
      out << "  " << step.pose << ": commanded " << fixed(step.commanded_deg, 3) << " deg, measured "
          << fixed(step.measured_deg, 3) << " deg, step " << fixed(step.step_deg, 3) << " deg, residual "
          << fixed(step.residual_mm, 4) << " mm" << (step.corner_order_reversed ? " (corner order reversed)" : "")
          << "\n";
  }
  for (const PoseReport& pose : poses) {
    out << "  " << pose.name << ": ";
    if (!pose.board_found) {
      out << "skipped\n";
      continue;
    }
    out << "camera " << fixed(pose.camera_rms_px, 3) << " px";
    for (std::size_t s = 0; s < 2; ++s)
      if (pose.projector_rms_px[s] >= 0)
        out << ", " << slproto::projector_side_name(kSides[s]) << " " << fixed(pose.projector_rms_px[s], 3) << " px ("
            << pose.projector_corners[s] << " corners)";
    out << "\n";
  }
  for (const SkippedImage& s : skipped) out << "skipped " << s.pose << ", " << s.what << ": " << s.reason << "\n";
  return out.str();
}

CalibrationPoseCheck check_calibration_pose(const CalibrationCapture& capture, int pose,
                                            const CalibrationOptions& options, bool projectors) {
  return check_calibration_pose(measure_calibration_pose(capture, pose, options, projectors), capture.target);
}

CalibrationPoseCheck check_calibration_pose(const CalibrationPoseMeasurement& measured,
                                            const CheckerboardTarget& target) {
  CalibrationPoseCheck check;
  check.corners = target.corner_count();
  check.board_found = measured.detection.found;
  check.width = measured.width;
  check.height = measured.height;
  if (check.board_found) check.camera_corners = measured.detection.view;
  check.reason = measured.has_image ? measured.detection.reason : "no camera image and no white pattern frame";
  for (std::size_t s = 0; s < 2; ++s)
    if (measured.projectors[s]) check.lit_corners[s] = static_cast<int>(measured.projectors[s]->view.corners.size());
  return check;
}

std::string CalibrationPoseCheck::problem(double min_lit_fraction) const {
  if (!board_found) return "the board was not found (" + reason + ")";
  std::string problem;
  for (std::size_t s = 0; s < 2; ++s)
    if (lit_corners[s] < min_lit_fraction * corners) {
      if (!problem.empty()) problem += "; ";
      problem += std::string("the ") + slproto::projector_side_name(kSides[s]) + " projector lights " +
                 std::to_string(lit_corners[s]) + " of its " + std::to_string(corners) + " corners (" +
                 fixed(100.0 * min_lit_fraction, 0) + " % wanted: turn the board toward it or move it into its light)";
    }
  return problem;
}

}  // namespace slscan::core
