// Importing foreign image sequences and calibrations: descriptions that don't match the
// images are refused with a message naming the difference; calibrations in OpenCV's
// K/D/R/T naming read back with the right pose direction.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "slproto/capture.hpp"
#include "slscan/io/capture_replay.hpp"
#include "slscan/io/foreign_calibration.hpp"
#include "slscan/io/image_sequence_import.hpp"
#include "slscan/io/io_error.hpp"

namespace fs = std::filesystem;
using namespace slscan;

namespace {

class Import : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_import_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
    // A 64-column projector, Gray code with 2 low bits left out: period 4, 16 periods, 4 bits.
    for (int i = 0; i < 6; ++i) write_image("f" + std::to_string(i) + ".png", 40, 30, CV_8U, 10 * i);
  }
  void TearDown() override { fs::remove_all(dir_); }
  void write_image(const std::string& name, int w, int h, int type, int value) {
    cv::imwrite((dir_ / name).string(), cv::Mat(h, w, type, cv::Scalar(value)));
  }
  std::string describe(const std::string& extra = "", const std::string& gray_count = "4") {
    return R"({"projector": {"width": 64, "height": 32}, "white": "f0.png", "black": "f1.png",
               "gray": {"files": {"pattern": "f%d.png", "first": 2, "count": )" +
           gray_count + R"(}, "bits_not_projected": 2})" + extra + "}";
  }
  std::string error_of(const std::string& description) {
    try {
      io::read_image_sequence(io::parse_sequence_description(description, dir_.string()));
    } catch (const io::IoError& e) {
      return e.what();
    }
    return "";
  }
  fs::path dir_;
};

TEST_F(Import, GrayWithoutLowBitsIsOurPlanWithALargerPeriod) {
  const io::SequenceDescription d = io::parse_sequence_description(describe(), dir_.string());
  EXPECT_EQ(d.plan.period_px, 4);
  EXPECT_EQ(d.plan.phase_steps, 0);
  EXPECT_FALSE(d.plan.complementary_bit);
  EXPECT_EQ(d.plan.gray_bits(), 4);
  ASSERT_EQ(d.files.size(), 6u);
  EXPECT_EQ(fs::path(d.files[2]).filename(), "f2.png");
  // The top bits of gray(x) are gray(x >> s): the plan's Gray frames are the full code's.
  const slproto::PatternPlan plan(d.plan);
  for (int x = 0; x < 64; ++x)
    for (int bit = 0; bit < 4; ++bit) {
      const float full_code_bit =
          static_cast<float>((slproto::binary_to_gray(static_cast<std::uint32_t>(x)) >> (5 - bit)) & 1u);
      EXPECT_EQ(plan.value(static_cast<std::size_t>(plan.index_of(slproto::PatternKind::gray_bit, bit)), x),
                full_code_bit)
          << "x " << x << " bit " << bit;
    }
  // LSB first reverses the list.
  const auto reversed = io::parse_sequence_description(
      R"({"projector": {"width": 64, "height": 32}, "white": "f0.png", "black": "f1.png",
          "gray": {"files": ["f2.png", "f3.png", "f4.png", "f5.png"], "bit_order": "lsb_first", "bits_not_projected": 2}})",
      dir_.string());
  EXPECT_EQ(fs::path(reversed.files[2]).filename(), "f5.png");
}

