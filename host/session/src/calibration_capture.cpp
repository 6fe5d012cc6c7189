#include "slscan/session/calibration_capture.hpp"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <optional>

#include "slscan/io/calibration_capture_files.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::session {

using Clock = std::chrono::steady_clock;
using slproto::CodingAxis;
using slproto::GuidedCalibrationPose;

namespace {

int bit_depth_of(slproto::pb::PixelFormat format) {
  switch (format) {
    case slproto::pb::PIXEL_FORMAT_MONO10:
      return 10;
    case slproto::pb::PIXEL_FORMAT_MONO12:
      return 12;
    default:
      return 8;
  }
}

slproto::pb::PixelFormat pixel_format_of(int bit_depth) {
  return bit_depth == 12   ? slproto::pb::PIXEL_FORMAT_MONO12
         : bit_depth == 10 ? slproto::pb::PIXEL_FORMAT_MONO10
                           : slproto::pb::PIXEL_FORMAT_MONO8;
}

std::string where_kept(const CalibrationCaptureRequest& request, std::size_t poses) {
  if (poses == 0) return "no pose was complete";
  if (request.folder.empty())
    return std::to_string(poses) + (poses == 1 ? " pose was" : " poses were") +
           " complete (give --write-capture DIR to keep them on disk)";
  return "the " + std::to_string(poses) + (poses == 1 ? " complete pose is in " : " complete poses are in ") +
         request.folder + " (--resume " + request.folder + " continues)";
}

// One scan of one pose along one axis: both projectors' plans at one table angle.
class PoseScanner {
 public:
  PoseScanner(const CalibrationCaptureRequest& request, ScannerConnection& scanner, int bit_depth, bool place_target)
      : request_(request), scanner_(scanner), bit_depth_(bit_depth), place_target_(place_target) {}

  // Appends the frames to `capture` as pose `pose`.
  void scan(const GuidedCalibrationPose& guided, CodingAxis axis, int pose, core::CalibrationCapture& capture) {
    slproto::PatternPlanConfig config = request_.pattern_plan;
    config.axis = axis;
    const slproto::PatternPlan plan(config);
    slproto::pb::ScanRequest scan;
    scan.set_scan_id(static_cast<std::uint64_t>(std::chrono::system_clock::now().time_since_epoch().count()));
    scan.add_turntable_angles_deg(guided.table_angle_deg);
    scan.add_projectors(0);
    scan.add_projectors(1);
    *scan.mutable_plan() = slproto::to_proto(config);
    const PatternTiming timing = pattern_timing(request_.exposure_us, request_.pattern_period_us, scanner_.board);
    scan.set_exposure_us(timing.exposure_us);
    scan.set_pattern_period_us(timing.period_us);
    scan.set_settle_ms(request_.settle_ms);
    scan.set_pixel_format(pixel_format_of(bit_depth_));
    if (place_target_) *scan.mutable_calibration_target() = slproto::to_proto(guided, request_.target);
    if (auto status = slproto::check_scan_request(scan); !status) throw std::invalid_argument(status.error().message);
    const std::string what = guided.name + " (" + slproto::coding_axis_name(axis) + ")";
    slproto::Connection& connection = scanner_.connection;
    if (auto status = connection.send(scan); !status)
      throw DeviceError(what + ": sending the scan request: " + status.error().message);

    const std::size_t expected = 2 * plan.size();
    std::size_t received = 0;
    auto last_frame_at = Clock::now();
    auto abort = [&](const std::string& reason) {
      slproto::pb::Abort message;
      message.set_scan_id(scan.scan_id());
      message.set_reason(reason);
      (void)connection.send(message);
    };
    while (true) {
      if (request_.stop != nullptr && request_.stop->load()) {
        abort("interrupted on the host (Ctrl-C)");
        throw CalibrationCaptureStopped(CalibrationCaptureStopped::Why::interrupted, "interrupted during " + what);
      }
      auto message = connection.receive(std::chrono::milliseconds(200));
      if (!message) {
        if (message.error().code == slproto::Errc::timeout) {
          if (Clock::now() - last_frame_at >= request_.stall_timeout) {
            abort("the host timed out waiting for frames");
            throw DeviceError(what + ": the scanner sent no frame for " +
                              std::to_string(request_.stall_timeout.count() / 1000) + " s after " +
                              std::to_string(received) + " of " + std::to_string(expected) + " frames");
          }
          continue;
        }
        throw DeviceError(what + ": connection to the scanner: " + message.error().message);
      }
      if (const auto* header = message->get<slproto::pb::FrameHeader>()) {
        add_frame(*header, message->payload, plan, axis, pose, what, capture);
        ++received;
        last_frame_at = Clock::now();
      } else if (const auto* done = message->get<slproto::pb::ScanDone>()) {
        if (done->final_state() != slproto::pb::SCAN_STATE_DONE)
          throw DeviceError(what + ": the scan ended early: " + done->text());
        break;
      } else if (const auto* error = message->get<slproto::pb::Error>()) {
        throw DeviceError(what + ": the scanner reported: " + error->text());
      }
    }
    if (received != expected)
      throw DeviceError(what + ": " + std::to_string(received) + " frames arrived, the scan has " +
                        std::to_string(expected));
  }

