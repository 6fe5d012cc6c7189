// The calibration file (JSON, "slscan-calibration", docs/calibration.md) and the JSON spellings
// of its pieces: every file that records a camera, a pose or a pattern plan (capture manifests,
// the virtual rig's scene files) writes and reads them with these functions, so each is spelt
// one way everywhere.
#pragma once

#include <nlohmann/json_fwd.hpp>
#include <string>
#include <string_view>

#include "slproto/file_util.hpp"
#include "slproto/rig_model.hpp"

namespace slproto {

class JsonObject;  // json_fields.hpp: include it to call the readers below

// JSON text <-> calibration. Parsing validates everything and names the offending field;
// unknown and duplicate keys are refused.
Result<RigCalibration> parse_calibration(std::string_view json_text, std::string_view origin = "calibration");
std::string format_calibration(const RigCalibration& calibration);
Result<RigCalibration> load_calibration(const std::string& path);
// Writes to a temporary file then renames, so a crash never leaves a half-written file.
Status save_calibration(const std::string& path, const RigCalibration& calibration);

// The pattern plan alone, as the calibration file writes it (a JSON object): capture manifests
// and other files that record a plan use the same layout. Parsing validates (check()).
std::string format_pattern_plan(const PatternPlanConfig& config);
Result<PatternPlanConfig> parse_pattern_plan(std::string_view json_text, std::string_view origin = "pattern_plan");

// The pieces' spellings. The readers take every field as required and throw JsonFieldError
// (json_fields.hpp) naming the field; they call finish() on the objects they read.
//   camera/projector: {"width", "height", "fx", "fy", "cx", "cy", "distortion": {k1 k2 p1 p2 k3}}
//   pose:             {"R": [9 numbers, row-major], "t": [3 numbers, mm]}
nlohmann::json pinhole_to_json(const PinholeModel& model);
PinholeModel read_pinhole(JsonObject object);
nlohmann::json pose_to_json(const RigidTransform& pose);
RigidTransform read_pose(JsonObject object);
nlohmann::json pattern_plan_to_json(const PatternPlanConfig& config);
PatternPlanConfig read_pattern_plan(JsonObject object);

}  // namespace slproto
