// slscan: the host command. A thin table of subcommands over the run_* functions.
#include <oneapi/tbb/global_control.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <iostream>
#include <new>
#include <optional>
#include <string>
#include <vector>

#include "batch.hpp"
#include "calibrate.hpp"
#include "inspect.hpp"
#include "real_data.hpp"
#include "run.hpp"
#include "slproto/messages.hpp"
#include "slscan/core/huge_pages.hpp"
#include "slscan/io/io_error.hpp"
#include "slscan/session/file_hash.hpp"
#include "status.hpp"
#include "worker_threads.hpp"

namespace {

using namespace slscan::app;

// Set by the input-file validator when a named file does not exist: CLI11 reports that as a
// validation error (its code 105), docs/cli.md as bad input (exit 2).
bool g_missing_input_file = false;

// CLI::ExistingFile / ExistingDirectory, remembering that the failure is a missing input.
CLI::Validator existing(bool directory) {
  return CLI::Validator(
      [directory](std::string& path) -> std::string {
        std::error_code ec;
        const auto status = std::filesystem::status(path, ec);
        if (!std::filesystem::exists(status)) {
          g_missing_input_file = true;
          return (directory ? "folder does not exist: " : "file does not exist: ") + path;
        }
        if (directory != std::filesystem::is_directory(status)) {
          g_missing_input_file = true;
          return (directory ? "not a folder: " : "is a folder, not a file: ") + path;
        }
        return {};
      },
      directory ? "DIR" : "FILE");
}

// scan / reprocess: --mesh, --fill-holes, --mesh-formats (docs/cli.md). A bad value is refused
// by CLI11 (exit 1) naming the option; contradictions with the config are apply_mesh_overrides'.
void add_mesh_options(CLI::App& command, MeshOverrides& mesh) {
  command
      .add_option("--mesh", mesh.mode,
                  "Mesh: watertight (closed, holes filled and flagged; the default), raw (only where points are, "
                  "holes open) or none (overrides the config's mesh section)")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            return text == "watertight" || text == "raw" || text == "none"
                       ? std::string()
                       : "must be watertight, raw or none, not \"" + text + "\"";
          },
          "watertight|raw|none"));
  command
      .add_option_function<double>(
          "--fill-holes", [&mesh](const double& mm) { mesh.fill_holes_mm = mm; },
          "Watertight mesh: holes up to this diameter (mm, default 10) are closed with a smooth patch, larger ones "
          "with a flat one")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            try {
              std::size_t used = 0;
              const double v = std::stod(text, &used);
              if (used == text.size() && std::isfinite(v) && v >= 0) return {};
            } catch (const std::exception&) {
            }
            return "must be a hole diameter >= 0 (mm), not \"" + text + "\"";
          },
          "MM >= 0"));
  command
      .add_option_function<std::size_t>(
          "--max-triangles", [&mesh](const std::size_t& n) { mesh.max_triangles = n; },
          "Mesh: at most this many triangles (edge collapse, flat regions first; 0: as many as the cell gives)")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            const bool digits =
                !text.empty() && text.size() <= 12 && text.find_first_not_of("0123456789") == std::string::npos;
            if (digits && (std::stoull(text) == 0 || std::stoull(text) >= 4)) return {};
            return "must be 0 (no limit) or a triangle count >= 4, not \"" + text + "\"";
          },
          "N"));
  command
      .add_option_function<double>(
          "--simplify-tolerance", [&mesh](const double& mm) { mesh.simplify_tolerance_mm = mm; },
          "Mesh: collapse edges while every triangle stays within this distance (mm, <= 1) of the full mesh: "
          "coarse where flat, fine at edges (0: no bound)")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            try {
              std::size_t used = 0;
              const double v = std::stod(text, &used);
              if (used == text.size() && v >= 0 && v <= 1) return {};
            } catch (const std::exception&) {
            }
            return "must be a distance in [0, 1] mm, not \"" + text + "\"";
          },
          "MM in [0, 1]"));
  command
      .add_option("--mesh-formats", mesh.formats,
                  "Mesh files, comma-separated: ply, stl, obj, 3mf (default ply,stl; all in mm)")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            slscan::core::MeshFormats formats;
            return slscan::core::parse_mesh_formats(text, formats);
          },
          "ply,stl,obj,3mf"));
}

