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

TEST(Calibration, UnknownAndDuplicateKeysAreRefused) {
  std::string text = format_calibration(example());
  const auto pos = text.find("\"fy\"");
  ASSERT_NE(pos, std::string::npos);
  std::string unknown = text;
  unknown.insert(pos, "\"skew\": 0.0, ");
  auto parsed = parse_calibration(unknown, "cal.json");
  ASSERT_FALSE(parsed.ok());
  EXPECT_EQ(parsed.error().message, "cal.json: camera.skew: unknown field");
  std::string twice = text;
  twice.insert(pos, "\"fx\": 1.0, ");
  parsed = parse_calibration(twice, "cal.json");
  ASSERT_FALSE(parsed.ok());
  EXPECT_EQ(parsed.error().message, "cal.json: camera.fx: duplicate key");
  // A width beyond int is refused, never wrapped into a plausible one.
  std::string wide = text;
  const auto width = wide.find("\"width\": 640");
  ASSERT_NE(width, std::string::npos);
  wide.replace(width, 14, "\"width\": 4294967936");
  parsed = parse_calibration(wide, "cal.json");
  ASSERT_FALSE(parsed.ok());
  EXPECT_NE(parsed.error().message.find("camera.width: 4294967936 is out of range"), std::string::npos)
      << parsed.error().message;
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

// Issue 17: camera.fx 1e20 parsed, passed check() and crashed reprocessing (lround of a pixel
// coordinate of 1e20). Every value is held to physical bounds when a calibration is read, and
// the message names the field and shows the value in a few digits.
TEST(Calibration, AbsurdButParseableValuesAreRefusedNamingTheField) {
  struct Case {
    const char* what;
    void (*edit)(RigCalibration&);
    const char* message;  // expected in the error
  };
  const Case cases[] = {
      {"fx 1e20", [](RigCalibration& c) { c.camera.fx = 1e20; }, "camera.fx: 1e+20 px is not a focal length"},
      {"fx 1e100", [](RigCalibration& c) { c.camera.fx = 1e100; }, "camera.fx: 1e+100 px"},
      {"fx 1e308", [](RigCalibration& c) { c.camera.fx = 1e308; }, "camera.fx: 1e+308 px"},
      {"fy tiny", [](RigCalibration& c) { c.camera.fy = 1e-3; }, "camera.fy: 0.001 px"},
      {"cx far", [](RigCalibration& c) { c.camera.cx = 1e9; }, "camera.cx: 1e+09 lies far outside"},
      {"k1", [](RigCalibration& c) { c.camera.distortion.k1 = 1e12; }, "camera.distortion.k1: 1e+12 is out of range"},
      {"p2", [](RigCalibration& c) { c.camera.distortion.p2 = -5; }, "camera.distortion.p2: -5 is out of range"},
      {"projector fx", [](RigCalibration& c) { c.projectors[1].intrinsics.fx = 1e20; },
       "projectors.right.intrinsics.fx: 1e+20 px"},
      {"projector t", [](RigCalibration& c) { c.projectors[0].cam_from_proj.t[2] = 1e300; },
       "projectors.left.cam_from_proj.t: 1e+300 mm from the camera is out of range"},
      {"table t", [](RigCalibration& c) { c.turntable.cam_from_table.t[0] = -3e7; },
       "turntable.cam_from_table.t: 3e+07 mm"},
      {"radius", [](RigCalibration& c) { c.turntable.platform_radius_mm = 1e200; },
       "turntable.platform_radius_mm: 1e+200 is out of range"},
      {"rms", [](RigCalibration& c) { c.camera_reprojection_rms_px = -1; },
       "camera_reprojection_rms_px: -1 is out of range"},
  };
  for (const Case& c : cases) {
    RigCalibration cal = example();
    c.edit(cal);
    auto parsed = parse_calibration(format_calibration(cal), "cal.json");
    ASSERT_FALSE(parsed.ok()) << c.what;
    EXPECT_EQ(parsed.error().code, Errc::invalid_argument) << c.what;
    EXPECT_NE(parsed.error().message.find(std::string("cal.json: ") + c.message), std::string::npos)
        << c.what << ": " << parsed.error().message;
    EXPECT_LT(parsed.error().message.size(), 300u) << c.what << ": " << parsed.error().message;
    EXPECT_FALSE(save_calibration("/nonexistent/never-written.json", cal).ok()) << c.what;
  }
  // The bounds leave real lenses alone: a fisheye (f = 0.2 x side, strong distortion), a long
  // lens (50 x side), the placeholder turntable 100 m away.
  RigCalibration wide = example();
  wide.camera.fx = wide.camera.fy = 130;
  wide.camera.distortion = {-0.9, 0.6, 0.01, -0.01, -0.2};
  wide.projectors[0].intrinsics.fx = 50 * 1140;
  wide.turntable.cam_from_table.t = {0, 0, 100000};
  wide.turntable.platform_radius_mm = 1e6;
  auto parsed = parse_calibration(format_calibration(wide), "cal.json");
  EXPECT_TRUE(parsed.ok()) << parsed.error().message;
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
