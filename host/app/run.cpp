#include "run.hpp"

#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <new>
#include <nlohmann/json.hpp>

#include "config.hpp"
#include "outputs.hpp"
#include "slproto/calibration.hpp"
#include "slproto/handshake.hpp"
#include "slproto/number_text.hpp"
#include "slproto/pattern_plan.hpp"
#include "slproto/zstd_codec.hpp"
#include "slscan/core/measure.hpp"
#include "slscan/io/capture_replay.hpp"
#include "slscan/io/ply.hpp"
#include "slscan/session/file_hash.hpp"
#include "slscan/session/live_scan.hpp"
#include "slscan/session/reprocess.hpp"
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

// The output folder, checked before any work (and for scan created before the scanner is
// asked for anything: the capture must have a place): a path that names a file, or a folder
// that cannot be made, is the user's to fix (exit 2 naming it), not an internal error after the
// scan.
void prepare_output_folder(const std::string& dir, const std::string& option, bool create) {
  namespace fs = std::filesystem;
  std::error_code error;
  const fs::file_status status = fs::status(dir, error);
  if (fs::exists(status) && !fs::is_directory(status))
    throw std::invalid_argument(option + " " + dir + ": exists and is not a folder");
  if (fs::exists(status) || !create) return;
  fs::create_directories(dir, error);
  if (error) throw io::IoError(option + " " + dir + ": cannot create the folder (" + error.message() + ")");
}

core::ReconstructionOptions options_from(const std::string& config_path, const MeshOverrides& mesh) {
  core::ReconstructionOptions options = config_path.empty() ? core::ReconstructionOptions{} : load_config(config_path);
  apply_mesh_overrides(mesh, options);
  return options;
}

// "2026-12-03T14:16:03Z".
std::string utc_seconds(std::chrono::system_clock::time_point when) {
  const std::time_t t = std::chrono::system_clock::to_time_t(when);
  std::tm tm{};
  ::gmtime_r(&t, &tm);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return text;
}

// A file's modification time; nullopt when it cannot be read.
std::optional<std::chrono::system_clock::time_point> file_time(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return std::nullopt;
  return std::chrono::system_clock::from_time_t(st.st_mtime);
}

// Who ran what when: the run's start, part and operator (report.json "run").
struct RunInfo {
  std::string command;  // "scan" or "reprocess"
  std::chrono::system_clock::time_point started;
  std::string part_id;
  std::string operator_name;
};

json provenance(const core::ReconstructionOptions& options, const slproto::RigCalibration& calibration,
                const std::string& calibration_path, const RunInfo& run) {
  json calibration_json = {{"file", calibration_path},
                           {"sha256", session::sha256_file(calibration_path)},
                           {"source", calibration.source},
                           {"created_by", calibration.created_by},
                           {"camera_reprojection_rms_px", calibration.camera_reprojection_rms_px}};
  // The calibration format has no creation date: the file's modification time stands for it.
  if (const auto written = file_time(calibration_path)) {
    calibration_json["file_utc"] = utc_seconds(*written);
    const double days = std::chrono::duration<double>(run.started - *written).count() / 86400.0;
    calibration_json["age_days"] = std::round(days * 10.0) / 10.0;
  }
  return {{"run",
           {{"command", run.command},
            {"started_utc", utc_seconds(run.started)},
            {"part_id", run.part_id},
            {"operator", run.operator_name}}},
          {"software", {{"slscan", SLSCAN_VERSION}, {"protocol_version", slproto::protocol_version}}},
          {"parameters", config_to_json(options)},
          {"calibration", calibration_json}};
}

// The capture's hash and modification time (when it was recorded), for report.json "capture".
void describe_capture_file(json& capture, const std::string& path, const std::string& sha256) {
  capture["sha256"] = sha256;
  if (const auto written = file_time(path)) capture["file_utc"] = utc_seconds(*written);
}

