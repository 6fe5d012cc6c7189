#include "slproto/calibration_file.hpp"

#include <nlohmann/json.hpp>

#include "slproto/file_util.hpp"
#include "slproto/json_fields.hpp"

namespace slproto {

using json = nlohmann::json;

json pinhole_to_json(const PinholeModel& m) {
  return {{"width", m.width},
          {"height", m.height},
          {"fx", m.fx},
          {"fy", m.fy},
          {"cx", m.cx},
          {"cy", m.cy},
          {"distortion",
           {{"k1", m.distortion.k1},
            {"k2", m.distortion.k2},
            {"p1", m.distortion.p1},
            {"p2", m.distortion.p2},
            {"k3", m.distortion.k3}}}};
}

json pose_to_json(const RigidTransform& p) { return {{"R", p.R}, {"t", p.t}}; }

json pattern_plan_to_json(const PatternPlanConfig& c) {
  return {{"projector_width", c.projector_width},
          {"projector_height", c.projector_height},
          {"axis", coding_axis_name(c.axis)},
          {"period_px", c.period_px},
          {"phase_steps", c.phase_steps},
          {"complementary_bit", c.complementary_bit},
          {"with_white_black", c.with_white_black},
          {"inverse_gray", c.inverse_gray},
          {"gray_low_bits", gray_low_bits_name(c.gray_low_bits)},
          {"phase_offset_rad", c.phase_offset_rad},
          {"phase_offset_steps", c.phase_offset_steps}};
}

PinholeModel read_pinhole(JsonObject r) {
  PinholeModel m;
  // The range keeps the value in an int; PinholeModel::check() judges what is plausible.
  m.width = r.integer<int>("width", 0, 65536);
  m.height = r.integer<int>("height", 0, 65536);
  m.fx = r.number("fx");
  m.fy = r.number("fy");
  m.cx = r.number("cx");
  m.cy = r.number("cy");
  JsonObject d = r.object("distortion");
  m.distortion = {d.number("k1"), d.number("k2"), d.number("p1"), d.number("p2"), d.number("k3")};
  d.finish();
  r.finish();
  return m;
}

RigidTransform read_pose(JsonObject r) {
  RigidTransform p;
  p.R = r.numbers<9>("R");
  p.t = r.numbers<3>("t");
  r.finish();
  return p;
}

PatternPlanConfig read_pattern_plan(JsonObject r) {
  PatternPlanConfig c;
  c.projector_width = r.integer<int>("projector_width", 0, 1 << 20);
  c.projector_height = r.integer<int>("projector_height", 0, 1 << 20);
  c.axis = r.choice<CodingAxis>("axis", {{"columns", CodingAxis::columns}, {"rows", CodingAxis::rows}});
  c.period_px = r.integer<int>("period_px", 0, 1 << 20);
  c.phase_steps = r.integer<int>("phase_steps", 0, 1 << 10);
  c.complementary_bit = r.boolean("complementary_bit");
  c.with_white_black = r.boolean("with_white_black");
  // Later additions: optional, so files written before them still read (as false, centre).
  r.read("inverse_gray", c.inverse_gray);
  if (r.has("gray_low_bits"))
    c.gray_low_bits = r.choice<GrayLowBits>(
        "gray_low_bits", {{"centre", GrayLowBits::centre}, {"slstudio_parity", GrayLowBits::slstudio_parity}});
  r.read("phase_offset_rad", c.phase_offset_rad, -10.0, 10.0);  // check() bounds it to [-2 pi, 2 pi]
  r.read("phase_offset_steps", c.phase_offset_steps, 0, 1 << 10);
  r.finish();
  return c;
}

std::string format_calibration(const RigCalibration& cal) {
  json projectors = json::object();
  for (std::size_t i = 0; i < cal.projectors.size(); ++i) {
    const ProjectorCalibration& p = cal.projectors[i];
    projectors[projector_side_name(static_cast<ProjectorSide>(i))] = {{"intrinsics", pinhole_to_json(p.intrinsics)},
                                                                      {"cam_from_proj", pose_to_json(p.cam_from_proj)},
                                                                      {"reprojection_rms_px", p.reprojection_rms_px}};
  }
  json doc = {
      {"format", "slscan-calibration"},
      {"format_version", cal.format_version},
      {"units", "mm"},
      {"camera", pinhole_to_json(cal.camera)},
      {"camera_reprojection_rms_px", cal.camera_reprojection_rms_px},
      {"projectors", projectors},
      {"turntable",
       {{"cam_from_table", pose_to_json(cal.turntable.cam_from_table)},
        {"platform_radius_mm", cal.turntable.platform_radius_mm},
        {"pose_residual_mm", cal.turntable.pose_residual_mm}}},
      {"pattern_plan", pattern_plan_to_json(cal.pattern_plan)},
      {"source", cal.source},
      {"created_by", cal.created_by},
  };
  return doc.dump(2) + "\n";
}

namespace {

// The version is read first and alone: a file of another version may have other fields, and
// "format_version 2 is not supported" says more than the first field this build does not know.
struct VersionMismatch {
  int version;
};

RigCalibration read_calibration(const json& doc) {
  JsonObject r(doc, "");
  if (r.text("format") != "slscan-calibration") r.fail("format", "expected \"slscan-calibration\"");
  RigCalibration cal;
  cal.format_version = r.integer<int>("format_version");
  if (cal.format_version != RigCalibration::kFormatVersion) throw VersionMismatch{cal.format_version};
  if (r.text("units") != "mm") r.fail("units", "only \"mm\" is supported");
  cal.camera = read_pinhole(r.object("camera"));
  cal.camera_reprojection_rms_px = r.number("camera_reprojection_rms_px");
  JsonObject projectors = r.object("projectors");
  for (std::size_t i = 0; i < cal.projectors.size(); ++i) {
    JsonObject p = projectors.object(projector_side_name(static_cast<ProjectorSide>(i)));
    cal.projectors[i].intrinsics = read_pinhole(p.object("intrinsics"));
    cal.projectors[i].cam_from_proj = read_pose(p.object("cam_from_proj"));
    cal.projectors[i].reprojection_rms_px = p.number("reprojection_rms_px");
    p.finish();
  }
  projectors.finish();
  JsonObject table = r.object("turntable");
  cal.turntable.cam_from_table = read_pose(table.object("cam_from_table"));
  cal.turntable.platform_radius_mm = table.number("platform_radius_mm");
  cal.turntable.pose_residual_mm = table.number("pose_residual_mm");
  table.finish();
  cal.pattern_plan = read_pattern_plan(r.object("pattern_plan"));
  cal.source = r.text("source");
  cal.created_by = r.text("created_by");
  r.finish();
  return cal;
}

}  // namespace

Result<RigCalibration> parse_calibration(std::string_view text, std::string_view origin) {
  const std::string where(origin);
  Result<RigCalibration> cal = make_error(Errc::internal, "");
  try {
    cal = read_json(text, origin, read_calibration);
  } catch (const VersionMismatch& mismatch) {
    return make_error(Errc::wrong_version, where + ": format_version " + std::to_string(mismatch.version) +
                                               " is not supported (this build reads version " +
                                               std::to_string(RigCalibration::kFormatVersion) + ")");
  }
  if (!cal) return cal;
  if (auto status = cal->check(); !status)
    return make_error(status.error().code, where + ": " + status.error().message);
  return cal;
}

std::string format_pattern_plan(const PatternPlanConfig& config) { return pattern_plan_to_json(config).dump(); }

Result<PatternPlanConfig> parse_pattern_plan(std::string_view json_text, std::string_view origin) {
  auto config = read_json(json_text, origin, [](const json& doc) { return read_pattern_plan(JsonObject(doc, "")); });
  if (!config) return config;
  if (auto status = config->check(); !status)
    return make_error(status.error().code, std::string(origin) + ": " + status.error().message);
  return config;
}

Result<RigCalibration> load_calibration(const std::string& path) {
  auto text = read_whole_file(path);
  if (!text) return std::move(text).error();
  return parse_calibration(*text, path);
}

Status save_calibration(const std::string& path, const RigCalibration& calibration) {
  if (auto status = calibration.check(); !status) return status;
  return write_file_atomically(path, format_calibration(calibration));
}

}  // namespace slproto