// scan / verify / demo: auto-exposure (docs/hdr.md, "Auto-exposure").
void add_auto_exposure_options(CLI::App& command, std::string& mode, slscan::session::AutoExposureRequest& limits) {
  auto* exposure = command
                       .add_option("--exposure", mode,
                                   "fixed: --exposure-us (or --exposure-bracket); auto: meter white and black at a "
                                   "ladder of exposures first and pick one exposure or a bracket")
                       ->check(CLI::IsMember({"fixed", "auto"}))
                       ->capture_default_str();
  command
      .add_option("--time-budget-s", limits.time_budget_s,
                  "With --exposure auto: the most the scan's pattern frames may take (s; 0: no limit)")
      ->check(CLI::Range(0.0, 86400.0))
      ->needs(exposure);
  command
      .add_option("--mains", limits.mains_hz,
                  "With --exposure auto: 50 or 60 to keep exposures whole periods of the lights' flicker (0: off)")
      ->check(CLI::IsMember({0, 50, 60}))
      ->needs(exposure);
  command
      .add_option("--max-saturation", limits.max_saturated_share,
                  "With --exposure auto: the share of the lit pixels that may stay clipped")
      ->check(CLI::Range(0.0, 0.5))
      ->capture_default_str()
      ->needs(exposure);
  command
      .add_option("--max-dark", limits.max_dark_share,
                  "With --exposure auto: the share of the lit pixels that may stay too faint to decode")
      ->check(CLI::Range(0.0, 0.5))
      ->capture_default_str()
      ->needs(exposure);
}

// scan / verify / demo: the fringe period (docs/hdr.md, "Interreflection").
void add_fringe_period_option(CLI::App& command, int& period_px) {
  command
      .add_option("--fringe-period-px", period_px,
                  "Fringe period of the scan's patterns, projector pixels (default: the calibration's plan's, 8); "
                  "4 resists light bouncing inside concave or glossy parts")
      ->check(CLI::Range(2, 16384));
}

// scan / verify: the scanner, the calibration, the output folder and the scan plan.
void add_scan_options(CLI::App& command, ScanCommand& scan, std::string& connect) {
  command.add_option("--connect", connect, "Scanner address HOST:PORT")->capture_default_str();
  command.add_option("--calib", scan.calibration_path, "Calibration file (JSON)")->required()->check(existing(false));
  command.add_option("--out", scan.output_dir, "Output folder")->required();
  command.add_option("--config", scan.config_path, "Reconstruction parameters (JSON)")->check(existing(false));
  command.add_option("--angles", scan.angles_deg, "Turntable angles in degrees")->capture_default_str();
  command.add_option("--projectors", scan.projectors, "Projector ids (0 left, 1 right)")->capture_default_str();
  command.add_option("--exposure-us", scan.exposure_us,
                     "Exposure per pattern (default: the board's, from its board file)");
  command
      .add_option("--exposure-bracket", scan.exposure_bracket_us,
                  "HDR: capture every view at each of these exposures (us, comma-separated) and merge them per pixel; "
                  "--exposure-us is then the reference intensities are scaled to")
      ->delimiter(',')
      ->check(CLI::Range(1u, 1'000'000u));
  add_auto_exposure_options(command, scan.exposure_mode, scan.auto_exposure);
  add_fringe_period_option(command, scan.fringe_period_px);
  command.add_option("--period-us", scan.pattern_period_us, "Pattern period (default: the board's)");
  command.add_option("--settle-ms", scan.settle_ms, "Turntable settle time")->capture_default_str();
  command
      .add_option("--stall-timeout-s", scan.stall_timeout_s,
                  "Fail the scan (keeping what arrived) when the scanner sends no frame for this long")
      ->check(CLI::Range(1, 3600))
      ->capture_default_str();
  command.add_option("--token-file", scan.token_file, "File holding the scanner's shared token");
  command.add_flag("--compress", scan.compress,
                   "Record the capture with zstd-compressed frames (lossless; reprocess reads both)");
  command.add_flag("--overwrite", scan.overwrite,
                   "Replace the capture already in --out (without it, such a folder is refused)");
  add_mesh_options(command, scan.mesh);
  command.add_option("--part-id", scan.part_id, "Part identifier, for the reports");
  command.add_option("--operator", scan.operator_name, "Operator, for the reports");
}

// measure / verify: which artefact, its calibrated sizes, the region rule and the MPEs judged.
struct ArtefactChoice {
  bool ball_bar = false, sphere = false, plane = false;
  std::vector<double> ball_bar_diameters;
};

