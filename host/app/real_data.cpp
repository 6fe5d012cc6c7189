#include "real_data.hpp"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <tuple>

#include "detect.hpp"
#include "progress.hpp"
#include "slproto/calibration.hpp"
#include "slscan/io/foreign_calibration.hpp"
#include "slscan/io/image_sequence_import.hpp"
#include "slscan/io/ply.hpp"

namespace slscan::app {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

json read_json_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw io::IoError(path + ": cannot open the sequence description");
  std::ostringstream text;
  text << in.rdbuf();
  try {
    return json::parse(text.str());
  } catch (const json::exception& e) {
    throw io::IoError(path + ": not valid JSON: " + e.what());
  }
}

void print_findings(const core::DecodeChecks& checks) {
  for (const auto& f : checks.findings) std::cerr << "slscan: self-check [" << f.check << "]: " << f.message() << "\n";
}

}  // namespace

int run_import(const ImportCommand& command, const Console& console) {
  io::ForeignCalibrationOptions calibration_options;
  if (command.pose_direction == "proj_from_cam") {
    calibration_options.pose_direction = io::PoseDirection::proj_from_cam;
  } else if (command.pose_direction == "cam_from_proj") {
    calibration_options.pose_direction = io::PoseDirection::cam_from_proj;
  } else {
    throw std::invalid_argument("import: --pose-direction must be proj_from_cam or cam_from_proj, got '" +
                                command.pose_direction + "'");
  }
  calibration_options.more_paths = command.more_calibration_paths;
  const std::string base_dir = fs::path(command.description_path).parent_path().string();
  io::SequenceDescription description = io::load_sequence_description(command.description_path);
  std::optional<DetectResult> detected;
  if (command.detect) {
    std::vector<std::string> calibrations{command.calibration_path};
    calibrations.insert(calibrations.end(), command.more_calibration_paths.begin(),
                        command.more_calibration_paths.end());
    DetectInput input{read_json_file(command.description_path), base_dir, command.description_path, calibrations,
                      calibration_options};
    detected = detect_conventions(input, console);
    std::cout << format_detect_table(detected->candidates);
    if (!detected->consistent) {
      print_findings(detected->final_report.checks);
      std::cerr << "slscan: no description tried is consistent with the data; the best is above (nothing written)\n";
      return exit_inconsistent;
    }
    description = io::parse_sequence_description(detected->description.dump(), base_dir, command.description_path);
    calibration_options.pose_direction = detected->pose_direction;
  }
  calibration_options.projector_width = description.plan.projector_width;
  calibration_options.projector_height = description.plan.projector_height;
  calibration_options.camera_width = description.camera_width;
  calibration_options.camera_height = description.camera_height;
  if (!description.calibration_keys.empty())
    calibration_options.keys = io::calibration_keys_from(description.calibration_keys, command.description_path);
  slproto::RigCalibration calibration = io::read_foreign_calibration(command.calibration_path, calibration_options);
  const io::ImportedSequence sequence = io::read_image_sequence(description);

  // The images, the description and the calibration must agree on the geometry.
  if (sequence.width != calibration.camera.width || sequence.height != calibration.camera.height)
    throw io::IoError(command.calibration_path + ": the camera is " + std::to_string(calibration.camera.width) + " x " +
                      std::to_string(calibration.camera.height) + " but the images are " +
                      std::to_string(sequence.width) + " x " + std::to_string(sequence.height));
  const auto& projector = calibration.projector(slproto::ProjectorSide::left).intrinsics;
  if (projector.width != description.plan.projector_width || projector.height != description.plan.projector_height)
    throw io::IoError(command.calibration_path + ": the projector is " + std::to_string(projector.width) + " x " +
                      std::to_string(projector.height) + " but the description says " +
                      std::to_string(description.plan.projector_width) + " x " +
                      std::to_string(description.plan.projector_height));
  calibration.pattern_plan = description.plan;

  // Self-check: decode and triangulate the view as reprocess would, before anything is written.
  const core::ProjectorViewReport check = evaluate_imported(sequence, calibration);
  if (check.checks.flagged()) {
    print_findings(check.checks);
    if (!command.force) {
      std::cerr << "slscan: " << command.description_path
                << " does not describe these images (nothing written); fix it as said above, or let slscan import "
                   "--detect find the conventions (--force writes the capture anyway)\n";
      return exit_inconsistent;
    }
    console.warn("--force: writing a capture that contradicts its description");
  }

  fs::create_directories(command.output_dir);
  const std::string capture_path = (fs::path(command.output_dir) / "capture.slcap").string();
  const std::string calibration_path = (fs::path(command.output_dir) / "calibration.json").string();
  if (detected) {
    // The corrected description, its images found from where it is written.
    json corrected = detected->description;
    const fs::path images = fs::absolute(fs::path(base_dir) / fs::path(corrected.value("image_dir", std::string(""))));
    corrected["image_dir"] = fs::relative(images, fs::absolute(command.output_dir)).string();
    json table = json::array();
    for (const auto& c : detected->candidates)
      table.push_back(
          {{"stage", c.stage}, {"candidate", c.label}, {"score", c.score}, {"chosen", c.chosen}, {"note", c.note}});
    io::write_file_atomically((fs::path(command.output_dir) / "description.json").string(), corrected.dump(2) + "\n");
    io::write_file_atomically(
        (fs::path(command.output_dir) / "detect.json").string(),
        json{{"pose_direction",
              detected->pose_direction == io::PoseDirection::proj_from_cam ? "proj_from_cam" : "cam_from_proj"},
             {"candidates", table}}
                .dump(2) +
            "\n");
  }
  if (auto status = slproto::save_calibration(calibration_path, calibration); !status)
    throw io::IoError(calibration_path + ": " + status.error().message);
  io::write_imported_capture(capture_path, sequence);
  if (sequence.source_bit_depth == 16)
    console.warn("16-bit images were reduced to 12 bits (the capture format's deepest pixel format)");
  console.info("imported " + std::to_string(sequence.frames.size()) + " frames of " + std::to_string(sequence.width) +
               " x " + std::to_string(sequence.height) + " (" + std::to_string(sequence.bit_depth) + " bit) into " +
               capture_path + " and " + calibration_path + "; self-checks passed (" +
               std::to_string(check.decode.valid) + " pixels decoded, " + std::to_string(check.triangulate.valid) +
               " triangulated)");
  if (detected)
    console.info("the corrected description is " + (fs::path(command.output_dir) / "description.json").string());
  if (sequence.bit_depth > 8)
    console.info("reprocess it with a config whose decode.bit_depth is " + std::to_string(sequence.bit_depth));
  if (description.plan.phase_steps == 0)
    console.info(
        "a Gray code without phase steps: its steps are the signal, reprocess with decode.smoothing_radius 0 "
        "and depth_smoothing.enabled false (docs/real-data.md)");
  return exit_ok;
}

