#include "config.hpp"

#include <fstream>
#include <sstream>

#include "slscan/io/ply.hpp"

namespace slscan::app {

using nlohmann::json;

namespace {

// Reads the listed keys of one section into their fields; any other key is an error.
class Section {
 public:
  Section(const json& parent, const std::string& name) : name_(name) {
    auto it = parent.find(name);
    if (it == parent.end()) return;
    if (!it->is_object()) throw std::invalid_argument("config: '" + name + "' must be an object");
    object_ = &*it;
  }
  template <class T>
  Section& read(const char* key, T& field) {
    seen_.push_back(key);
    if (!object_) return *this;
    auto it = object_->find(key);
    if (it == object_->end()) return *this;
    try {
      field = it->get<T>();
    } catch (const json::exception&) {
      throw std::invalid_argument("config: '" + name_ + "." + key + "' has the wrong type (" + it->dump() + ")");
    }
    return *this;
  }
  void finish() const {
    if (!object_) return;
    for (const auto& [key, value] : object_->items())
      if (std::find(seen_.begin(), seen_.end(), key) == seen_.end())
        throw std::invalid_argument("config: unknown key '" + name_ + "." + key + "'");
  }

 private:
  std::string name_;
  const json* object_ = nullptr;
  std::vector<std::string> seen_;
};

}  // namespace

void apply_config(const json& config, core::ReconstructionOptions& o) {
  if (!config.is_object()) throw std::invalid_argument("config: the top level must be an object");
  static const char* sections[] = {
      "decode",       "triangulate", "fusion",          "flying_pixels",  "turntable_denoise",
      "registration", "outliers",    "depth_smoothing", "view_selection", "model",
      "mesh",         "normals"};
  for (const auto& [key, value] : config.items())
    if (std::find(std::begin(sections), std::end(sections), key) == std::end(sections))
      throw std::invalid_argument("config: unknown section '" + key + "'");
  Section(config, "decode")
      .read("bit_depth", o.decode.bit_depth)
      .read("min_contrast_dn", o.decode.min_contrast_dn)
      .read("min_modulation_dn", o.decode.min_modulation_dn)
      .read("saturation_dn", o.decode.saturation_dn)
      .read("smoothing_radius", o.decode.smoothing_radius)
      .read("smoothing_max_deviation_px", o.decode.smoothing_max_deviation_px)
      .finish();
  Section(config, "triangulate")
      .read("newton_iterations", o.triangulate.newton_iterations)
      .read("max_residual_px", o.triangulate.max_residual_px)
      .read("min_depth_mm", o.triangulate.min_depth_mm)
      .read("max_depth_mm", o.triangulate.max_depth_mm)
      .finish();
  Section(config, "fusion").read("agreement_mm", o.fusion.agreement_mm).finish();
  Section(config, "flying_pixels")
      .read("enabled", o.remove_flying_pixels)
      .read("max_abs_mm", o.flying_pixels.max_abs_mm)
      .read("relative", o.flying_pixels.relative)
      .finish();
  Section(config, "turntable_denoise")
      .read("enabled", o.denoise_turntable)
      .read("min_height_mm", o.turntable_denoise.min_height_mm)
      .read("max_height_mm", o.turntable_denoise.max_height_mm)
      .read("radius_mm", o.turntable_denoise.radius_mm)
      .finish();
  std::string mode = o.registration.mode == core::RefinementMode::joint ? "joint" : "sequential";
  Section(config, "registration")
      .read("enabled", o.register_views)
      .read("mode", mode)
      .read("gates_mm", o.registration.icp.gates_mm)
      .read("max_normal_angle_deg", o.registration.icp.max_normal_angle_deg)
      .read("source_points_per_view", o.registration.icp.source_points_per_view)
      .read("close_loop", o.registration.close_loop)
      .read("turntable_prior_deg", o.registration.turntable_prior_deg)
      .read("turntable_prior_mm", o.registration.turntable_prior_mm)
      .finish();
  if (mode == "joint")
    o.registration.mode = core::RefinementMode::joint;
  else if (mode == "sequential")
    o.registration.mode = core::RefinementMode::sequential;
  else
    throw std::invalid_argument("config: registration.mode must be \"joint\" or \"sequential\", not \"" + mode + "\"");
  Section(config, "outliers")
      .read("enabled", o.remove_outliers)
      .read("k", o.outliers.k)
      .read("std_ratio", o.outliers.std_ratio)
      .finish();
  Section(config, "depth_smoothing")
      .read("enabled", o.smooth_depth)
      .read("window_radius_mm", o.depth_smoothing.window_radius_mm)
      .read("max_window_radius_px", o.depth_smoothing.max_window_radius_px)
      .read("max_depth_slope", o.depth_smoothing.max_depth_slope)
      .read("min_neighbors", o.depth_smoothing.min_neighbors)
      .finish();
  Section(config, "view_selection")
      .read("enabled", o.select_best_views)
      .read("max_incidence_deg", o.overlap.max_incidence_deg)
      .read("same_spot_mm", o.overlap.same_spot_mm)
      .read("same_spot_footprints", o.overlap.same_spot_footprints)
      .finish();
  Section(config, "normals")
      .read("window_radius", o.grid_normals.window_radius)
      .read("max_neighbor_distance_mm", o.grid_normals.max_neighbor_distance_mm)
      .read("min_neighbors", o.grid_normals.min_neighbors)
      .finish();
  Section(config, "model").read("voxel_mm", o.voxel_mm).read("normal_neighbors", o.normal_neighbors).finish();
  Section(config, "mesh")
      .read("enabled", o.build_mesh)
      .read("resolution", o.mesh.resolution)
      .read("density_trim_ratio", o.mesh.density_trim_ratio)
      .finish();
  o.check();
}

core::ReconstructionOptions load_config(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw io::IoError(path + ": cannot open the config file");
  std::stringstream text;
  text << in.rdbuf();
  json config;
  try {
    config = json::parse(text.str());
  } catch (const json::parse_error& e) {
    throw io::IoError(path + ": not valid JSON (" + e.what() + ")");
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
        {"mode", o.registration.mode == core::RefinementMode::joint ? "joint" : "sequential"},
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
      {"model", {{"voxel_mm", o.voxel_mm}, {"normal_neighbors", o.normal_neighbors}}},
      {"mesh",
       {{"enabled", o.build_mesh},
        {"resolution", o.mesh.resolution},
        {"density_trim_ratio", o.mesh.density_trim_ratio}}},
  };
}

}  // namespace slscan::app