void add_artefact_options(CLI::App& command, MeasureCommand& measure, ArtefactChoice& choice) {
  choice.ball_bar_diameters = {measure.nominal_diameter_a_mm, measure.nominal_diameter_b_mm};
  auto* ballbar_flag = command.add_flag(
      "--ballbar", choice.ball_bar, "The ball bar: PF and PS of each sphere, SD of their centre distance (default)");
  auto* sphere_flag = command.add_flag("--sphere", choice.sphere, "One sphere (give --diameter-mm): PF and PS");
  auto* plane_flag = command.add_flag("--plane", choice.plane, "The largest plane: flatness F");
  ballbar_flag->excludes(sphere_flag)->excludes(plane_flag);
  sphere_flag->excludes(plane_flag);
  command.add_option("--reference-mm", measure.reference_distance_mm, "Ball bar's calibrated centre distance")
      ->capture_default_str();
  command
      .add_option("--diameters-mm", choice.ball_bar_diameters, "Ball bar's calibrated sphere diameters (first, second)")
      ->expected(2)
      ->capture_default_str();
  command.add_option("--diameter-mm", measure.sphere_diameter_mm, "With --sphere: its calibrated diameter")
      ->check(CLI::PositiveNumber);
  command.add_option("--band-mm", measure.rule.band_mm, "Region: points within this of the robust fit")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  command
      .add_option("--cone-margin-deg", measure.rule.cone_margin_deg,
                  "Region: added to each joint cone's half-angle (sphere and ball bar)")
      ->check(CLI::Range(0.0, 89.0))
      ->capture_default_str();
  command
      .add_option("--exclude-fraction", measure.rule.exclude_fraction,
                  "Share of a feature's points left out as outliers (VDI/VDE 2634-2: at most 0.003)")
      ->check(CLI::Range(0.0, 0.003))
      ->capture_default_str();
  auto mpe_option = [&](const char* name, std::optional<double>& value, const char* what) {
    command
        .add_option_function<double>(
            name, [&value](const double& v) { value = v; }, what)
        ->check(CLI::NonNegativeNumber);
  };
  mpe_option("--mpe-pf", measure.mpe.pf_um, "Maximum permissible probing error form PF (um): PASS / FAIL");
  mpe_option("--mpe-ps", measure.mpe.ps_um, "Maximum permissible |probing error size PS| (um)");
  mpe_option("--mpe-sd", measure.mpe.sd_um, "Maximum permissible |sphere-spacing error SD| (um)");
  mpe_option("--mpe-f", measure.mpe.f_um, "Maximum permissible flatness error F (um)");
}

// The artefact chosen; false (after saying why) when --sphere lacks its diameter.
bool resolve_artefact(const std::string& command, const ArtefactChoice& choice, MeasureCommand& measure) {
  if (choice.sphere && !(measure.sphere_diameter_mm > 0)) {
    std::cerr << "slscan " << command << ": --sphere needs --diameter-mm (the sphere's calibrated diameter)\n";
    return false;
  }
  measure.artefact = choice.sphere ? Artefact::sphere : (choice.plane ? Artefact::plane : Artefact::ball_bar);
  measure.nominal_diameter_a_mm = choice.ball_bar_diameters.at(0);
  measure.nominal_diameter_b_mm = choice.ball_bar_diameters.at(1);
  return true;
}

// Levenshtein distance, for "did you mean".
std::size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

std::string closest(const std::string& word, const std::vector<std::string>& names) {
  std::string best;
  std::size_t best_distance = 3;  // at most two edits away
  for (const auto& n : names) {
    const std::size_t d = edit_distance(word, n);
    if (d < best_distance && d < n.size()) best_distance = d, best = n;
  }
  return best;
}

std::vector<std::string> subcommand_names(CLI::App& app) {
  std::vector<std::string> names;
  for (const CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; })) names.push_back(sub->get_name());
  return names;
}

// The first word that is not a global flag must name a subcommand: say which word is wrong
// (CLI11 would only say that a subcommand is required).
bool check_subcommand_word(CLI::App& app, int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "-q" || arg == "--quiet" || arg == "--json-log") continue;
    if (!arg.empty() && arg[0] == '-') return true;  // --help, --version or an option CLI11 names
    const auto names = subcommand_names(app);
    if (std::find(names.begin(), names.end(), arg) != names.end()) return true;
    std::string list;
    for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
    const std::string suggestion = closest(arg, names);
    std::cerr << "slscan: unknown command '" << arg << "'"
              << (suggestion.empty() ? std::string() : " (did you mean '" + suggestion + "'?)")
              << "; commands: " << list << "\nRun 'slscan --help' for more information.\n";
    return false;
  }
  return true;
}

