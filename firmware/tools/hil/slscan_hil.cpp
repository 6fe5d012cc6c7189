// slscan_hil: the hardware-in-the-loop timing harness (docs/hil.md).
//
//   slscan_hil --board FILE --slscand PATH [--views N] [--exposure-bracket US,US,...] [--out DIR] [--json FILE]
//              [--no-timing] [--no-realtime]
//       launches `slscand --board FILE --port 0 --timing-log DIR`, drives a scan as a host would, and checks it
//       (with a bracket, every view at each exposure: the frames' order and exposures, the waits after
//       each change in the ideal scan time);
//   slscan_hil --board FILE --connect HOST:PORT --timing-log-dir DIR [...]
//       the same against a slscand already running on this board (started with --timing-log DIR);
//   slscan_hil check --board FILE --dir DIR [--json FILE] [--no-timing]
//       re-checks a record saved by a run (DIR holds scan.txt, timing.csv, frames.csv, edges.csv).
//
// The observer: on the sim board, the virtual GPIO bus's own edge record (slscand writes it next
// to the timing log); on a real board, libgpiod edge events on the inputs the board file's
// [observer] section names, wired back from the trigger outputs. The harness must run on the
// board itself then, so that its edge timestamps and slscand's share one CLOCK_MONOTONIC.
//
// Exit codes: 0 every check passed, 1 a budget or a cross-check failed (named on stderr),
// 2 bad command line or board file, 3 the scan could not be run.
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "gpiod_observer.hpp"
#include "hil_check.hpp"
#include "hil_record.hpp"
#include "slproto/calibration.hpp"
#include "slproto/file_util.hpp"
#include "slproto/handshake.hpp"
#include "slproto/pattern_plan.hpp"
#include "slproto/transport.hpp"
#include "slscand/hal/board.hpp"

extern char** environ;

namespace {

using namespace std::chrono_literals;
namespace pb = slproto::pb;
using slscan::hil::Nanos;

struct Options {
  std::string board_path, slscand_path, connect, timing_log_dir, out_dir, json_path, token_file, token, check_dir;
  long views = 2;
  std::vector<std::uint32_t> exposure_bracket_us;  // HDR (docs/hdr.md); empty: the board's exposure alone
  bool timing = true;
  bool realtime = true;
};

[[noreturn]] void usage_error(const std::string& message) {
  std::fprintf(
      stderr,
      "slscan_hil: %s\n"
      "usage: slscan_hil --board FILE (--slscand PATH | --connect HOST:PORT --timing-log-dir DIR)\n"
      "                  [--views N] [--exposure-bracket US,US,...] [--out DIR] [--json FILE] [--token-file F]\n"
      "                  [--no-timing] [--no-realtime]\n"
      "       slscan_hil check --board FILE --dir DIR [--json FILE] [--no-timing]\n",
      message.c_str());
  std::exit(2);  // NOLINT(concurrency-mt-unsafe): the command line is read before any thread starts
}

// slscand as a child process, stopped (SIGTERM) when this goes out of scope.
class Daemon {
 public:
  ~Daemon() { stop(); }
  bool start(const Options& o, const std::string& log_dir, std::string& error, std::uint16_t& port) {
    int out[2];
    if (pipe2(out, O_CLOEXEC) != 0) {
      error = std::string("pipe: ") + slproto::errno_text(errno);
      return false;
    }
    std::vector<std::string> args = {o.slscand_path, "--board", o.board_path, "--port", "0", "--timing-log", log_dir};
    if (!o.realtime) args.emplace_back("--no-realtime");
    if (!o.token_file.empty()) args.insert(args.end(), {"--token-file", o.token_file});
    std::vector<char*> argv;
    argv.reserve(args.size() + 1);
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, out[1], 1);
    const int rc = posix_spawn(&pid_, o.slscand_path.c_str(), &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    close(out[1]);
    if (rc != 0) {
      close(out[0]);
      pid_ = -1;
      error = "cannot start " + o.slscand_path + ": " + slproto::errno_text(rc);
      return false;
    }
    out_fd_ = out[0];
    // "slscand: board 'sim' (...), listening on 127.0.0.1:PORT"; the sim board builds its scene
    // first, which takes a while under a sanitizer.
    std::string text;
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    while (text.find('\n') == std::string::npos) {
      const auto left =
          std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
      pollfd p{out_fd_, POLLIN, 0};
      if (left.count() <= 0 || poll(&p, 1, static_cast<int>(left.count())) <= 0) {
        error = "slscand did not report its port within 60 s";
        return false;
      }
      char buffer[256];
      const ssize_t n = read(out_fd_, buffer, sizeof buffer);
      if (n <= 0) {
        error = "slscand exited before listening (" + exit_status() + ")";
        return false;
      }
      text.append(buffer, static_cast<std::size_t>(n));
    }
    const auto colon = text.rfind(':', text.find('\n'));
    const long p = colon == std::string::npos ? -1 : std::strtol(text.c_str() + colon + 1, nullptr, 10);
    if (p <= 0 || p > 65535) {
      error = "cannot read slscand's port from '" + text.substr(0, text.find('\n')) + "'";
      return false;
    }
    port = static_cast<std::uint16_t>(p);
    return true;
  }
  void stop() {
    if (pid_ > 0) {
      kill(pid_, SIGTERM);
      int status = 0;
      waitpid(pid_, &status, 0);
      pid_ = -1;
    }
    if (out_fd_ >= 0) close(out_fd_);
    out_fd_ = -1;
  }

