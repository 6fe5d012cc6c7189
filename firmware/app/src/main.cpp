// slscand: the scanner board's daemon.
//   slscand --board boards/sim.toml [--port N] [--bind ADDR] [--timing-log DIR] [--token-file F]
//           [--insecure-no-token] [--no-mdns]
//   slscand --config /etc/slscan/slscand.toml [options above override it]
//   slscand --config FILE | --board FILE --check
//   slscand --board boards/sim.toml --timing-report [--views N] [--exposure-us E] [--period-us P]
//   slscand --board boards/sim.toml --write-true-calibration FILE   (simulated boards only)
//   slscand --list-backends | --version
// Exit codes: 0 ok, 1 runtime failure, 2 bad command line or board file.
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>

#include "slproto/calibration.hpp"
#include "slproto/discovery.hpp"
#include "slproto/mdns.hpp"
#include "slproto/messages.hpp"
#include "slscand/app/check.hpp"
#include "slscand/app/config.hpp"
#include "slscand/app/daemon.hpp"
#include "slscand/app/security.hpp"
#include "slscand/sequencer/realtime.hpp"

namespace {

std::atomic<slscand::Daemon*> g_daemon{nullptr};

void on_signal(int) {
  if (slscand::Daemon* d = g_daemon.load()) d->stop();
}

void usage(std::FILE* out) {
  std::fputs(
      "usage: slscand --board FILE [--port N] [--bind ADDR] [--timing-log DIR] [--token-file FILE]\n"
      "               [--insecure-no-token] [--no-realtime] [--no-mdns]\n"
      "       slscand --config FILE [the options above override the file's]\n"
      "       slscand (--config FILE | --board FILE) --check\n"
      "       slscand --board FILE --timing-report [--views N] [--exposure-us E] [--period-us P]\n"
      "       slscand --board FILE --write-true-calibration FILE\n"
      "       slscand --list-backends | --version | --help\n"
      "Serves scans to one host at a time over slproto (TCP). --timing-report runs one scan on the\n"
      "board locally (use the sim board for a machine without hardware) and prints its timing.\n"
      "It listens on loopback unless --bind or the board file's bind_address say otherwise; any\n"
      "other address needs --token-file (a file of mode 600 holding the hosts' shared token) or\n"
      "an explicit --insecure-no-token (docs/security.md). It announces itself with mDNS/DNS-SD\n"
      "(avahi-daemon) unless it listens on loopback or --no-mdns is given.\n"
      "--check reports each device, permission and setting the board needs, present or missing with\n"
      "the fix, and exits 0 only if nothing is missing.\n"
      "--write-true-calibration writes a simulated board's exact calibration (the virtual rig as\n"
      "built: `slscan demo --true-calibration`, checking an estimated one) and exits; a board with\n"
      "hardware has none (exit 2).\n",
      out);
}

bool parse_int(const char* text, long min, long max, long& out) {
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(text, &end, 10);
  if (errno != 0 || end == text || *end != '\0' || v < min || v > max) return false;
  out = v;
  return true;
}

int timing_report(const slscand::hal::BoardConfig& board, slscand::hal::BoardDevices& devices, long views,
                  long exposure_us, long period_us, bool realtime) {
  namespace pb = slproto::pb;
  pb::ScanRequest request;
  request.set_scan_id(1);
  for (long v = 0; v < views; ++v) request.add_turntable_angles_deg(60.0 * static_cast<double>(v));
  request.add_projectors(0);
  request.add_projectors(1);
  *request.mutable_plan() = slproto::to_proto(slproto::PatternPlanConfig{});
  request.set_exposure_us(
      static_cast<std::uint32_t>(exposure_us > 0 ? exposure_us : static_cast<long>(board.pattern_exposure_us)));
  request.set_pattern_period_us(
      static_cast<std::uint32_t>(period_us > 0 ? period_us : static_cast<long>(board.pattern_period_us)));
  request.set_timing_events(true);
  request.set_pixel_format(slscand::to_proto(devices.camera_format.pixel_format));
  auto plan = slscand::make_scan_plan(request, board, devices.camera_format);
  if (!plan) {
    std::fprintf(stderr, "slscand: %s\n", plan.error().message.c_str());
    return 2;
  }
  slscand::Sequencer sequencer(devices, board);
  slscand::BoundedQueue<slscand::SequencedFrame> queue(8);
  std::atomic<bool> abort{false};
  std::thread consumer([&] {
    while (!queue.closed_and_empty()) (void)queue.pop(std::chrono::milliseconds(50));
  });
  slscand::ScanOutcome outcome;
  std::thread runner([&] {
    if (realtime && board.realtime) {
      const auto rt = slscand::enter_realtime(board.realtime_priority, board.cpu);
      if (!rt.warnings.empty()) std::fprintf(stderr, "slscand: warning: %s\n", rt.warnings.c_str());
      std::printf("realtime: mlockall %s, SCHED_FIFO %s\n", rt.memory_locked ? "yes" : "no", rt.fifo ? "yes" : "no");
    }
    outcome = sequencer.run(*plan, queue, abort);
    queue.close();
  });
  runner.join();
  consumer.join();
  if (outcome.state != pb::SCAN_STATE_DONE) {
    std::fprintf(stderr, "slscand: timing scan failed: %s\n", outcome.error.message.c_str());
    return 1;
  }
  std::printf("board %s: %llu frames, %u views x %zu projectors x %zu patterns, exposure %u us, scan %.2f s\n",
              board.name.c_str(), static_cast<unsigned long long>(outcome.frames_captured), outcome.views_completed,
              plan->projectors.size(), plan->patterns.size(), request.exposure_us(),
              static_cast<double>(outcome.duration_ns) * 1e-9);
  std::fputs(
      slscand::make_timing_report(outcome.frames, static_cast<double>(plan->period_ns) / 1000.0).to_text().c_str(),
      stdout);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  slscand::reuse_freed_frame_memory();
  std::string board_path, bind, timing_dir, token_file, config_path, true_calibration_path;
  long port = -1, views = 6, exposure_us = 0, period_us = 0;
  bool report = false, realtime = true, check = false, bind_given = false, realtime_given = false, mdns = true;
  bool insecure_no_token = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&](const char* name) -> const char* {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "slscand: %s needs a value\n", name);
        std::exit(2);  // NOLINT(concurrency-mt-unsafe): the command line is read before any thread starts
      }
      return argv[++i];
    };
    if (arg == "--board")
      board_path = value("--board");
    else if (arg == "--config")
      config_path = value("--config");
    else if (arg == "--check")
      check = true;
    else if (arg == "--write-true-calibration")
      true_calibration_path = value("--write-true-calibration");
    else if (arg == "--no-mdns")
      mdns = false;
    else if (arg == "--bind")
      bind = value("--bind"), bind_given = true;
    else if (arg == "--timing-log")
      timing_dir = value("--timing-log");
    else if (arg == "--token-file")
      token_file = value("--token-file");
    else if (arg == "--insecure-no-token")
      insecure_no_token = true;
    else if (arg == "--timing-report")
      report = true;
    else if (arg == "--no-realtime")
      realtime = false, realtime_given = true;
    else if (arg == "--list-backends") {
      std::printf("%s\n", slscand::hal::available_backends().c_str());
      return 0;
    } else if (arg == "--port" || arg == "--views" || arg == "--exposure-us" || arg == "--period-us") {
      const char* text = value(arg.c_str());
      long* out = arg == "--port"          ? &port
                  : arg == "--views"       ? &views
                  : arg == "--exposure-us" ? &exposure_us
                                           : &period_us;
      const long max = arg == "--port" ? 65535 : arg == "--views" ? 360 : 10'000'000;
      if (!parse_int(text, arg == "--port" ? 0 : 1, max, *out)) {
        std::fprintf(stderr, "slscand: %s: '%s' is not an integer in range\n", arg.c_str(), text);
        return 2;
      }
    } else if (arg == "--version") {
      std::printf("%s (slproto %u..%u)\n", slscand::software_version(), unsigned{slproto::min_protocol_version},
                  unsigned{slproto::protocol_version});
      return 0;
    } else if (arg == "--help" || arg == "-h") {
      usage(stdout);
      return 0;
    } else {
      std::fprintf(stderr, "slscand: unknown argument '%s'\n", arg.c_str());
      usage(stderr);
      return 2;
    }
  }
  if (!config_path.empty()) {
    // The configuration fills in what the command line left out.
    auto config = slscand::load_daemon_config(config_path);
    if (!config) {
      std::fprintf(stderr, "slscand: %s\n", config.error().message.c_str());
      return 2;
    }
    if (board_path.empty()) board_path = config->board;
    if (!bind_given && config->bind_address) bind = *config->bind_address;
    if (port < 0 && config->port) port = *config->port;
    if (timing_dir.empty()) timing_dir = config->timing_log_dir;
    if (!realtime_given && config->realtime) realtime = *config->realtime;
    if (config->mdns && !*config->mdns) mdns = false;
    if (token_file.empty()) token_file = config->token_file;
  }
  if (board_path.empty()) {
    std::fprintf(stderr, "slscand: --board (or --config with a board) is required\n");
    usage(stderr);
    return 2;
  }
  auto board = slscand::hal::load_board(board_path);
  if (!board) {
    std::fprintf(stderr, "slscand: %s\n", board.error().message.c_str());
    return 2;
  }
  if (check) {
    slscand::CheckOptions options;
    options.bind_address = bind;
    options.port = static_cast<int>(port);
    options.token_file = token_file;
    options.token_given = false;
    options.realtime = realtime;
    const slscand::CheckReport result = slscand::check_board(*board, options);
    std::fputs(result.to_text().c_str(), stdout);
    return result.all_ok() ? 0 : 1;
  }
  if (!true_calibration_path.empty()) {
    // Only the simulation is opened: a hardware board's devices are not touched.
    slscand::hal::BoardDevices devices;
    if (auto opened = slscand::hal::open_board_simulation(*board, devices); !opened) {
      std::fprintf(stderr, "slscand: %s: %s\n", board_path.c_str(), opened.error().message.c_str());
      return 2;
    }
    auto truth = devices.true_calibration();
    if (!truth) {
      std::fprintf(stderr, "slscand: --write-true-calibration: board '%s' (%s): %s\n", board->name.c_str(),
                   board_path.c_str(), truth.error().message.c_str());
      return 2;
    }
    truth->created_by = std::string("slscand --write-true-calibration (") + slscand::software_version() + ")";
    if (auto saved = slproto::save_calibration(true_calibration_path, *truth); !saved) {
      std::fprintf(stderr, "slscand: %s\n", saved.error().message.c_str());
      return 1;
    }
    std::printf("slscand: wrote the true calibration of board '%s' to %s\n", board->name.c_str(),
                true_calibration_path.c_str());
    return 0;
  }
  // The network policy before any device is opened: a refused start touches no hardware.
  std::string token;
  if (!report) {
    if (!token_file.empty()) {
      auto read = slscand::read_token_file(token_file);
      if (!read) {
        std::fprintf(stderr, "slscand: %s\n", read.error().message.c_str());
        return 2;
      }
      token = std::move(*read);
    }
    const std::string address = bind.empty() ? board->bind_address : bind;
    if (auto policy = slscand::check_listen_policy(address, !token.empty(), insecure_no_token); !policy) {
      std::fprintf(stderr, "slscand: %s\n", policy.error().message.c_str());
      return 2;
    }
    if (token.empty() && !slscand::is_loopback_address(address)) {
      std::fprintf(stderr, "slscand: warning: --insecure-no-token: anyone who can reach %s can drive the scanner\n",
                   address.c_str());
    }
  }
  auto devices = slscand::hal::open_board_devices(*board);
  if (!devices) {
    std::fprintf(stderr, "slscand: cannot open the board's devices: %s\n", devices.error().message.c_str());
    return 1;
  }
  if (report) return timing_report(*board, *devices, views, exposure_us, period_us, realtime);

  slscand::DaemonOptions options;
  options.bind_address = bind;
  options.port = static_cast<int>(port);
  options.timing_log_dir = timing_dir;
  options.auth_token = token;
  options.realtime = realtime;
  auto daemon = slscand::Daemon::create(*board, std::move(*devices), options);
  if (!daemon) {
    std::fprintf(stderr, "slscand: %s\n", daemon.error().message.c_str());
    return 1;
  }
  // Announce the scanner on the local network (mDNS/DNS-SD) unless it only listens on loopback.
  const std::string listen_address = bind.empty() ? board->bind_address : bind;
  std::unique_ptr<slproto::MdnsPublisher> publisher;
  if (mdns && listen_address.rfind("127.", 0) != 0 && listen_address != "::1" && listen_address != "localhost") {
    char host[256] = {};
    (void)::gethostname(host, sizeof host - 1);
    slproto::ScannerAdvert advert{
        board->name,    slscand::software_version(), slproto::min_protocol_version, slproto::protocol_version,
        !token.empty(), (*daemon)->simulated()};
    auto started = slproto::MdnsPublisher::start("slscan " + board->name + " on " + host, (*daemon)->port(),
                                                 slproto::to_txt_records(advert));
    if (started) {
      publisher = std::move(*started);
      std::printf("slscand: mDNS: announcing %s on port %u (hosts find it with `slscan discover`)\n",
                  slproto::dns_sd_service_type, (*daemon)->port());
    } else {
      std::fprintf(stderr, "slscand: warning: %s; hosts can still connect to HOST:%u\n",
                   started.error().message.c_str(), (*daemon)->port());
    }
  }
  g_daemon = daemon->get();
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  std::signal(SIGPIPE, SIG_IGN);
  std::printf("slscand: board '%s' (%s), listening on %s:%u\n", board->name.c_str(),
              slscand::hal::available_backends().c_str(), bind.empty() ? board->bind_address.c_str() : bind.c_str(),
              (*daemon)->port());
  std::fflush(stdout);
  (*daemon)->serve();
  g_daemon = nullptr;
  return 0;
}
