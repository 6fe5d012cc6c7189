// `slscan calibrate --connect` against slscand on the sim board (boards/sim.toml, small rig),
// as two processes over loopback: the host asks for each pose of the pose set, the sim board
// places its checkerboard there (ScanRequest.calibration_target) and steps its turntable for the
// table poses, the host checks each pose and writes the capture folder pose by pose, then
// solves. Checked: the calibration against the rig's truth (the tolerances of
// tests/host/test_calibration_rig.cpp, which calibrates the virtual rig's rendered capture), the
// folder recalibrating to the identical file, a capture cut by slscand dying: a clear
// message, the completed poses kept, and --resume finishing the capture; the user quitting
// (poses kept, coverage shown per pose), a pose taken again refused as too similar, and Ctrl-C
// during a pose.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>

#include "slproto/calibration.hpp"
#include "slrig/rig.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A child process with stdin from a file (/dev/null unless given) and stdout / stderr in files.
class Child {
 public:
  Child(std::vector<std::string> args, const fs::path& log_stem, const std::string& stdin_path = "/dev/null")
      : out_(log_stem.string() + ".out"), err_(log_stem.string() + ".err"), name_(args.at(0)) {
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, stdin_path.c_str(), O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, out_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, err_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    const int rc = posix_spawn(&pid_, argv[0], &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    if (rc != 0) throw std::runtime_error("cannot start " + name_ + ": " + std::strerror(rc));
  }
  ~Child() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;

  // Waits for the exit (killing the child after `timeout`); the exit code.
  int wait(std::chrono::seconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    int status = 0;
    while (::waitpid(pid_, &status, WNOHANG) == 0) {
      if (std::chrono::steady_clock::now() > deadline) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, &status, 0);
        pid_ = -1;
        throw std::runtime_error(name_ + " did not finish within " + std::to_string(timeout.count()) +
                                 " s (stderr: " + err_ + ")");
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    pid_ = -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  }
  void signal(int number) {
    if (pid_ > 0) ::kill(pid_, number);
  }
  void kill() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  std::string out() const { return read_bytes(out_); }
  std::string err() const { return read_bytes(err_); }
  const std::string& out_path() const { return out_; }

 private:
  std::string out_, err_, name_;
  pid_t pid_ = -1;
};

// slscand on the sim board on an ephemeral loopback port: the port from its "listening on" line.
class Slscand {
 public:
  explicit Slscand(const fs::path& log_stem)
      : child_({SLSCAND_BIN, "--board", SLSCAN_SOURCE_DIR "/boards/sim.toml", "--port", "0", "--no-realtime"},
               log_stem) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (port_ == 0) {
      const std::string text = child_.out();
      if (const auto at = text.find("listening on "); at != std::string::npos) {
        const auto end = text.find('\n', at);
        if (end != std::string::npos) {
          const std::string line = text.substr(at, end - at);
          port_ = std::stoi(line.substr(line.rfind(':') + 1));
          break;
        }
      }
      if (std::chrono::steady_clock::now() > deadline)
        throw std::runtime_error("slscand did not start listening (its log: " + child_.err() + ")");
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  void kill() { child_.kill(); }

 private:
  Child child_;
  int port_ = 0;
};

std::size_t poses_in(const fs::path& folder) {
  const std::string text = read_bytes(folder / "manifest.json");
  if (text.empty()) return 0;
  return json::parse(text).at("poses").size();
}

// The calibration against the sim board's rig (its scene without objects: the rig itself).
void expect_close_to_the_rigs_truth(const fs::path& calibration_file, const fs::path& report_file) {
  auto loaded = slproto::load_calibration(calibration_file.string());
  ASSERT_TRUE(loaded.ok()) << loaded.error().message;
  const slproto::RigCalibration& cal = *loaded;
  slrig::Scene scene = slrig::scene_preset("sphere", slrig::RigSize::small).value();
  scene.objects.clear();
  const slproto::RigCalibration truth = slrig::ground_truth_calibration(scene);

  EXPECT_LT(std::abs(100 * (cal.camera.fx / truth.camera.fx - 1)), 0.1);
  EXPECT_LT(std::abs(100 * (cal.camera.fy / truth.camera.fy - 1)), 0.1);
  EXPECT_LT(std::abs(cal.camera.cx - truth.camera.cx), 1.0);
  EXPECT_LT(std::abs(cal.camera.cy - truth.camera.cy), 1.0);
  EXPECT_LT(cal.camera_reprojection_rms_px, 0.1);
  for (std::size_t s = 0; s < 2; ++s) {
    const auto& p = cal.projectors[s];
    const auto& t = truth.projectors[s];
    EXPECT_LT(std::abs(100 * (p.intrinsics.fx / t.intrinsics.fx - 1)), 0.2) << "side " << s;
    EXPECT_LT(std::abs(100 * (p.intrinsics.fy / t.intrinsics.fy - 1)), 0.2) << "side " << s;
    double d2 = 0;
    for (std::size_t i = 0; i < 3; ++i) d2 += std::pow(p.cam_from_proj.t[i] - t.cam_from_proj.t[i], 2);
    EXPECT_LT(std::sqrt(d2), 0.5) << "side " << s;
    // The angle of R_est R_true^T.
    double trace = 0;
    for (std::size_t i = 0; i < 3; ++i)
      for (std::size_t k = 0; k < 3; ++k) trace += p.cam_from_proj.R[3 * i + k] * t.cam_from_proj.R[3 * i + k];
    EXPECT_LT(std::acos(std::clamp((trace - 1) / 2, -1.0, 1.0)) * 180 / M_PI, 0.075) << "side " << s;
    EXPECT_LT(p.reprojection_rms_px, 0.15) << "side " << s;
  }
  const auto n = cal.turntable.axis_direction(), n_true = truth.turntable.axis_direction();
  const double cos_axis = n[0] * n_true[0] + n[1] * n_true[1] + n[2] * n_true[2];
  EXPECT_LT(std::acos(std::clamp(cos_axis, -1.0, 1.0)) * 180 / M_PI, 0.05);
  const auto c = truth.turntable.axis_point(), o = cal.turntable.axis_point();
  const std::array<double, 3> diff{c[0] - o[0], c[1] - o[1], c[2] - o[2]};
  const double plane = diff[0] * n[0] + diff[1] * n[1] + diff[2] * n[2];
  const double position =
      std::sqrt(std::max(0.0, diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2] - plane * plane));
  EXPECT_LT(position, 0.385);
  // The rendered capture's test holds the plane to 0.19 mm (one noise realisation: +0.055 mm).
  // Through slscand every scan is its own exposure set (other noise): measured +0.19 and
  // +0.12 mm in two runs, so 0.25 mm here (the full rig's target is 0.05 mm, scaled 0.19).
  EXPECT_LT(std::abs(plane), 0.25);
  // The sim's table lands exactly on every commanded angle: each step is 60 deg.
  const json report = json::parse(read_bytes(report_file));
  EXPECT_EQ(report.at("camera_views").get<int>(), 20);
  EXPECT_TRUE(report.at("skipped").empty()) << report.at("skipped").dump();
  const json& steps = report.at("turntable");
  ASSERT_EQ(steps.size(), 6u);
  for (std::size_t i = 1; i < steps.size(); ++i)
    EXPECT_NEAR(steps[i].at("step_deg").get<double>(), 60.0, 0.02) << steps[i].at("pose");
  std::printf(
      "calibration vs the rig's truth: camera fx %+.4f %%, cx %+.3f px, RMS %.4f px; axis position %.4f mm, "
      "plane %+.4f mm\n",
      100 * (cal.camera.fx / truth.camera.fx - 1), cal.camera.cx - truth.camera.cx, cal.camera_reprojection_rms_px,
      position, plane);
}

class CalibrateConnect : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_calconnect_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  fs::path dir_;
};

