#include "feature_report.hpp"

#include <cmath>
#include <cstdio>

namespace slscan::app {
namespace {

using json = nlohmann::json;

std::string fmt(const char* format, auto... args) {
  char buffer[400];
  std::snprintf(buffer, sizeof buffer, format, args...);
  return buffer;
}

// One judged figure: its value, the MPE and PASS / FAIL, or "not judged" without an MPE.
json judged(double value_um, const std::optional<double>& mpe_um) {
  const core::Verdict v = core::judge(value_um, mpe_um);
  json out = {{"value_um", value_um}};
  if (v.mpe_um) {
    out["mpe_um"] = *v.mpe_um;
    out["verdict"] = v.pass ? "PASS" : "FAIL";
  } else {
    out["verdict"] = "not judged (no MPE given)";
  }
  return out;
}

std::string verdict_text(const json& figure) {
  if (!figure.contains("mpe_um")) return "";
  return fmt("  %s (MPE %.1f um)", figure["verdict"].get<std::string>().c_str(), figure["mpe_um"].get<double>());
}

json vec(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

}  // namespace

std::string region_rule_text(const core::FeatureRule& rule) {
  return fmt(
      "points within %.2f mm of the robust fit (RANSAC, then least squares), outside a cone around each joint "
      "(attached points %.2f-%.2f mm beyond the surface, cone = their widest direction + %.1f deg); unconstrained "
      "least squares on them with up to %.1f %% of the points left out (VDI/VDE 2634-2), the figure with every "
      "point beside it",
      rule.band_mm, rule.band_mm, rule.band_mm + rule.attachment_shell_mm, rule.cone_margin_deg,
      100 * rule.exclude_fraction);
}

json region_rule_json(const core::FeatureRule& rule) {
  return {{"text", region_rule_text(rule)},
          {"band_mm", rule.band_mm},
          {"attachment_shell_mm", rule.attachment_shell_mm},
          {"cone_margin_deg", rule.cone_margin_deg},
          {"min_attachment_points", rule.min_attachment_points},
          {"exclude_fraction", rule.exclude_fraction}};
}

json sphere_feature_to_json(const core::SphereFeature& s, double calibrated_diameter_mm, const MpeLimits& mpe) {
  const core::SphereFit& fit = s.probing.fit;
  json joints = json::array();
  for (const auto& j : s.joints)
    joints.push_back(
        {{"axis", vec(j.axis)}, {"half_angle_deg", j.half_angle_deg}, {"attachment_points", j.attachment_points}});
  return {{"centre_mm", vec(fit.centre)},
          {"diameter_mm", 2 * fit.radius_mm},
          {"calibrated_diameter_mm", calibrated_diameter_mm},
          {"pf", judged(s.probing.form_um, mpe.pf_um)},
          {"pf_all_points_um", s.probing.form_all_um},
          {"ps", judged(s.probing.size_um, mpe.ps_um)},
          {"rms_um", 1e3 * fit.rms_mm},
          {"points", s.region.size()},
          {"left_out", s.probing.excluded},
          {"band_points", s.band_points},
          {"cone_points", s.cone_points},
          {"joints", joints}};
}

json ball_bar_features_to_json(const core::BallBarFeatures& bar, std::array<double, 2> calibrated_diameters_mm,
                               double reference_length_mm, const core::FeatureRule& rule, const MpeLimits& mpe) {
  json spheres = json::array();
  for (std::size_t i = 0; i < 2; ++i)
    spheres.push_back(sphere_feature_to_json(bar.spheres[i], calibrated_diameters_mm[i], mpe));
  return {{"procedure", "VDI/VDE 2634-2 from the scan alone (no ground truth)"},
          {"region_rule", region_rule_json(rule)},
          {"centre_distance_mm", bar.centre_distance_mm},
          {"reference_distance_mm", reference_length_mm},
          {"distance_error_um", bar.sd_um},
          {"sd", judged(bar.sd_um, mpe.sd_um)},
          {"spheres", spheres}};
}

json plane_feature_to_json(const core::PlaneFeature& p, const core::FeatureRule& rule, const MpeLimits& mpe) {
  const core::PlaneFit& fit = p.flatness.fit;
  return {{"procedure", "VDI/VDE 2634-2 from the scan alone (no ground truth)"},
          {"region_rule", region_rule_json(rule)},
          {"normal", vec(fit.normal)},
          {"centroid_mm", vec(fit.centroid)},
          {"f", judged(p.flatness.flatness_um, mpe.f_um)},
          {"f_all_points_um", p.flatness.flatness_all_um},
          {"rms_um", 1e3 * fit.rms_mm},
          {"points", p.region_points},
          {"left_out", p.flatness.excluded}};
}

std::string feature_text(const std::string& kind, const json& f) {
  auto sphere_lines = [](const json& s, const std::string& name) {
    const auto& joints = s["joints"];
    std::string cones;
    for (const auto& j : joints)
      cones += fmt("%s%.1f deg", cones.empty() ? "" : ", ", j["half_angle_deg"].get<double>());
    return fmt("  %s: PF %.1f um (all points %.1f um)%s\n", name.c_str(), s["pf"]["value_um"].get<double>(),
               s["pf_all_points_um"].get<double>(), verdict_text(s["pf"]).c_str()) +
           fmt("  %*s  PS %+.1f um (diameter %.4f mm, calibrated %.4f mm)%s\n", static_cast<int>(name.size()), "",
               s["ps"]["value_um"].get<double>(), s["diameter_mm"].get<double>(),
               s["calibrated_diameter_mm"].get<double>(), verdict_text(s["ps"]).c_str()) +
           fmt("  %*s  %zu points (%zu left out), fit RMS %.1f um; %zu in %zu joint cone(s)%s%s%s\n",
               static_cast<int>(name.size()), "", s["points"].get<std::size_t>(), s["left_out"].get<std::size_t>(),
               s["rms_um"].get<double>(), s["cone_points"].get<std::size_t>(), joints.size(),
               cones.empty() ? "" : " of ", cones.c_str(), "");
  };
  std::string out;
  if (kind == "ball_bar") {
    out += fmt("ball bar: SD %+.1f um (centre distance %.4f mm, reference %.4f mm)%s\n",
               f["sd"]["value_um"].get<double>(), f["centre_distance_mm"].get<double>(),
               f["reference_distance_mm"].get<double>(), verdict_text(f["sd"]).c_str());
    for (std::size_t i = 0; i < f["spheres"].size(); ++i) out += sphere_lines(f["spheres"][i], fmt("sphere %zu", i));
  } else if (kind == "sphere") {
    out += "sphere:\n" + sphere_lines(f, "sphere");
  } else if (kind == "plane") {
    out += fmt("plane: F %.1f um (all points %.1f um)%s, %zu points (%zu left out), fit RMS %.1f um\n",
               f["f"]["value_um"].get<double>(), f["f_all_points_um"].get<double>(), verdict_text(f["f"]).c_str(),
               f["points"].get<std::size_t>(), f["left_out"].get<std::size_t>(), f["rms_um"].get<double>());
  }
  if (f.contains("region_rule")) out += "region: " + f["region_rule"]["text"].get<std::string>() + "\n";
  return out;
}

bool all_within_mpe(const json& figures) {
  if (figures.is_object()) {
    if (figures.contains("verdict") && figures["verdict"] == "FAIL") return false;
    for (const auto& [key, value] : figures.items())
      if (!all_within_mpe(value)) return false;
  } else if (figures.is_array()) {
    for (const auto& value : figures)
      if (!all_within_mpe(value)) return false;
  }
  return true;
}

}  // namespace slscan::app
