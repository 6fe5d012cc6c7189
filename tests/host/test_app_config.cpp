#include <gtest/gtest.h>

#include <fstream>
#include <stdexcept>
#include <string>

#include "config.hpp"
#include "slscan/core/registration.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::app {
namespace {

using nlohmann::json;

TEST(AppConfig, AppliesValuesAndRoundTrips) {
  core::ReconstructionOptions options;
  EXPECT_EQ(options.registration.mode, core::RefinementMode::turntable);  // the default
  EXPECT_EQ(config_to_json(options)["registration"]["mode"], "turntable");
  for (const auto mode : {core::RefinementMode::joint, core::RefinementMode::turntable}) {
    core::ReconstructionOptions chosen;
    apply_config(json::parse(std::string(R"({"registration": {"mode": ")") + core::refinement_mode_name(mode) + "\"}}"),
                 chosen);
    EXPECT_EQ(chosen.registration.mode, mode);
  }
  try {
    apply_config(json::parse(R"({"registration": {"mode": "free"}})"), options);
    FAIL() << "an unknown registration mode was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("\"turntable\", \"joint\" or \"sequential\", not \"free\""), std::string::npos)
        << e.what();
  }
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
  apply_config(json::parse(R"({"decode": {"quadratic_radius": 4}})"), options);
  EXPECT_EQ(options.decode.quadratic_radius, 4);
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
  EXPECT_THROW(apply_config(json::parse(R"({"decode": {"quadratic_radius": 2}})"), options), std::invalid_argument);
}

// Issue 17 case 6: {"registration":{"gates_mm":[1e999]}} was an internal error (exit 5). A number
// beyond double is refused naming the file; a gate that is no length (negative, 1e308, none at
// all) names the field, when the config is read rather than when registration runs.
TEST(AppConfig, RegistrationGatesAreBoundedAndNamed) {
  const std::string dir = ::testing::TempDir();
  auto load_error = [&](const std::string& name, const std::string& text) -> std::string {
    const std::string path = dir + "/" + name;
    std::ofstream(path) << text;
    try {
      (void)load_config(path);
    } catch (const std::exception& e) {  // IoError or std::invalid_argument: both exit 2
      EXPECT_TRUE(dynamic_cast<const io::IoError*>(&e) != nullptr ||
                  dynamic_cast<const std::invalid_argument*>(&e) != nullptr)
          << e.what();
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
      return e.what();
    }
    return "";
  };
  EXPECT_NE(load_error("overflow.json", R"({"registration":{"gates_mm":[1e999]}})").find("number overflow"),
            std::string::npos);
  EXPECT_NE(load_error("negative.json", R"({"registration":{"gates_mm":[2, -1]}})")
                .find("config: registration.gates_mm[1]: -1 is out of range (allowed above 0, at most 10000 mm)"),
            std::string::npos)
      << load_error("negative.json", R"({"registration":{"gates_mm":[2, -1]}})");
  EXPECT_NE(
      load_error("huge.json", R"({"registration":{"gates_mm":[1e308]}})").find("registration.gates_mm[0]: 1e+308"),
      std::string::npos)
      << load_error("huge.json", R"({"registration":{"gates_mm":[1e308]}})");
  EXPECT_NE(load_error("none.json", R"({"registration":{"gates_mm":[]}})").find("registration.gates_mm: expected 1"),
            std::string::npos);
  EXPECT_EQ(load_error("fine.json", R"({"registration":{"gates_mm":[4, 1, 0.25]}})"), "");
}

}  // namespace
}  // namespace slscan::app
