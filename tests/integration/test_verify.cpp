// slscan verify (issue 18, docs/calibration.md "Checking a calibration"): the real slscand on
// the sim board (small rig, the 50 mm sphere) and the real slscan. The rig's exact calibration
// must hold; the same calibration with the projectors 0.5 % farther from the camera (a bumped
// projector, a rig that was taken apart) must not, and verify must say so from the scan alone.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "processes.hpp"
#include "slproto/calibration.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using slscan::testing::Finished;
using slscan::testing::read_text;
using slscan::testing::run;
using slscan::testing::Slscand;

class Verify : public slscan::testing::SuiteFolder<Verify> {
 protected:
  static void SetUpTestSuite() {
    SuiteFolder::SetUpTestSuite();
    // The same rig with both projectors 0.5 % farther from the camera: a calibration gone wrong.
    auto calibration = slproto::load_calibration((dir_ / "calib.json").string());
    ASSERT_TRUE(calibration.ok()) << calibration.error().message;
    for (auto& projector : calibration->projectors)
      for (double& t : projector.cam_from_proj.t) t *= 1.005;
    ASSERT_TRUE(slproto::save_calibration((dir_ / "bumped.json").string(), *calibration).ok());
  }
  // Three views keep the test short; the sphere is whole in them.
  static Finished verify(const Slscand& daemon, const std::string& calibration, const std::string& out,
                         std::vector<std::string> limits) {
    std::vector<std::string> args{
        SLSCAN_BIN,      "verify",        "--connect",   daemon.address(), "--calib",     calibration, "--out",  out,
        "--exposure-us", "2000",          "--period-us", "5000",           "--settle-ms", "20",        "--mesh", "none",
        "--sphere",      "--diameter-mm", "50",          "--angles",       "0",           "120",       "240"};
    args.insert(args.end(), limits.begin(), limits.end());
    return run(args, dir_ / out);
  }
};

TEST_F(Verify, TheExactCalibrationHoldsAndABumpedProjectorFails) {
  Slscand daemon(dir_ / "slscand");
  const fs::path good = dir_ / "good";
  const Finished pass =
      verify(daemon, (dir_ / "calib.json").string(), good.string(), {"--mpe-ps", "40", "--mpe-pf", "80"});
  ASSERT_EQ(pass.exit_code, 0) << pass.out << pass.err;
  EXPECT_NE(pass.out.find("calibration check: PASS: " + (dir_ / "calib.json").string() + " holds"), std::string::npos)
      << pass.out;
  const json verdict = json::parse(read_text(good / "verify.json"));
  EXPECT_EQ(verdict["verdict"], "PASS");
  EXPECT_EQ(verdict["artefact"], "sphere");
  EXPECT_EQ(verdict["calibration"]["file"], (dir_ / "calib.json").string());
  EXPECT_EQ(verdict["calibration"]["sha256"].get<std::string>().size(), 64u);
  ASSERT_TRUE(verdict["sphere"].is_object()) << verdict.dump(2);
  EXPECT_TRUE(fs::exists(good / "report.json"));
  EXPECT_TRUE(fs::exists(good / "capture.slcap"));

  const fs::path bumped = dir_ / "bumped";
  const Finished fail =
      verify(daemon, (dir_ / "bumped.json").string(), bumped.string(), {"--mpe-ps", "40", "--mpe-pf", "80"});
  EXPECT_EQ(fail.exit_code, 7) << fail.out << fail.err;
  EXPECT_NE(fail.out.find("calibration check: FAIL: " + (dir_ / "bumped.json").string() + " no longer holds"),
            std::string::npos)
      << fail.out;
  EXPECT_NE(fail.out.find("slscan calibrate --connect 127.0.0.1:"), std::string::npos) << fail.out;
  const json failed = json::parse(read_text(bumped / "verify.json"));
  EXPECT_EQ(failed["verdict"], "FAIL");
}

TEST_F(Verify, ALimitTheArtefactCannotGiveIsRefusedBeforeScanning) {
  Slscand daemon(dir_ / "slscand-limits");
  const Finished none = verify(daemon, (dir_ / "calib.json").string(), (dir_ / "none").string(), {});
  EXPECT_EQ(none.exit_code, 1);
  EXPECT_NE(none.err.find("verify needs at least one limit"), std::string::npos) << none.err;
  const Finished flatness = verify(daemon, (dir_ / "calib.json").string(), (dir_ / "f").string(), {"--mpe-f", "10"});
  EXPECT_EQ(flatness.exit_code, 1);
  EXPECT_NE(flatness.err.find("--mpe-f is a plane's"), std::string::npos) << flatness.err;
  EXPECT_FALSE(fs::exists(dir_ / "none" / "capture.slcap"));
  EXPECT_FALSE(fs::exists(dir_ / "f" / "capture.slcap"));
}

}  // namespace