 private:
  void add_frame(const slproto::pb::FrameHeader& header, std::span<const std::byte> payload,
                 const slproto::PatternPlan& plan, CodingAxis axis, int pose, const std::string& what,
                 core::CalibrationCapture& capture) {
    if (header.projector_id() > 1 || header.pattern_index() >= plan.size() || header.view_index() != 0 ||
        header.pixel_format() != pixel_format_of(bit_depth_))
      throw DeviceError(what + ": the scanner sent a frame the request has no slot for (view " +
                        std::to_string(header.view_index()) + ", projector " + std::to_string(header.projector_id()) +
                        ", pattern " + std::to_string(header.pattern_index()) + ")");
    if (auto status = slproto::check_frame_geometry(header, payload.size()); !status)
      throw DeviceError(what + ": " + status.error().message);
    const int type = bit_depth_ > 8 ? CV_16UC1 : CV_8UC1;
    // The payload lives in the connection's buffer until the next receive(): copy it out.
    const cv::Mat wrapped(static_cast<int>(header.height()), static_cast<int>(header.width()), type,
                          const_cast<std::byte*>(payload.data()), header.stride_bytes());
    core::CalibrationFrame frame;
    frame.pose = pose;
    frame.kind = core::CalibrationFrame::Kind::pattern;
    frame.side = header.projector_id() == 0 ? slproto::ProjectorSide::left : slproto::ProjectorSide::right;
    frame.axis = axis;
    frame.pattern_index = header.pattern_index();
    frame.image = wrapped.clone();
    capture.frames.push_back(std::move(frame));
  }

  const CalibrationCaptureRequest& request_;
  ScannerConnection& scanner_;
  int bit_depth_;
  bool place_target_;
};

void check_resumed(const core::CalibrationCapture& have, const core::CalibrationCapture& want,
                   const std::vector<GuidedCalibrationPose>& guide, const std::string& folder) {
  auto refuse = [&](const std::string& what) {
    throw std::invalid_argument("--resume " + folder + ": " + what + " (start a new capture in another folder)");
  };
  if (have.target.squares_x != want.target.squares_x || have.target.squares_y != want.target.squares_y ||
      have.target.square_mm != want.target.square_mm || have.target.thickness_mm != want.target.thickness_mm)
    refuse("the capture's target differs from this one");
  if (!(have.pattern_plan == want.pattern_plan)) refuse("the capture's pattern plan differs from this one");
  if (have.bit_depth != want.bit_depth)
    refuse("the capture is " + std::to_string(have.bit_depth) + "-bit, the scanner sends " +
           std::to_string(want.bit_depth) + "-bit frames");
  if (have.poses.size() > guide.size()) refuse("it has more poses than the pose set");
  for (std::size_t p = 0; p < have.poses.size(); ++p)
    if (have.poses[p].name != guide[p].name)
      refuse("pose " + std::to_string(p) + " is '" + have.poses[p].name + "', the pose set's is '" + guide[p].name +
             "'");
}

// The pose's frames on their own (shallow copies): what measuring it looks at.
core::CalibrationCapture frames_of_pose(const core::CalibrationCapture& capture, int pose) {
  core::CalibrationCapture one;
  one.target = capture.target;
  one.pattern_plan = capture.pattern_plan;
  one.bit_depth = capture.bit_depth;
  one.platform_radius_mm = capture.platform_radius_mm;
  one.poses = capture.poses;
  one.source = capture.source;
  for (const core::CalibrationFrame& frame : capture.frames)
    if (frame.pose == pose) one.frames.push_back(frame);
  return one;
}

// A measured pose needs its frames no more: only their manifest entries stay.
void release_images(core::CalibrationCapture& capture, int pose) {
  for (core::CalibrationFrame& frame : capture.frames)
    if (frame.pose == pose) frame.image.release();
}

}  // namespace

