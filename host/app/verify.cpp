// slscan verify: does the calibration still hold? A scan of a calibrated artefact, measured from
// the scan alone as `measure` does, judged against the limits the user states (docs/calibration.md,
// "Checking a calibration").
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "feature_report.hpp"
#include "run.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::app {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// The limits an artefact can be judged by; a limit it cannot give is a mistake on the command line.
void check_limits(const MeasureCommand& measure) {
  const MpeLimits& mpe = measure.mpe;
  if (!mpe.pf_um && !mpe.ps_um && !mpe.sd_um && !mpe.f_um)
    throw UsageError(
        "verify needs at least one limit to judge the calibration by: --mpe-sd, --mpe-ps, --mpe-pf (ball bar, "
        "sphere) or --mpe-f (plane)");
  switch (measure.artefact) {
    case Artefact::ball_bar:
      if (mpe.f_um) throw UsageError("verify --ballbar: --mpe-f is a plane's (flatness); use --plane");
      break;
    case Artefact::sphere:
      if (mpe.sd_um) throw UsageError("verify --sphere: --mpe-sd needs two spheres; use --ballbar");
      if (mpe.f_um) throw UsageError("verify --sphere: --mpe-f is a plane's (flatness); use --plane");
      break;
    case Artefact::plane:
      if (mpe.pf_um || mpe.ps_um || mpe.sd_um)
        throw UsageError("verify --plane: only --mpe-f (flatness) applies to a plane");
      break;
  }
}

json read_report(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw io::IoError(path.string() + ": the scan left no report");
  std::ostringstream text;
  text << in.rdbuf();
  return json::parse(text.str(), nullptr, /*allow_exceptions=*/false);
}

}  // namespace

int run_verify(VerifyCommand command, const Console& console) {
  check_limits(command.measure);
  const int scanned = run_scan(command.scan, console);
  if (scanned != exit_ok) return scanned;

  const fs::path folder = command.scan.output_dir;
  command.measure.model_path = (folder / "model.ply").string();
  const json report = read_report(folder / "report.json");
  json verdict = {{"command", "verify"},
                  {"scan", {{"folder", folder.string()}, {"report", "report.json"}, {"model", "model.ply"}}}};
  if (report.is_object() && report.contains("calibration")) verdict["calibration"] = report["calibration"];
  if (report.is_object() && report.contains("run")) verdict["run"] = report["run"];

  const auto measured = measure_artefact(command.measure, console);
  if (!measured) {
    verdict["verdict"] = "not measured";
    verdict["why"] = "the artefact was not found in the scan (see the warning above)";
    io::write_file_atomically((folder / "verify.json").string(), verdict.dump(2) + "\n");
    std::printf("calibration check: not judged: the artefact was not found in %s\n",
                command.measure.model_path.c_str());
    return exit_measurement;
  }
  verdict["verdict"] = measured->within_mpe ? "PASS" : "FAIL";
  verdict["artefact"] = measured->kind;
  verdict[measured->kind] = measured->figures;
  io::write_file_atomically((folder / "verify.json").string(), verdict.dump(2) + "\n");

  std::printf("%s", feature_text(measured->kind, measured->figures).c_str());
  const std::string calibration = command.scan.calibration_path;
  if (measured->within_mpe) {
    std::printf("calibration check: PASS: %s holds (every figure within its limit; %s)\n", calibration.c_str(),
                (folder / "verify.json").c_str());
    return exit_ok;
  }
  std::printf(
      "calibration check: FAIL: %s no longer holds (a figure beyond its limit, above; %s). Recalibrate: slscan "
      "calibrate --connect %s:%u --out NEW.json (docs/calibration.md)\n",
      calibration.c_str(), (folder / "verify.json").c_str(), command.scan.host.c_str(),
      static_cast<unsigned>(command.scan.port));
  return exit_out_of_tolerance;
}

}  // namespace slscan::app
