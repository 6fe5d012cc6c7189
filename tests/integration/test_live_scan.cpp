// The product end to end, as a person runs it: slscand on the sim board (small rig, ball bar)
// and slscan as separate processes over loopback. One live scan is made for the whole suite;
// the tests then check what it left: the ball bar's length, report.json's figures, that
// `slscan reprocess` of the recorded capture gives the same bytes, that a capture cut mid-frame
// reprocesses what it holds, and that report.html renders its 3D viewer in headless Chromium.
//
// Calibration: estimated, as on a real rig, by `slscan calibrate --virtual small` (the virtual
// rig's calibration capture: checkerboard at 14 free poses and 6 table angles), which also
// saves the capture folder; the scan then runs with that calibration.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cctype>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <thread>

#include "slproto/calibration.hpp"
#include "slproto/file_util.hpp"
#include "slproto/pattern_plan.hpp"
#include "slrig/rig.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr double reference_distance_mm = 150.1164;
// Small rig (640 x 512): see tests/host/test_app_reprocess.cpp and docs/accuracy.md.
constexpr double distance_tolerance_mm = 0.030;

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

struct Finished {
  int exit_code = -1;
  std::string out, err;
};

// Runs a program to the end with stdout and stderr in files; kills it after `timeout`.
Finished run(std::vector<std::string> args, const fs::path& log_stem, std::chrono::seconds timeout) {
  const std::string out_path = log_stem.string() + ".out", err_path = log_stem.string() + ".err";
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, out_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  std::vector<char*> argv;
  argv.reserve(args.size() + 1);
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) throw std::runtime_error("cannot start " + args[0] + ": " + slproto::errno_text(rc));
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  int status = 0;
  while (::waitpid(pid, &status, WNOHANG) == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      throw std::runtime_error(args[0] + " did not finish within " + std::to_string(timeout.count()) +
                               " s (stderr: " + err_path + ")");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return {WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status), read_bytes(out_path), read_bytes(err_path)};
}

// slscand on a board file, on an ephemeral loopback port, until the suite ends.
class Slscand {
 public:
  Slscand(const std::string& board, const fs::path& log) {
    int out[2];
    if (::pipe2(out, O_CLOEXEC) != 0) throw std::runtime_error("pipe");
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, out[1], STDOUT_FILENO);
    posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    std::vector<std::string> args{SLSCAND_BIN, "--board", board, "--port", "0", "--no-realtime"};
    std::vector<char*> argv;
    argv.reserve(args.size() + 1);
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    const int rc = posix_spawn(&pid_, argv[0], &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    ::close(out[1]);
    if (rc != 0) {
      ::close(out[0]);
      throw std::runtime_error(std::string("cannot start slscand: ") + slproto::errno_text(rc));
    }
    // slscand prints "... listening on ADDR:PORT" when it accepts connections.
    std::string line;
    char c;
    while (port_ == 0 && ::read(out[0], &c, 1) == 1) {
      if (c != '\n') {
        line += c;
        continue;
      }
      if (const auto at = line.find("listening on "); at != std::string::npos)
        port_ = std::stoi(line.substr(line.rfind(':') + 1));
      line.clear();
    }
    ::close(out[0]);
    if (port_ == 0) {
      stop();
      throw std::runtime_error("slscand did not start listening (its log: " + log.string() + ")");
    }
  }
  ~Slscand() { stop(); }
  Slscand(const Slscand&) = delete;
  Slscand& operator=(const Slscand&) = delete;
  int port() const { return port_; }
  void stop() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGTERM);
    ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }

 private:
  pid_t pid_ = -1;
  int port_ = 0;
};