TEST_F(Import, MismatchesAreNamed) {
  EXPECT_NE(error_of(describe("", "3")).find("lists 3 frames but a Gray code of 64 projector columns"),
            std::string::npos)
      << error_of(describe("", "3"));
  write_image("f4.png", 41, 30, CV_8U, 0);
  EXPECT_NE(error_of(describe()).find("f4.png (gray_bit 2): the image is 41 x 30, the first image is 40 x 30"),
            std::string::npos)
      << error_of(describe());
  write_image("f4.png", 40, 30, CV_16U, 0);
  EXPECT_NE(error_of(describe()).find("the image is 16-bit, the description says camera.bit_depth 8"),
            std::string::npos)
      << error_of(describe());
  write_image("f4.png", 40, 30, CV_8U, 0);
  const std::string sized = R"(, "camera": {"width": 48, "height": 30})";
  EXPECT_NE(error_of(describe(sized)).find("the image is 40 x 30, the description says 48 x 30"), std::string::npos)
      << error_of(describe(sized));
  fs::remove(dir_ / "f5.png");
  EXPECT_NE(error_of(describe()).find("f5.png (gray_bit 3): no such image file"), std::string::npos)
      << error_of(describe());
  EXPECT_NE(error_of(R"({"projector": {"width": 64, "height": 32}, "white": "f0.png", "black": "f1.png",
      "gray": {"files": ["f2.png"]}, "inverse": ["f3.png"]})")
                .find("inverse"),
            std::string::npos);
  EXPECT_NE(error_of(R"({"projector": {"width": 64, "height": 32}, "white": "f0.png",
      "gray": {"files": ["f2.png"], "bits_not_projected": 5}})")
                .find("white and black frames come as a pair"),
            std::string::npos);
}

TEST_F(Import, InverseGrayFramesFollowTheirBitsAndNeedNoWhiteBlack) {
  for (int i = 0; i < 4; ++i) write_image("i" + std::to_string(i) + ".png", 40, 30, CV_8U, 200 - 10 * i);
  const std::string description = R"({"projector": {"width": 64, "height": 32},
      "gray": {"files": {"pattern": "f%d.png", "first": 2, "count": 4},
               "inverse_files": ["i0.png", "i1.png", "i2.png", "i3.png"],
               "bits_not_projected": 2, "convention": "slstudio"}})";
  const io::SequenceDescription d = io::parse_sequence_description(description, dir_.string());
  EXPECT_TRUE(d.plan.inverse_gray);
  EXPECT_FALSE(d.plan.with_white_black);
  EXPECT_EQ(d.plan.gray_low_bits, slproto::GrayLowBits::slstudio_parity);
  std::vector<std::string> names;
  for (const auto& f : d.files) names.push_back(fs::path(f).filename().string());
  EXPECT_EQ(names,
            (std::vector<std::string>{"f2.png", "i0.png", "f3.png", "i1.png", "f4.png", "i2.png", "f5.png", "i3.png"}));
  // The capture carries the whole plan, inverse frames and convention included.
  const auto sequence = io::read_image_sequence(d);
  io::write_imported_capture((dir_ / "c.slcap").string(), sequence);
  io::replay_capture((dir_ / "c.slcap").string(),
                     [&](const slproto::pb::ScanRequest& request) { EXPECT_EQ(io::plan_of(request).config(), d.plan); },
                     [](const slproto::pb::FrameHeader&, std::span<const std::byte>) {});
  // LSB first reverses both lists alike.
  const auto reversed = io::parse_sequence_description(
      R"({"projector": {"width": 64, "height": 32},
          "gray": {"files": ["f2.png", "f3.png", "f4.png", "f5.png"], "inverse_files": ["i0.png", "i1.png", "i2.png",
                   "i3.png"], "bit_order": "lsb_first", "bits_not_projected": 2}})",
      dir_.string());
  EXPECT_EQ(fs::path(reversed.files[0]).filename(), "f5.png");
  EXPECT_EQ(fs::path(reversed.files[1]).filename(), "i3.png");
  EXPECT_EQ(reversed.plan.gray_low_bits, slproto::GrayLowBits::centre);
}