core::PixelTaggedCloud read_pixel_tagged_ply(const std::string& path, const slproto::PinholeModel* camera,
                                             bool ignore_stored_pixels) {
  const io::PlyTable table = io::read_ply_table(path);
  const auto& x = table.column("x");
  const auto& y = table.column("y");
  const auto& z = table.column("z");
  core::PixelTaggedCloud cloud;
  cloud.points.resize(table.vertex_count);
  for (std::size_t i = 0; i < table.vertex_count; ++i)
    cloud.points[i] = Eigen::Vector3f(static_cast<float>(x[i]), static_cast<float>(y[i]), static_cast<float>(z[i]));
  if (table.find("u") >= 0 && table.find("v") >= 0 && !(ignore_stored_pixels && camera != nullptr)) {
    const auto& u = table.column("u");
    const auto& v = table.column("v");
    cloud.u.assign(u.begin(), u.end());
    cloud.v.assign(v.begin(), v.end());
  } else if (camera != nullptr) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    cloud.u.assign(table.vertex_count, nan);
    cloud.v.assign(table.vertex_count, nan);
    for (std::size_t i = 0; i < table.vertex_count; ++i) {
      double u = 0, v = 0;
      if (!camera->project({x[i], y[i], z[i]}, u, v)) continue;
      if (u < -0.5 || v < -0.5 || u > camera->width - 0.5 || v > camera->height - 0.5) continue;
      cloud.u[i] = static_cast<float>(u);
      cloud.v[i] = static_cast<float>(v);
    }
  }
  return cloud;
}

namespace {

json stats_json(const core::DistanceStats& s) {
  return {{"count", s.count}, {"mean_mm", s.mean}, {"rms_mm", s.rms}, {"median_mm", s.median},
          {"p90_mm", s.p90},  {"p99_mm", s.p99},   {"max_mm", s.max}};
}

std::string stats_line(const core::DistanceStats& s) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(3) << "median " << s.median << " mm, p90 " << s.p90 << " mm, p99 " << s.p99
      << " mm, rms " << s.rms << " mm over " << s.count << " points";
  return out.str();
}

}  // namespace

