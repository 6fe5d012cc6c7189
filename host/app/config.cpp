#include "config.hpp"

#include <cstdio>
#include <optional>

#include "slproto/file_util.hpp"
#include "slproto/json_fields.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::app {

using nlohmann::json;

namespace {

// One section of the config: the listed keys are read into their fields (absent keys leave
// the defaults); finish() refuses any other key.
class Section {
 public:
  Section(slproto::JsonObject& top, const char* name) {
    if (top.has(name)) object_.emplace(top.object(name));
  }
  template <class T>
  Section& read(const char* key, T& field) {
    if (object_) object_->read(key, field);
    return *this;
  }
  void finish() const {
    if (object_) object_->finish();
  }

 private:
  std::optional<slproto::JsonObject> object_;
};

void apply_sections(const json& config, core::ReconstructionOptions& o) {
  slproto::JsonObject top(config, "");
  Section(top, "decode")
      .read("bit_depth", o.decode.bit_depth)
      .read("min_contrast_dn", o.decode.min_contrast_dn)
      .read("min_modulation_dn", o.decode.min_modulation_dn)
      .read("saturation_dn", o.decode.saturation_dn)
      .read("smoothing_radius", o.decode.smoothing_radius)
      .read("quadratic_radius", o.decode.quadratic_radius)
      .read("smoothing_max_deviation_px", o.decode.smoothing_max_deviation_px)
      .finish();
  Section(top, "triangulate")
      .read("newton_iterations", o.triangulate.newton_iterations)
      .read("max_residual_px", o.triangulate.max_residual_px)
      .read("min_depth_mm", o.triangulate.min_depth_mm)
      .read("max_depth_mm", o.triangulate.max_depth_mm)
      .finish();
  Section(top, "fusion").read("agreement_mm", o.fusion.agreement_mm).finish();
  Section(top, "flying_pixels")
      .read("enabled", o.remove_flying_pixels)
      .read("max_abs_mm", o.flying_pixels.max_abs_mm)
      .read("relative", o.flying_pixels.relative)
      .finish();
  Section(top, "turntable_denoise")
      .read("enabled", o.denoise_turntable)
      .read("min_height_mm", o.turntable_denoise.min_height_mm)
      .read("max_height_mm", o.turntable_denoise.max_height_mm)
      .read("radius_mm", o.turntable_denoise.radius_mm)
      .finish();
  std::string mode = core::refinement_mode_name(o.registration.mode);
  Section(top, "registration")
      .read("enabled", o.register_views)
      .read("mode", mode)
      .read("gates_mm", o.registration.icp.gates_mm)
      .read("max_normal_angle_deg", o.registration.icp.max_normal_angle_deg)
      .read("source_points_per_view", o.registration.icp.source_points_per_view)
      .read("close_loop", o.registration.close_loop)
      .read("turntable_prior_deg", o.registration.turntable_prior_deg)
      .read("turntable_prior_mm", o.registration.turntable_prior_mm)
      .finish();
  // The gates are the ICP's search radii, coarse to fine: each must be a length a point can be
  // off by (above 0, at most 10 m), checked here so the message names the field, not the stage.
  if (o.registration.icp.gates_mm.empty() || o.registration.icp.gates_mm.size() > 16)
    throw slproto::JsonFieldError("registration.gates_mm: expected 1 to 16 gates, got " +
                                  std::to_string(o.registration.icp.gates_mm.size()));
  for (std::size_t i = 0; i < o.registration.icp.gates_mm.size(); ++i) {
    const double gate = o.registration.icp.gates_mm[i];
    if (!(gate > 0 && gate <= 10000)) {
      char shown[32];
      std::snprintf(shown, sizeof shown, "%.6g", gate);
      throw slproto::JsonFieldError("registration.gates_mm[" + std::to_string(i) + "]: " + shown +
                                    " is out of range (allowed above 0, at most 10000 mm)");
    }
  }
  if (mode == "turntable")
    o.registration.mode = core::RefinementMode::turntable;
  else if (mode == "joint")
    o.registration.mode = core::RefinementMode::joint;
  else if (mode == "sequential")
    o.registration.mode = core::RefinementMode::sequential;
  else
    throw std::invalid_argument("config: registration.mode must be \"turntable\", \"joint\" or \"sequential\", not \"" +
                                mode + "\"");
  Section(top, "outliers")
      .read("enabled", o.remove_outliers)
      .read("k", o.outliers.k)
      .read("std_ratio", o.outliers.std_ratio)
      .finish();
  Section(top, "depth_smoothing")
      .read("enabled", o.smooth_depth)
      .read("window_radius_mm", o.depth_smoothing.window_radius_mm)
      .read("max_window_radius_px", o.depth_smoothing.max_window_radius_px)
      .read("max_depth_slope", o.depth_smoothing.max_depth_slope)
      .read("min_neighbors", o.depth_smoothing.min_neighbors)
      .finish();
  Section(top, "view_selection")
      .read("enabled", o.select_best_views)
      .read("max_incidence_deg", o.overlap.max_incidence_deg)
      .read("same_spot_mm", o.overlap.same_spot_mm)
      .read("same_spot_footprints", o.overlap.same_spot_footprints)
      .finish();
  Section(top, "normals")
      .read("window_radius", o.grid_normals.window_radius)
      .read("max_neighbor_distance_mm", o.grid_normals.max_neighbor_distance_mm)
      .read("min_neighbors", o.grid_normals.min_neighbors)
      .finish();
  // One knob for every noise-adaptive limit (docs/pipeline.md): the decoder's smoothing gate, the
  // flying-pixel limit and the fusion agreement.
  double noise_factor = o.noise_factor;
  Section(top, "noise").read("factor", noise_factor).finish();
  o.noise_factor = noise_factor;
  o.decode.noise_factor = static_cast<float>(noise_factor);
  Section(top, "model").read("voxel_mm", o.voxel_mm).read("normal_neighbors", o.normal_neighbors).finish();
  std::string mesh_mode = core::mesh_mode_name(o.mesh.mode);
  std::string mesh_formats = core::mesh_formats_text(o.mesh_formats);
  Section(top, "mesh")
      .read("enabled", o.build_mesh)
      .read("mode", mesh_mode)
      .read("formats", mesh_formats)
      .read("cell_mm", o.mesh.cell_mm)
      .read("cell_spacing_factor", o.mesh.cell_spacing_factor)
      .read("min_cell_mm", o.mesh.min_cell_mm)
      .read("kernel_factor", o.mesh.kernel_factor)
      .read("adaptivity", o.mesh.adaptivity)
      .read("trim_factor", o.mesh.trim_factor)
      .read("fill_holes_mm", o.mesh.fill_holes_mm)
      .read("max_triangles", o.mesh.max_triangles)
      .read("simplify_tolerance_mm", o.mesh.simplify_tolerance_mm)
      .finish();
  if (!core::parse_mesh_mode(mesh_mode, o.mesh.mode))
    throw std::invalid_argument("config: mesh.mode must be \"raw\" or \"watertight\", not \"" + mesh_mode + "\"");
  if (const std::string why = core::parse_mesh_formats(mesh_formats, o.mesh_formats); !why.empty())
    throw std::invalid_argument("config: mesh.formats: " + why);
  top.finish();
}

}  // namespace

