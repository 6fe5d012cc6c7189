#include "slscan/session/live_scan.hpp"

#include <chrono>
#include <filesystem>
#include <new>

#include "slproto/capture.hpp"
#include "slproto/framing.hpp"
#include "slproto/zstd_codec.hpp"
#include "slscan/io/capture_replay.hpp"
#include "slscan/io/io_error.hpp"
#include "slscan/session/file_hash.hpp"
#include "slscan/session/stream_reconstruction.hpp"

namespace slscan::session {

using Clock = std::chrono::steady_clock;

namespace {

slproto::pb::ScanRequest make_scan_request(const LiveScanRequest& command, const slproto::RigCalibration& calibration,
                                           const core::ReconstructionOptions& options,
                                           const slproto::pb::HelloReply& board) {
  const PatternTiming timing = pattern_timing(command.exposure_us, command.pattern_period_us, board);
  slproto::pb::ScanRequest request;
  request.set_scan_id(static_cast<std::uint64_t>(std::chrono::system_clock::now().time_since_epoch().count()));
  for (double angle : command.angles_deg) request.add_turntable_angles_deg(angle);
  for (std::uint32_t projector : command.projectors) request.add_projectors(projector);
  *request.mutable_plan() = slproto::to_proto(calibration.pattern_plan);
  request.set_exposure_us(timing.exposure_us);
  for (const std::uint32_t exposure_us : command.exposure_bracket_us) request.add_exposure_bracket_us(exposure_us);
  request.set_pattern_period_us(timing.period_us);
  request.set_settle_ms(command.settle_ms);
  request.set_pixel_format(
      options.decode.bit_depth > 8
          ? (options.decode.bit_depth > 10 ? slproto::pb::PIXEL_FORMAT_MONO12 : slproto::pb::PIXEL_FORMAT_MONO10)
          : slproto::pb::PIXEL_FORMAT_MONO8);
  request.set_timing_events(true);
  if (auto status = slproto::check_scan_request(request); !status) throw std::invalid_argument(status.error().message);
  return request;
}

}  // namespace

LiveScanResult run_live_scan(const LiveScanRequest& command, const slproto::RigCalibration& calibration,
                             const core::ReconstructionOptions& options, const SessionLog& log) {
  ScannerConnection scanner = connect_to_scanner(command.scanner, "slscan");
  slproto::Connection& connection = scanner.connection;
  LiveScanResult out;
  out.board = scanner.board;
  log.info("connected to " + out.board.board_name() + " (" + out.board.software_version() + ", protocol " +
           std::to_string(out.board.protocol_version()) + ")");

  if (!command.exposure_bracket_us.empty() &&
      (out.board.capabilities() & slproto::pb::CAPABILITY_EXPOSURE_BRACKET) == 0)
    throw DeviceError("the scanner '" + out.board.board_name() + "' (" + out.board.software_version() +
                      ") cannot sequence an exposure bracket (no CAPABILITY_EXPOSURE_BRACKET): it would capture one "
                      "exposure; upgrade slscand, or scan without --exposure-bracket");
  LiveScanRequest scan_command = command;
  if (command.auto_exposure) {
    if (!command.exposure_bracket_us.empty())
      throw std::invalid_argument("--exposure auto chooses the bracket: give it or --exposure-bracket, not both");
    if (command.angles_deg.empty()) throw std::invalid_argument("the scan has no view (no --angles)");
    MeteringScan metering;
    metering.first_angle_deg = command.angles_deg.front();
    metering.projectors = command.projectors;
    metering.exposure_us = command.exposure_us;
    metering.period_us = command.pattern_period_us;
    metering.settle_ms = command.settle_ms;
    metering.scan_frames_per_exposure =
        slproto::PatternPlan(calibration.pattern_plan).size() * command.angles_deg.size() * command.projectors.size();
    metering.stall_timeout = command.stall_timeout;
    metering.stop = command.stop;
    out.auto_exposure = meter_exposure(scanner, metering, *command.auto_exposure, calibration, options, log);
    scan_command.exposure_us = out.auto_exposure->exposure_us;
    scan_command.exposure_bracket_us = out.auto_exposure->bracket_us;
    scan_command.pattern_period_us = out.auto_exposure->period_us;
  }
  const slproto::pb::ScanRequest request = make_scan_request(scan_command, calibration, options, scanner.board);
  if (const auto folder = std::filesystem::path(command.capture_path).parent_path(); !folder.empty())
    std::filesystem::create_directories(folder);
  const slproto::FrameCodec* codec = nullptr;
  if (command.compress) {
    codec = slproto::zstd_codec();
    if (codec == nullptr)
      throw std::invalid_argument(std::string("--compress: this slscan is ") + slproto::zstd_codec_description());
  }
  auto capture = slproto::CaptureWriter::create(command.capture_path, {codec, 0});
  if (!capture) throw io::IoError(capture.error().message);
  // The capture begins with the request the host sent, so reprocessing knows the plan.
  auto request_bytes = slproto::encode(request);
  if (!request_bytes) throw std::logic_error(request_bytes.error().message);
  if (auto status = capture->append(*request_bytes); !status) throw io::IoError(status.error().message);
  // Records are appended here, once checked, not by the connection as they arrive: a frame the
  // request has no slot for (a lying or broken board) never reaches the capture, so the capture
  // stays one consistent scan that reprocesses with every valid frame received.
  io::FrameSlots slots(request, 0);

  StreamReconstruction stream(calibration, options);
  stream.set_plan(slproto::PatternPlan(calibration.pattern_plan));
  stream.set_exposures(request);
  if (auto status = connection.send(request); !status)
    throw DeviceError("sending the scan request: " + status.error().message);
  const std::size_t expected = slproto::PatternPlan(calibration.pattern_plan).size() *
                               slproto::exposures_of(request).size() * command.angles_deg.size() *
                               command.projectors.size();
  bool abort_sent = false;
  // After Ctrl-C the board sends what it has queued and ScanDone; a board that does not answer
  // within this grace does not hold the host (every frame received is in the capture either way).
  constexpr auto kAbortGrace = std::chrono::seconds(5);
  Clock::time_point abort_deadline{};
  std::size_t frames = 0;  // received and recorded, reconstructed or not
  std::optional<std::string> failure;
  auto abort_scan = [&](const std::string& reason) {
    slproto::pb::Abort abort;
    abort.set_scan_id(request.scan_id());
    abort.set_reason(reason);
    (void)connection.send(abort);
  };
  auto last_frame_at = Clock::now();
  // Out of memory: in the reconstruction (decoding), the reconstruction is given up and its memory
  // freed, and the rest of the scan is still recorded, so the capture is complete; in receiving
  // or recording, the scanner is stopped and the capture keeps every complete frame before.
  auto run_out_of_memory = [&](const std::string& stage) {
    out.out_of_memory_stage = stage;
    stream.abandon();
    log.end_progress();
  };
  try {
    while (!out.done && !failure) {
      if (command.stop != nullptr && command.stop->load() && !abort_sent) {
        slproto::pb::Abort abort;
        abort.set_scan_id(request.scan_id());
        abort.set_reason("interrupted on the host (Ctrl-C)");
        (void)connection.send(abort);
        abort_sent = true;
        abort_deadline = Clock::now() + kAbortGrace;
        log.end_progress();
        log.warn("interrupted: asking the scanner to stop (" + std::to_string(frames) + " frames received so far)");
      }
      if (abort_sent && Clock::now() > abort_deadline) {
        log.warn("the scanner did not confirm the stop within " + std::to_string(kAbortGrace.count()) +
                 " s; closing the connection");
        break;
      }
      auto message = connection.receive(std::chrono::milliseconds(200));
      if (!message) {
        if (message.error().code == slproto::Errc::timeout) {
          // A board that keeps the connection alive (heartbeats) but sends no frame is stuck.
          const auto silent = Clock::now() - last_frame_at;
          if (!abort_sent && silent >= command.stall_timeout) {
            failure = "the scanner sent no frame for " +
                      std::to_string(std::chrono::duration_cast<std::chrono::seconds>(silent).count()) + " s after " +
                      std::to_string(frames) + " of " + std::to_string(expected) + " frames (--stall-timeout-s " +
                      std::to_string(command.stall_timeout.count() / 1000) + ")";
            abort_scan("the host timed out waiting for frames");
          }
          continue;
        }
        failure = "connection to the scanner: " + message.error().message;
        break;
      }
      if (const auto* header = message->get<slproto::pb::FrameHeader>()) {
        if (auto problem = slots.take(*header, message->payload.size(), message->stream_offset)) {
          failure = "the scanner sent frame " + std::to_string(frames) + " (stream offset " +
                    std::to_string(message->stream_offset) + "), " + *problem + "; it was not recorded";
          abort_scan("the host refused a frame: " + *problem);
          break;
        }
        // Interrupted: the frames still coming are only recorded (the model is not built), so
        // the scan ends as soon as the board stops sending.
        if (!abort_sent && !out.out_of_memory_stage) {
          try {
            stream.add(*header, message->payload);
          } catch (const core::ReconstructionOutOfMemory& e) {
            run_out_of_memory(e.stage());
            log.warn("out of memory in the reconstruction's " + e.stage() + " stage after " + std::to_string(frames) +
                     " frames: recording the rest of the scan without reconstructing it");
          } catch (const std::exception& e) {
            failure = "the scanner sent frame " + std::to_string(frames) + " (stream offset " +
                      std::to_string(message->stream_offset) + "): " + e.what();
            abort_scan(std::string("the host refused a frame: ") + e.what());
            break;
          }
        }
        last_frame_at = Clock::now();
      }
      if (message->type() != slproto::MessageType::heartbeat) {
        if (auto status = capture->append(*message); !status) {
          // Our capture could not be written (disk full, file size limit): stop the scanner,
          // which would otherwise go on scanning into nothing.
          failure = "recording the stream: " + status.error().message;
          abort_scan("the host cannot record: " + failure.value());
          break;
        }
      }
      if (message->get<slproto::pb::FrameHeader>() != nullptr) {
        ++frames;  // checked and recorded, reconstructed or not
        if (!abort_sent && !out.out_of_memory_stage) log.progress({"frames", frames, expected, "frames", {}});
      } else if (const auto* scan_done = message->get<slproto::pb::ScanDone>()) {
        out.done = *scan_done;
      } else if (const auto* error = message->get<slproto::pb::Error>()) {
        failure = "the scanner reported: " + error->text();
      }
    }
  } catch (const std::bad_alloc&) {
    // The frame being received or recorded is lost (never half-written); the ones before are kept.
    run_out_of_memory("receiving and recording the frames");
    abort_scan("the host ran out of memory");
  }
  log.end_progress();
  connection.close();
  const slproto::Status finished = capture->finish();
  // The cause first: a write error also makes finish() fail, and its message alone would hide why.
  if (failure) {
    const std::string kept = finished ? command.capture_path : capture->partial_path();
    throw DeviceError(*failure + " (the capture up to the last complete frame is in " + kept + ")");
  }
  if (!finished) throw io::IoError(finished.error().message);
  out.frames = frames;
  out.frames_expected = expected;
  // TCP delivers in order: every frame the board sent arrived before its ScanDone.
  if (out.done && out.done->frames_sent() != out.frames)
    throw DeviceError("the scanner's ScanDone says " + std::to_string(out.done->frames_sent()) +
                      " frames were sent, but " + std::to_string(out.frames) + " arrived (the capture of those is in " +
                      command.capture_path + ")");
  if (abort_sent) out.aborted = true;
  if (abort_sent || out.out_of_memory_stage) return out;
  const auto last_frame = Clock::now();
  BackgroundSha256 capture_hash(command.capture_path);     // while the last views are reconstructed
  out.reconstruction = stream.finish(command.stop, &log);  // Ctrl-C now: the capture is complete
  out.last_frame_to_model_s = std::chrono::duration<double>(Clock::now() - last_frame).count();
  out.capture_sha256 = capture_hash.get();
  return out;
}

}  // namespace slscan::session