 private:
  std::string exit_status() {
    int status = 0;
    if (pid_ > 0 && waitpid(pid_, &status, 0) == pid_) {
      pid_ = -1;
      if (WIFEXITED(status)) return "exit code " + std::to_string(WEXITSTATUS(status));
      if (WIFSIGNALED(status)) return "signal " + std::to_string(WTERMSIG(status));
    }
    return "unknown status";
  }
  pid_t pid_ = -1;
  int out_fd_ = -1;
};

int report(const slscan::hil::HilRecord& record, const slscand::hal::BoardConfig& board, const Options& o) {
  slscan::hil::CheckOptions check_options;
  check_options.timing = o.timing;
  const auto result = slscan::hil::evaluate(record, board, check_options);
  std::string exposures = std::to_string(static_cast<long long>(record.scan.exposure_us)) + " us";
  if (!record.scan.exposures_us.empty()) {
    exposures.clear();
    for (const double e : record.scan.exposures_us) {
      if (!exposures.empty()) exposures += ", ";
      exposures += std::to_string(static_cast<long long>(e));
    }
    exposures = "bracket " + exposures + " us (" + std::to_string(record.scan.exposure_change_frames) +
                " periods after each change)";
  }
  std::printf(
      "board %s (%s): %u views x %u projectors x %u patterns, period %.0f us, exposure %s, scan %.3f s (ideal "
      "%llu periods + moves)\n",
      board.name.c_str(), board.source_path.c_str(), record.scan.views, record.scan.projectors, record.scan.patterns,
      record.scan.period_us, exposures.c_str(), static_cast<double>(record.scan.duration_ns) * 1e-9,
      static_cast<unsigned long long>(record.scan.capture_periods()));
  std::fputs(result.table().c_str(), stdout);
  std::fflush(stdout);
  if (!o.json_path.empty()) {
    if (auto s = slproto::write_file_atomically(o.json_path, result.json()); !s) {
      std::fprintf(stderr, "slscan_hil: %s\n", s.error().message.c_str());
      return 3;
    }
  }
  if (result.passed()) {
    std::printf("slscan_hil: PASS (%zu checks)\n", result.checks.size());
    return 0;
  }
  for (const auto* c : result.failures()) {
    std::fprintf(stderr, "slscan_hil: FAILED %s: measured %s, limit %s%s%s\n", c->name.c_str(), c->measured.c_str(),
                 c->limit.c_str(), c->detail.empty() ? "" : ": ", c->detail.c_str());
  }
  return 1;
}

int run(const Options& o, const slscand::hal::BoardConfig& board) {
  std::error_code ec;
  std::string out_dir = o.out_dir;
  if (out_dir.empty()) {
    char templ[] = "/tmp/slscan-hil-XXXXXX";
    if (mkdtemp(templ) == nullptr) {
      std::fprintf(stderr, "slscan_hil: cannot make a temporary directory: %s\n", slproto::errno_text(errno).c_str());
      return 3;
    }
    out_dir = templ;
  }
  std::filesystem::create_directories(out_dir, ec);
  if (ec) {
    std::fprintf(stderr, "slscan_hil: cannot create %s: %s\n", out_dir.c_str(), ec.message().c_str());
    return 3;
  }
  std::string log_dir = o.timing_log_dir;
  Daemon daemon;
  std::string host = "127.0.0.1";
  std::uint16_t port = 0;
  if (!o.slscand_path.empty()) {
    log_dir = out_dir + "/board-log";
    std::filesystem::create_directories(log_dir, ec);
    std::string error;
    if (!daemon.start(o, log_dir, error, port)) {
      std::fprintf(stderr, "slscan_hil: %s\n", error.c_str());
      return 3;
    }
  } else {
    const auto colon = o.connect.rfind(':');
    const long p = colon == std::string::npos ? -1 : std::strtol(o.connect.c_str() + colon + 1, nullptr, 10);
    if (p <= 0 || p > 65535) usage_error("--connect wants HOST:PORT, not '" + o.connect + "'");
    host = o.connect.substr(0, colon);
    port = static_cast<std::uint16_t>(p);
  }

  auto connection = slproto::connect(host, port, 10s);
  if (!connection) {
    std::fprintf(stderr, "slscan_hil: cannot connect to slscand at %s:%u: %s\n", host.c_str(), port,
                 connection.error().message.c_str());
    return 3;
  }
  auto hello = slproto::client_handshake(*connection, slproto::make_hello("slscan_hil", "0.1.0", 0, o.token));
  if (!hello) {
    std::fprintf(stderr, "slscan_hil: hello refused: %s\n", hello.error().message.c_str());
    return 3;
  }

  // A simulated scanner records its own trigger edges (the observer's CSV); on hardware an
  // independent gpiod observer watches the lines, started before the scan is requested.
  slscan::hil::GpiodObserver gpiod_observer;
  const bool sim_observer = (hello->capabilities() & pb::CAPABILITY_SIMULATED) != 0;
  bool gpiod_observing = false;
  if (!sim_observer && !board.observer.chip.empty()) {
    std::string error;
    if (!gpiod_observer.start(board, error)) {
      std::fprintf(stderr, "slscan_hil: %s\n", error.c_str());
      return 3;
    }
    gpiod_observing = true;
  }

  constexpr std::uint64_t kScanId = 1;
  // A log left by an earlier scan with the same id must not pass for this one's.
  const std::string log_path = log_dir + "/scan-" + std::to_string(kScanId) + "-timing.csv";
  const std::string edges_path = log_dir + "/scan-" + std::to_string(kScanId) + "-edges.csv";
  const auto requested_at = std::filesystem::file_time_type::clock::now();
  auto fresh = [&](const std::string& path) {
    std::error_code stat_error;
    const auto written = std::filesystem::last_write_time(path, stat_error);
    return !stat_error && written >= requested_at - 2s;  // coarse file-system clocks
  };
  pb::ScanRequest request;
  request.set_scan_id(kScanId);
  for (long v = 0; v < o.views; ++v) request.add_turntable_angles_deg(60.0 * static_cast<double>(v));
  request.add_projectors(0);
  request.add_projectors(1);
  const slproto::PatternPlanConfig plan_config;
  *request.mutable_plan() = slproto::to_proto(plan_config);
  request.set_exposure_us(static_cast<std::uint32_t>(board.pattern_exposure_us));
  // A bracket's longest exposure with the read-out margin of the board's own timing.
  std::uint32_t longest_us = static_cast<std::uint32_t>(board.pattern_exposure_us);
  for (const std::uint32_t e : o.exposure_bracket_us) {
    request.add_exposure_bracket_us(e);
    longest_us = std::max(longest_us, e);
  }
  request.set_pattern_period_us(static_cast<std::uint32_t>(
      board.pattern_period_us + (longest_us - static_cast<std::uint32_t>(board.pattern_exposure_us))));
  request.set_timing_events(true);
  request.set_pixel_format(hello->camera().pixel_formats_size() > 0 ? hello->camera().pixel_formats(0)
                                                                    : pb::PIXEL_FORMAT_MONO8);
  if (auto s = connection->send(request); !s) {
    std::fprintf(stderr, "slscan_hil: cannot send the scan request: %s\n", s.error().message.c_str());
    return 3;
  }

  slscan::hil::HilRecord record;
  record.scan.views = static_cast<std::uint32_t>(o.views);
  record.scan.projectors = 2;
  record.scan.patterns = static_cast<std::uint32_t>(slproto::PatternPlan(plan_config).size());
  record.scan.period_us = request.pattern_period_us();
  record.scan.exposure_us = request.exposure_us();
  for (const std::uint32_t e : o.exposure_bracket_us) record.scan.exposures_us.push_back(e);
  record.scan.exposure_change_frames = static_cast<std::uint32_t>(board.exposure_change_frames);
  std::string error_text;
  for (;;) {
    auto m = connection->receive(60s);
    if (!m) {
      std::fprintf(stderr, "slscan_hil: the scan stopped: %s\n", m.error().message.c_str());
      return 3;
    }
    if (const auto* f = m->get<pb::FrameHeader>()) {
      slscan::hil::FrameRecord fr;
      fr.sequence = f->sequence();
      fr.view = f->view_index();
      fr.projector = f->projector_id();
      fr.pattern = f->pattern_index();
      fr.exposure_index = f->exposure_index();
      fr.trigger_ns = static_cast<Nanos>(f->trigger_ns());
      fr.exposure_start_ns = static_cast<Nanos>(f->exposure_start_ns());
      fr.exposure_end_ns = static_cast<Nanos>(f->exposure_end_ns());
      fr.dequeued_ns = static_cast<Nanos>(f->readout_ns());
      record.frames.push_back(fr);
    } else if (const auto* e = m->get<pb::Error>()) {
      error_text = e->text();
    } else if (const auto* d = m->get<pb::ScanDone>()) {
      std::string state = pb::ScanState_Name(d->final_state());
      record.scan.final_state = state.rfind("SCAN_STATE_", 0) == 0 ? state.substr(11) : state;
      record.scan.frames_sent = d->frames_sent();
      record.scan.frames_dropped = d->frames_dropped();
      record.scan.duration_ns = static_cast<Nanos>(d->duration_ns());
      record.scan.text = error_text.empty() ? d->text() : error_text;
      break;
    }
  }
  connection->close();
  gpiod_observer.stop();

  // slscand writes its log before it sends ScanDone.
  if (!fresh(log_path)) {
    std::fprintf(stderr, "slscan_hil: %s was not written by this scan (is slscand running with --timing-log %s?)\n",
                 log_path.c_str(), log_dir.c_str());
    return 3;
  }
  auto log_text = slscan::hil::read_text_file(log_path);
  if (!log_text) {
    std::fprintf(stderr, "slscan_hil: no timing log: %s (is slscand running with --timing-log %s?)\n",
                 log_text.error().message.c_str(), log_dir.c_str());
    return 3;
  }
  auto log = slscan::hil::parse_timing_log(*log_text, log_path);
  if (!log) {
    std::fprintf(stderr, "slscan_hil: %s\n", log.error().message.c_str());
    return 3;
  }
  record.log = std::move(*log);
  if (sim_observer) {
    if (!fresh(edges_path)) {
      std::fprintf(stderr, "slscan_hil: %s was not written by this scan\n", edges_path.c_str());
      return 3;
    }
    auto edges_text = slscan::hil::read_text_file(edges_path);
    if (!edges_text) {
      std::fprintf(stderr, "slscan_hil: the sim bus's edge record is missing: %s\n",
                   edges_text.error().message.c_str());
      return 3;
    }
    auto edges = slscan::hil::parse_edges(*edges_text, edges_path);
    if (!edges) {
      std::fprintf(stderr, "slscan_hil: %s\n", edges.error().message.c_str());
      return 3;
    }
    record.edges = std::move(*edges);
    record.have_edges = true;
  } else if (gpiod_observing) {
    if (const std::string e = gpiod_observer.error(); !e.empty()) {
      std::fprintf(stderr, "slscan_hil: observer: %s\n", e.c_str());
      return 3;
    }
    record.edges = gpiod_observer.edges();
    record.have_edges = true;
  }
  daemon.stop();
  if (auto s = slscan::hil::save_record(record, out_dir); !s) {
    std::fprintf(stderr, "slscan_hil: %s\n", s.error().message.c_str());
    return 3;
  }
  std::printf("record: %s\n", out_dir.c_str());
  return report(record, board, o);
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  int first = 1;
  const bool check_mode = argc > 1 && std::string(argv[1]) == "check";
  if (check_mode) first = 2;
  for (int i = first; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage_error(arg + " needs a value");
      return argv[++i];
    };
    if (arg == "--board")
      o.board_path = value();
    else if (arg == "--slscand")
      o.slscand_path = value();
    else if (arg == "--connect")
      o.connect = value();
    else if (arg == "--timing-log-dir")
      o.timing_log_dir = value();
    else if (arg == "--out")
      o.out_dir = value();
    else if (arg == "--dir")
      o.check_dir = value();
    else if (arg == "--json")
      o.json_path = value();
    else if (arg == "--token-file")
      o.token_file = value();
    else if (arg == "--no-timing")
      o.timing = false;
    else if (arg == "--no-realtime")
      o.realtime = false;
    else if (arg == "--exposure-bracket") {
      const std::string text = value();
      std::size_t start = 0;
      while (start <= text.size()) {
        const std::size_t comma = std::min(text.find(',', start), text.size());
        const std::string item = text.substr(start, comma - start);
        char* end = nullptr;
        const unsigned long us = std::strtoul(item.c_str(), &end, 10);
        if (item.empty() || *end != '\0' || us < 1 || us > 1'000'000)
          usage_error("--exposure-bracket wants exposures in us (1..1000000), comma-separated, not '" + text + "'");
        o.exposure_bracket_us.push_back(static_cast<std::uint32_t>(us));
        start = comma + 1;
      }
      if (o.exposure_bracket_us.size() > 8) usage_error("--exposure-bracket: at most 8 exposures");
    } else if (arg == "--views") {
      const std::string text = value();
      char* end = nullptr;
      o.views = std::strtol(text.c_str(), &end, 10);
      if (*end != '\0' || o.views < 1 || o.views > 6) usage_error("--views wants 1..6, not '" + text + "'");
    } else if (arg == "--help" || arg == "-h") {
      usage_error("help");
    } else {
      usage_error("unknown argument '" + arg + "'");
    }
  }
  if (o.board_path.empty()) usage_error("--board is required");
  if (!o.token_file.empty()) {
    // The host's side of the shared token (slscand checks the file's mode itself).
    std::FILE* file = std::fopen(o.token_file.c_str(), "r");
    if (file == nullptr) {
      std::fprintf(stderr, "slscan_hil: %s: cannot read the token file: %s\n", o.token_file.c_str(),
                   slproto::errno_text(errno).c_str());
      return 2;
    }
    char line[4096] = {};
    if (std::fgets(line, sizeof line, file) != nullptr) o.token = line;
    std::fclose(file);
    while (!o.token.empty() && std::isspace(static_cast<unsigned char>(o.token.back()))) o.token.pop_back();
  }
  auto board = slscand::hal::load_board(o.board_path);
  if (!board) {
    std::fprintf(stderr, "slscan_hil: %s\n", board.error().message.c_str());
    return 2;
  }
  if (check_mode) {
    if (o.check_dir.empty()) usage_error("check needs --dir");
    auto record = slscan::hil::load_record(o.check_dir);
    if (!record) {
      std::fprintf(stderr, "slscan_hil: %s\n", record.error().message.c_str());
      return 2;
    }
    return report(*record, *board, o);
  }
  if (o.slscand_path.empty() == o.connect.empty()) usage_error("give one of --slscand PATH and --connect HOST:PORT");
  if (!o.connect.empty() && o.timing_log_dir.empty()) {
    usage_error("--connect needs --timing-log-dir (the directory slscand writes its timing log to)");
  }
  return run(o, *board);
}
