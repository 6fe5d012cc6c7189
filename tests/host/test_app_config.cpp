#include <gtest/gtest.h>

#include "config.hpp"

namespace slscan::app {
namespace {

using nlohmann::json;

TEST(AppConfig, AppliesValuesAndRoundTrips) {
  core::ReconstructionOptions options;
  apply_config(json::parse(R"({"fusion": {"agreement_mm": 0.35}, "registration": {"mode": "sequential",
      "gates_mm": [1.0, 0.3], "turntable_prior_deg": 0.2}, "mesh": {"enabled": false}, "model": {"voxel_mm": 0.2}})"),
               options);
  EXPECT_FLOAT_EQ(options.fusion.agreement_mm, 0.35f);
  EXPECT_EQ(options.registration.mode, core::RefinementMode::sequential);
  EXPECT_EQ(options.registration.icp.gates_mm, (std::vector<double>{1.0, 0.3}));
  EXPECT_DOUBLE_EQ(options.registration.turntable_prior_deg, 0.2);
  EXPECT_DOUBLE_EQ(options.registration.turntable_prior_mm, 0.05);  // untouched: the default
  EXPECT_FALSE(options.build_mesh);
  EXPECT_DOUBLE_EQ(options.voxel_mm, 0.2);
  apply_config(json::parse(R"({"decode": {"smoothing_radius": 0}, "flying_pixels": {"enabled": false},
      "turntable_denoise": {"enabled": false}})"),
               options);
  EXPECT_EQ(options.decode.smoothing_radius, 0);
  EXPECT_FALSE(options.remove_flying_pixels);
  EXPECT_FALSE(options.denoise_turntable);
  EXPECT_FLOAT_EQ(options.fusion.agreement_mm, 0.35f) << "a second config leaves the first's values";
  apply_config(json::parse(R"({"depth_smoothing": {"enabled": false, "window_radius_mm": 0.3},
      "view_selection": {"max_incidence_deg": 70}})"),
               options);
  EXPECT_FALSE(options.smooth_depth);
  EXPECT_DOUBLE_EQ(options.depth_smoothing.window_radius_mm, 0.3);
  EXPECT_TRUE(options.select_best_views);
  EXPECT_DOUBLE_EQ(options.overlap.max_incidence_deg, 70);
  core::ReconstructionOptions refused;
  EXPECT_THROW(apply_config(json::parse(R"({"view_selection": {"max_incidence_deg": 95}})"), refused),
               std::invalid_argument);
  // What a report records can be fed back and gives the same parameters.
  core::ReconstructionOptions again;
  apply_config(config_to_json(options), again);
  EXPECT_EQ(config_to_json(again), config_to_json(options));
}

TEST(AppConfig, MisspeltOrMistypedKeysAreNamed) {
  core::ReconstructionOptions options;
  try {
    apply_config(json::parse(R"({"fusion": {"agreement": 0.3}})"), options);
    FAIL() << "unknown key accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("fusion.agreement"), std::string::npos) << e.what();
  }
  try {
    apply_config(json::parse(R"({"fusion": {"agreement_mm": "wide"}})"), options);
    FAIL() << "string accepted for a number";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("fusion.agreement_mm"), std::string::npos) << e.what();
  }
  EXPECT_THROW(apply_config(json::parse(R"({"fuson": {}})"), options), std::invalid_argument);
  EXPECT_THROW(apply_config(json::parse(R"({"registration": {"mode": "magic"}})"), options), std::invalid_argument);
  EXPECT_THROW(apply_config(json::parse(R"({"model": {"voxel_mm": -1}})"), options), std::invalid_argument);
  EXPECT_THROW(apply_config(json::parse(R"({"decode": {"smoothing_radius": 5}})"), options), std::invalid_argument);
}

}  // namespace
}  // namespace slscan::app