std::string seconds_text(double seconds) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f s", seconds);
  return text;
}

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
               std::to_string(right) + " right only, " + std::to_string(rejected) +
               " rejected), reconstructed and written in " + seconds_text(seconds) + " -> " + files.model_ply);
  if (result.meshed) {
    char cell[32];
    std::snprintf(cell, sizeof cell, "%.3g", result.mesh.cell_mm);
    std::string written;
    for (const std::string* file : {&files.mesh_ply, &files.mesh_stl, &files.mesh_obj, &files.mesh_3mf})
      if (!file->empty()) written += (written.empty() ? "" : ", ") + *file;
    console.info(std::string("mesh (") + core::mesh_mode_name(result.mesh.mode) + ", cell " + cell +
                 " mm): " + std::to_string(result.mesh.mesh.triangles.size()) + " triangles" +
                 (result.mesh.stats.simplified
                      ? " (simplified from " + std::to_string(result.mesh.stats.triangles_before_simplify) + ")"
                      : std::string()) +
                 " in " + seconds_text(result.mesh.stats.mesh_ms / 1000) + " -> " + written);
    if (!result.mesh.stats.simplify_skipped.empty())
      console.warn("mesh not simplified: " + result.mesh.stats.simplify_skipped);
  } else if (!result.mesh_error.empty()) {
    console.warn("no mesh: " + result.mesh_error);
  }
}

// The camera transport's own counters (GenICam cameras; zeros for V4L2, libcamera, the sim):
// a frame the stream lost is a frame the scan lacks, resends are the link's health.
json camera_link_json(const slproto::pb::ScanDone& done, const Console& console) {
  if (done.camera_frames_lost() != 0 || done.camera_packets_missing() != 0)
    console.warn("the camera link lost " + std::to_string(done.camera_frames_lost()) + " frame(s) and " +
                 std::to_string(done.camera_packets_missing()) +
                 " packet(s) during the scan (docs/hardware.md: MTU, packet size, socket buffers)");
  return {{"frames_lost", done.camera_frames_lost()},
          {"packets_missing", done.camera_packets_missing()},
          {"packets_resent", done.camera_packets_resent()},
          {"resend_requests", done.camera_resend_requests()}};
}

// The outputs are written either way (report.json and report.html show the checks); a
// contradiction makes the run fail with its own exit code, naming cause and fix.
int report_self_checks(const Console& console, const core::ScanResult& result) {
  const std::vector<std::string> findings = self_check_findings(result);
  for (const auto& line : findings) console.warn("self-check: " + line);
  if (findings.empty()) return exit_ok;
  std::cerr << "slscan: the capture contradicts its description (" << findings.size() << " self-check finding"
            << (findings.size() > 1 ? "s" : "") << " above; the outputs are written, report.html shows the checks)\n";
  return exit_inconsistent;
}

// An empty reconstruction is a failure, not a result: says why (no complete view, or nothing
// survived), naming the capture; nothing is written.
void check_not_empty(const core::ScanResult& result, const std::string& capture, const std::string& kept) {
  if (result.views.empty())
    throw io::IoError(capture +
                      ": no view has the complete frames of a projector (see the missing frames above): "
                      "nothing to reconstruct, nothing written" +
                      kept);
  if (result.model.size() == 0) {
    std::size_t decoded = 0, triangulated = 0;
    for (const auto& view : result.views)
      for (const auto& p : view.projectors)
        if (p.present) {
          decoded += p.decode.valid;
          triangulated += p.triangulate.valid;
        }
    throw io::IoError(
        capture + ": the reconstruction of " + std::to_string(result.views.size()) + " view(s) has no points (" +
        std::to_string(decoded) + " pixels decoded, " + std::to_string(triangulated) +
        " triangulated, none kept by the cleanup): check the calibration and --config; nothing written" + kept);
  }
}

}  // namespace