class LiveScan : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("slscan_live_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    auto scene = slrig::scene_preset("ballbar", slrig::RigSize::small);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    scene_ = new slrig::Scene(*scene);
    calibrate_ = new Finished(
        run({SLSCAN_BIN, "calibrate", "--virtual", "small", "--write-capture", (dir_ / "calibration-capture").string(),
             "--out", (dir_ / "calib.json").string(), "--report", (dir_ / "calibration_report.json").string()},
            dir_ / "calibrate", std::chrono::seconds(600)));
    ASSERT_EQ(calibrate_->exit_code, 0) << "slscan calibrate failed:\n" << calibrate_->err;

    std::string board = read_bytes(fs::path(SLSCAN_SOURCE_DIR) / "boards" / "sim.toml");
    const auto at = board.find("scene = \"sphere\"");
    ASSERT_NE(at, std::string::npos) << "boards/sim.toml no longer says scene = \"sphere\"";
    board.replace(at, 16, "scene = \"ballbar\"");
    std::ofstream(dir_ / "board.toml") << board;

    daemon_ = new Slscand((dir_ / "board.toml").string(), dir_ / "slscand.log");
    std::vector<std::string> args{SLSCAN_BIN,
                                  "--json-log",
                                  "scan",
                                  "--connect",
                                  "127.0.0.1:" + std::to_string(daemon_->port()),
                                  "--calib",
                                  (dir_ / "calib.json").string(),
                                  "--out",
                                  (dir_ / "live").string(),
                                  "--exposure-us",
                                  "2000",
                                  "--period-us",
                                  "5000",
                                  "--settle-ms",
                                  "50",
                                  "--measure-ballbar",
                                  "--angles"};
    for (double angle : scene_->view_angles_deg) args.push_back(std::to_string(angle));
    const auto start = std::chrono::steady_clock::now();
    scan_ = new Finished(run(args, dir_ / "scan", std::chrono::seconds(600)));
    scan_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    daemon_->stop();
  }
  static void TearDownTestSuite() {
    delete daemon_;
    delete scan_;
    delete calibrate_;
    delete scene_;
    if (!keep_) fs::remove_all(dir_);
  }
  void TearDown() override {
    if (HasFailure() && !keep_) {
      keep_ = true;
      std::printf("keeping %s (logs, outputs) to look at\n", dir_.c_str());
    }
  }
  void SetUp() override {
    ASSERT_NE(scan_, nullptr);
    ASSERT_EQ(scan_->exit_code, 0) << "slscan scan failed:\n" << scan_->err;
  }
  static json report(const std::string& run_dir) { return json::parse(read_bytes(dir_ / run_dir / "report.json")); }

  static inline fs::path dir_;
  static inline slrig::Scene* scene_ = nullptr;
  static inline Slscand* daemon_ = nullptr;
  static inline Finished* scan_ = nullptr;
  static inline Finished* calibrate_ = nullptr;
  static inline double scan_seconds_ = 0;
  static inline bool keep_ = false;
};

TEST_F(LiveScan, BallBarLengthWithinToleranceFromTheCommandLine) {
  const Finished measure = run({SLSCAN_BIN, "measure", (dir_ / "live" / "model.ply").string(), "--ballbar", "--json"},
                               dir_ / "measure", std::chrono::seconds(120));
  ASSERT_EQ(measure.exit_code, 0) << measure.err;
  const json figures = json::parse(measure.out);
  const double distance = figures["ball_bar"]["centre_distance_mm"].get<double>();
  EXPECT_NEAR(distance, reference_distance_mm, distance_tolerance_mm);
  for (const auto& sphere : figures["ball_bar"]["spheres"]) EXPECT_NEAR(sphere["diameter_mm"], 30.001, 0.030);
  // The scan measured the same model itself and put it in its report.
  EXPECT_DOUBLE_EQ(report("live")["measurement"]["ball_bar"]["centre_distance_mm"].get<double>(), distance);
}

// `slscan calibrate` left a calibration file that loads, a report of every pose, and the
// capture folder it rendered, which calibrates again to the same file.
TEST_F(LiveScan, CalibrationFromTheCommandLine) {
  const auto calibration = slproto::load_calibration((dir_ / "calib.json").string());
  ASSERT_TRUE(calibration.ok()) << calibration.error().message;
  EXPECT_LT(calibration->camera_reprojection_rms_px, 0.1);
  const json report = json::parse(read_bytes(dir_ / "calibration_report.json"));
  EXPECT_EQ(report["camera_views"].get<int>(), 20);
  EXPECT_EQ(report["turntable"].size(), 6u);
  EXPECT_TRUE(report["skipped"].empty()) << report["skipped"].dump();
  ASSERT_TRUE(fs::exists(dir_ / "calibration-capture" / "manifest.json"));
  const Finished again = run({SLSCAN_BIN, "--quiet", "calibrate", (dir_ / "calibration-capture").string(), "--out",
                              (dir_ / "calib-again.json").string()},
                             dir_ / "calibrate-again", std::chrono::seconds(600));
  ASSERT_EQ(again.exit_code, 0) << again.err;
  auto reread = slproto::load_calibration((dir_ / "calib-again.json").string());
  ASSERT_TRUE(reread.ok()) << reread.error().message;
  EXPECT_EQ(*reread, *calibration);
}

