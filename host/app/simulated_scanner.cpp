#include "simulated_scanner.hpp"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <thread>
#include <vector>

#include "run.hpp"
#include "slproto/file_util.hpp"
#include "slscan/io/io_error.hpp"

extern char** environ;

namespace slscan::app {

namespace fs = std::filesystem;

namespace {

fs::path executable_dir() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  return ec ? fs::current_path() : self.parent_path();
}

// The camera format each rig size renders (slrig's default rig; the sim camera refuses any other).
struct CameraFormat {
  int width, height;
};
CameraFormat camera_format_of(VirtualRigSize size) {
  return size == VirtualRigSize::full ? CameraFormat{2464, 2056} : CameraFormat{640, 512};
}

// The last non-empty line of a log file ("" when there is none), for an error message.
std::string last_line(const fs::path& path) {
  std::ifstream in(path);
  std::string line, last;
  while (std::getline(in, line))
    if (!line.empty()) last = line;
  return last;
}

pid_t spawn(const std::vector<std::string>& args, posix_spawn_file_actions_t& actions) {
  std::vector<std::string> copy = args;
  std::vector<char*> argv;
  argv.reserve(copy.size() + 1);
  for (auto& a : copy) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  if (rc != 0) throw DeviceError("cannot start " + args[0] + ": " + slproto::errno_text(rc));
  return pid;
}

}  // namespace

std::string find_slscand(const std::string& given) {
  if (!given.empty()) {
    if (!fs::exists(given)) throw io::IoError(given + ": slscand not found");
    return given;
  }
  const fs::path here = executable_dir();
  const std::array<fs::path, 2> candidates{here / ".." / ".." / "firmware" / "app" / "slscand", here / "slscand"};
  for (const fs::path& candidate : candidates)
    if (fs::exists(candidate)) return candidate.lexically_normal().string();
  throw io::IoError("slscand not found in the build tree (" + candidates[0].lexically_normal().string() +
                    ") or beside slscan (" + candidates[1].string() + "): build it, or pass --slscand PATH");
}

void write_sim_board(const std::string& template_path, const std::string& scene, VirtualRigSize size,
                     const fs::path& board_path) {
  std::string path = template_path;
  if (path.empty()) {
    // The source tree's (a build), else the one installed with slscand (/usr/share/slscan/boards).
    path = std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml";
    const fs::path installed = executable_dir() / ".." / "share" / "slscan" / "boards" / "sim.toml";
    if (!fs::exists(path) && fs::exists(installed)) path = installed.lexically_normal().string();
  }
  std::ifstream in(path);
  if (!in) throw io::IoError(path + ": cannot read the sim board file");
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
          std::string assignment = key;
          assignment += " = ";
          assignment += value;
          board.replace(at, end - at, assignment);
          return;
        }
      }
      at = end + 1;
    }
    throw io::IoError(path + ": has no '" + key + "' line to set");
  };
  const CameraFormat format = camera_format_of(size);
  replace("scene", "\"" + scene + "\"");
  replace("rig_size", size == VirtualRigSize::small ? "\"small\"" : "\"full\"");
  // [camera] is the only section with these keys.
  replace("width", std::to_string(format.width));
  replace("height", std::to_string(format.height));
  io::write_file_atomically(board_path.string(), board);
}

void write_true_calibration(const std::string& slscand, const fs::path& board_path, const fs::path& out_path) {
  const fs::path log_path = out_path.string() + ".log";
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  pid_t pid = -1;
  try {
    pid = spawn({slscand, "--board", board_path.string(), "--write-true-calibration", out_path.string()}, actions);
  } catch (...) {
    posix_spawn_file_actions_destroy(&actions);
    throw;
  }
  posix_spawn_file_actions_destroy(&actions);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  const std::string said = last_line(log_path);
  std::error_code ec;
  fs::remove(log_path, ec);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
    throw DeviceError(slscand + " --write-true-calibration failed" + (said.empty() ? std::string() : ": " + said));
}

SimulatedScanner::SimulatedScanner(const std::string& slscand, const fs::path& board_path, const fs::path& log_path) {
  int out[2];
  if (::pipe2(out, O_CLOEXEC) != 0) throw DeviceError("cannot create a pipe for slscand");
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, out[1], STDOUT_FILENO);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  try {
    pid_ = spawn({slscand, "--board", board_path.string(), "--port", "0", "--no-realtime", "--no-mdns"}, actions);
  } catch (...) {
    posix_spawn_file_actions_destroy(&actions);
    ::close(out[0]);
    ::close(out[1]);
    throw;
  }
  posix_spawn_file_actions_destroy(&actions);
  ::close(out[1]);
  // slscand prints "slscand: board 'sim' (...), listening on ADDR:PORT" once it is ready, and
  // closes its end (exits) when it cannot start.
  std::string line;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  char c = 0;
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
      port_ = static_cast<std::uint16_t>(std::strtoul(address.substr(colon + 1).c_str(), nullptr, 10));
      break;
    }
    line.clear();
  }
  ::close(out[0]);
  if (port_ == 0) {
    stop();
    const std::string said = last_line(log_path);
    throw DeviceError("slscand on the sim board did not start listening" +
                      (said.empty() ? std::string() : ": " + said) + " (its log: " + log_path.string() + ")");
  }
}

SimulatedScanner::~SimulatedScanner() { stop(); }

void SimulatedScanner::stop() {
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

TemporaryFolder::TemporaryFolder(const std::string& prefix) {
  std::string pattern = (fs::temp_directory_path() / (prefix + "XXXXXX")).string();
  if (::mkdtemp(pattern.data()) == nullptr)
    throw io::IoError(pattern + ": cannot create a temporary folder: " + slproto::errno_text(errno));
  path_ = pattern;
}

TemporaryFolder::~TemporaryFolder() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

}  // namespace slscan::app