core::CalibrationMeasurements capture_calibration(const CalibrationCaptureRequest& request, const SessionLog& log) {
  std::vector<GuidedCalibrationPose> guide;
  for (const GuidedCalibrationPose& pose : slproto::calibration_pose_guide())
    if (request.turntable || !pose.on_turntable) guide.push_back(pose);

  ScannerConnection scanner = connect_to_scanner(request.scanner, "slscan calibrate");
  const slproto::pb::HelloReply& board = scanner.board;
  log.info("connected to " + board.board_name() + " (" + board.software_version() + ", protocol " +
           std::to_string(board.protocol_version()) + ")");
  const bool simulated = (board.capabilities() & slproto::pb::CAPABILITY_SIMULATED) != 0;
  const bool places_target = (board.capabilities() & slproto::pb::CAPABILITY_CALIBRATION_TARGET) != 0;
  if (simulated && !places_target)
    throw DeviceError("the scanner '" + board.board_name() + "' (" + board.software_version() +
                      ") is simulated but cannot place a calibration target (no CAPABILITY_CALIBRATION_TARGET): "
                      "upgrade slscand to calibrate it");
  if (board.projector_count() < 2)
    throw DeviceError("the scanner has " + std::to_string(board.projector_count()) +
                      " projector(s); calibration needs both");
  const int bit_depth = board.camera().pixel_formats_size() > 0 ? bit_depth_of(board.camera().pixel_formats(0)) : 8;

  core::CalibrationCapture capture;
  capture.target = {request.target.squares_x, request.target.squares_y, request.target.square_mm,
                    request.target.thickness_mm};
  capture.pattern_plan = request.pattern_plan;
  capture.pattern_plan.axis = CodingAxis::columns;
  capture.bit_depth = bit_depth;
  capture.platform_radius_mm = request.platform_radius_mm;
  capture.source = !request.source.empty() ? request.source
                                           : "slscan calibrate --connect " + request.scanner.host + ":" +
                                                 std::to_string(request.scanner.port) + " (board '" +
                                                 board.board_name() + "', " + board.software_version() + ")";
  std::optional<io::CalibrationCaptureFolder> resumed_folder;
  if (request.resume) {
    resumed_folder.emplace(request.folder);
    check_resumed(resumed_folder->capture(), capture, guide, request.folder);
    capture = resumed_folder->capture();  // the frames' entries; their images are read pose by pose below
    log.info("resuming " + request.folder + ": " + std::to_string(capture.poses.size()) + " of " +
             std::to_string(guide.size()) + " poses are there");
  } else if (!request.folder.empty() && std::filesystem::exists(request.folder)) {
    throw io::IoError(request.folder + ": already exists (give --resume " + request.folder +
                      " to continue that capture, or another folder)");
  }

  // Each pose is measured once, as it arrives (resumed ones now), and its frames let go: the
  // solve needs only the measurements.
  core::CalibrationMeasurements measured = core::measurements_of(capture);
  // The boards of the poses taken (resumed ones included): a new pose must differ from them.
  std::vector<core::PoseFootprint> taken;
  int width = 0, height = 0;
  core::CalibrationPoseMeasurer measurer(request.options);
  for (std::size_t p = 0; p < capture.poses.size(); ++p) {
    const int pose = static_cast<int>(p);
    measured.poses.push_back(capture.poses[p]);
    measured.measured.push_back(measurer.measure(resumed_folder->read_pose(pose), pose));
    const core::CalibrationPoseCheck check = core::check_calibration_pose(measured.measured.back(), capture.target);
    width = check.width;
    height = check.height;
    if (check.board_found)
      taken.push_back(core::pose_footprint(capture.poses[p].name, check.camera_corners, capture.target));
  }
  const std::size_t resumed = measured.poses.size();
  std::size_t frames_received = 0;

  PoseScanner scanner_pass(request, scanner, bit_depth, places_target);
  for (std::size_t p = capture.poses.size(); p < guide.size(); ++p) {
    const GuidedCalibrationPose& guided = guide[p];
    const int pose = static_cast<int>(p);
    std::string problem;
    while (true) {
      const std::string text = guided.instruction();
      if (request.ask && (!text.empty() || !problem.empty())) {
        if (request.ask(guided, problem) == PoseAnswer::quit)
          throw CalibrationCaptureStopped(CalibrationCaptureStopped::Why::quit,
                                          "stopped before " + guided.name + ": " + where_kept(request, p));
      } else if (!text.empty()) {
        log.info(guided.name + ": " + (places_target ? "the simulated board places the target" : text));
      }
      capture.poses.push_back({guided.name, guided.on_turntable, guided.table_angle_deg});
      try {
        for (CodingAxis axis : {CodingAxis::columns, CodingAxis::rows}) scanner_pass.scan(guided, axis, pose, capture);
      } catch (const CalibrationCaptureStopped& e) {
        throw CalibrationCaptureStopped(e.why, std::string(e.what()) + ": " + where_kept(request, p));
      } catch (const DeviceError& e) {
        throw DeviceError(std::string(e.what()) + "; " + where_kept(request, p));
      }
      core::CalibrationPoseMeasurement measurement = measurer.measure(frames_of_pose(capture, pose), pose);
      const core::CalibrationPoseCheck check = core::check_calibration_pose(measurement, capture.target);
      problem = check.problem(request.min_lit_fraction);
      if (check.board_found)
        log.info(guided.name + ": board found (" + std::to_string(check.corners) + " corners), left projector lights " +
                 std::to_string(check.lit_corners[0]) + ", right " + std::to_string(check.lit_corners[1]));
      std::optional<core::PoseFootprint> footprint;
      if (problem.empty()) {
        width = check.width;
        height = check.height;
        footprint = core::pose_footprint(guided.name, check.camera_corners, capture.target);
        if (request.min_pose_shift > 0) problem = core::too_similar_problem(*footprint, taken, request.min_pose_shift);
      }
      if (problem.empty()) {
        taken.push_back(std::move(*footprint));
        measured.poses.push_back(capture.poses.back());
        measured.measured.push_back(std::move(measurement));
        log.info(guided.name + ": coverage " + core::pose_set_coverage(capture.target, taken, width, height).summary());
        break;
      }
      log.warn(guided.name + ": " + problem);
      // Not kept: the next attempt (or the next run, --resume) takes this pose again.
      std::erase_if(capture.frames, [&](const core::CalibrationFrame& f) { return f.pose == pose; });
      capture.poses.pop_back();
      if (!request.ask)
        throw CalibrationCaptureStopped(CalibrationCaptureStopped::Why::pose_rejected,
                                        guided.name + ": " + problem + "; " + where_kept(request, p));
    }
    if (!request.folder.empty()) io::write_calibration_capture_pose(capture, pose, request.folder);
    frames_received += static_cast<std::size_t>(std::count_if(
        capture.frames.begin(), capture.frames.end(), [&](const core::CalibrationFrame& f) { return f.pose == pose; }));
    release_images(capture, pose);
  }
  scanner.connection.close();
  log.info("captured " + std::to_string(frames_received) + " frames of " +
           std::to_string(measured.poses.size() - resumed) + " poses" +
           (resumed > 0 ? " (and " + std::to_string(resumed) + " resumed)" : std::string()) +
           (request.folder.empty() ? std::string() : " in " + request.folder));
  return measured;
}

}  // namespace slscan::session