// CLI11's errors as docs/cli.md's exit codes: a missing input file is bad input (2), anything
// else wrong on the command line is exit 1; --help and --version exit 0.
int parse_failure(CLI::App& app, const CLI::ParseError& e) {
  if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) return app.exit(e);  // --help, --version
  const CLI::App* sub = nullptr;
  for (const CLI::App* s : app.get_subcommands()) sub = s;
  const std::string who = sub ? "slscan " + sub->get_name() : "slscan";
  std::string message = e.what();
  if (dynamic_cast<const CLI::ExtrasError*>(&e) != nullptr) {
    const std::vector<std::string> extras = sub ? sub->remaining() : app.remaining();
    if (!extras.empty()) {
      const std::string& word = extras.front();
      if (!word.empty() && word[0] == '-') {
        std::vector<std::string> options;
        for (const CLI::Option* o : (sub ? sub : &app)->get_options())
          for (const auto& n : o->get_lnames()) options.push_back("--" + n);
        const std::string suggestion = closest(word.substr(0, word.find('=')), options);
        message = "unknown option '" + word + "'" +
                  (suggestion.empty() ? std::string() : " (did you mean '" + suggestion + "'?)");
      } else {
        message = "unexpected argument '" + word + "'";
      }
    }
  }
  std::cerr << who << ": " << message << "\nRun '" << who << " --help' for more information.\n";
  return g_missing_input_file ? exit_bad_input : exit_usage;
}

}  // namespace