void apply_mesh_overrides(const MeshOverrides& overrides, core::ReconstructionOptions& options) {
  if (overrides.mode == "none") {
    options.build_mesh = false;
  } else if (!overrides.mode.empty()) {
    if (!core::parse_mesh_mode(overrides.mode, options.mesh.mode))
      throw UsageError("--mesh must be watertight, raw or none, not \"" + overrides.mode + "\"");
    options.build_mesh = true;
  }
  // Why this run makes no watertight mesh, for the options that need one.
  const auto no_mesh = [&] {
    return overrides.mode == "none" ? std::string("--mesh none") : std::string("the config's mesh.enabled is false");
  };
  if (!overrides.formats.empty()) {
    if (!options.build_mesh) throw UsageError("--mesh-formats: this run makes no mesh (" + no_mesh() + ")");
    if (const std::string why = core::parse_mesh_formats(overrides.formats, options.mesh_formats); !why.empty())
      throw UsageError("--mesh-formats: " + why);
  }
  if (overrides.fill_holes_mm) {
    const double mm = *overrides.fill_holes_mm;
    if (!options.build_mesh) throw UsageError("--fill-holes: this run makes no mesh (" + no_mesh() + ")");
    if (options.mesh.mode != core::MeshMode::watertight)
      throw UsageError(std::string("--fill-holes applies to the watertight mesh; this run's is raw (") +
                       (overrides.mode.empty() ? "the config's mesh.mode" : "--mesh raw") +
                       "), which leaves every hole open");
    if (!(mm >= 0) || !std::isfinite(mm)) throw UsageError("--fill-holes must be a diameter >= 0 mm");
    options.mesh.fill_holes_mm = mm;
  }
  if (overrides.max_triangles) {
    if (!options.build_mesh) throw UsageError("--max-triangles: this run makes no mesh (" + no_mesh() + ")");
    if (*overrides.max_triangles > 0 && *overrides.max_triangles < 4)
      throw UsageError("--max-triangles must be 0 (no limit) or >= 4, not " + std::to_string(*overrides.max_triangles));
    options.mesh.max_triangles = *overrides.max_triangles;
  }
  if (overrides.simplify_tolerance_mm) {
    const double mm = *overrides.simplify_tolerance_mm;
    if (!options.build_mesh) throw UsageError("--simplify-tolerance: this run makes no mesh (" + no_mesh() + ")");
    if (!(mm >= 0 && mm <= 1)) throw UsageError("--simplify-tolerance must be in [0, 1] mm");
    options.mesh.simplify_tolerance_mm = mm;
  }
  options.check();
}

void install_interrupt_handler() {
  struct sigaction action {};
  action.sa_handler = on_sigint;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
}

namespace {

// Every --json-log line: its UTC time first, then the fields.
json log_line(const char* level) {
  json line;
  line["time"] = utc_timestamp(std::chrono::system_clock::now());
  line["level"] = level;
  return line;
}

double rounded_ms(double seconds) { return std::round(seconds * 1000.0) / 1000.0; }

}  // namespace

void Console::info(const std::string& text) const {
  if (quiet) return;
  if (json_log) {
    json line = log_line("info");
    line["message"] = text;
    std::cerr << line.dump() << "\n";
  } else {
    std::cerr << text << "\n";
  }
}

void Console::warn(const std::string& text) const {
  if (json_log) {
    json line = log_line("warning");
    line["message"] = text;
    std::cerr << line.dump() << "\n";
  } else {
    std::cerr << "warning: " << text << "\n";
  }
}

void Console::progress(const session::Progress& update) const {
  if (quiet) return;
  const ProgressReading reading = meter.update(update, ProgressMeter::Clock::now());
  if (json_log) {
    json line = log_line("progress");
    line["stage"] = update.stage;
    line["done"] = update.done;
    line["total"] = update.total;
    if (!update.unit.empty()) line["unit"] = update.unit;
    if (!update.step.empty()) line["step"] = update.step;
    line["elapsed_s"] = rounded_ms(reading.elapsed_s);
    if (reading.rate_per_s) line["rate_per_s"] = std::round(*reading.rate_per_s * 1000.0) / 1000.0;
    if (reading.eta_s) line["eta_s"] = rounded_ms(*reading.eta_s);
    std::cerr << line.dump() << "\n";
    return;
  }
  if (!::isatty(STDERR_FILENO)) return;
  // \r redraws the line, ESC[K clears what a longer earlier line left after it.
  std::cerr << "\r" << progress_line(update, reading) << "\x1b[K" << std::flush;
}

void Console::end_progress() const {
  meter.reset();
  if (!quiet && !json_log && ::isatty(STDERR_FILENO)) std::cerr << "\n";
}

namespace {

// The number after `key` in a /proc file of "key: value kB" lines, in bytes; 0 if not found.
std::uint64_t proc_kilobytes(const char* file, const std::string& key) {
  std::ifstream in(file);
  std::string line;
  while (std::getline(in, line))
    if (line.compare(0, key.size(), key) == 0) return std::strtoull(line.c_str() + key.size(), nullptr, 10) * 1024;
  return 0;
}

std::string mib(std::uint64_t bytes) { return std::to_string(bytes >> 20) + " MiB"; }

}  // namespace

