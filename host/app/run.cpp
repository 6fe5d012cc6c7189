#include "run.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>

#include "config.hpp"
#include "outputs.hpp"
#include "slproto/calibration.hpp"
#include "slproto/capture.hpp"
#include "slproto/handshake.hpp"
#include "slproto/transport.hpp"
#include "slscan/core/measure.hpp"
#include "slscan/io/capture_replay.hpp"
#include "slscan/io/ply.hpp"
#include "status.hpp"

#ifndef SLSCAN_VERSION
#define SLSCAN_VERSION "unknown"
#endif

namespace slscan::app {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

std::atomic<bool> interrupted{false};

namespace {

extern "C" void on_sigint(int /*signal*/) { interrupted.store(true); }

double seconds_since(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

slproto::RigCalibration load_calibration_or_throw(const std::string& path) {
  auto calibration = slproto::load_calibration(path);
  if (!calibration) throw io::IoError(calibration.error().message);
  return std::move(calibration).value();
}

core::ReconstructionOptions options_from(const std::string& config_path) {
  return config_path.empty() ? core::ReconstructionOptions{} : load_config(config_path);
}

json provenance(const core::ReconstructionOptions& options, const slproto::RigCalibration& calibration,
                const std::string& calibration_path) {
  return {{"software", {{"slscan", SLSCAN_VERSION}, {"protocol_version", slproto::protocol_version}}},
          {"parameters", config_to_json(options)},
          {"calibration",
           {{"file", calibration_path},
            {"source", calibration.source},
            {"created_by", calibration.created_by},
            {"camera_reprojection_rms_px", calibration.camera_reprojection_rms_px}}}};
}

// Feeds frames to a reconstructor made on the first frame (its size comes from the stream).
class StreamReconstruction {
 public:
  StreamReconstruction(const slproto::RigCalibration& calibration, const core::ReconstructionOptions& options)
      : calibration_(calibration), options_(options) {}

  void set_plan(const slproto::PatternPlan& plan) {
    if (!(plan.config() == calibration_.pattern_plan))
      throw io::IoError("the capture's pattern plan differs from the plan the calibration was made with: " +
                        differences(plan.config(), calibration_.pattern_plan) + " (capture " + describe(plan.config()) +
                        ", calibration " + describe(calibration_.pattern_plan) + ")");
    plan_ = plan;
  }

  void add(const slproto::pb::FrameHeader& header, std::span<const std::byte> payload) {
    if (!plan_) throw io::IoError("a frame arrived before the scan request: the capture does not say its pattern plan");
    if (!reconstructor_)
      reconstructor_ = std::make_unique<core::ScanReconstructor>(calibration_, *plan_, static_cast<int>(header.width()),
                                                                 static_cast<int>(header.height()), options_);
    reconstructor_->add_frame(io::frame_info(header), payload);
    received_.push_back(header);
    received_.back().clear_timing_events();
  }

  core::ScanResult finish() {
    if (!reconstructor_) throw io::IoError("the capture holds no frames");
    return reconstructor_->finish();
  }
  const std::vector<slproto::pb::FrameHeader>& received() const { return received_; }

 private:
  // "period_px 8 in the capture, 16 in the calibration; ..." for each field that differs.
  static std::string differences(const slproto::PatternPlanConfig& capture, const slproto::PatternPlanConfig& calib) {
    std::string out;
    auto field = [&](const char* name, const std::string& a, const std::string& b) {
      if (a == b) return;
      out += (out.empty() ? "" : "; ") + std::string(name) + " " + a + " in the capture, " + b + " in the calibration";
    };
    auto yes_no = [](bool v) { return std::string(v ? "true" : "false"); };
    field("projector_width", std::to_string(capture.projector_width), std::to_string(calib.projector_width));
    field("projector_height", std::to_string(capture.projector_height), std::to_string(calib.projector_height));
    field("axis", slproto::coding_axis_name(capture.axis), slproto::coding_axis_name(calib.axis));
    field("period_px", std::to_string(capture.period_px), std::to_string(calib.period_px));
    field("phase_steps", std::to_string(capture.phase_steps), std::to_string(calib.phase_steps));
    field("complementary_bit", yes_no(capture.complementary_bit), yes_no(calib.complementary_bit));
    field("with_white_black", yes_no(capture.with_white_black), yes_no(calib.with_white_black));
    field("inverse_gray", yes_no(capture.inverse_gray), yes_no(calib.inverse_gray));
    field("gray_low_bits", slproto::gray_low_bits_name(capture.gray_low_bits),
          slproto::gray_low_bits_name(calib.gray_low_bits));
    return out;
  }
  static std::string describe(const slproto::PatternPlanConfig& c) {
    return std::to_string(c.projector_width) + "x" + std::to_string(c.projector_height) + " " +
           slproto::coding_axis_name(c.axis) + " P=" + std::to_string(c.period_px) +
           " N=" + std::to_string(c.phase_steps) + (c.complementary_bit ? " +complementary" : "") +
           (c.with_white_black ? "" : " -white/black") + (c.inverse_gray ? " +inverse" : "") +
           (c.gray_low_bits == slproto::GrayLowBits::centre
                ? ""
                : std::string(" ") + slproto::gray_low_bits_name(c.gray_low_bits));
  }
  slproto::RigCalibration calibration_;
  core::ReconstructionOptions options_;
  std::optional<slproto::PatternPlan> plan_;
  std::unique_ptr<core::ScanReconstructor> reconstructor_;
  std::vector<slproto::pb::FrameHeader> received_;
};

void print_summary(const Console& console, const core::ScanResult& result, const OutputFiles& files, double seconds) {
  std::size_t both = 0, left = 0, right = 0, rejected = 0;
  for (const auto& v : result.views) {
    both += v.fusion.both;
    left += v.fusion.left_only;
    right += v.fusion.right_only;
    rejected += v.fusion.rejected;
  }
  console.info(std::to_string(result.views.size()) + " views, " + std::to_string(result.model.size()) +
               " points (fusion: " + std::to_string(both) + " both, " + std::to_string(left) + " left only, " +
               std::to_string(right) + " right only, " + std::to_string(rejected) + " rejected)" +
               (result.meshed ? ", mesh " + std::to_string(result.mesh.mesh.triangles.size()) + " triangles" : "") +
               " in " + std::to_string(seconds).substr(0, 5) + " s -> " + files.model_ply);
}

}  // namespace

void install_interrupt_handler() {
  struct sigaction action {};
  action.sa_handler = on_sigint;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
}

void Console::info(const std::string& text) const {
  if (quiet) return;
  if (json_log)
    std::cerr << json{{"level", "info"}, {"message", text}}.dump() << "\n";
  else
    std::cerr << text << "\n";
}

void Console::warn(const std::string& text) const {
  if (json_log)
    std::cerr << json{{"level", "warning"}, {"message", text}}.dump() << "\n";
  else
    std::cerr << "warning: " << text << "\n";
}

void Console::progress(const std::string& stage, std::size_t done, std::size_t total) const {
  if (quiet) return;
  if (json_log) {
    std::cerr << json{{"level", "progress"}, {"stage", stage}, {"done", done}, {"total", total}}.dump() << "\n";
    return;
  }
  if (!::isatty(STDERR_FILENO)) return;
  const int width = 30;
  const int filled = total ? static_cast<int>(width * done / total) : 0;
  std::cerr << "\r" << stage << " [" << std::string(static_cast<std::size_t>(filled), '#')
            << std::string(static_cast<std::size_t>(width - filled), '.') << "] " << done << "/" << total << std::flush;
}

void Console::end_progress() const {
  if (!quiet && !json_log && ::isatty(STDERR_FILENO)) std::cerr << "\n";
}

int run_reprocess(const ReprocessRequest& request, const Console& console) {
  const auto start = Clock::now();
  const slproto::RigCalibration calibration = load_calibration_or_throw(request.calibration_path);
  const core::ReconstructionOptions options = options_from(request.config_path);
  StreamReconstruction stream(calibration, options);
  std::size_t expected_frames = 0;
  const io::CaptureSummary summary = io::replay_capture(
      request.capture_path,
      [&](const slproto::pb::ScanRequest& scan_request) {
        const slproto::PatternPlan plan = io::plan_of(scan_request);
        stream.set_plan(plan);
        expected_frames = plan.size() * static_cast<std::size_t>(scan_request.turntable_angles_deg_size()) *
                          static_cast<std::size_t>(scan_request.projectors_size());
      },
      [&](const slproto::pb::FrameHeader& header, std::span<const std::byte> payload) {
        stream.add(header, payload);
        console.progress("frames", stream.received().size(), expected_frames);
      });
  console.end_progress();
  if (!summary.request) throw io::IoError(request.capture_path + ": the capture has no scan request");

  json report = provenance(options, calibration, request.calibration_path);
  report["capture"] = {
      {"file", request.capture_path}, {"frames", summary.frames}, {"complete", summary.done.has_value()}};
  std::vector<std::string> missing = io::describe_missing_frames(*summary.request, stream.received());
  if (summary.truncation) {
    console.warn(request.capture_path + " is truncated at byte " + std::to_string(summary.truncation->record_offset) +
                 " (" + summary.truncation->what + "); reconstructing the " + std::to_string(summary.frames) +
                 " complete frames before it");
    report["capture"]["truncated_at_byte"] = summary.truncation->record_offset;
  }
  for (const auto& line : missing) console.warn("missing: " + line);
  report["capture"]["missing"] = missing;
  for (const auto& error : summary.errors) console.warn("the board reported: " + error.text());

  console.info("reconstructing " + std::to_string(summary.frames) + " frames");
  const core::ScanResult result = stream.finish();
  const OutputFiles files = write_scan_outputs(request.output_dir, result, report);
  print_summary(console, result, files, seconds_since(start));
  return exit_ok;
}

int run_scan(const ScanCommand& command, const Console& console) {
  const auto start = Clock::now();
  const slproto::RigCalibration calibration = load_calibration_or_throw(command.calibration_path);
  const core::ReconstructionOptions options = options_from(command.config_path);
  const std::string token = read_token_file(command.token_file);

  auto connection = slproto::connect(command.host, command.port, std::chrono::seconds(3));
  if (!connection)
    throw DeviceError("cannot connect to " + command.host + ":" + std::to_string(command.port) + ": " +
                      connection.error().message);
  auto reply =
      slproto::client_handshake(*connection, slproto::make_hello("slscan", "slscan " SLSCAN_VERSION, 0, token));
  if (!reply) throw DeviceError("the scanner refused the connection: " + reply.error().message);
  console.info("connected to " + reply->board_name() + " (" + reply->software_version() + ", protocol " +
               std::to_string(reply->protocol_version()) + ")");

  slproto::pb::ScanRequest request;
  request.set_scan_id(static_cast<std::uint64_t>(std::chrono::system_clock::now().time_since_epoch().count()));
  for (double angle : command.angles_deg) request.add_turntable_angles_deg(angle);
  for (std::uint32_t projector : command.projectors) request.add_projectors(projector);
  *request.mutable_plan() = slproto::to_proto(calibration.pattern_plan);
  request.set_exposure_us(command.exposure_us);
  request.set_pattern_period_us(command.pattern_period_us);
  request.set_settle_ms(command.settle_ms);
  request.set_pixel_format(
      options.decode.bit_depth > 8
          ? (options.decode.bit_depth > 10 ? slproto::pb::PIXEL_FORMAT_MONO12 : slproto::pb::PIXEL_FORMAT_MONO10)
          : slproto::pb::PIXEL_FORMAT_MONO8);
  request.set_timing_events(true);
  if (auto status = slproto::check_scan_request(request); !status) throw std::invalid_argument(status.error().message);

  std::filesystem::create_directories(command.output_dir);
  const std::string capture_path = (std::filesystem::path(command.output_dir) / "capture.slcap").string();
  auto capture = slproto::CaptureWriter::create(capture_path);
  if (!capture) throw io::IoError(capture.error().message);
  // The capture begins with the request the host sent, so reprocessing knows the plan.
  auto request_bytes = slproto::encode(request);
  if (!request_bytes) throw std::logic_error(request_bytes.error().message);
  if (auto status = capture->append(*request_bytes); !status) throw io::IoError(status.error().message);
  connection->record_to(&*capture);

  StreamReconstruction stream(calibration, options);
  stream.set_plan(slproto::PatternPlan(calibration.pattern_plan));
  if (auto status = connection->send(request); !status)
    throw DeviceError("sending the scan request: " + status.error().message);
  const std::size_t expected =
      slproto::PatternPlan(calibration.pattern_plan).size() * command.angles_deg.size() * command.projectors.size();
  bool abort_sent = false;
  std::optional<slproto::pb::ScanDone> done;
  std::optional<std::string> failure;
  while (!done && !failure) {
    if (interrupted.load() && !abort_sent) {
      slproto::pb::Abort abort;
      abort.set_scan_id(request.scan_id());
      abort.set_reason("interrupted on the host (Ctrl-C)");
      (void)connection->send(abort);
      abort_sent = true;
      console.end_progress();
      console.warn("interrupted: asking the scanner to stop");
    }
    auto message = connection->receive(std::chrono::milliseconds(200));
    if (!message) {
      if (message.error().code == slproto::Errc::timeout) continue;
      if (message.error().code == slproto::Errc::io_error) {
        // Our capture could not be written (disk full, file size limit): stop the scanner,
        // which would otherwise go on scanning into nothing.
        failure = message.error().message;
        slproto::pb::Abort abort;
        abort.set_scan_id(request.scan_id());
        abort.set_reason("the host cannot record: " + message.error().message);
        (void)connection->send(abort);
      } else {
        failure = "connection to the scanner: " + message.error().message;
      }
      break;
    }
    if (const auto* header = message->get<slproto::pb::FrameHeader>()) {
      stream.add(*header, message->payload);
      console.progress("frames", stream.received().size(), expected);
    } else if (const auto* scan_done = message->get<slproto::pb::ScanDone>()) {
      done = *scan_done;
    } else if (const auto* error = message->get<slproto::pb::Error>()) {
      failure = "the scanner reported: " + error->text();
    }
  }
  console.end_progress();
  connection->record_to(nullptr);
  connection->close();
  const slproto::Status finished = capture->finish();
  // The cause first: a write error also makes finish() fail, and its message alone would hide why.
  if (failure) {
    const std::string kept = finished ? capture_path : capture->partial_path();
    throw DeviceError(*failure + " (the capture up to the last complete frame is in " + kept + ")");
  }
  if (!finished) throw io::IoError(finished.error().message);
  if (abort_sent) {
    console.warn("scan aborted; the capture of what arrived is in " + capture_path);
    return exit_interrupted;
  }

  json report = provenance(options, calibration, command.calibration_path);
  report["capture"] = {{"file", "capture.slcap"}, {"frames", stream.received().size()}, {"complete", true}};
  report["board"] = {{"name", reply->board_name()}, {"software", reply->software_version()}};
  json timing = json::array();
  for (const auto& stat : done->timing())
    timing.push_back({{"name", stat.name()},
                      {"count", stat.count()},
                      {"mean_us", stat.mean_us()},
                      {"stddev_us", stat.stddev_us()},
                      {"max_us", stat.max_us()},
                      {"p99_us", stat.p99_us()}});
  report["board_timing"] = timing;
  report["board_frames_dropped"] = done->frames_dropped();
  const auto last_frame = Clock::now();
  const core::ScanResult result = stream.finish();
  report["last_frame_to_model_s"] = seconds_since(last_frame);
  if (command.measure_ball_bar) {
    try {
      const core::BallBarResult bar = core::measure_ball_bar(result.model);
      report["measurement"]["ball_bar"] = ball_bar_to_json(bar);
      const double error_um = 1000 * (bar.centre_distance_mm - 150.1164);
      report["measurement"]["ball_bar"]["distance_error_um"] = error_um;
      console.info("ball bar: centre distance " + std::to_string(bar.centre_distance_mm) +
                   " mm (reference 150.1164, error " + std::to_string(error_um) + " um); diameters " +
                   std::to_string(2 * bar.spheres[0].radius_mm) + " / " + std::to_string(2 * bar.spheres[1].radius_mm) +
                   " mm");
    } catch (const std::runtime_error& e) {
      report["measurement"]["ball_bar"] = {{"error", e.what()}};
      console.warn(std::string("ball bar not measured: ") + e.what());
    }
  }
  const OutputFiles files = write_scan_outputs(command.output_dir, result, report);
  print_summary(console, result, files, seconds_since(start));
  return exit_ok;
}

int run_measure(const MeasureCommand& command, const Console& console) {
  const core::PointCloud cloud = io::read_ply(command.model_path);
  json out = {{"model", command.model_path}, {"points", cloud.size()}};
  try {
    switch (command.artefact) {
      case Artefact::ball_bar: {
        core::BallBarOptions options;
        options.nominal_radii_mm = {command.nominal_diameter_a_mm / 2, command.nominal_diameter_b_mm / 2};
        const core::BallBarResult bar = core::measure_ball_bar(cloud, options);
        out["ball_bar"] = ball_bar_to_json(bar);
        out["ball_bar"]["reference_distance_mm"] = command.reference_distance_mm;
        out["ball_bar"]["distance_error_um"] = 1000 * (bar.centre_distance_mm - command.reference_distance_mm);
        if (!command.json) {
          std::printf("ball bar: centre distance %.4f mm (reference %.4f mm, error %+.1f um)\n", bar.centre_distance_mm,
                      command.reference_distance_mm, 1000 * (bar.centre_distance_mm - command.reference_distance_mm));
          for (std::size_t i = 0; i < 2; ++i) {
            const auto& s = bar.spheres[i];
            std::printf("  sphere %zu: diameter %.4f mm, form error %.1f um, RMS %.1f um, %zu points\n", i,
                        2 * s.radius_mm, 1000 * s.form_error_mm, 1000 * s.rms_mm, s.point_count);
          }
        }
        break;
      }
      case Artefact::sphere: {
        const core::SphereFit s = core::fit_sphere(cloud.points);
        out["sphere"] = {{"centre_mm", {s.centre.x(), s.centre.y(), s.centre.z()}},
                         {"diameter_mm", 2 * s.radius_mm},
                         {"form_error_mm", s.form_error_mm},
                         {"rms_mm", s.rms_mm}};
        if (!command.json)
          std::printf("sphere: diameter %.4f mm, centre (%.4f, %.4f, %.4f), form error %.1f um, RMS %.1f um\n",
                      2 * s.radius_mm, s.centre.x(), s.centre.y(), s.centre.z(), 1000 * s.form_error_mm,
                      1000 * s.rms_mm);
        break;
      }
      case Artefact::plane: {
        const core::PlaneFit p = core::fit_plane(cloud.points);
        out["plane"] = {{"normal", {p.normal.x(), p.normal.y(), p.normal.z()}},
                        {"flatness_mm", p.flatness_mm},
                        {"rms_mm", p.rms_mm}};
        if (!command.json)
          std::printf("plane: flatness %.1f um, RMS %.1f um over %zu points\n", 1000 * p.flatness_mm, 1000 * p.rms_mm,
                      p.point_count);
        break;
      }
    }
  } catch (const io::IoError&) {
    throw;
  } catch (const std::exception& e) {  // the fit itself failed: the artefact is not in the cloud
    console.warn(command.model_path + ": " + e.what());
    return exit_measurement;
  }
  if (command.json) std::printf("%s\n", out.dump(2).c_str());
  return exit_ok;
}

}  // namespace slscan::app