static int run_command_line(int argc, char** argv) {
  CLI::App app{"slscan: structured-light 3D scanning host (scan, reprocess, calibrate, measure, inspect, demo)"};
  app.require_subcommand(1);
  app.set_version_flag("--version",
                       "slscan " SLSCAN_VERSION " (slproto " + std::to_string(slproto::protocol_version) + ")");
  Console console;
  app.add_flag("-q,--quiet", console.quiet, "Print nothing but errors and the final figures");
  app.add_flag("--json-log", console.json_log, "Log as one JSON object per line on stderr");

  ReprocessRequest reprocess;
  auto* reprocess_cmd = app.add_subcommand("reprocess", "Reconstruct a recorded capture file");
  reprocess_cmd->add_option("capture", reprocess.capture_path, "Capture file (.slcap)")
      ->required()
      ->check(existing(false));
  reprocess_cmd->add_option("--calib", reprocess.calibration_path, "Calibration file (JSON)")
      ->required()
      ->check(existing(false));
  reprocess_cmd->add_option("--out", reprocess.output_dir, "Output folder")->required();
  reprocess_cmd->add_option("--config", reprocess.config_path, "Reconstruction parameters (JSON)")
      ->check(existing(false));
  add_mesh_options(*reprocess_cmd, reprocess.mesh);
  reprocess_cmd->add_option("--part-id", reprocess.part_id, "Part identifier, for the reports");
  reprocess_cmd->add_option("--operator", reprocess.operator_name, "Operator, for the reports");

  ScanCommand scan;
  std::string connect = "127.0.0.1:7878";
  auto* scan_cmd = app.add_subcommand("scan", "Scan with a connected scanner, record the capture and reconstruct it");
  add_scan_options(*scan_cmd, scan, connect);
  scan_cmd->add_flag("--measure-ballbar", scan.measure_ball_bar,
                     "Fit the ball bar in the model and put its figures in the reports");

  ConvertCommand convert;
  auto* convert_cmd = app.add_subcommand(
      "convert", "Rewrite a capture with zstd-compressed frames (--compress) or raw (--no-compress)");
  convert_cmd->add_option("input", convert.input_path, "Capture file (.slcap)")->required()->check(CLI::ExistingFile);
  convert_cmd->add_option("output", convert.output_path, "Capture file to write")->required();
  convert_cmd->add_flag("--compress,!--no-compress", convert.compress, "Compress frames (default) or store them raw");

  auto* batch_cmd = app.add_subcommand("batch", "Reprocess many captures: a Slurm array job, or locally");
  batch_cmd->require_subcommand(1);
  BatchPlanCommand batch_plan;
  auto* batch_plan_cmd = batch_cmd->add_subcommand(
      "plan", "Write the job list (ROOT/jobs.json) and the sbatch array script (ROOT/batch.sbatch)");
  batch_plan_cmd->add_option("captures", batch_plan.captures, "Capture files (.slcap)")
      ->required()
      ->check(CLI::ExistingFile);
  batch_plan_cmd->add_option("--calib", batch_plan.calibration_path, "Calibration file (JSON)")
      ->required()
      ->check(CLI::ExistingFile);
  batch_plan_cmd->add_option("--config", batch_plan.config_path, "Reconstruction parameters (JSON)")
      ->check(CLI::ExistingFile);
  batch_plan_cmd->add_option("--out", batch_plan.root, "Batch folder ROOT")->required();
  batch_plan_cmd->add_option("--partition", batch_plan.partition, "Slurm partition (default: the cluster's)");
  BatchRunCommand batch_run;
  auto* batch_run_cmd = batch_cmd->add_subcommand("run", "Run the batch's jobs that are not done on this machine");
  batch_run_cmd->add_option("root", batch_run.root, "Batch folder")->required()->check(CLI::ExistingDirectory);
  batch_run_cmd->add_option("--jobs,-j", batch_run.jobs, "Tasks at a time")
      ->capture_default_str()
      ->check(CLI::Range(1, 256));
  BatchStatusCommand batch_status;
  auto* batch_status_cmd = batch_cmd->add_subcommand("status", "Done, failed (with why), running and pending jobs");
  batch_status_cmd->add_option("root", batch_status.root, "Batch folder")->required()->check(CLI::ExistingDirectory);
  batch_status_cmd->add_flag("--json", batch_status.json, "Print the status as JSON");
  BatchTaskCommand batch_task;
  auto* batch_task_cmd = batch_cmd->add_subcommand("task", "Do one job of the batch (what each Slurm array task runs)");
  batch_task_cmd->add_option("root", batch_task.root, "Batch folder")->required()->check(CLI::ExistingDirectory);
  batch_task_cmd->add_option("--index", batch_task.index, "Job index ($SLURM_ARRAY_TASK_ID)")->required();

  StatusCommand status;
  auto* status_cmd =
      app.add_subcommand("status", "Show a scanner's board, firmware and protocol versions and its last scan");
  status_cmd->add_option("scanner", status.address, "HOST[:PORT] (port 7878 unless given)")->required();
  status_cmd->add_option("--token-file", status.token_file, "File holding the scanner's shared token");
  status_cmd->add_flag("--json", status.json, "Print the status as JSON");

  DiscoverCommand discover;
  auto* discover_cmd = app.add_subcommand("discover", "Find scanners on the local network (mDNS/DNS-SD via Avahi)");
  discover_cmd->add_option("--wait", discover.wait_s, "Seconds to listen for answers")->capture_default_str();
  discover_cmd->add_flag("--json", discover.json, "Print the scanners as JSON");

  MeasureCommand measure;
  auto* measure_cmd =
      app.add_subcommand("measure", "VDI/VDE 2634-2 figures of an artefact found in a model (no ground truth)");
  measure_cmd->add_option("model", measure.model_path, "Point cloud (PLY)")->required()->check(existing(false));
  ArtefactChoice measure_choice;
  add_artefact_options(*measure_cmd, measure, measure_choice);
  measure_cmd->add_flag("--json", measure.json, "Print the figures as JSON");

  VerifyCommand verify;
  std::string verify_connect = "127.0.0.1:7878";
  ArtefactChoice verify_choice;
  auto* verify_cmd = app.add_subcommand(
      "verify",
      "Check that a calibration still holds: scan a calibrated artefact, measure it, PASS / FAIL against the MPEs");
  add_scan_options(*verify_cmd, verify.scan, verify_connect);
  add_artefact_options(*verify_cmd, verify.measure, verify_choice);

  InspectCommand inspect;
  auto* inspect_cmd = app.add_subcommand(
      "inspect", "Compare a scan with its nominal shape (STL, PLY, OBJ): best fit, signed deviation, PASS / FAIL");
  inspect_cmd->add_option("model", inspect.model_path, "Scan (PLY point cloud)")->required()->check(existing(false));
  inspect_cmd->add_option("--nominal", inspect.nominal_path, "Nominal mesh (STL, PLY with faces, OBJ)")
      ->required()
      ->check(existing(false));
  inspect_cmd->add_option("--out", inspect.output_dir, "Output folder")->required();
  inspect_cmd
      ->add_option_function<double>(
          "--tolerance", [&inspect](const double& v) { inspect.tolerance_mm = v; },
          "Tolerance +-MM: PASS when --pass-percent of the points are within it")
      ->check(CLI::PositiveNumber);
  inspect_cmd->add_option("--pass-percent", inspect.pass_percent, "Share of points within tolerance for PASS")
      ->check(CLI::Range(0.0, 100.0))
      ->capture_default_str();
  inspect_cmd
      ->add_option("--max-distance", inspect.max_distance_mm,
                   "Points farther from the nominal after the fit are not on the part (mm)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  inspect_cmd->add_option("--nominal-units", inspect.nominal_units, "Unit of the nominal file")
      ->check(CLI::IsMember({"auto", "mm", "m", "in"}))
      ->capture_default_str();
  inspect_cmd->add_flag("--no-coarse-search", inspect.scan_frame_only,
                        "Fit from the scan frame only (no centroid / principal-axes candidates)");
  inspect_cmd->add_option("--part-id", inspect.part_id, "Part identifier, for the reports");
  inspect_cmd->add_option("--operator", inspect.operator_name, "Operator, for the reports");
  inspect_cmd->add_option("--calib", inspect.calibration_path, "Calibration the scan was made with (hash, date)")
      ->check(existing(false));
  inspect_cmd->add_flag("--json", inspect.json, "Print the report as JSON");

  CalibrateCommand calibrate;
  auto* calibrate_cmd =
      app.add_subcommand("calibrate", "Calibrate camera, projectors and turntable from a calibration capture");
  calibrate_cmd->add_option("capture", calibrate.capture_dir, "Calibration capture folder (manifest.json + PNGs)")
      ->check(existing(true));
  calibrate_cmd->add_option("--out", calibrate.output_path, "Calibration file to write (JSON)")->required();
  calibrate_cmd->add_option("--report", calibrate.report_path, "Also write the calibration report (JSON)");
  calibrate_cmd->add_flag("--no-turntable", calibrate.no_turntable, "Camera and projectors only");
  calibrate_cmd
      ->add_option("--virtual", calibrate.virtual_rig,
                   "Calibrate the virtual rig (small or full) through slscand on the sim board")
      ->check(CLI::IsMember({"small", "full"}));
  calibrate_cmd->add_option("--slscand", calibrate.slscand_path, "With --virtual: the slscand executable")
      ->check(existing(false));
  calibrate_cmd->add_option("--board", calibrate.board_path, "With --virtual: the sim board file to start from")
      ->check(existing(false));
  calibrate_cmd->add_option("--write-capture", calibrate.write_capture_dir,
                            "With --virtual or --connect: also write the capture folder (--connect: pose by pose)");
  calibrate_cmd->add_option("--connect", calibrate.connect,
                            "Capture through the scanner at HOST[:PORT], pose by pose (docs/calibration.md)");
  calibrate_cmd->add_option("--token-file", calibrate.token_file, "With --connect: the scanner's shared token");
  calibrate_cmd->add_flag("--auto", calibrate.auto_mode,
                          "With --connect: do not wait for Enter at each pose; a pose whose board is not found or "
                          "lit is an error");
  calibrate_cmd
      ->add_option("--resume", calibrate.resume_dir,
                   "With --connect: continue the capture folder DIR after the poses already in it")
      ->check(existing(true));
  calibrate_cmd->add_option("--squares-x", calibrate.target.squares_x, "Checkerboard squares along x")
      ->capture_default_str();
  calibrate_cmd->add_option("--squares-y", calibrate.target.squares_y, "Checkerboard squares along y")
      ->capture_default_str();
  calibrate_cmd->add_option("--square-mm", calibrate.target.square_mm, "Checkerboard square size (measured)")
      ->capture_default_str();
  calibrate_cmd->add_option("--thickness-mm", calibrate.target.thickness_mm, "Checkerboard plate thickness")
      ->capture_default_str();
  calibrate_cmd->add_option("--platform-radius-mm", calibrate.platform_radius_mm, "Turntable platform radius")
      ->capture_default_str();
  calibrate_cmd->add_option("--exposure-us", calibrate.exposure_us,
                            "With --connect: exposure per pattern (default: the board's, from its board file)");
  calibrate_cmd->add_option("--period-us", calibrate.pattern_period_us,
                            "With --connect: pattern period (default: the board's)");
  calibrate_cmd->add_option("--settle-ms", calibrate.settle_ms, "With --connect: turntable settle time")
      ->capture_default_str();

  ImportCommand import;
  auto* import_cmd = app.add_subcommand(
      "import", "Turn another scanner's images, sequence description and calibration into a capture");
  import_cmd->add_option("description", import.description_path, "Sequence description (JSON, docs/real-data.md)")
      ->required()
      ->check(existing(false));
  std::vector<std::string> import_calibrations;
  import_cmd
      ->add_option("--calib", import_calibrations,
                   "Calibration: OpenCV FileStorage (any key set, docs/real-data.md), Kalibr or ROS YAML, or ours "
                   "(JSON); repeat for a calibration in several files")
      ->required()
      ->check(existing(false));
  import_cmd->add_option("--out", import.output_dir, "Output folder (capture.slcap, calibration.json)")->required();
  import_cmd->add_option("--pose-direction", import.pose_direction, "How the file's R, T map points")
      ->check(CLI::IsMember({"proj_from_cam", "cam_from_proj"}))
      ->capture_default_str();
  import_cmd->add_flag("--detect", import.detect,
                       "Find the conventions (bit order, phase direction and origin, axis, pose direction) from the "
                       "data; writes DIR/description.json and DIR/detect.json");
  import_cmd->add_flag("--force", import.force, "Write the capture even if the self-checks find it inconsistent");

  CompareCommand compare;
  auto* compare_cmd = app.add_subcommand("compare", "Differences between a measured cloud and a reference cloud");
  compare_cmd->add_option("measured", compare.measured_path, "Measured cloud (PLY)")
      ->required()
      ->check(existing(false));
  compare_cmd->add_option("reference", compare.reference_path, "Reference cloud (PLY)")
      ->required()
      ->check(existing(false));
  compare_cmd
      ->add_option("--calib", compare.calibration_path, "Calibration, to find camera pixels of clouds without u, v")
      ->check(existing(false));
  compare_cmd->add_option("--max-distance", compare.max_distance_mm, "Farther points count as unmatched (mm)")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            try {
              std::size_t used = 0;
              const double v = std::stod(text, &used);
              if (used == text.size() && std::isfinite(v) && v > 0) return {};
            } catch (const std::exception&) {
            }
            return "must be a distance > 0 (mm), not " + text;
          },
          "MM > 0"))
      ->capture_default_str();
  compare_cmd
      ->add_option("--min-matched", compare.min_matched,
                   "Fewer measured points than this share within --max-distance: a warning and exit 8")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  compare_cmd->add_option("--neighbors", compare.surface_neighbors, "Reference points per local surface")
      ->capture_default_str();
  compare_cmd
      ->add_flag("--project-pixels", compare.project_pixels,
                 "Pixels of both clouds from --calib's camera even where the PLY has u, v (SLStudio's u, v are of "
                 "its undistorted image)")
      ->needs("--calib");
  compare_cmd->add_flag("--json", compare.json, "Print the figures as JSON");
  compare_cmd->add_option("--report", compare.report_path, "Also write the figures to this JSON file");

  DemoCommand demo;
  auto* demo_cmd = app.add_subcommand("demo", "Start slscand on the sim board, scan a scene and reconstruct it");
  demo_cmd->add_option("--scene", demo.scene, "ballbar, sphere, plane, blade or teacup")->capture_default_str();
  demo_cmd->add_option("--out", demo.output_dir, "Output folder")->capture_default_str();
  demo_cmd->add_flag("--small", demo.small, "The 640 x 512 rig: a quick run");
  demo_cmd->add_flag("--true-calibration", demo.true_calibration,
                     "Scan with the rig's exact calibration instead of calibrating it first");
  demo_cmd->add_option("--config", demo.config_path, "Reconstruction parameters (JSON)")->check(existing(false));
  demo_cmd->add_option("--slscand", demo.slscand_path, "slscand executable")->check(existing(false));
  demo_cmd->add_option("--board", demo.board_path, "Sim board file to start from")->check(existing(false));
  demo_cmd
      ->add_option("--exposure-bracket", demo.exposure_bracket_us,
                   "HDR: exposures (us, comma-separated; the sim camera's 2000 us is the scene's reference)")
      ->delimiter(',')
      ->check(CLI::Range(1u, 1'000'000u));
  add_auto_exposure_options(*demo_cmd, demo.exposure_mode, demo.auto_exposure);
  add_fringe_period_option(*demo_cmd, demo.fringe_period_px);
  demo_cmd->add_flag("--overwrite", demo.overwrite,
                     "Replace the capture of an earlier demo in --out (without it, such a folder is refused)");

  if (!check_subcommand_word(app, argc, argv)) return exit_usage;
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return parse_failure(app, e);
  }
  install_interrupt_handler();
  try {
    if (*reprocess_cmd) return run_reprocess(reprocess, console);
    if (*scan_cmd) {
      std::tie(scan.host, scan.port) = parse_scanner_address(connect);
      return run_scan(scan, console);
    }
    if (*status_cmd) return run_status(status, console);
    if (*convert_cmd) return run_convert(convert, console);
    if (*batch_plan_cmd) return run_batch_plan(batch_plan, console);
    if (*batch_run_cmd) return run_batch_run(batch_run, console);
    if (*batch_status_cmd) return run_batch_status(batch_status, console);
    if (*batch_task_cmd) return run_batch_task(batch_task, console);
    if (*discover_cmd) return run_discover(discover, console);
    if (*import_cmd) {
      import.calibration_path = import_calibrations.front();
      import.more_calibration_paths.assign(import_calibrations.begin() + 1, import_calibrations.end());
      return run_import(import, console);
    }
    if (*calibrate_cmd) return run_calibrate(calibrate, console);
    if (*compare_cmd) return run_compare(compare, console);
    if (*inspect_cmd) return run_inspect(inspect, console);
    if (*demo_cmd) return run_demo(demo, console);
    if (*measure_cmd) {
      if (!resolve_artefact("measure", measure_choice, measure)) return exit_usage;
      return run_measure(measure, console);
    }
    if (*verify_cmd) {
      if (!resolve_artefact("verify", verify_choice, verify.measure)) return exit_usage;
      std::tie(verify.scan.host, verify.scan.port) = parse_scanner_address(verify_connect);
      return run_verify(verify, console);
    }
  } catch (const slscan::io::IoError& e) {
    std::cerr << "slscan: " << e.what() << "\n";
    return exit_bad_input;
  } catch (const UsageError& e) {
    std::cerr << "slscan: " << e.what() << "\n";
    return exit_usage;
  } catch (const std::invalid_argument& e) {
    std::cerr << "slscan: " << e.what() << "\n";
    return exit_bad_input;
  } catch (const DeviceError& e) {
    std::cerr << "slscan: " << e.what() << "\n";
    return exit_device;
  } catch (const ResourceError& e) {
    std::cerr << "slscan: " << e.what() << "\n";
    return exit_resources;
  } catch (const std::bad_alloc&) {
    std::cerr << "slscan: out of memory (" << memory_situation() << ")\n";
    return exit_resources;
  } catch (const std::filesystem::filesystem_error& e) {
    // A folder or file the command was told to use and cannot (a file where a folder should be,
    // no permission, a full disk): the user's to fix, named with its path.
    std::cerr << "slscan: " << (e.path1().empty() ? std::string() : e.path1().string() + ": ") << e.code().message()
              << " (" << e.what() << ")\n";
    return exit_bad_input;
  } catch (const std::exception& e) {
    if (is_thread_start_failure(e)) {
      mark_worker_threads_unreliable();
      std::cerr << "slscan: out of memory: a thread could not be started (" << e.what() << "; " << memory_situation()
                << ")\n";
      return exit_resources;
    }
    std::cerr << "slscan: internal error: " << e.what() << "\n";
    return exit_internal;
  }
  return exit_usage;
}