// --auto end to end: 14 free poses and 6 table poses through slscand, the capture folder
// written as they arrive, the calibration within the tolerances of the rendered capture's.
TEST_F(CalibrateConnect, AutoCaptureThroughSlscandMatchesTheRigsTruth) {
  Slscand daemon(dir_ / "slscand");
  const auto start = std::chrono::steady_clock::now();
  Child calibrate({SLSCAN_BIN, "calibrate", "--connect", daemon.address(), "--auto", "--exposure-us", "2000",
                   "--period-us", "5000", "--settle-ms", "50", "--write-capture", (dir_ / "capture").string(), "--out",
                   (dir_ / "calib.json").string(), "--report", (dir_ / "report.json").string()},
                  dir_ / "calibrate");
  ASSERT_EQ(calibrate.wait(std::chrono::seconds(1500)), 0) << calibrate.err();
  std::printf("calibrate --connect --auto: %.1f s\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  // Every pose was reported found and lit.
  const std::string log = calibrate.err() + calibrate.out();
  EXPECT_NE(log.find("free 0: board found (48 corners)"), std::string::npos) << log;
  EXPECT_NE(log.find("table 300: board found"), std::string::npos) << log;
  expect_close_to_the_rigs_truth(dir_ / "calib.json", dir_ / "report.json");
  EXPECT_EQ(poses_in(dir_ / "capture"), 20u);

  // The folder recalibrates to the identical file.
  Child again(
      {SLSCAN_BIN, "--quiet", "calibrate", (dir_ / "capture").string(), "--out", (dir_ / "again.json").string()},
      dir_ / "again");
  ASSERT_EQ(again.wait(std::chrono::seconds(600)), 0) << again.err();
  EXPECT_EQ(read_bytes(dir_ / "again.json"), read_bytes(dir_ / "calib.json"));
}

// slscand dies mid-capture: the host says so, naming the folder and --resume; the completed
// poses are in the folder; --resume on a restarted slscand takes the rest and calibrates.
TEST_F(CalibrateConnect, DisconnectKeepsThePosesAndResumeCompletes) {
  const fs::path folder = dir_ / "capture";
  {
    Slscand daemon(dir_ / "slscand1");
    Child calibrate(
        {SLSCAN_BIN, "calibrate", "--connect", daemon.address(), "--auto", "--exposure-us", "2000", "--period-us",
         "5000", "--settle-ms", "50", "--write-capture", folder.string(), "--out", (dir_ / "calib.json").string()},
        dir_ / "cut");
    // Poll the manifest (no fixed delay): once two poses are on disk, the board goes away.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(900);
    while (poses_in(folder) < 2) {
      ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "no two poses written: " << calibrate.err();
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    daemon.kill();
    EXPECT_EQ(calibrate.wait(std::chrono::seconds(120)), 3) << calibrate.err();
    const std::string err = calibrate.err();
    EXPECT_NE(err.find("complete poses are in " + folder.string() + " (--resume " + folder.string() + " continues)"),
              std::string::npos)
        << err;
    EXPECT_FALSE(fs::exists(dir_ / "calib.json"));
  }
  const std::size_t kept = poses_in(folder);
  ASSERT_GE(kept, 2u);
  ASSERT_LT(kept, 20u);
  const std::string first_pose_image = read_bytes(folder / "pose00" / "left_columns_00.png");
  ASSERT_FALSE(first_pose_image.empty());

  Slscand daemon(dir_ / "slscand2");
  Child resume({SLSCAN_BIN, "calibrate", "--connect", daemon.address(), "--auto", "--exposure-us", "2000",
                "--period-us", "5000", "--settle-ms", "50", "--resume", folder.string(), "--out",
                (dir_ / "calib.json").string(), "--report", (dir_ / "report.json").string()},
               dir_ / "resume");
  ASSERT_EQ(resume.wait(std::chrono::seconds(1500)), 0) << resume.err();
  EXPECT_NE(resume.err().find("resuming " + folder.string() + ": " + std::to_string(kept) + " of 20 poses"),
            std::string::npos)
      << resume.err();
  EXPECT_EQ(poses_in(folder), 20u);
  EXPECT_EQ(read_bytes(folder / "pose00" / "left_columns_00.png"), first_pose_image);  // kept, not retaken
  expect_close_to_the_rigs_truth(dir_ / "calib.json", dir_ / "report.json");
}

// The user at the keyboard: Enter, Enter, then q before the third pose. The two poses taken are
// in the folder and the message says how to resume. Then the folder is made to hold 'free 1'
// under the name 'free 0' (as if the user had set the second pose for the first): resuming with
// --auto takes 'free 1' again, which is refused as too similar, naming both, exit 4.
TEST_F(CalibrateConnect, QuitKeepsThePosesAndAPoseTakenAgainIsRefused) {
  const fs::path folder = dir_ / "capture";
  {
    std::ofstream keys(dir_ / "keys");
    keys << "\n\nq\n";
  }
  Slscand daemon(dir_ / "slscand");
  Child calibrate(
      {SLSCAN_BIN, "calibrate", "--connect", daemon.address(), "--exposure-us", "2000", "--period-us", "5000",
       "--settle-ms", "50", "--write-capture", folder.string(), "--out", (dir_ / "calib.json").string()},
      dir_ / "quit", (dir_ / "keys").string());
  EXPECT_EQ(calibrate.wait(std::chrono::seconds(900)), 130) << calibrate.err();  // as Ctrl-C
  const std::string err = calibrate.err();
  EXPECT_NE(err.find("stopped before free 2: the 2 complete poses are in " + folder.string() + " (--resume " +
                     folder.string() + " continues)"),
            std::string::npos)
      << err;
  // The live coverage after each pose: the share of the image, no depth before 3 poses.
  EXPECT_NE((err + calibrate.out()).find("free 1: coverage image "), std::string::npos) << err << calibrate.out();
  EXPECT_NE((err + calibrate.out()).find("over 2 poses; depth known from 3 poses on"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir_ / "calib.json"));
  ASSERT_EQ(poses_in(folder), 2u);

  // 'free 1''s frames as pose 0, named 'free 0'.
  json manifest = json::parse(read_bytes(folder / "manifest.json"));
  json frames = json::array();
  for (json frame : manifest.at("frames"))
    if (frame.at("pose").get<int>() == 1) {
      frame["pose"] = 0;
      frames.push_back(frame);
    }
  ASSERT_FALSE(frames.empty());
  manifest["frames"] = frames;
  manifest["poses"].erase(1);
  std::ofstream(folder / "manifest.json") << manifest.dump(1);

  Child resume(
      {SLSCAN_BIN, "calibrate", "--connect", daemon.address(), "--auto", "--exposure-us", "2000", "--period-us", "5000",
       "--settle-ms", "50", "--resume", folder.string(), "--out", (dir_ / "calib.json").string()},
      dir_ / "resume");
  EXPECT_EQ(resume.wait(std::chrono::seconds(900)), 4) << resume.err();
  const std::string refused = resume.err();
  EXPECT_NE(refused.find("free 1: too similar to 'free 0'"), std::string::npos) << refused;
  EXPECT_NE(refused.find("the 1 complete pose is in " + folder.string()), std::string::npos) << refused;
  EXPECT_EQ(poses_in(folder), 1u);
  EXPECT_FALSE(fs::exists(dir_ / "calib.json"));
}

// Ctrl-C during a pose: slscan aborts the scan on the board, says which pose was cut and where
// the complete ones are, exit 130; the folder holds only complete poses.
TEST_F(CalibrateConnect, CtrlCDuringAPoseKeepsTheCompleteOnes) {
  const fs::path folder = dir_ / "capture";
  Slscand daemon(dir_ / "slscand");
  Child calibrate(
      {SLSCAN_BIN, "calibrate", "--connect", daemon.address(), "--auto", "--exposure-us", "2000", "--period-us", "5000",
       "--settle-ms", "50", "--write-capture", folder.string(), "--out", (dir_ / "calib.json").string()},
      dir_ / "interrupted");
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(900);
  while (poses_in(folder) < 1) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "no pose written: " << calibrate.err();
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  calibrate.signal(SIGINT);
  EXPECT_EQ(calibrate.wait(std::chrono::seconds(120)), 130) << calibrate.err();
  const std::string err = calibrate.err();
  std::printf("after Ctrl-C: %s", err.substr(err.rfind("warning:")).c_str());
  EXPECT_NE(err.find("interrupted during free "), std::string::npos) << err;
  EXPECT_NE(err.find("complete pose"), std::string::npos) << err;
  EXPECT_NE(err.find("(--resume " + folder.string() + " continues)"), std::string::npos) << err;
  const std::size_t kept = poses_in(folder);
  EXPECT_GE(kept, 1u);
  EXPECT_LT(kept, 20u);
  EXPECT_FALSE(fs::exists(dir_ / "calib.json"));
}

}  // namespace