TEST_F(Import, InverseFramesAndConventionMismatchesAreNamed) {
  auto parse_error = [&](const std::string& description) -> std::string {
    try {
      io::parse_sequence_description(description, dir_.string(), "seq.json");
    } catch (const io::IoError& e) {
      return e.what();
    }
    return "";
  };
  const std::string three_inverses = parse_error(R"({"projector": {"width": 64, "height": 32},
      "gray": {"files": ["f2.png", "f3.png", "f4.png", "f5.png"], "inverse_files": ["i0.png", "i1.png", "i2.png"],
               "bits_not_projected": 2}})");
  EXPECT_NE(three_inverses.find("seq.json: gray.inverse_files lists 3 frames but gray.files lists 4"),
            std::string::npos)
      << three_inverses;
  const std::string convention = parse_error(R"({"projector": {"width": 64, "height": 32}, "white": "f0.png",
      "black": "f1.png", "gray": {"files": ["f2.png", "f3.png", "f4.png", "f5.png"], "bits_not_projected": 2,
      "convention": "opencv"}})");
  EXPECT_NE(convention.find("gray.convention must be \"centre\" or \"slstudio\", got \"opencv\""), std::string::npos)
      << convention;
  const std::string with_phase = parse_error(R"({"projector": {"width": 64, "height": 32}, "white": "f0.png",
      "black": "f1.png", "gray": {"files": ["f2.png", "f3.png", "f4.png"], "convention": "slstudio"},
      "phase": {"files": ["f0.png", "f1.png", "f2.png"], "period_px": 8}})");
  EXPECT_NE(with_phase.find("gray.convention \"slstudio\" is about a Gray code's unshown low bits"), std::string::npos)
      << with_phase;
  const std::string complementary = parse_error(R"({"projector": {"width": 64, "height": 32},
      "gray": {"files": ["f2.png", "f3.png", "f4.png"], "inverse_files": ["i0.png", "i1.png", "i2.png"]},
      "complementary": "f5.png", "phase": {"files": ["f0.png", "f1.png", "f2.png"], "period_px": 8}})");
  EXPECT_NE(complementary.find("the complementary frame needs its inverse too: complementary_inverse"),
            std::string::npos)
      << complementary;
  const std::string old_field = parse_error(R"({"projector": {"width": 64, "height": 32},
      "gray": {"files": ["f2.png"]}, "inverse": ["f3.png"]})");
  EXPECT_NE(old_field.find("list the inverse (negative) Gray frames as gray.inverse_files"), std::string::npos)
      << old_field;
  // Strict at every level, with the path and the nearest known name.
  const std::string misspelt = parse_error(R"({"projector": {"width": 64, "height": 32}, "white": "f0.png",
      "black": "f1.png", "gray": {"files": ["f2.png", "f3.png", "f4.png"]},
      "phase": {"files": ["f0.png", "f1.png", "f2.png"], "period_px": 8, "offset_radians": 0.3}})");
  EXPECT_NE(misspelt.find("seq.json: phase.offset_radians: unknown field; did you mean offset_rad?"), std::string::npos)
      << misspelt;
  const std::string in_projector = parse_error(R"({"projector": {"width": 64, "heigth": 32},
      "gray": {"files": ["f2.png"]}})");
  EXPECT_NE(in_projector.find("projector.heigth: unknown field; did you mean height?"), std::string::npos)
      << in_projector;
  const std::string in_pattern = parse_error(R"({"projector": {"width": 64, "height": 32}, "white": "f0.png",
      "black": "f1.png", "gray": {"files": {"pattern": "f%d.png", "frist": 2, "count": 4}, "bits_not_projected": 2}})");
  EXPECT_NE(in_pattern.find("gray.files.frist: unknown field; did you mean first?"), std::string::npos) << in_pattern;
  const std::string duplicate = parse_error(R"({"projector": {"width": 64, "width": 32}})");
  EXPECT_NE(duplicate.find("duplicate"), std::string::npos) << duplicate;
  const std::string nothing = parse_error(R"({"projector": {"width": 64, "height": 32},
      "gray": {"files": ["f2.png", "f3.png", "f4.png", "f5.png"], "bits_not_projected": 2}})");
  EXPECT_NE(nothing.find("give white and black frames, gray.inverse_files or phase frames"), std::string::npos)
      << nothing;
}