int run_compare(const CompareCommand& command, const Console& console) {
  std::optional<slproto::RigCalibration> calibration;
  if (!command.calibration_path.empty()) {
    auto loaded = slproto::load_calibration(command.calibration_path);
    if (!loaded) throw io::IoError(loaded.error().message);
    calibration = std::move(loaded).value();
  }
  if (command.project_pixels && !calibration)
    throw std::invalid_argument("compare: --project-pixels needs --calib (the camera to project with)");
  const slproto::PinholeModel* camera = calibration ? &calibration->camera : nullptr;
  if (!(command.max_distance_mm > 0) || !std::isfinite(command.max_distance_mm))
    throw std::invalid_argument("compare: --max-distance " + short_number(command.max_distance_mm) +
                                " must be a finite distance > 0 (mm)");
  if (!(command.min_matched >= 0 && command.min_matched <= 1))
    throw std::invalid_argument("compare: --min-matched " + short_number(command.min_matched) +
                                " must be a share in [0, 1]");
  const core::PixelTaggedCloud measured = read_pixel_tagged_ply(command.measured_path, camera, command.project_pixels);
  const core::PixelTaggedCloud reference =
      read_pixel_tagged_ply(command.reference_path, camera, command.project_pixels);
  // An empty cloud has no differences to report: "0.000 mm over 0 points" would read as a match.
  for (const auto& [cloud, path, what] : {std::tuple{&measured, &command.measured_path, "measured"},
                                          std::tuple{&reference, &command.reference_path, "reference"}}) {
    std::size_t finite = 0;
    for (const auto& p : cloud->points) finite += p.allFinite() ? 1 : 0;
    if (finite == 0)
      throw io::IoError(*path + ": the " + std::string(what) + " cloud has no points (" +
                        std::to_string(cloud->points.size()) + " vertices, none finite): nothing to compare");
  }
  core::CompareOptions options;
  options.max_distance_mm = command.max_distance_mm;
  options.surface_neighbors = command.surface_neighbors;
  const core::CloudComparison c = core::compare_clouds(measured, reference, options);
  const double matched_share =
      c.measured_points > 0 ? static_cast<double>(c.measured_points - c.unmatched) / c.measured_points : 0.0;
  const bool too_few_matched = matched_share < command.min_matched;
  char share_text[160];
  std::snprintf(share_text, sizeof share_text,
                "%.1f %% of the measured points (%zu of %zu) are within %g mm of the reference, fewer than "
                "--min-matched %.1f %%",
                100.0 * matched_share, c.measured_points - c.unmatched, c.measured_points, command.max_distance_mm,
                100.0 * command.min_matched);
  const std::string warning =
      too_few_matched ? std::string(share_text) +
                            ": the clouds are probably in different frames (align them first: both in the camera "
                            "frame, e.g. views/view_N.ply against a camera-frame reference), or not of the same object"
                      : std::string();

  json report = {{"measured", {{"file", command.measured_path}, {"points", c.measured_points}}},
                 {"reference", {{"file", command.reference_path}, {"points", c.reference_points}}},
                 {"max_distance_mm", command.max_distance_mm},
                 {"unmatched", c.unmatched},
                 {"matched_share", matched_share},
                 {"min_matched", command.min_matched},
                 {"point_to_point", stats_json(c.point_to_point)},
                 {"point_to_surface", stats_json(c.point_to_surface)}};
  if (c.per_pixel) {
    const auto& p = *c.per_pixel;
    report["per_pixel"] = {{"distance", stats_json(p.distance)},     {"median_signed_z_mm", p.median_signed_z},
                           {"reference_pixels", p.reference_pixels}, {"measured_pixels", p.measured_pixels},
                           {"common_pixels", p.common_pixels},       {"coverage", p.coverage}};
  }
  if (too_few_matched) report["warning"] = warning;
  if (!command.report_path.empty()) io::write_file_atomically(command.report_path, report.dump(2) + "\n");
  if (command.json) {
    std::cout << report.dump(2) << "\n";
  } else {
    std::cout << "point to point:   " << stats_line(c.point_to_point) << "\n";
    std::cout << "point to surface: " << stats_line(c.point_to_surface) << "\n";
    std::cout << "unmatched: " << c.unmatched << " measured points beyond " << command.max_distance_mm
              << " mm of the reference\n";
    if (c.per_pixel) {
      const auto& p = *c.per_pixel;
      std::cout << "per pixel:        " << stats_line(p.distance) << "\n";
      std::cout << std::fixed << std::setprecision(1) << "coverage: " << 100.0 * p.coverage << " % of the "
                << p.reference_pixels << " reference pixels; median depth difference " << std::setprecision(3)
                << p.median_signed_z << " mm\n";
    } else {
      console.warn("no per-pixel comparison: give both clouds u/v, or --calib to project camera-frame clouds");
    }
  }
  if (too_few_matched) {
    console.warn(warning);
    return exit_unmatched;
  }
  return exit_ok;
}

}  // namespace slscan::app