TEST_F(LiveScan, ReportHoldsCountsResidualsAndTimings) {
  const json r = report("live");
  const slproto::PatternPlan plan(scene_->pattern_plan);
  const std::size_t views = scene_->view_angles_deg.size();
  EXPECT_EQ(r["capture"]["frames"].get<std::size_t>(), views * 2 * plan.size());
  EXPECT_TRUE(r["capture"]["complete"].get<bool>());
  EXPECT_EQ(r["board"]["name"], "sim");
  EXPECT_EQ(r["board_frames_dropped"].get<std::size_t>(), 0u);
  for (const char* counter : {"frames_lost", "packets_missing", "packets_resent", "resend_requests"})
    EXPECT_EQ(r["camera_link"][counter].get<std::uint64_t>(), 0u) << counter;  // the sim's link is perfect
  // `slscan calibrate --virtual small`: through slscand's sim board, as a scanner is calibrated.
  EXPECT_EQ(r["calibration"]["source"], "virtual rig (small), through slscand on the sim board");

  const json& scan = r["scan"];
  ASSERT_EQ(scan["views"].size(), views);
  std::size_t sum_points = 0;
  for (const auto& view : scan["views"]) {
    SCOPED_TRACE("view " + view["view_index"].dump());
    for (const auto& p : view["projectors"]) {
      EXPECT_TRUE(p["present"].get<bool>());
      // Each stage keeps at most what the one before it passed on.
      const auto decoded = p["decode"]["valid"].get<std::size_t>();
      const auto triangulated = p["triangulate"]["valid"].get<std::size_t>();
      EXPECT_GT(decoded, 10000u);
      EXPECT_LE(triangulated, decoded);
      EXPECT_GT(triangulated, decoded / 2);
      EXPECT_GT(p["decode_ms"].get<double>(), 0.0);
      EXPECT_GT(p["triangulate_ms"].get<double>(), 0.0);
    }
    EXPECT_GT(view["fusion"]["both"].get<std::size_t>(), 1000u);
    // The fuse step's parts, each timed within the whole.
    double parts_ms = 0;
    for (const char* step : {"flying_pixels", "fusion", "denoise", "outliers", "depth_smoothing", "normals"}) {
      ASSERT_TRUE(view["fuse_step_ms"].contains(step)) << step;
      EXPECT_GE(view["fuse_step_ms"][step].get<double>(), 0.0) << step;
      parts_ms += view["fuse_step_ms"][step].get<double>();
    }
    EXPECT_LE(parts_ms, view["fuse_ms"].get<double>());
    const json& denoise = view["turntable_denoise"];
    EXPECT_GT(denoise["below_min_height"].get<std::size_t>(), 1000u) << "the platform is removed";
    EXPECT_EQ(denoise["kept"].get<std::size_t>() + denoise["below_min_height"].get<std::size_t>() +
                  denoise["above_max_height"].get<std::size_t>() + denoise["outside_radius"].get<std::size_t>(),
              denoise["input"].get<std::size_t>());
    EXPECT_GT(view["points"].get<std::size_t>(), 1000u);
    // The small rig's pixel covers ~0.6 mm at the working distance, more than the smoothing
    // window's +-0.5 mm: the report says so and nothing was moved (the full rig smooths with a
    // 3-pixel radius: docs/accuracy.md).
    const json& smoothing = view["depth_smoothing"];
    EXPECT_EQ(smoothing["window_radius_px"].get<int>(), 0) << smoothing.dump();
    EXPECT_EQ(smoothing["full"].get<std::size_t>() + smoothing["partial"].get<std::size_t>(), 0u) << smoothing.dump();
    sum_points += view["points"].get<std::size_t>();
  }
  // The views' clouds are merged whole (outliers are removed per view before that) but for the
  // steep points another view saw better, and the model keeps at most what was merged.
  const std::size_t replaced = scan["model"]["steep_points_replaced"].get<std::size_t>();
  EXPECT_GT(replaced, 0u) << "six views 60 deg apart overlap: some steep points must give way";
  EXPECT_LE(replaced, scan["model"]["steep_points"].get<std::size_t>());
  EXPECT_EQ(scan["model"]["merged_points"].get<std::size_t>() + replaced, sum_points);
  EXPECT_LE(scan["model"]["points"].get<std::size_t>(), sum_points);
  EXPECT_GT(scan["model"]["points"].get<std::size_t>(), sum_points / 2);

  const json& reg = scan["registration"];
  ASSERT_TRUE(reg["applied"].get<bool>()) << reg.dump();
  ASSERT_EQ(reg["views"].size(), views);
  // The default mode: one axis for every view, moved only as far as the estimated calibration
  // was off, and one angle correction per view (the rig's angles are exact; view 0 is the zero).
  EXPECT_EQ(reg["mode"], "turntable");
  EXPECT_LT(reg["axis_tilt_deg"].get<double>(), 0.05) << reg.dump();
  EXPECT_LT(reg["axis_shift_mm"].get<double>(), 0.1) << reg.dump();
  EXPECT_EQ(reg["views"][0]["angle_correction_deg"].get<double>(), 0.0);
  for (const auto& v : reg["views"]) {
    EXPECT_LT(std::abs(v["angle_correction_deg"].get<double>()), 0.1) << reg.dump();
    // Estimated calibration and exact turntable angles: ICP has little to correct and the
    // residual is the small rig's surface noise (~10 um).
    EXPECT_GT(v["residual_rms_mm"].get<double>(), 0.0);
    EXPECT_LT(v["residual_rms_mm"].get<double>(), 0.05);
    EXPECT_LT(std::abs(v["correction_deg"].get<double>()), 0.3);
    EXPECT_GT(v["correspondences"].get<std::size_t>(), 100u);
  }

  // Timings: present, positive and within the wall time of the whole scan.
  ASSERT_FALSE(scan["stage_ms"].empty());
  for (const auto& [stage, ms] : scan["stage_ms"].items()) {
    EXPECT_GE(ms.get<double>(), 0.0) << stage;
    EXPECT_LT(ms.get<double>(), 1000 * scan_seconds_) << stage;
  }
  const double to_model = r["last_frame_to_model_s"].get<double>();
  EXPECT_GT(to_model, 0.0);
  EXPECT_LT(to_model, scan_seconds_);
  ASSERT_FALSE(r["board_timing"].empty());
  for (const auto& event : r["board_timing"]) EXPECT_GT(event["count"].get<std::size_t>(), 0u) << event.dump();

  // Every output the report names is on disk, and nothing is left under a temporary name.
  for (const auto& [key, name] : r["outputs"].items())
    EXPECT_TRUE(fs::exists(dir_ / "live" / name.get<std::string>())) << key;
  for (const auto& entry : fs::recursive_directory_iterator(dir_ / "live"))
    EXPECT_EQ(entry.path().filename().string().find(".tmp"), std::string::npos) << entry.path();
}

