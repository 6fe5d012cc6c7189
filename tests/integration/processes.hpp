// Programs as separate processes for the integration tests: run one to its end with its output
// in files, pinned to CPUs or under memory and file-size limits, and slscand on the sim board.
// SLSCAN_SOURCE_DIR and SLSCAND_BIN come from the test's compile definitions.
#pragma once

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sched.h>
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

// What a child runs under: the CPUs, the address space and the file size it may use (as
// `taskset -c`, `prlimit --as`, a full disk), and variables added to its environment.
struct Limits {
  int cpus = 0;                       // the first `cpus` CPUs this process may use; 0: all
  rlim_t address_space = 0;           // RLIMIT_AS in bytes; 0: none
  rlim_t file_size = 0;               // RLIMIT_FSIZE in bytes, SIGXFSZ ignored (a write past it fails with EFBIG)
  std::vector<std::string> env = {};  // NAME=VALUE
};

// The first `count` CPUs of this process's affinity mask: `taskset -c 0` where CPU 0 is ours.
inline cpu_set_t first_allowed_cpus(int count) {
  cpu_set_t allowed, chosen;
  CPU_ZERO(&allowed);
  CPU_ZERO(&chosen);
  if (::sched_getaffinity(0, sizeof allowed, &allowed) != 0) CPU_SET(0, &allowed);
  for (int cpu = 0; cpu < CPU_SETSIZE && CPU_COUNT(&chosen) < count; ++cpu)
    if (CPU_ISSET(cpu, &allowed)) CPU_SET(cpu, &chosen);
  return chosen;
}

// Starts a program with stdin from /dev/null and stdout / stderr in LOG_STEM.out / .err.
inline Child spawn(const std::vector<std::string>& args, const fs::path& log_stem, const Limits& limits = {}) {
  Child child{-1, log_stem.string() + ".out", log_stem.string() + ".err"};
  std::vector<std::string> args_copy = args;
  std::vector<char*> argv;
  argv.reserve(args_copy.size() + 1);
  for (auto& a : args_copy) argv.push_back(a.data());
  argv.push_back(nullptr);
  std::vector<std::string> env_copy = limits.env;
  const cpu_set_t cpus = first_allowed_cpus(limits.cpus);
  child.pid = ::fork();
  if (child.pid == 0) {
    const int in = ::open("/dev/null", O_RDONLY);
    const int out = ::open(child.out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int err = ::open(child.err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ::dup2(in, STDIN_FILENO);
    ::dup2(out, STDOUT_FILENO);
    ::dup2(err, STDERR_FILENO);
    for (auto& e : env_copy) ::putenv(e.data());
    if (limits.cpus > 0 && ::sched_setaffinity(0, sizeof cpus, &cpus) != 0) ::_exit(126);
    if (limits.address_space > 0) {
      const rlimit limit{limits.address_space, limits.address_space};
      if (::setrlimit(RLIMIT_AS, &limit) != 0) ::_exit(126);
    }
    if (limits.file_size > 0) {
      ::signal(SIGXFSZ, SIG_IGN);
      const rlimit limit{limits.file_size, limits.file_size};
      if (::setrlimit(RLIMIT_FSIZE, &limit) != 0) ::_exit(126);
    }
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  if (child.pid < 0) throw std::runtime_error("fork failed");
  return child;
}

// A deadline, not a timing assertion: a child that hangs is killed and fails the test
// (exit_code -1, with what it printed).
inline Finished wait_for(Child& child, std::chrono::seconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  int status = 0;
  while (::waitpid(child.pid, &status, WNOHANG) == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(child.pid, SIGKILL);
      ::waitpid(child.pid, &status, 0);
      child.pid = -1;
      ADD_FAILURE() << "hung: killed after " << timeout.count() << " s (stderr: " << child.err.string() << "):\n"
                    << read_text(child.err);
      return {-1, read_text(child.out), read_text(child.err)};
    }
    std::this_thread::sleep_for(20ms);
  }
  child.pid = -1;
  return {WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status), read_text(child.out), read_text(child.err)};
}

inline Finished run(const std::vector<std::string>& args, const fs::path& log_stem, const Limits& limits = {},
                    std::chrono::seconds timeout = 300s) {
  Child child = spawn(args, log_stem, limits);
  return wait_for(child, timeout);
}

// slscand on the sim board until the test ends; port() once it listens.
class Slscand {
 public:
  explicit Slscand(const fs::path& log_stem, std::vector<std::string> extra = {}) {
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
  Slscand(const Slscand&) = delete;
  Slscand& operator=(const Slscand&) = delete;
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

// A test suite's own folder (/tmp/slscan_<suite>_<pid>) holding the sim board's exact
// calibration as calib.json (`slscand --write-true-calibration`, boards/sim.toml: the small
// rig); removed after the suite unless a test failed, then kept and said so. Derive as
// `class Verify : public SuiteFolder<Verify>` (each suite its own folder).
template <typename Suite>
class SuiteFolder : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const std::string suite = ::testing::UnitTest::GetInstance()->current_test_suite()->name();
    dir_ = fs::temp_directory_path() / ("slscan_" + suite + "_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    const Finished truth = run({SLSCAND_BIN, "--board", std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml",
                                "--write-true-calibration", (dir_ / "calib.json").string()},
                               dir_ / "write-true-calibration", {}, 60s);
    ASSERT_EQ(truth.exit_code, 0) << truth.err;
  }
  static void TearDownTestSuite() {
    if (!keep_) fs::remove_all(dir_);
  }
  void TearDown() override {
    if (HasFailure()) {
      keep_ = true;
      std::printf("keeping %s (logs, outputs) to look at\n", dir_.c_str());
    }
  }
  static inline fs::path dir_;
  static inline bool keep_ = false;
};

}  // namespace slscan::testing
