// The work behind each subcommand, as functions the tests call too (the CLI is a thin table
// of subcommands over these).
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "feature_report.hpp"
#include "progress.hpp"
#include "slscan/core/feature_metrology.hpp"
#include "slscan/core/scan_reconstruction.hpp"
#include "slscan/session/exposure_metering.hpp"
#include "slscan/session/session_log.hpp"

namespace slscan::app {

// Documented exit codes (docs/cli.md).
enum ExitCode : int {
  exit_ok = 0,
  exit_usage = 1,             // bad command line (CLI11 prints why)
  exit_bad_input = 2,         // unreadable, corrupt or inconsistent input file or configuration
  exit_device = 3,            // the scanner: connection, protocol, board-side errors
  exit_measurement = 4,       // the artefact could not be found or fitted
  exit_internal = 5,          // a bug
  exit_inconsistent = 6,      // the data contradicts its description (the decoder's self-checks: docs/real-data.md)
  exit_out_of_tolerance = 7,  // measured, but a figure is outside its stated MPE (FAIL)
  exit_unmatched = 8,         // compare: fewer than --min-matched of the measured points matched the reference
  exit_resources = 9,         // out of memory: the stage, the memory peak, limit and what was available are named
  exit_interrupted = 130      // Ctrl-C
};

// The machine's resources did not suffice (memory): exit_resources, not an internal error.
class ResourceError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// What memory looked like after an allocation failed, for its message: the process's peak
// address space, its limit (ulimit -v) and the RAM available, each when known
// ("address space peaked at 1019 MiB of its 1024 MiB limit (ulimit -v); 5120 MiB of RAM available").
std::string memory_situation();

// Thrown for problems with the scanner itself (connection, protocol, board errors).
using session::DeviceError;

struct Console {
  bool quiet = false;
  bool json_log = false;  // one JSON object per line on stderr instead of text
  void info(const std::string& text) const;
  void warn(const std::string& text) const;
  // A progress line for long steps with its rate and ETA (progress.hpp), redrawn in place when
  // stderr is a terminal and not shown otherwise; with json_log, one line per update with the
  // same figures. Nothing with quiet.
  void progress(const session::Progress& update) const;
  void end_progress() const;
  mutable ProgressMeter meter{};  // the stage the progress line follows
};

// A console as what a session (host/session) tells its user.
class ConsoleLog final : public session::SessionLog {
 public:
  explicit ConsoleLog(const Console& console) : console_(console) {}
  void info(const std::string& text) const override { console_.info(text); }
  void warn(const std::string& text) const override { console_.warn(text); }
  void progress(const session::Progress& update) const override { console_.progress(update); }
  void end_progress() const override { console_.end_progress(); }