// True when text has shape's length and, where shape has '9', a digit, elsewhere shape's own
// character (std::regex trips GCC 12's -Wmaybe-uninitialized in the ASan build).
bool matches_shape(const std::string& text, const std::string& shape) {
  if (text.size() != shape.size()) return false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const bool ok = shape[i] == '9' ? std::isdigit(static_cast<unsigned char>(text[i])) != 0 : text[i] == shape[i];
    if (!ok) return false;
  }
  return true;
}

// --json-log: every line carries its UTC time; the frames' progress has its rate and ETA, the
// reconstruction's stages after the last frame come in order and end at 8/8. The report names
// the run and links the capture it recorded (docs/cli.md).
TEST_F(LiveScan, JsonLogLinesCarryTheirTimeAndProgressFigures) {
  const std::string iso = "9999-99-99T99:99:99.999Z";
  std::istringstream lines(scan_->err);
  std::string line;
  std::size_t parsed = 0, frame_lines = 0;
  json last_frames;
  std::vector<std::string> stages;
  while (std::getline(lines, line)) {
    if (line.empty() || line[0] != '{') continue;
    const json entry = json::parse(line);
    ++parsed;
    ASSERT_TRUE(entry.contains("time") && matches_shape(entry["time"].get<std::string>(), iso)) << line;
    ASSERT_TRUE(entry.contains("level")) << line;
    if (entry["level"] != "progress") continue;
    EXPECT_GE(entry["elapsed_s"].get<double>(), 0.0) << line;
    if (entry["stage"] == "frames") {
      ++frame_lines;
      EXPECT_EQ(entry["unit"], "frames");
      last_frames = entry;
    } else if (entry["stage"] == "reconstruction") {
      stages.push_back(entry["step"].get<std::string>());
    }
  }
  EXPECT_GT(parsed, 0u) << scan_->err;
  const json r = report("live");
  const auto frames = r["capture"]["frames"].get<std::size_t>();
  EXPECT_EQ(frame_lines, frames);
  ASSERT_FALSE(last_frames.is_null());
  EXPECT_EQ(last_frames["done"].get<std::size_t>(), frames);
  EXPECT_EQ(last_frames["total"].get<std::size_t>(), frames);
  ASSERT_TRUE(last_frames.contains("rate_per_s")) << last_frames.dump();
  // The rate is the frames after the first over the time since it.
  EXPECT_NEAR(last_frames["rate_per_s"].get<double>(),
              static_cast<double>(frames - 1) / last_frames["elapsed_s"].get<double>(),
              0.01 * last_frames["rate_per_s"].get<double>() + 0.01);
  EXPECT_EQ(last_frames["eta_s"].get<double>(), 0.0);
  const std::vector<std::string> expected{"wait_for_views", "fuse_remaining", "register", "select_views", "merge",
                                          "voxel",          "normals",        "mesh",     "done"};
  EXPECT_EQ(stages, expected);

  EXPECT_EQ(r["run"]["command"], "scan");
  EXPECT_TRUE(matches_shape(r["run"]["started_utc"].get<std::string>(), "9999-99-99T99:99:99Z"))
      << r["run"]["started_utc"];
  EXPECT_EQ(r["capture"]["sha256"].get<std::string>().size(), 64u);
  EXPECT_EQ(r["calibration"]["sha256"].get<std::string>().size(), 64u);
  EXPECT_GE(r["calibration"]["age_days"].get<double>(), 0.0);
  std::set<std::string> files;
  for (const auto& f : r["files"]) files.insert(f.get<std::string>());
  for (const char* f : {"capture.slcap", "model.ply", "mesh.ply", "report.json", "report.html"})
    EXPECT_TRUE(files.count(f)) << f << " not in " << r["files"].dump();
}