void apply_config(const json& config, core::ReconstructionOptions& o) {
  try {
    apply_sections(config, o);
  } catch (const slproto::JsonFieldError& e) {
    throw std::invalid_argument(std::string("config: ") + e.what());
  }
  o.check();
}

core::ReconstructionOptions load_config(const std::string& path) {
  auto text = slproto::read_whole_file(path);
  if (!text) throw io::IoError(text.error().message);
  json config;
  try {
    config = slproto::parse_json_strict(*text);
  } catch (const slproto::JsonFieldError& e) {
    throw io::IoError(path + ": " + e.what());
  }
  core::ReconstructionOptions options;
  try {
    apply_config(config, options);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(path + ": " + e.what());
  }
  return options;
}

json config_to_json(const core::ReconstructionOptions& o) {
  return {
      {"decode",
       {{"bit_depth", o.decode.bit_depth},
        {"min_contrast_dn", o.decode.min_contrast_dn},
        {"min_modulation_dn", o.decode.min_modulation_dn},
        {"saturation_dn", o.decode.saturation_dn},
        {"smoothing_radius", o.decode.smoothing_radius},
        {"quadratic_radius", o.decode.quadratic_radius},
        {"smoothing_max_deviation_px", o.decode.smoothing_max_deviation_px}}},
      {"triangulate",
       {{"newton_iterations", o.triangulate.newton_iterations},
        {"max_residual_px", o.triangulate.max_residual_px},
        {"min_depth_mm", o.triangulate.min_depth_mm},
        {"max_depth_mm", o.triangulate.max_depth_mm}}},
      {"fusion", {{"agreement_mm", o.fusion.agreement_mm}}},
      {"flying_pixels",
       {{"enabled", o.remove_flying_pixels},
        {"max_abs_mm", o.flying_pixels.max_abs_mm},
        {"relative", o.flying_pixels.relative}}},
      {"turntable_denoise",
       {{"enabled", o.denoise_turntable},
        {"min_height_mm", o.turntable_denoise.min_height_mm},
        {"max_height_mm", o.turntable_denoise.max_height_mm},
        {"radius_mm", o.turntable_denoise.radius_mm}}},
      {"registration",
       {{"enabled", o.register_views},
        {"mode", core::refinement_mode_name(o.registration.mode)},
        {"gates_mm", o.registration.icp.gates_mm},
        {"max_normal_angle_deg", o.registration.icp.max_normal_angle_deg},
        {"source_points_per_view", o.registration.icp.source_points_per_view},
        {"close_loop", o.registration.close_loop},
        {"turntable_prior_deg", o.registration.turntable_prior_deg},
        {"turntable_prior_mm", o.registration.turntable_prior_mm}}},
      {"outliers", {{"enabled", o.remove_outliers}, {"k", o.outliers.k}, {"std_ratio", o.outliers.std_ratio}}},
      {"depth_smoothing",
       {{"enabled", o.smooth_depth},
        {"window_radius_mm", o.depth_smoothing.window_radius_mm},
        {"max_window_radius_px", o.depth_smoothing.max_window_radius_px},
        {"max_depth_slope", o.depth_smoothing.max_depth_slope},
        {"min_neighbors", o.depth_smoothing.min_neighbors}}},
      {"view_selection",
       {{"enabled", o.select_best_views},
        {"max_incidence_deg", o.overlap.max_incidence_deg},
        {"same_spot_mm", o.overlap.same_spot_mm},
        {"same_spot_footprints", o.overlap.same_spot_footprints}}},
      {"normals",
       {{"window_radius", o.grid_normals.window_radius},
        {"max_neighbor_distance_mm", o.grid_normals.max_neighbor_distance_mm},
        {"min_neighbors", o.grid_normals.min_neighbors}}},
      {"noise", {{"factor", o.noise_factor}}},
      {"model", {{"voxel_mm", o.voxel_mm}, {"normal_neighbors", o.normal_neighbors}}},
      {"mesh",
       {{"enabled", o.build_mesh},
        {"mode", core::mesh_mode_name(o.mesh.mode)},
        {"formats", core::mesh_formats_text(o.mesh_formats)},
        {"cell_mm", o.mesh.cell_mm},
        {"cell_spacing_factor", o.mesh.cell_spacing_factor},
        {"min_cell_mm", o.mesh.min_cell_mm},
        {"kernel_factor", o.mesh.kernel_factor},
        {"adaptivity", o.mesh.adaptivity},
        {"trim_factor", o.mesh.trim_factor},
        {"fill_holes_mm", o.mesh.fill_holes_mm},
        {"max_triangles", o.mesh.max_triangles},
        {"simplify_tolerance_mm", o.mesh.simplify_tolerance_mm}}},
  };
}

}  // namespace slscan::app