 private:
  const Console& console_;
};

// Set by the SIGINT handler; long loops poll it.
extern std::atomic<bool> interrupted;
void install_interrupt_handler();

// A command line that contradicts itself or its config file (`--fill-holes` with `--mesh raw`):
// exit_usage, where other invalid_arguments (a bad config file) are exit_bad_input.
class UsageError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// scan / reprocess: the mesh options of the command line, over the config file's mesh section.
struct MeshOverrides {
  std::string mode = {};                             // "" = the config's; watertight, raw or none
  std::optional<double> fill_holes_mm = {};          // watertight only (mm, >= 0)
  std::string formats = {};                          // "" = the config's; a list such as "ply,stl,obj,3mf"
  std::optional<std::size_t> max_triangles = {};     // >= 4, or 0 for no limit
  std::optional<double> simplify_tolerance_mm = {};  // [0, 1] mm
};
// Applies them and checks the result; throws UsageError naming the option.
void apply_mesh_overrides(const MeshOverrides& overrides, core::ReconstructionOptions& options);

struct ReprocessRequest {
  std::string capture_path;
  std::string calibration_path;
  std::string output_dir;
  std::string config_path;  // "" = defaults
  MeshOverrides mesh = {};
  std::string part_id = {};        // for the reports (--part-id)
  std::string operator_name = {};  // for the reports (--operator)
};
int run_reprocess(const ReprocessRequest& request, const Console& console);

struct ScanCommand {
  std::string host = "127.0.0.1";
  std::uint16_t port = 7878;
  std::string calibration_path;
  std::string output_dir;
  std::string config_path;
  std::vector<double> angles_deg{0, 60, 120, 180, 240, 300};
  std::vector<std::uint32_t> projectors{0, 1};
  std::uint32_t exposure_us = 0;                   // 0: the board's [timing] pattern_exposure_us
  std::vector<std::uint32_t> exposure_bracket_us;  // HDR (docs/hdr.md); empty: exposure_us alone
  std::string exposure_mode = "fixed";             // "auto": metered first (docs/hdr.md, "Auto-exposure")
  // The fringe period of the scan's plan, projector pixels (0: the calibration's plan's); a
  // shorter one resists light bouncing inside the part (docs/hdr.md, "Interreflection").
  int fringe_period_px = 0;
  session::AutoExposureRequest auto_exposure;  // its limits, used with "auto"
  std::uint32_t pattern_period_us = 0;         // 0: the board's pattern_period_us
  std::uint32_t settle_ms = 200;
  std::uint32_t stall_timeout_s = 60;  // no frame for this long: the scan fails
  std::string token_file;              // shared secret for boards that listen on a network
  bool measure_ball_bar = false;       // fit the ball bar in the model and put it in the report
  bool compress = false;               // record the capture with zstd-compressed frames
  bool overwrite = false;              // replace a capture already in output_dir (refused otherwise)
  MeshOverrides mesh;
  std::string part_id;        // for the reports (--part-id)
  std::string operator_name;  // for the reports (--operator)
};
int run_scan(const ScanCommand& command, const Console& console);

// The capture already in `output_dir` (capture.slcap, or the .partial a failed scan kept), or
// "" when there is none. `scan` and `demo` refuse such a folder unless --overwrite.
std::string capture_in(const std::string& output_dir);
// The refusal: names the file and the way out; exit_usage.
int refuse_to_overwrite(const std::string& command, const std::string& capture);

struct ConvertCommand {
  std::string input_path;
  std::string output_path;
  bool compress = true;  // --compress (default) or --no-compress
};
int run_convert(const ConvertCommand& command, const Console& console);

enum class Artefact { ball_bar, sphere, plane };
struct MeasureCommand {
  std::string model_path;
  Artefact artefact = Artefact::ball_bar;
  double nominal_diameter_a_mm = 30.0008, nominal_diameter_b_mm = 30.0015;  // the ball bar's, calibrated
  double reference_distance_mm = 150.1164;
  double sphere_diameter_mm = 0;  // --sphere: the calibrated diameter (required)
  core::FeatureRule rule;         // the region rule (docs/inspection.md)
  MpeLimits mpe;                  // --mpe-*: PASS / FAIL; unset = not judged
  bool json = false;
};
int run_measure(const MeasureCommand& command, const Console& console);

// The artefact's figures in command.model_path (what run_measure prints), judged against the
// MPEs given; nullopt when the artefact was not found in the model (warned, exit_measurement).
// Throws IoError / invalid_argument on bad input, as run_measure.
// NOLINTNEXTLINE(bugprone-exception-escape): its implicit moves are nlohmann::json's and std::string's, noexcept
struct MeasuredArtefact {
  std::string kind;        // "ball_bar", "sphere", "plane"
  nlohmann::json figures;  // as report.json and `measure --json` give them
  bool within_mpe = true;  // every judged figure within its MPE
  std::size_t points = 0;  // in the model
};
std::optional<MeasuredArtefact> measure_artefact(const MeasureCommand& command, const Console& console);

// The field check of a calibration (issue 18): scan a calibrated artefact with the scanner and
// the calibration, measure it from the scan alone, and say whether the calibration still holds:
// PASS (exit 0) when every figure given an MPE is within it, FAIL (exit_out_of_tolerance)
// otherwise. The scan's outputs go into scan.output_dir with verify.json beside report.json.
struct VerifyCommand {
  ScanCommand scan;        // the artefact's scan
  MeasureCommand measure;  // the artefact, its calibrated sizes and the MPEs (model_path is set from the scan)
};
int run_verify(VerifyCommand command, const Console& console);

struct DemoCommand {
  std::string scene = "ballbar";
  std::string output_dir = "out";
  bool small = false;             // the 640 x 512 rig (fast) instead of the full 2464 x 2056
  bool true_calibration = false;  // use the rig's exact calibration instead of calibrating it first
  std::string config_path;
  std::string slscand_path;  // default: next to slscan in the build tree
  std::string board_path;    // default: boards/sim.toml of the source tree
  bool overwrite = false;    // replace the capture of an earlier demo in output_dir
  // HDR: exposures (us) of the sim board's camera, whose 2000 us stands for the scene's
  // reference exposure; empty: 2000 alone.
  std::vector<std::uint32_t> exposure_bracket_us;
  std::string exposure_mode = "fixed";  // "auto": metered first
  session::AutoExposureRequest auto_exposure;
  int fringe_period_px = 0;  // ScanCommand
};
int run_demo(const DemoCommand& command, const Console& console);

}  // namespace slscan::app