std::string memory_situation() {
  std::string out;
  const std::uint64_t peak = proc_kilobytes("/proc/self/status", "VmPeak:");
  rlimit limit{};
  const bool limited = ::getrlimit(RLIMIT_AS, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY;
  if (peak > 0) out = "address space peaked at " + mib(peak);
  if (limited)
    out += (out.empty() ? "the address-space limit is " : " of its ") + mib(limit.rlim_cur) + " limit (ulimit -v)";
  if (const std::uint64_t available = proc_kilobytes("/proc/meminfo", "MemAvailable:"); available > 0)
    out += (out.empty() ? "" : "; ") + mib(available) + " of RAM available";
  return out.empty() ? "no figures available" : out;
}

namespace {

// Out of memory while reprocessing: the stage, the figures, and that nothing was written.
[[noreturn]] void throw_out_of_memory(const ReprocessRequest& request, const std::string& stage) {
  throw ResourceError("reprocess " + request.capture_path + ": out of memory in the reconstruction's " + stage +
                      " stage (" + memory_situation() + "); nothing was written to " + request.output_dir +
                      " (raise the limit, or reprocess on a machine with more memory)");
}

}  // namespace

int run_reprocess(const ReprocessRequest& request, const Console& console) {
  const auto start = Clock::now();
  const RunInfo run{"reprocess", std::chrono::system_clock::now(), request.part_id, request.operator_name};
  // The options first: a command line that contradicts itself is refused before any file is read.
  const core::ReconstructionOptions options = options_from(request.config_path, request.mesh);
  const slproto::RigCalibration calibration = load_calibration_or_throw(request.calibration_path);
  prepare_output_folder(request.output_dir, "reprocess --out", false);
  session::BackgroundSha256 capture_hash(request.capture_path);  // while it is reconstructed
  session::ReprocessResult replayed;
  try {
    replayed =
        session::reprocess_capture(request.capture_path, calibration, options, ConsoleLog(console), &interrupted);
  } catch (const core::ReconstructionInterrupted& e) {
    console.warn("interrupted (Ctrl-C) in the reconstruction's " + e.stage() + " stage: nothing was written to " +
                 request.output_dir);
    return exit_interrupted;
  } catch (const core::ReconstructionOutOfMemory& e) {
    throw_out_of_memory(request, e.stage());
  } catch (const std::bad_alloc&) {
    throw_out_of_memory(request, "reprocess");
  }

  json report = provenance(options, calibration, request.calibration_path, run);
  report["capture"] = {{"file", request.capture_path},
                       {"frames", replayed.summary.frames},
                       {"complete", replayed.summary.done.has_value()}};
  describe_capture_file(report["capture"], request.capture_path, capture_hash.get());
  // The capture in the output folder itself (reprocess --out of its own folder): linked too.
  if (std::error_code e; std::filesystem::equivalent(
          request.capture_path,
          std::filesystem::path(request.output_dir) / std::filesystem::path(request.capture_path).filename(), e))
    report["capture"]["in_folder"] = std::filesystem::path(request.capture_path).filename().string();
  if (replayed.summary.truncation) report["capture"]["truncated_at_byte"] = replayed.summary.truncation->record_offset;
  report["capture"]["missing"] = replayed.missing;
  if (replayed.summary.done) report["camera_link"] = camera_link_json(*replayed.summary.done, console);
  check_not_empty(replayed.reconstruction, request.capture_path, "");
  OutputFiles files;
  try {
    files = write_scan_outputs(request.output_dir, replayed.reconstruction, report, options.mesh_formats);
  } catch (const std::bad_alloc&) {
    throw_out_of_memory(request, "writing the outputs");
  }
  print_summary(console, replayed.reconstruction, files, seconds_since(start));
  return report_self_checks(console, replayed.reconstruction);
}

int run_convert(const ConvertCommand& command, const Console& console) {
  const auto start = Clock::now();
  const slproto::FrameCodec* codec = nullptr;
  if (command.compress) {
    codec = slproto::zstd_codec();
    if (codec == nullptr) throw std::invalid_argument(std::string("--compress: ") + slproto::zstd_codec_description());
  }
  const io::CaptureStorage storage = io::convert_capture(command.input_path, command.output_path, codec);
  if (storage.truncation)
    console.warn(command.input_path + " is cut inside the record at offset " +
                 std::to_string(storage.truncation->record_offset) + " (" + storage.truncation->what +
                 "); converted the records before it");
  const double ratio = storage.payload_stored > 0
                           ? static_cast<double>(storage.payload_decoded) / static_cast<double>(storage.payload_stored)
                           : 1.0;
  char line[256];
  std::snprintf(line, sizeof line,
                "%s: %zu records (%zu frames), %s, payload %.1f MB stored for %.1f MB (%.2fx), %.1f s",
                command.output_path.c_str(), storage.records, storage.frames, slproto::frame_codec_name(storage.codec),
                static_cast<double>(storage.payload_stored) / 1e6, static_cast<double>(storage.payload_decoded) / 1e6,
                ratio, seconds_since(start));
  console.info(line);
  return exit_ok;
}

std::string capture_in(const std::string& output_dir) {
  std::error_code error;
  for (const char* name : {"capture.slcap", "capture.slcap.partial"}) {
    const std::filesystem::path path = std::filesystem::path(output_dir) / name;
    if (std::filesystem::exists(path, error)) return path.string();
  }
  return {};
}

int refuse_to_overwrite(const std::string& command, const std::string& capture) {
  std::cerr << "slscan " << command << ": " << capture
            << " holds the capture of an earlier scan, and a capture cannot be recomputed: scan into a new --out "
               "folder, or pass --overwrite to replace it\n";
  return exit_usage;
}

namespace {

// The metering pass's choice and what it saw (docs/hdr.md, "Auto-exposure").
json auto_exposure_json(const session::MeteredExposure& metered, const session::AutoExposureRequest& limits) {
  const core::AutoExposureChoice& choice = metered.choice;
  json rungs = json::array();
  for (const core::RungMeter& rung : choice.rungs)
    rungs.push_back({{"exposure_us", rung.exposure_us},
                     {"usable_share", rung.usable_share},
                     {"clipped_share", rung.clipped_share},
                     {"dark_share", rung.dark_share}});
  return {{"exposures_us", choice.exposures_us},
          {"reference_us", metered.exposure_us},
          {"period_us", metered.period_us},
          {"lit_pixels", choice.lit_pixels},
          {"usable_share", choice.usable_share},
          {"saturated_share", choice.saturated_share},
          {"dark_share", choice.dark_share},
          {"unreachable_share", choice.unreachable_share},
          {"met", choice.met},
          {"reason", choice.reason},
          {"capture_s", choice.capture_s},
          {"limits",
           {{"max_saturated_share", limits.max_saturated_share},
            {"max_dark_share", limits.max_dark_share},
            {"time_budget_s", limits.time_budget_s},
            {"mains_hz", limits.mains_hz}}},
          {"metered", rungs}};
}

std::string auto_exposure_text(const core::AutoExposureChoice& choice) {
  std::string exposures;
  for (const double e : choice.exposures_us) {
    if (!exposures.empty()) exposures += ", ";
    exposures += slproto::short_number(e);
  }
  auto percent = [](double share) {
    std::array<char, 32> text{};
    std::snprintf(text.data(), text.size(), "%.1f %%", 100 * share);
    return std::string(text.data());
  };
  return std::string("auto-exposure: ") + (choice.exposures_us.size() == 1 ? "one exposure, " : "a bracket of ") +
         exposures + " us: " + percent(choice.usable_share) + " of the lit pixels usable, " +
         percent(choice.saturated_share) + " left clipped, " + percent(choice.dark_share) + " left faint, " +
         percent(choice.unreachable_share) + " beyond any exposure" +
         (choice.met ? "" : " (the limits are not met: " + choice.reason + ")");
}

}  // namespace

int run_scan(const ScanCommand& command, const Console& console) {
  const auto start = Clock::now();
  const RunInfo run{"scan", std::chrono::system_clock::now(), command.part_id, command.operator_name};
  if (const std::string capture = capture_in(command.output_dir); !capture.empty() && !command.overwrite)
    return refuse_to_overwrite("scan", capture);
  const core::ReconstructionOptions options = options_from(command.config_path, command.mesh);
  slproto::RigCalibration calibration = load_calibration_or_throw(command.calibration_path);
  if (command.fringe_period_px != 0) {
    // The calibration maps projector coordinates, whatever period coded them: it holds.
    calibration.pattern_plan.period_px = command.fringe_period_px;
    if (auto plan = slproto::PatternPlan::make(calibration.pattern_plan); !plan)
      throw UsageError("--fringe-period-px " + std::to_string(command.fringe_period_px) + ": " + plan.error().message);
  }
  prepare_output_folder(command.output_dir, "scan --out", true);
  session::LiveScanRequest request;
  request.scanner = {command.host, command.port, read_token_file(command.token_file)};
  request.angles_deg = command.angles_deg;
  request.projectors = command.projectors;
  request.exposure_us = command.exposure_us;
  request.exposure_bracket_us = command.exposure_bracket_us;
  if (command.exposure_mode == "auto") request.auto_exposure = command.auto_exposure;
  request.pattern_period_us = command.pattern_period_us;
  request.settle_ms = command.settle_ms;
  request.stall_timeout = std::chrono::seconds(command.stall_timeout_s);
  request.stop = &interrupted;
  request.capture_path = (std::filesystem::path(command.output_dir) / "capture.slcap").string();
  request.compress = command.compress;

  session::LiveScanResult scan;
  try {
    scan = session::run_live_scan(request, calibration, options, ConsoleLog(console));
  } catch (const core::ReconstructionInterrupted& e) {
    // After the last frame: the capture is complete, only the model is not built.
    console.warn("interrupted (Ctrl-C) in the reconstruction's " + e.stage() + " stage: the complete capture is in " +
                 request.capture_path + " (no model written); slscan reprocess reconstructs it");
    return exit_interrupted;
  } catch (const core::ReconstructionOutOfMemory& e) {
    throw ResourceError("scan: out of memory in the reconstruction's " + e.stage() + " stage (" + memory_situation() +
                        "); the complete capture is in " + request.capture_path +
                        " (no model written): slscan reprocess with more memory reconstructs it");
  }
  if (scan.aborted) {
    console.warn("interrupted: kept all " + std::to_string(scan.frames) + " frames received (of " +
                 std::to_string(scan.frames_expected) + " planned) in " + request.capture_path +
                 "; slscan reprocess reconstructs them");
    return exit_interrupted;
  }
  if (scan.out_of_memory_stage) {
    // While frames arrived: the reconstruction was given up; what was received is recorded.
    const bool complete = scan.done.has_value() && scan.frames == scan.frames_expected;
    throw ResourceError("scan: out of memory in the reconstruction's " + *scan.out_of_memory_stage + " stage (" +
                        memory_situation() + "); " +
                        (complete ? "the complete capture (" + std::to_string(scan.frames) + " frames) is in "
                                  : "kept all " + std::to_string(scan.frames) + " frames received (of " +
                                        std::to_string(scan.frames_expected) + " planned) in ") +
                        request.capture_path +
                        " (no model written): slscan reprocess with more memory reconstructs it");
  }
  if (scan.auto_exposure) {
    const std::string text = auto_exposure_text(scan.auto_exposure->choice);
    if (scan.auto_exposure->choice.met)
      console.info(text);
    else
      console.warn(text);
  }
  const core::ScanResult& result = *scan.reconstruction;
  check_not_empty(result, request.capture_path, " (the capture is kept)");
  json report = provenance(options, calibration, command.calibration_path, run);
  report["capture"] = {
      {"file", "capture.slcap"}, {"in_folder", "capture.slcap"}, {"frames", scan.frames}, {"complete", true}};
  describe_capture_file(report["capture"], request.capture_path, scan.capture_sha256);
  report["board"] = {{"name", scan.board.board_name()}, {"software", scan.board.software_version()}};
  json timing = json::array();
  for (const auto& stat : scan.done->timing())
    timing.push_back({{"name", stat.name()},
                      {"count", stat.count()},
                      {"mean_us", stat.mean_us()},
                      {"stddev_us", stat.stddev_us()},
                      {"max_us", stat.max_us()},
                      {"p99_us", stat.p99_us()}});
  report["board_timing"] = timing;
  report["board_frames_dropped"] = scan.done->frames_dropped();
  report["camera_link"] = camera_link_json(*scan.done, console);
  report["last_frame_to_model_s"] = scan.last_frame_to_model_s;
  if (scan.auto_exposure) report["auto_exposure"] = auto_exposure_json(*scan.auto_exposure, command.auto_exposure);
  if (command.measure_ball_bar) {
    try {
      const core::FeatureRule rule;
      const std::array<double, 2> diameters{30.0008, 30.0015};
      const core::BallBarFeatures bar = core::ball_bar_features(result.model, diameters, 150.1164, rule);
      report["measurement"]["ball_bar"] = ball_bar_features_to_json(bar, diameters, 150.1164, rule, {});
      std::string text = feature_text("ball_bar", report["measurement"]["ball_bar"]);
      if (!text.empty() && text.back() == '\n') text.pop_back();
      console.info(text);
    } catch (const std::runtime_error& e) {
      report["measurement"]["ball_bar"] = {{"error", e.what()}};
      console.warn(std::string("ball bar not measured: ") + e.what());
    }
  }
  OutputFiles files;
  try {
    files = write_scan_outputs(command.output_dir, result, report, options.mesh_formats);
  } catch (const std::bad_alloc&) {
    throw ResourceError("scan: out of memory writing the outputs (" + memory_situation() +
                        "); the complete capture is in " + request.capture_path +
                        " (no model written): slscan reprocess with more memory reconstructs it");
  }
  print_summary(console, result, files, seconds_since(start));
  return report_self_checks(console, result);
}

std::optional<MeasuredArtefact> measure_artefact(const MeasureCommand& command, const Console& console) {
  const core::PointCloud cloud = io::read_ply(command.model_path);
  MeasuredArtefact measured;
  measured.points = cloud.size();
  try {
    switch (command.artefact) {
      case Artefact::ball_bar: {
        measured.kind = "ball_bar";
        const std::array<double, 2> diameters{command.nominal_diameter_a_mm, command.nominal_diameter_b_mm};
        const core::BallBarFeatures bar =
            core::ball_bar_features(cloud, diameters, command.reference_distance_mm, command.rule);
        measured.figures =
            ball_bar_features_to_json(bar, diameters, command.reference_distance_mm, command.rule, command.mpe);
        break;
      }
      case Artefact::sphere: {
        measured.kind = "sphere";
        if (!(command.sphere_diameter_mm > 0))
          throw std::invalid_argument("measure --sphere needs --diameter-mm (the sphere's calibrated diameter)");
        const core::FoundSphere found = core::find_sphere(cloud, command.sphere_diameter_mm / 2);
        const core::SphereFeature s =
            core::sphere_feature(cloud.points, found.fit, command.sphere_diameter_mm, command.rule);
        measured.figures = sphere_feature_to_json(s, command.sphere_diameter_mm, command.mpe);
        measured.figures["procedure"] = "VDI/VDE 2634-2 from the scan alone (no ground truth)";
        measured.figures["region_rule"] = region_rule_json(command.rule);
        break;
      }
      case Artefact::plane: {
        measured.kind = "plane";
        measured.figures = plane_feature_to_json(core::plane_feature(cloud, command.rule), command.rule, command.mpe);
        break;
      }
    }
  } catch (const io::IoError&) {
    throw;
  } catch (const std::invalid_argument&) {
    throw;
  } catch (const std::exception& e) {  // the fit itself failed: the artefact is not in the cloud
    console.warn(command.model_path + ": " + e.what());
    return std::nullopt;
  }
  measured.within_mpe = all_within_mpe(measured.figures);
  return measured;
}

int run_measure(const MeasureCommand& command, const Console& console) {
  const auto measured = measure_artefact(command, console);
  if (!measured) return exit_measurement;
  if (command.json) {
    const json out = {{"model", command.model_path}, {"points", measured->points}, {measured->kind, measured->figures}};
    std::printf("%s\n", out.dump(2).c_str());
  } else {
    std::printf("%s", feature_text(measured->kind, measured->figures).c_str());
  }
  return measured->within_mpe ? exit_ok : exit_out_of_tolerance;
}

}  // namespace slscan::app