static std::terminate_handler default_terminate = nullptr;

// A thread that could not be started on a thread of a library (TBB starting one worker from
// another) ends in std::terminate: reported as out of memory (exit 9), not as an abort.
[[noreturn]] static void on_terminate() {
  if (const std::exception_ptr current = std::current_exception()) {
    try {
      std::rethrow_exception(current);
    } catch (const std::exception& e) {
      if (is_thread_start_failure(e)) {
        std::cerr << "slscan: out of memory: a thread could not be started (" << e.what() << "; " << memory_situation()
                  << ")\n";
        std::cerr.flush();
        std::_Exit(exit_resources);
      }
    } catch (...) {
    }
  }
  if (default_terminate != nullptr) default_terminate();
  std::abort();
}

static void start_threads_or_warn() noexcept {
  try {
    const WorkerThreads threads = start_worker_threads();
    if (threads.start_failed)
      std::cerr << "slscan: warning: only 1 of " << threads.wanted << " threads could be started (" << threads.failure
                << "; " << memory_situation() << "); running on one thread\n";
  } catch (...) {
    // Out of memory before the command: it will say so itself, as the first thing it needs fails.
    mark_worker_threads_unreliable();
  }
}

// TBB's worker threads (ours and OpenCV's) are joined before the process exits instead of being
// torn down by static destructors: a thread still exiting while LeakSanitizer stops the world
// makes its tracer crash ("Tracer caught signal 11", google/sanitizers#1353), which failed CI.
//
// Every worker is started before the command runs (worker_threads.hpp): when the address space
// has no room for them the command runs on one thread, and the process does not wait for a
// half-started worker at exit.
int main(int argc, char** argv) {
  slscan::core::run_with_huge_pages(argv);  // first: it may re-execute the program
  default_terminate = std::set_terminate(on_terminate);
  try {
    slscan::session::prepare_sha256();  // before the workers take their address space
    tbb::task_scheduler_handle workers{tbb::attach{}};
    start_threads_or_warn();
    const int code = run_command_line(argc, argv);
    if (worker_threads_unreliable()) {
      std::fflush(nullptr);  // std::cout and std::cerr are synced with stdio: this flushes them too
      std::_Exit(code);
    }
    (void)tbb::finalize(workers, std::nothrow);
    return code;
  } catch (const std::bad_alloc&) {
    // Out of memory while the command line was being built and parsed, before the command's own
    // handlers: in an address space with barely room to start (prlimit, ulimit -v).
    try {
      std::cerr << "slscan: out of memory before the command started (" << memory_situation() << ")\n";
    } catch (...) {
      std::fputs("slscan: out of memory before the command started (the address-space limit (ulimit -v) or RAM)\n",
                 stderr);
    }
    return exit_resources;
  } catch (const std::exception& e) {
    std::fputs("slscan: internal error: ", stderr);
    std::fputs(e.what(), stderr);
    std::fputs("\n", stderr);
    return exit_internal;
  } catch (...) {
    std::fputs("slscan: internal error: an exception of unknown type\n", stderr);
    return exit_internal;
  }
}
