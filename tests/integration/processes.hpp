// Programs as separate processes for the integration tests: run one to its end with its output
// in files (optionally with a file-size limit, as a full disk), and slscand on the sim board.
// SLSCAN_SOURCE_DIR and SLSCAND_BIN come from the test's compile definitions.
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace slscan::testing {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

inline std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

struct Child {
  pid_t pid = -1;
  fs::path out, err;
};

struct Finished {
  int exit_code = -1;
  std::string out, err;
};

// Starts a program with stdout/stderr in files. `file_size_limit` > 0 sets RLIMIT_FSIZE in
// the child (SIGXFSZ ignored, so a write past it fails with EFBIG as on a full disk).
inline Child spawn(const std::vector<std::string>& args, const fs::path& log_stem,
                   const std::vector<std::string>& env = {}, rlim_t file_size_limit = 0) {
  Child child{-1, log_stem.string() + ".out", log_stem.string() + ".err"};
  std::vector<std::string> args_copy = args;
  std::vector<char*> argv;
  for (auto& a : args_copy) argv.push_back(a.data());
  argv.push_back(nullptr);
  std::vector<std::string> env_copy = env;
  child.pid = ::fork();
  if (child.pid == 0) {
    const int in = ::open("/dev/null", O_RDONLY);
    const int out = ::open(child.out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int err = ::open(child.err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ::dup2(in, STDIN_FILENO);
    ::dup2(out, STDOUT_FILENO);
    ::dup2(err, STDERR_FILENO);
    for (auto& e : env_copy) ::putenv(e.data());
    if (file_size_limit > 0) {
      ::signal(SIGXFSZ, SIG_IGN);
      const rlimit limit{file_size_limit, file_size_limit};
      ::setrlimit(RLIMIT_FSIZE, &limit);
    }
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  if (child.pid < 0) throw std::runtime_error("fork failed");
  return child;
}

inline Finished wait_for(Child& child, std::chrono::seconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  int status = 0;
  while (::waitpid(child.pid, &status, WNOHANG) == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(child.pid, SIGKILL);
      ::waitpid(child.pid, &status, 0);
      throw std::runtime_error("a child did not finish in time (stderr: " + child.err.string() + ")");
    }
    std::this_thread::sleep_for(20ms);
  }
  child.pid = -1;
  return {WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status), read_text(child.out), read_text(child.err)};
}

inline Finished run(const std::vector<std::string>& args, const fs::path& log_stem,
                    const std::vector<std::string>& env = {}, rlim_t file_size_limit = 0) {
  Child child = spawn(args, log_stem, env, file_size_limit);
  return wait_for(child, 300s);
}

// slscand on the sim board until the test ends; port() once it listens.
class Slscand {
 public:
  Slscand(const fs::path& log_stem, std::vector<std::string> extra = {}) {
    std::vector<std::string> args{SLSCAND_BIN, "--board", std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml",
                                  "--port",    "0",       "--no-realtime"};
    args.insert(args.end(), extra.begin(), extra.end());
    child_ = spawn(args, log_stem);
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    while (port_ == 0 && std::chrono::steady_clock::now() < deadline) {
      const std::string out = read_text(child_.out);
      if (const auto at = out.find("listening on "); at != std::string::npos && out.find('\n', at) != std::string::npos)
        port_ = std::stoi(out.substr(out.rfind(':', out.find('\n', at)) + 1));
      else if (::waitpid(child_.pid, nullptr, WNOHANG) != 0)
        break;
      std::this_thread::sleep_for(20ms);
    }
    if (port_ == 0) throw std::runtime_error("slscand did not start (stderr: " + child_.err.string() + ")");
  }
  ~Slscand() { stop(SIGTERM); }
  pid_t pid() const { return child_.pid; }
  int port() const { return port_; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  void stop(int signal) {
    if (child_.pid <= 0) return;
    ::kill(child_.pid, signal);
    ::waitpid(child_.pid, nullptr, 0);
    child_.pid = -1;
  }
  std::string log() const { return read_text(child_.err); }

 private:
  Child child_;
  int port_ = 0;
};

}  // namespace slscan::testing
