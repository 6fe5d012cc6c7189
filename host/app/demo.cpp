// slscan demo: the whole product on one machine. Starts slscand on the sim board (the virtual
// rig) on loopback, scans a scene, reconstructs it live, measures the artefact and writes
// everything to the output folder.
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "calibrate.hpp"
#include "run.hpp"
#include "slproto/calibration.hpp"
#include "slrig/rig.hpp"
#include "slscan/io/io_error.hpp"

extern char** environ;

namespace slscan::app {

namespace {

namespace fs = std::filesystem;

fs::path executable_dir() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  return ec ? fs::current_path() : self.parent_path();
}

// The board file of the demo: the sim board with the demo's scene and size.
std::string demo_board(const std::string& template_path, const std::string& scene, bool small, int width, int height) {
  std::ifstream in(template_path);
  if (!in) throw io::IoError(template_path + ": cannot read the sim board file");
  std::stringstream text;
  text << in.rdbuf();
  std::string board = text.str();
  // Sets `key = value` on the first line that assigns `key` (plain TOML, one key per line).
  const auto replace = [&](const std::string& key, const std::string& value) {
    std::size_t at = 0;
    while (at < board.size()) {
      const std::size_t end = std::min(board.find('\n', at), board.size());
      const std::string_view line(board.data() + at, end - at);
      if (line.substr(0, key.size()) == key) {
        const std::size_t rest = line.find_first_not_of(" \t", key.size());
        if (rest != std::string_view::npos && line[rest] == '=') {
          board.replace(at, end - at, key + " = " + value);
          return;
        }
      }
      at = end + 1;
    }
    throw io::IoError(template_path + ": has no '" + key + "' line to set");
  };
  replace("scene", "\"" + scene + "\"");
  replace("rig_size", small ? "\"small\"" : "\"full\"");
  // The board's camera format must be what the rig renders ([camera] is the only section
  // with these keys).
  replace("width", std::to_string(width));
  replace("height", std::to_string(height));
  return board;
}

class Daemon {
 public:
  Daemon(const std::string& slscand, const std::string& board_path, const std::string& log_path) {
    int out[2];
    if (::pipe2(out, O_CLOEXEC) != 0) throw DeviceError("cannot create a pipe for slscand");
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, out[1], STDOUT_FILENO);
    posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    std::vector<std::string> args{slscand, "--board", board_path, "--port", "0", "--no-realtime"};
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    const int rc = posix_spawn(&pid_, slscand.c_str(), &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    ::close(out[1]);
    if (rc != 0) {
      ::close(out[0]);
      throw DeviceError("cannot start " + slscand + ": " + std::strerror(rc));
    }
    // slscand prints "slscand: board 'sim' (...), listening on ADDR:PORT" once it is ready.
    std::string line;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    char c;
    while (std::chrono::steady_clock::now() < deadline && ::read(out[0], &c, 1) == 1) {
      if (c != '\n') {
        line += c;
        continue;
      }
      const auto at = line.find("listening on ");
      if (at != std::string::npos) {
        const std::string address = line.substr(at + 13);
        const auto colon = address.rfind(':');
        host_ = address.substr(0, colon);
        port_ = static_cast<std::uint16_t>(std::stoi(address.substr(colon + 1)));
        break;
      }
      line.clear();
    }
    ::close(out[0]);
    if (port_ == 0) {
      stop();
      throw DeviceError("slscand did not start listening (its log: " + log_path + ")");
    }
  }
  ~Daemon() { stop(); }
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  void stop() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGTERM);
    for (int i = 0; i < 50; ++i) {
      if (::waitpid(pid_, nullptr, WNOHANG) == pid_) {
        pid_ = -1;
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  const std::string& host() const { return host_; }
  std::uint16_t port() const { return port_; }

 private:
  pid_t pid_ = -1;
  std::string host_;
  std::uint16_t port_ = 0;
};

}  // namespace

int run_demo(const DemoCommand& command, const Console& console) {
  const auto start = std::chrono::steady_clock::now();
  const fs::path out = command.output_dir;
  if (const std::string capture = capture_in(out.string()); !capture.empty() && !command.overwrite)
    return refuse_to_overwrite("demo", capture);
  fs::create_directories(out);
  const fs::path here = executable_dir();
  const std::string slscand = !command.slscand_path.empty()
                                  ? command.slscand_path
                                  : (here / ".." / ".." / "firmware" / "app" / "slscand").string();
  if (!fs::exists(slscand)) throw io::IoError(slscand + ": slscand not found (build it, or pass --slscand PATH)");
  const std::string board_template =
      !command.board_path.empty() ? command.board_path : std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml";

  auto scene = slrig::scene_preset(command.scene, command.small ? slrig::RigSize::small : slrig::RigSize::full);
  if (!scene) throw std::invalid_argument(scene.error().message);

  // The calibration: estimated from the virtual rig's calibration capture (checkerboard at ten
  // free poses and six table angles, docs/calibration.md), as on a real rig; or, on request,
  // the rig's exact one, said plainly in the report.
  const std::string calibration_path = (out / "calibration.json").string();
  if (command.true_calibration) {
    if (auto status = slproto::save_calibration(calibration_path, slrig::ground_truth_calibration(*scene)); !status)
      throw io::IoError(status.error().message);
    console.info("calibration: the virtual rig's ground truth -> " + calibration_path);
  } else {
    CalibrateCommand calibrate;
    calibrate.virtual_rig = command.small ? "small" : "full";
    calibrate.output_path = calibration_path;
    calibrate.report_path = (out / "calibration_report.json").string();
    Console calibration_console = console;
    if (const int rc = run_calibrate(calibrate, calibration_console); rc != exit_ok) return rc;
  }

  const std::string board_path = (out / "board.toml").string();
  io::write_file_atomically(
      board_path, demo_board(board_template, command.scene, command.small, scene->camera.width, scene->camera.height));
  console.info("starting slscand on the sim board (scene '" + command.scene + "', " +
               (command.small ? "640 x 512" : "2464 x 2056") + ")");
  Daemon daemon(slscand, board_path, (out / "slscand.log").string());

  ScanCommand scan;
  scan.host = daemon.host();
  scan.port = daemon.port();
  scan.calibration_path = calibration_path;
  scan.output_dir = out.string();
  scan.config_path = command.config_path;
  scan.angles_deg = scene->view_angles_deg;
  scan.exposure_us = 2000;
  scan.pattern_period_us = 5000;
  scan.settle_ms = 50;
  if (command.scene == "ballbar") scan.measure_ball_bar = true;
  scan.overwrite = command.overwrite;
  const int rc = run_scan(scan, console);
  daemon.stop();
  if (rc != exit_ok) return rc;
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  console.info("demo finished in " + std::to_string(static_cast<int>(seconds)) + " s; results in " +
               fs::absolute(out).string() +
               " (open report.html in a browser; model.ply, mesh.ply, mesh.stl, report.json, pictures/)");
  return exit_ok;
}

}  // namespace slscan::app