TEST_F(Import, WritesACaptureThatReplaysInPlanOrder) {
  const auto sequence = io::read_image_sequence(io::parse_sequence_description(describe(), dir_.string()));
  io::write_imported_capture((dir_ / "c.slcap").string(), sequence);
  std::vector<std::uint32_t> indices;
  std::vector<int> first_pixel;
  const auto summary =
      io::replay_capture((dir_ / "c.slcap").string(),
                         [&](const slproto::pb::ScanRequest& request) {
                           EXPECT_EQ(io::plan_of(request).config(), sequence.plan.config());
                         },
                         [&](const slproto::pb::FrameHeader& header, std::span<const std::byte> payload) {
                           EXPECT_EQ(header.width(), 40u);
                           EXPECT_EQ(header.projector_id(), 0u);
                           indices.push_back(header.pattern_index());
                           first_pixel.push_back(static_cast<int>(payload[0]));
                         });
  EXPECT_TRUE(summary.done.has_value());
  EXPECT_EQ(indices, (std::vector<std::uint32_t>{0, 1, 2, 3, 4, 5}));
  EXPECT_EQ(first_pixel, (std::vector<int>{0, 10, 20, 30, 40, 50}));
}

TEST_F(Import, OpenCvStereoNamingAndPoseDirection) {
  const std::string path = (dir_ / "stereo.yml").string();
  cv::Mat rvec = (cv::Mat_<double>(3, 1) << 0.0, 0.3, 0.0);
  {
    cv::FileStorage fs(path, cv::FileStorage::WRITE);
    fs << "K1" << (cv::Mat_<double>(3, 3) << 1000, 0, 320, 0, 1001, 240, 0, 0, 1);
    fs << "D1" << (cv::Mat_<double>(1, 5) << -0.1, 0.01, 0, 0, 0);
    fs << "K2" << (cv::Mat_<double>(3, 3) << 1200, 0, 400, 0, 1200, 300, 0, 0, 1);
    fs << "D2" << (cv::Mat_<double>(1, 4) << 0.05, 0, 0, 0);
    fs << "R" << rvec;
    fs << "T" << (cv::Mat_<double>(3, 1) << -100, 0, 10);
  }
  io::ForeignCalibrationOptions options;
  options.camera_width = 640;
  options.camera_height = 480;
  options.projector_width = 800;
  options.projector_height = 600;
  const auto rig = io::read_foreign_calibration(path, options);
  EXPECT_EQ(rig.camera.fy, 1001);
  EXPECT_EQ(rig.camera.distortion.k1, -0.1);
  EXPECT_EQ(rig.projectors[0].intrinsics.distortion.k1, 0.05);
  // proj_from_cam T = (-100, 0, 10): the projector centre in the camera frame is -R^T T.
  const auto proj_from_cam = rig.projectors[0].cam_from_proj.inverse();
  EXPECT_NEAR(proj_from_cam.t[0], -100, 1e-9);
  EXPECT_NEAR(proj_from_cam.R[2], std::sin(0.3), 1e-9);
  EXPECT_EQ(rig.projectors[1], rig.projectors[0]) << "a one-projector rig fills both slots";
  options.pose_direction = io::PoseDirection::cam_from_proj;
  EXPECT_NEAR(io::read_foreign_calibration(path, options).projectors[0].cam_from_proj.t[0], -100, 1e-9);

  options.camera_width = 0;
  try {
    io::read_foreign_calibration(path, options);
    ADD_FAILURE() << "no camera width anywhere";
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("does not give the camera width"), std::string::npos) << e.what();
  }
  {
    cv::FileStorage fs(path, cv::FileStorage::WRITE);
    fs << "K1" << (cv::Mat_<double>(3, 3) << 1000, 0, 320, 0, 1001, 240, 0, 0, 1);
  }
  try {
    io::read_foreign_calibration(path, options);
    ADD_FAILURE() << "no distortion";
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("no known calibration key set fits; the file has the keys K1"),
              std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("calibration_keys"), std::string::npos) << e.what();
  }
}

