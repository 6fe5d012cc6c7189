// The truth-free feature figures (core/feature_metrology.hpp) as report.json / --json objects
// and as the lines `slscan measure` and `slscan scan --measure-ballbar` print: VDI/VDE 2634-2
// PF, PS, SD and F, each with PASS / FAIL against its stated maximum permissible error.
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "slscan/core/feature_metrology.hpp"

namespace slscan::app {

// Maximum permissible errors in um (--mpe-pf, --mpe-ps, --mpe-sd, --mpe-f); unset = not judged.
struct MpeLimits {
  std::optional<double> pf_um, ps_um, sd_um, f_um;
};

// The region rule in words, with its parameters (docs/inspection.md).
std::string region_rule_text(const core::FeatureRule& rule);
nlohmann::json region_rule_json(const core::FeatureRule& rule);

nlohmann::json sphere_feature_to_json(const core::SphereFeature& sphere, double calibrated_diameter_mm,
                                      const MpeLimits& mpe);
// Keeps the keys report.json always had (centre_distance_mm, distance_error_um, spheres[].diameter_mm).
nlohmann::json ball_bar_features_to_json(const core::BallBarFeatures& bar,
                                         std::array<double, 2> calibrated_diameters_mm, double reference_length_mm,
                                         const core::FeatureRule& rule, const MpeLimits& mpe);
nlohmann::json plane_feature_to_json(const core::PlaneFeature& plane, const core::FeatureRule& rule,
                                     const MpeLimits& mpe);

// Lines for a person, from one of the objects above ("ball_bar", "sphere" or "plane").
std::string feature_text(const std::string& kind, const nlohmann::json& figures);
// False when any judged figure in the object is outside its MPE.
bool all_within_mpe(const nlohmann::json& figures);

}  // namespace slscan::app