TEST_F(LiveScan, ReprocessOfTheRecordedCaptureIsBitIdentical) {
  const Finished re = run({SLSCAN_BIN, "--quiet", "reprocess", (dir_ / "live" / "capture.slcap").string(), "--calib",
                           (dir_ / "calib.json").string(), "--out", (dir_ / "re").string()},
                          dir_ / "reprocess", std::chrono::seconds(600));
  ASSERT_EQ(re.exit_code, 0) << re.err;
  std::size_t compared = 0;
  for (const auto& entry : fs::recursive_directory_iterator(dir_ / "live")) {
    const fs::path relative = fs::relative(entry.path(), dir_ / "live");
    if (entry.path().extension() != ".ply" && entry.path().extension() != ".stl") continue;
    ASSERT_TRUE(fs::exists(dir_ / "re" / relative)) << relative;
    EXPECT_TRUE(read_bytes(entry.path()) == read_bytes(dir_ / "re" / relative))
        << relative << " differs between the live scan and its reprocessing";
    ++compared;
  }
  EXPECT_GE(compared, 3 + scene_->view_angles_deg.size()) << "model, mesh PLY and STL and every view cloud";
  // Counts and residuals agree exactly; only timings may differ.
  json live = report("live")["scan"], again = report("re")["scan"];
  for (json* s : {&live, &again}) {
    s->erase("stage_ms");
    if (s->contains("mesh")) {
      (*s)["mesh"].erase("mesh_ms");
      (*s)["mesh"].erase("step_ms");
    }
    for (auto& v : (*s)["views"]) {
      v.erase("fuse_ms");
      v.erase("fuse_step_ms");
      for (auto& p : v["projectors"]) {
        p.erase("decode_ms");
        p.erase("triangulate_ms");
      }
    }
  }
  EXPECT_EQ(live, again);
}

