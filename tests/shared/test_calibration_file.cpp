#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>

#include "slproto/calibration.hpp"

namespace slproto {
namespace {

RigCalibration example() {
  RigCalibration cal;
  cal.camera = {640, 512, 1200.5, 1201.25, 319.5, 255.5, {-0.08, 0.01, 0.0002, -0.0001, 0.0}};
  cal.projectors[0].intrinsics = {1140, 912, 1500, 1500, 570, 900, {0.01, 0, 0, 0, 0}};
  cal.projectors[0].cam_from_proj = RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, 0.3);
  cal.projectors[0].cam_from_proj.t = {-150, 0, 20};
  cal.projectors[1] = cal.projectors[0];
  cal.projectors[1].cam_from_proj = RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, -0.3);
  cal.projectors[1].cam_from_proj.t = {150, 0, 20};
  cal.turntable.cam_from_table.t = {0, 50, 600};
  cal.source = "unit test";
  cal.created_by = "test_calibration_file";
  return cal;
}

TEST(Calibration, JsonRoundTripIsExact) {
  const RigCalibration cal = example();
  auto parsed = parse_calibration(format_calibration(cal));
  ASSERT_TRUE(parsed.ok()) << parsed.error().message;
  EXPECT_EQ(*parsed, cal);
}

TEST(Calibration, PlanFieldsAddedLaterAreOptional) {
  RigCalibration cal = example();
  cal.pattern_plan.phase_steps = 0;
  cal.pattern_plan.period_px = 2;
  cal.pattern_plan.complementary_bit = false;
  cal.pattern_plan.inverse_gray = true;
  cal.pattern_plan.gray_low_bits = GrayLowBits::slstudio_parity;
  std::string text = format_calibration(cal);
  auto parsed = parse_calibration(text);
  ASSERT_TRUE(parsed.ok()) << parsed.error().message;
  EXPECT_EQ(*parsed, cal);
  // A file written before inverse_gray and gray_low_bits existed reads as false / centre.
  auto without = [&](std::string t, const std::string& key) {
    const auto pos = t.find("\"" + key + "\"");
    const auto end = t.find_first_of(",}", pos);
    t.erase(pos, end - pos + (t[end] == ',' ? 1 : 0));
    return t;
  };
  const RigCalibration old = example();
  auto read_old = parse_calibration(without(without(format_calibration(old), "inverse_gray"), "gray_low_bits"));
  ASSERT_TRUE(read_old.ok()) << read_old.error().message;
  EXPECT_EQ(*read_old, old);
  const auto pos = text.find("\"slstudio_parity\"");
  ASSERT_NE(pos, std::string::npos);
  text.replace(pos, 17, "\"opencv\"");
  parsed = parse_calibration(text, "cal.json");
  ASSERT_FALSE(parsed.ok());
  EXPECT_NE(parsed.error().message.find("pattern_plan.gray_low_bits: expected \"centre\" or \"slstudio_parity\""),
            std::string::npos)
      << parsed.error().message;
}

TEST(Calibration, MissingFieldIsNamed) {
  std::string text = format_calibration(example());
  const auto pos = text.find("\"fy\"");
  ASSERT_NE(pos, std::string::npos);
  text.replace(pos, 4, "\"fz\"");
  auto parsed = parse_calibration(text, "cal.json");
  ASSERT_FALSE(parsed.ok());
  EXPECT_EQ(parsed.error().code, Errc::malformed);
  EXPECT_NE(parsed.error().message.find("cal.json"), std::string::npos) << parsed.error().message;
  EXPECT_NE(parsed.error().message.find("camera.fy: missing"), std::string::npos) << parsed.error().message;
}

TEST(Calibration, WrongVersionAndImpossibleValuesAreRejected) {
  RigCalibration cal = example();
  std::string text = format_calibration(cal);
  const auto pos = text.find("\"format_version\": 1");
  ASSERT_NE(pos, std::string::npos);
  text.replace(pos, 19, "\"format_version\": 7");
  auto parsed = parse_calibration(text);
  ASSERT_FALSE(parsed.ok());
  EXPECT_EQ(parsed.error().code, Errc::wrong_version);

  cal.camera.fx = -3;
  parsed = parse_calibration(format_calibration(cal));
  ASSERT_FALSE(parsed.ok());
  EXPECT_NE(parsed.error().message.find("focal"), std::string::npos);

  cal = example();
  cal.projectors[1].cam_from_proj.R[0] = 2.0;  // not a rotation
  parsed = parse_calibration(format_calibration(cal));
  ASSERT_FALSE(parsed.ok());
  EXPECT_NE(parsed.error().message.find("projectors.right.cam_from_proj"), std::string::npos) << parsed.error().message;

  EXPECT_FALSE(parse_calibration("{ not json").ok());
  EXPECT_FALSE(parse_calibration(format_calibration(example()).substr(0, 300)).ok());
}

TEST(Calibration, SaveIsAtomicAndLoadReadsItBack) {
  const auto dir = std::filesystem::temp_directory_path() / ("slscan_cal_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "calib.json").string();
  ASSERT_TRUE(save_calibration(path, example()).ok());
  auto loaded = load_calibration(path);
  ASSERT_TRUE(loaded.ok()) << loaded.error().message;
  EXPECT_EQ(*loaded, example());
  // No temporary left behind.
  int files = 0;
  for ([[maybe_unused]] const auto& entry : std::filesystem::directory_iterator(dir)) ++files;
  EXPECT_EQ(files, 1);
  // An invalid calibration is refused and leaves the existing file untouched.
  RigCalibration bad = example();
  bad.turntable.platform_radius_mm = -1;
  EXPECT_FALSE(save_calibration(path, bad).ok());
  EXPECT_TRUE(load_calibration(path).ok());
  auto missing = load_calibration((dir / "nope.json").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, Errc::io_error);
  std::filesystem::remove_all(dir);
}

TEST(PinholeModel, UndistortInvertsDistortAcrossTheImage) {
  PinholeModel cam{2464, 2056, 5000, 5000, 1231.5, 1027.5, {-0.08, 0.02, 0.0005, -0.0003, 0.001}};
  for (double u = -0.5; u <= 2463.5; u += 123.1)
    for (double v = -0.5; v <= 2055.5; v += 102.7) {
      double x, y;
      ASSERT_TRUE(cam.pixel_to_ray(u, v, x, y));
      double u2, v2;
      ASSERT_TRUE(cam.project({x * 700, y * 700, 700}, u2, v2));
      EXPECT_NEAR(u2, u, 1e-9);
      EXPECT_NEAR(v2, v, 1e-9);
    }
}

TEST(RigidTransform, AxisRotationMatchesRodriguesAndComposes) {
  const Vec3 axis{0, 0, 1}, centre{10, 0, 0};
  const RigidTransform quarter = RigidTransform::rotation_about_axis(axis, centre, std::numbers::pi / 2);
  const Vec3 p = quarter.apply({11, 0, 0});  // one unit right of the centre turns to one unit up
  EXPECT_NEAR(p[0], 10, 1e-12);
  EXPECT_NEAR(p[1], 1, 1e-12);
  const RigidTransform half = quarter * quarter;
  const Vec3 q = half.apply({11, 0, 0});
  EXPECT_NEAR(q[0], 9, 1e-12);
  const Vec3 back = half.inverse().apply(q);
  EXPECT_NEAR(back[0], 11, 1e-12);
  EXPECT_NEAR(back[1], 0, 1e-12);
  EXPECT_TRUE(half.check("half").ok());
}

}  // namespace
}  // namespace slproto