// Other tools' key names: the built-in sets, an explicit mapping, Kalibr and ROS YAML.
TEST_F(Import, CalibrationKeySetsOfOtherTools) {
  const cv::Mat k1 = (cv::Mat_<double>(3, 3) << 1000, 0, 320, 0, 1001, 240, 0, 0, 1);
  const cv::Mat k2 = (cv::Mat_<double>(3, 3) << 1200, 0, 400, 0, 1200, 300, 0, 0, 1);
  const cv::Mat d1 = (cv::Mat_<double>(1, 5) << -0.1, 0.01, 0, 0, 0);
  const cv::Mat d2 = (cv::Mat_<double>(1, 5) << 0.05, 0, 0, 0, 0);
  const cv::Mat r = cv::Mat::eye(3, 3, CV_64F);
  const cv::Mat t = (cv::Mat_<double>(3, 1) << -100, 0, 10);
  io::ForeignCalibrationOptions options;
  options.camera_width = 640;
  options.camera_height = 480;
  options.projector_width = 800;
  options.projector_height = 600;
  auto expect_rig = [&](const slproto::RigCalibration& rig, double scale = 1) {
    EXPECT_EQ(rig.camera.fy, 1001);
    EXPECT_EQ(rig.camera.distortion.k1, -0.1);
    EXPECT_EQ(rig.projectors[0].intrinsics.fx, 1200);
    EXPECT_NEAR(rig.projectors[0].cam_from_proj.inverse().t[0], -100 * scale, 1e-9);
  };
  // OpenCV's stereo sample: intrinsics.yml and extrinsics.yml.
  {
    cv::FileStorage in((dir_ / "intrinsics.yml").string(), cv::FileStorage::WRITE);
    in << "M1" << k1 << "D1" << d1 << "M2" << k2 << "D2" << d2;
    cv::FileStorage ex((dir_ / "extrinsics.yml").string(), cv::FileStorage::WRITE);
    ex << "R" << r << "T" << t << "R1" << r << "P1" << cv::Mat::eye(3, 4, CV_64F);
  }
  io::ForeignCalibrationOptions two = options;
  two.more_paths = {(dir_ / "extrinsics.yml").string()};
  expect_rig(io::read_foreign_calibration((dir_ / "intrinsics.yml").string(), two));
  try {
    io::read_foreign_calibration((dir_ / "intrinsics.yml").string(), options);
    ADD_FAILURE() << "no pose in intrinsics.yml alone";
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("the file has the keys M1, D1, M2, D2"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("OpenCV stereo sample, lacks R, T"), std::string::npos) << e.what();
  }
  // MATLAB's stereoParametersToOpenCV names.
  {
    cv::FileStorage fs((dir_ / "matlab.yml").string(), cv::FileStorage::WRITE);
    fs << "intrinsicMatrix1" << k1 << "distortionCoefficients1" << d1 << "intrinsicMatrix2" << k2
       << "distortionCoefficients2" << d2 << "rotationMatrix" << r << "translationVector" << t;
  }
  expect_rig(io::read_foreign_calibration((dir_ / "matlab.yml").string(), options));
  // Anything else, named in the description.
  {
    cv::FileStorage fs((dir_ / "custom.xml").string(), cv::FileStorage::WRITE);
    fs << "CamK" << k1 << "CamD" << d1 << "ProK" << k2 << "ProD" << d2 << "Rlp" << r << "Tlp" << t;
  }
  io::ForeignCalibrationOptions mapped = options;
  mapped.keys = io::calibration_keys_from({{"camera_matrix", "CamK"},
                                           {"camera_distortion", "CamD"},
                                           {"projector_matrix", "ProK"},
                                           {"projector_distortion", "ProD"},
                                           {"rotation", "Rlp"},
                                           {"translation", "Tlp"}},
                                          "seq.json");
  expect_rig(io::read_foreign_calibration((dir_ / "custom.xml").string(), mapped));
  EXPECT_THROW(io::calibration_keys_from({{"camera_matrx", "CamK"}}, "seq.json"), io::IoError);
  // Kalibr camchain (metres).
  std::ofstream((dir_ / "camchain.yaml").string()) << R"(cam0:
  camera_model: pinhole
  intrinsics: [1000, 1001, 320, 240]
  distortion_model: radtan
  distortion_coeffs: [-0.1, 0.01, 0, 0]
  resolution: [640, 480]
cam1:
  T_cn_cnm1:
  - [1, 0, 0, -0.1]
  - [0, 1, 0, 0]
  - [0, 0, 1, 0.01]
  - [0, 0, 0, 1]
  camera_model: pinhole
  intrinsics: [1200, 1200, 400, 300]
  distortion_model: radtan
  distortion_coeffs: [0.05, 0, 0, 0]
  resolution: [800, 600]
)";
  expect_rig(io::read_foreign_calibration((dir_ / "camchain.yaml").string(), options));
  // ROS camera_info, one file per device; the projector's P holds Tx = -fx B (metres).
  std::ofstream((dir_ / "camera.yaml").string()) << R"(image_width: 640