TEST_F(LiveScan, CaptureCutMidFrameReprocessesWhatItHolds) {
  const fs::path cut = dir_ / "cut.slcap";
  fs::copy_file(dir_ / "live" / "capture.slcap", cut, fs::copy_options::overwrite_existing);
  // One view's frames are a sixth of the file: cutting 1/12 and a bit lands inside a frame of
  // the last view, as a scan stopped by a lost connection or a full disk leaves it.
  const auto size = fs::file_size(cut);
  fs::resize_file(cut, size - size / 12 - 777);
  const Finished re = run({SLSCAN_BIN, "reprocess", cut.string(), "--calib", (dir_ / "calib.json").string(), "--out",
                           (dir_ / "cut").string()},
                          dir_ / "cut", std::chrono::seconds(600));
  ASSERT_EQ(re.exit_code, 0) << re.err;
  EXPECT_NE(re.err.find("truncated at byte"), std::string::npos) << re.err;
  EXPECT_NE(re.err.find("missing: "), std::string::npos) << re.err;
  const json r = report("cut");
  EXPECT_FALSE(r["capture"]["complete"].get<bool>());
  EXPECT_LT(r["capture"]["truncated_at_byte"].get<std::uintmax_t>(), size);
  ASSERT_FALSE(r["capture"]["missing"].empty());
  const std::size_t views = scene_->view_angles_deg.size();
  // The cut falls in the last view: the views before it are reconstructed, the incomplete one is
  // left out and named.
  EXPECT_EQ(r["scan"]["views"].size(), views - 1);
  const std::string last = "view " + std::to_string(views - 1);
  for (const auto& line : r["capture"]["missing"]) EXPECT_EQ(line.get<std::string>().rfind(last, 0), 0u) << line;
  const slproto::PatternPlan plan(scene_->pattern_plan);
  EXPECT_LT(r["capture"]["frames"].get<std::size_t>(), views * 2 * plan.size());
  EXPECT_GT(r["capture"]["frames"].get<std::size_t>(), (views - 1) * 2 * plan.size());
  // report.html says it too.
  const std::string html = read_bytes(dir_ / "cut" / "report.html");
  EXPECT_NE(html.find("incomplete"), std::string::npos);
  EXPECT_NE(html.find(r["capture"]["missing"][0].get<std::string>().substr(0, 20)), std::string::npos);
}

// The page is loaded the way a person opens it (a file:// URL), with WebGL on SwiftShader.
std::optional<std::string> chromium() {
  for (const char* name : {"/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome"})
    if (fs::exists(name)) return name;
  return std::nullopt;
}

std::vector<std::string> browser_args(const std::string& browser, const fs::path& profile) {
  return {browser,
          "--headless",
          "--no-sandbox",
          "--disable-gpu-sandbox",
          "--use-gl=angle",
          "--use-angle=swiftshader",
          "--enable-unsafe-swiftshader",
          "--no-first-run",
          "--disable-extensions",
          "--user-data-dir=" + profile.string(),
          "--window-size=1280,900",
          "--virtual-time-budget=20000"};
}