image_height: 480
camera_name: camera
camera_matrix:
  rows: 3
  cols: 3
  data: [1000, 0, 320, 0, 1001, 240, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.1, 0.01, 0, 0, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [1000, 0, 320, 0, 0, 1001, 240, 0, 0, 0, 1, 0]
)";
  std::ofstream((dir_ / "projector.yaml").string()) << R"(image_width: 800
image_height: 600
camera_name: projector
camera_matrix:
  rows: 3
  cols: 3
  data: [1200, 0, 400, 0, 1200, 300, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.05, 0, 0, 0, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [1200, 0, 400, 120, 0, 1200, 300, 0, 0, 0, 1, 0]
)";
  io::ForeignCalibrationOptions ros = options;
  ros.more_paths = {(dir_ / "projector.yaml").string()};
  const auto rig = io::read_foreign_calibration((dir_ / "camera.yaml").string(), ros);
  EXPECT_EQ(rig.camera.fy, 1001);
  EXPECT_EQ(rig.projectors[0].intrinsics.fx, 1200);
  EXPECT_NEAR(rig.projectors[0].cam_from_proj.inverse().t[0], 100, 1e-9) << "Tx / fx = 0.1 m";
}

// Issue 17 cases 6 and 7: an import description's wrong types were JSON library errors (exit 5
// "internal error"), an integer past int wrapped, and "g_%999999999d.png" cost 24 s of CPU per 7
// names. Each is refused naming the field.
TEST_F(Import, DescriptionTypesRangesAndPatternWidthsAreChecked) {
  auto parse_error = [&](const std::string& files, const std::string& extra = "") -> std::string {
    const std::string description = R"({"projector": {"width": 64, "height": 32}, "white": "f0.png",
        "black": "f1.png", "gray": {"files": )" +
                                    files + R"(, "bits_not_projected": 2})" + extra + "}";
    try {
      io::parse_sequence_description(description, dir_.string(), "seq.json");
    } catch (const io::IoError& e) {
      return e.what();
    }
    return "";
  };
  const std::string wide = parse_error(R"({"pattern": "g_%999999999d.png", "count": 7})");
  EXPECT_NE(wide.find("seq.json: gray.files.pattern 'g_%999999999d.png': the width 999999999 is over 16"),
            std::string::npos)
      << wide;
  EXPECT_NE(parse_error(R"({"pattern": "g_%17d.png", "count": 4})").find("the width 17 is over 16"), std::string::npos);
  EXPECT_EQ(parse_error(R"({"pattern": "f%016d.png", "count": 4})"), "");  // wide enough for any int
  const std::string first = parse_error(R"({"pattern": "f%d.png", "first": "abc", "count": 4})");
  EXPECT_NE(first.find("seq.json: gray.files.first must be an integer in [0, 1000000], got \"abc\""), std::string::npos)
      << first;
  const std::string count = parse_error(R"({"pattern": "f%d.png", "first": 2, "count": 4294967300})");
  EXPECT_NE(count.find("gray.files.count must be an integer in [1, 4096], got 4294967300"), std::string::npos) << count;
  const std::string axis = parse_error(R"(["f2.png", "f3.png", "f4.png", "f5.png"])", R"(, "axis": 5)");
  EXPECT_NE(axis.find("seq.json: axis must be a string, got 5"), std::string::npos) << axis;
  const std::string order = parse_error(R"(["f2.png", "f3.png", "f4.png", "f5.png"], "bit_order": [1])");
  EXPECT_NE(order.find("seq.json: gray.bit_order must be a string, got [1]"), std::string::npos) << order;
  const std::string bits = [&] {
    try {
      io::parse_sequence_description(R"({"projector": {"width": 64, "height": 32}, "white": "f0.png",
          "black": "f1.png", "gray": {"files": ["f2.png"], "bits_not_projected": "two"}})",
                                     dir_.string(), "seq.json");
    } catch (const io::IoError& e) {
      return std::string(e.what());
    }
    return std::string();
  }();
  EXPECT_NE(bits.find("gray.bits_not_projected must be an integer in [0, 12], got \"two\""), std::string::npos) << bits;
  const std::string width = [&] {
    try {
      io::parse_sequence_description(R"({"projector": {"width": 4294967360, "height": 32}, "gray": {"files": []}})",
                                     dir_.string(), "seq.json");
    } catch (const io::IoError& e) {
      return std::string(e.what());
    }
    return std::string();
  }();
  EXPECT_NE(width.find("projector.width must be an integer in [1, 65535], got 4294967360"), std::string::npos) << width;
}

// Issue 17 case 8, foreign calibrations: an image size past int was wrapped (4294967936 -> 640).
TEST_F(Import, ForeignImageSizesAreRefusedNotWrapped) {
  const std::string path = (dir_ / "stereo.yml").string();
  {
    std::ofstream out(path);
    out << "%YAML:1.0\n---\n"
        << "K1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1000., 0., 320., 0., 1000., 240., 0., 0., "
           "1.]\n"
        << "D1: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [0., 0., 0., 0., 0.]\n"
        << "K2: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1200., 0., 400., 0., 1200., 300., 0., 0., "
           "1.]\n"
        << "D2: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [0., 0., 0., 0., 0.]\n"
        << "R: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [0., 0.3, 0.]\n"
        << "T: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [-100., 0., 10.]\n"
        << "image_width: 4294967936\nimage_height: 480\nprojector_width: 800\nprojector_height: 600\n";
  }
  try {
    const auto rig = io::read_foreign_calibration(path, {});
    ADD_FAILURE() << "read as " << rig.camera.width << " x " << rig.camera.height;
  } catch (const io::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("image_width"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("is not an image size"), std::string::npos) << e.what();
  }
}

// docs/security.md fuzz finding 12: OpenCV's FileStorage hangs on some malformed YAML and
// allocates what a file declares. The parser runs in a child process with a CPU and memory
// budget; the result is exactly the in-process parser's.
TEST_F(Import, ForeignCalibrationParserRunsInABoundedChildProcess) {
  const std::string path = (dir_ / "stereo.yml").string();
  {
    cv::FileStorage fs(path, cv::FileStorage::WRITE);
    fs << "K1" << (cv::Mat_<double>(3, 3) << 1000.125, 0, 320.3, 0, 1001.7, 240.1, 0, 0, 1);
    fs << "D1" << (cv::Mat_<double>(1, 5) << -0.1, 0.01, 1e-3, -2e-4, 0.3);
    fs << "K2" << (cv::Mat_<double>(3, 3) << 1200, 0, 400, 0, 1200, 300, 0, 0, 1);
    fs << "D2" << (cv::Mat_<double>(1, 4) << 0.05, 0, 0, 0);
    fs << "R" << (cv::Mat_<double>(3, 1) << 0.01, 0.3, -0.02);
    fs << "T" << (cv::Mat_<double>(3, 1) << -100.3, 0.7, 10.1);
    fs << "image_width" << 640 << "image_height" << 480 << "projector_width" << 800 << "projector_height" << 600;
  }
  EXPECT_EQ(io::read_foreign_calibration(path), io::read_foreign_calibration_in_process(path));

  auto error_of = [](const std::string& file, const io::ForeignCalibrationOptions& options) {
    try {
      io::read_foreign_calibration(file, options);
    } catch (const io::IoError& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  // The parser's own errors come back unchanged.
  const std::string missing = (dir_ / "missing.yml").string();
  EXPECT_EQ(error_of(missing, {}), missing + ": cannot open the calibration file");

  // The fuzz input's first byte picks the extension (1: .yaml); the file is the rest.
  const std::string hang = (dir_ / "hang.yaml").string();
  {
    std::ifstream in(SLSCAN_SOURCE_DIR "/tests/fuzz/known-hangs/foreign_calibration-timeout-6929d328",
                     std::ios::binary);
    const std::string input{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    ASSERT_EQ(input.at(0) % 4, 1);
    std::ofstream(hang, std::ios::binary) << input.substr(1);
  }
  io::ForeignCalibrationOptions one_second;
  one_second.parser_cpu_seconds = 1;
  const std::string hung = error_of(hang, one_second);
  EXPECT_NE(hung.find("foreign calibration " + hang + ": the parser did not finish within 1 s of CPU time"),
            std::string::npos)
      << hung;

  // OpenCV 4.6's FileStorage XML reader dies (SIGSEGV in libopencv_core) on a cut attribute:
  // the fuzz campaign of 2026-12-04 (docs/security.md, finding 13). The parser's process dies,
  // slscan does not; the message says the parser could not read the file. The first byte 0
  // picks .xml.
  const std::string crash = (dir_ / "crash.xml").string();
  {
    std::ifstream in(SLSCAN_SOURCE_DIR "/tests/fuzz/known-crashes/foreign_calibration-crash-6c9d8286",
                     std::ios::binary);
    const std::string input{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    ASSERT_EQ(input.at(0) % 4, 0);
    std::ofstream(crash, std::ios::binary) << input.substr(1);
  }
  const std::string crashed = error_of(crash, {});
  EXPECT_NE(crashed.find("foreign calibration " + crash + ": the parser "), std::string::npos) << crashed;

#if !defined(__SANITIZE_ADDRESS__)  // sanitizer builds set no address-space limit (ASan's shadow)
  // 16 MB of text against a 4 MB budget: reading it is already too much.
  const std::string big = (dir_ / "big.yml").string();
  {
    std::ofstream out(big);
    out << "%YAML:1.0\n---\nK1: \"" << std::string(16 << 20, 'x') << "\"\n";
  }
  io::ForeignCalibrationOptions small;
  small.parser_memory_mb = 4;
  const std::string memory = error_of(big, small);
  EXPECT_NE(memory.find("foreign calibration " + big + ": the parser needed more than 4 MB of memory"),
            std::string::npos)
      << memory;
  const std::string read = error_of(big, {});
  EXPECT_EQ(read, big + ": not an OpenCV FileStorage, ROS camera_info or Kalibr YAML file, nor our JSON calibration")
      << "within the default budget the same file is read (and refused by OpenCV)";
#endif
}

}  // namespace