TEST_F(LiveScan, ReportHtmlDrawsTheCloudInHeadlessChromium) {
  const auto browser = chromium();
  if (!browser)
    GTEST_SKIP() << "chromium is not installed (scripts/bootstrap.sh installs it): report.html not rendered";
  const fs::path page = dir_ / "live" / "report.html";
  const std::string html = read_bytes(page);
  if (html.find("data-status=\"missing\"") != std::string::npos)
    GTEST_SKIP() << "this slscan was built without the viewer bundle; the report says: "
                 << html.substr(html.find("data-reason=\""), 200);
  const std::string url = "file://" + page.string();

  auto args = browser_args(*browser, dir_ / "profile-dom");
  args.push_back("--dump-dom");
  args.push_back(url);
  const Finished dom = run(args, dir_ / "chromium_dom", std::chrono::seconds(180));
  ASSERT_EQ(dom.exit_code, 0) << dom.err;
  // Plain string search (std::regex trips GCC 12's -Wmaybe-uninitialized in the ASan build).
  const std::size_t tag_at = dom.out.find("<div id=\"viewer\"");
  ASSERT_NE(tag_at, std::string::npos) << dom.out.substr(0, 2000);
  const std::size_t tag_end = dom.out.find('>', tag_at);
  ASSERT_NE(tag_end, std::string::npos) << dom.out.substr(tag_at, 2000);
  const std::string tag = dom.out.substr(tag_at, tag_end + 1 - tag_at);
  const auto attribute = [&](const std::string& name) -> std::string {
    const std::string key = " " + name + "=\"";
    const std::size_t at = tag.find(key);
    if (at == std::string::npos) return {};
    const std::size_t begin = at + key.size();
    const std::size_t end = tag.find('"', begin);
    return end == std::string::npos ? std::string() : tag.substr(begin, end - begin);
  };
  ASSERT_EQ(attribute("data-status"), "drawn") << tag << "\n" << dom.err;
  const std::size_t embedded = std::stoul(attribute("data-points"));
  const std::size_t model_points = report("live")["scan"]["model"]["points"].get<std::size_t>();
  EXPECT_EQ(embedded, std::min<std::size_t>(model_points, 200000));
  EXPECT_EQ(std::stoul(attribute("data-points-drawn")), embedded);
  // The small rig's ~30k points cover ~19k pixels of the 1200 x 560 canvas; an empty one, 0.
  EXPECT_GT(std::stoul(attribute("data-nonblank-pixels")), 5000u) << "the canvas is (nearly) empty";

  // A screenshot, as a person would see it: inside the canvas the cloud is there (~3% of the
  // area at the default zoom) and shaded (many grey levels), not a flat fill.
  args = browser_args(*browser, dir_ / "profile-shot");
  const fs::path shot = dir_ / "report.png";
  args.push_back("--screenshot=" + shot.string());
  args.push_back(url);
  const Finished screenshot = run(args, dir_ / "chromium_shot", std::chrono::seconds(180));
  ASSERT_EQ(screenshot.exit_code, 0) << screenshot.err;
  const cv::Mat image = cv::imread(shot.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(image.empty()) << shot;
  std::vector<int> rect;
  std::stringstream text(attribute("data-canvas-rect"));
  for (std::string part; std::getline(text, part, ',');) rect.push_back(std::stoi(part));
  ASSERT_EQ(rect.size(), 4u);
  const cv::Rect area = cv::Rect(rect[0], rect[1], rect[2], rect[3]) & cv::Rect(0, 0, image.cols, image.rows);
  ASSERT_GT(area.area(), 100000) << "the viewer is not on the first screen";
  const cv::Vec3b background(0x2a, 0x24, 0x20);  // #20242a as BGR
  std::size_t covered = 0;
  std::set<int> levels;
  for (int y = area.y; y < area.y + area.height; ++y)
    for (int x = area.x; x < area.x + area.width; ++x) {
      const cv::Vec3b& p = image.at<cv::Vec3b>(y, x);
      if (std::abs(p[0] - background[0]) + std::abs(p[1] - background[1]) + std::abs(p[2] - background[2]) > 12) {
        ++covered;
        levels.insert((p[0] + p[1] + p[2]) / 3);
      }
    }
  EXPECT_GT(covered, static_cast<std::size_t>(area.area()) / 200) << "the cloud covers under 0.5% of the viewer";
  EXPECT_GT(levels.size(), 20u) << "the cloud is drawn flat, not shaded";
}

}  // namespace
