// Firmware timing and streaming on this machine, printed as tables:
//   scan     slscand (in-process, the real Daemon, sequencer and streamer) serves a sim scan to
//            a client over 127.0.0.1; the board's timing report (pattern period, jitter,
//            trigger-to-exposure latency, ...) and what the client received (frames/s, MB/s)
//   stream   the streamer path alone: a producer pushes ready frames into the sequencer's
//            bounded queue, the streamer thread sends them (header with timing events, CRC)
//            and a loopback client receives them; the highest frame rate the board's
//            streaming could carry, at the sim size and at full resolution
// Usage: bench_firmware [--board FILE] [--views N] [--exposure-us E] [--period-us P]
//                       [--stream-frames N] [--realtime]
// The sim scan runs without SCHED_FIFO unless --realtime (and the process may use it).
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "slproto/handshake.hpp"
#include "slproto/transport.hpp"
#include "slscand/app/daemon.hpp"
#include "slscand/sequencer/bounded_queue.hpp"

namespace {

using namespace slscand;
using namespace std::chrono_literals;
namespace pb = slproto::pb;
using Clock = std::chrono::steady_clock;

struct Options {
  std::string board = std::string(SLSCAN_SOURCE_DIR) + "/boards/sim.toml";
  long views = 6;
  long exposure_us = 0;  // 0 = the board's
  long period_us = 0;
  long stream_frames = 200;
  bool realtime = false;
};

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "bench_firmware: %s\n", what.c_str());
  std::exit(1);
}

long parse_long(const char* name, const char* text, long min, long max) {
  char* end = nullptr;
  const long v = std::strtol(text, &end, 10);
  if (end == text || *end != '\0' || v < min || v > max) {
    die(std::string(name) + ": '" + text + "' is not an integer in [" + std::to_string(min) + ", " +
        std::to_string(max) + "]");
  }
  return v;
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&]() -> const char* {
      if (i + 1 >= argc) die(arg + " needs a value");
      return argv[++i];
    };
    if (arg == "--board")
      o.board = value();
    else if (arg == "--views")
      o.views = parse_long("--views", value(), 1, 360);
    else if (arg == "--exposure-us")
      o.exposure_us = parse_long("--exposure-us", value(), 1, 10'000'000);
    else if (arg == "--period-us")
      o.period_us = parse_long("--period-us", value(), 1, 10'000'000);
    else if (arg == "--stream-frames")
      o.stream_frames = parse_long("--stream-frames", value(), 1, 1'000'000);
    else if (arg == "--realtime")
      o.realtime = true;
    else
      die("unknown argument '" + arg + "' (see the comment at the top of bench/firmware/bench_firmware.cpp)");
  }
  return o;
}

double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec) * 1e-9;
}

void print_report(const TimingReport& r) {
  std::printf("| interval (us) | count | mean | min | p50 | p99 | max |\n|---|---:|---:|---:|---:|---:|---:|\n");
  for (const TimingSummary& s : r.all()) {
    std::printf("| %s | %llu | %.1f | %.1f | %.1f | %.1f | %.1f |\n", s.name.c_str(),
                static_cast<unsigned long long>(s.count), s.mean_us, s.min_us, s.p50_us, s.p99_us, s.max_us);
  }
}

// slscand serving one sim scan over loopback to a client in this process.
void bench_scan(const Options& o) {
  auto board = hal::load_board(o.board);
  if (!board) die(board.error().message);
  if (!board->is_sim()) die(o.board + " is not a sim board: this benchmark needs no hardware and uses none");
  auto devices = hal::open_board_devices(*board);
  if (!devices) die("cannot open the board's devices: " + devices.error().message);
  const hal::CameraFormat format = devices->camera_format;
  DaemonOptions options;
  options.port = 0;
  options.bind_address = "127.0.0.1";
  options.realtime = o.realtime;
  auto daemon = Daemon::create(*board, std::move(*devices), options);
  if (!daemon) die(daemon.error().message);
  std::thread server([&] { (*daemon)->serve(); });

  auto connection = slproto::connect("127.0.0.1", (*daemon)->port(), 5s);
  if (!connection) die(connection.error().message);
  if (auto hello = slproto::client_handshake(*connection, slproto::make_hello("bench_firmware", "0")); !hello) {
    die(hello.error().message);
  }
  pb::ScanRequest request;
  request.set_scan_id(1);
  for (long v = 0; v < o.views; ++v) request.add_turntable_angles_deg(360.0 / static_cast<double>(o.views) * v);
  request.add_projectors(0);
  request.add_projectors(1);
  *request.mutable_plan() = slproto::to_proto(slproto::PatternPlanConfig{});
  const double exposure_us = o.exposure_us > 0 ? static_cast<double>(o.exposure_us) : board->pattern_exposure_us;
  const double period_us = o.period_us > 0 ? static_cast<double>(o.period_us) : board->pattern_period_us;
  request.set_exposure_us(static_cast<std::uint32_t>(exposure_us));
  request.set_pattern_period_us(static_cast<std::uint32_t>(period_us));
  request.set_pixel_format(to_proto(format.pixel_format));
  request.set_timing_events(true);

  const auto start = Clock::now();
  if (auto s = connection->send(request); !s) die(s.error().message);
  std::uint64_t frames = 0, bytes = 0, next_sequence = 0;
  Clock::time_point first{}, last{};
  std::optional<pb::ScanDone> done;
  while (!done) {
    auto m = connection->receive(60s);
    if (!m) die("receiving the scan: " + m.error().message);
    if (const auto* f = m->get<pb::FrameHeader>()) {
      if (f->sequence() != next_sequence) die("frame " + std::to_string(f->sequence()) + " arrived out of order");
      ++next_sequence;
      if (frames++ == 0) first = Clock::now();
      last = Clock::now();
      bytes += m->payload.size();
    } else if (const auto* d = m->get<pb::ScanDone>()) {
      done = *d;
    } else if (const auto* e = m->get<pb::Error>()) {
      std::fprintf(stderr, "bench_firmware: the board reported: %s\n", e->text().c_str());
    }
  }
  const double wall = std::chrono::duration<double>(Clock::now() - start).count();
  connection->close();
  (*daemon)->stop();
  server.join();
  if (done->final_state() != pb::SCAN_STATE_DONE) die("the sim scan did not complete: " + done->text());

  const DaemonStats stats = (*daemon)->stats();
  const double stream_s = std::chrono::duration<double>(last - first).count();
  std::printf("## sim scan served over loopback\n\n");
  std::printf(
      "board %s, %ld views x 2 projectors x %u patterns = %llu frames of %d x %d %s; exposure %.0f us, "
      "period %.0f us; realtime %s\n\n",
      board->name.c_str(), o.views, static_cast<unsigned>(slproto::PatternPlan().size()),
      static_cast<unsigned long long>(frames), format.width, format.height, hal::pixel_format_name(format.pixel_format),
      exposure_us, period_us, o.realtime ? "requested" : "off");
  print_report(stats.last_timing);
  std::printf("\n| delivery | value |\n|---|---:|\n");
  std::printf("| scan wall time (request -> ScanDone) | %.2f s |\n", wall);
  std::printf("| frames received, in order | %llu |\n", static_cast<unsigned long long>(frames));
  std::printf("| first -> last frame | %.2f s |\n", stream_s);
  std::printf("| frame rate while streaming | %.1f frames/s |\n", stream_s > 0 ? (frames - 1) / stream_s : 0.0);
  std::printf("| payload throughput | %.1f MB/s |\n",
              stream_s > 0 ? static_cast<double>(bytes) * 1e-6 / stream_s : 0.0);
  std::printf("| back-pressure pauses (full queue) | %llu |\n",
              static_cast<unsigned long long>(stats.last_backpressure_pauses));
  std::printf("| triggers paused (period excluded) | %llu |\n\n",
              static_cast<unsigned long long>(stats.last_timing.paused_frames));
}

// The daemon's streaming path without the sequencer: BoundedQueue -> streamer thread
// (make_frame_header with timing events + send_frame) -> loopback client (receive, CRC check).
void bench_stream(int width, int height, long count) {
  auto server = slproto::Server::listen("127.0.0.1", 0);
  if (!server) die(server.error().message);
  BoundedQueue<SequencedFrame> queue(8);
  std::atomic<bool> abort{false};
  SequencedFrame prototype;
  prototype.frame.format.width = width;
  prototype.frame.format.height = height;
  prototype.frame.format.pixel_format = hal::PixelFormat::mono8;
  prototype.frame.format.stride_bytes = static_cast<std::size_t>(width);
  prototype.frame.pixels.resize(prototype.frame.format.frame_bytes());
  for (std::size_t i = 0; i < prototype.frame.pixels.size(); ++i) {
    prototype.frame.pixels[i] = static_cast<std::uint8_t>(i * 7 + i / 4096);
  }
  for (int k = 0; k < 7; ++k) prototype.events.push_back({pb::TIMING_EVENT_PROJECTOR_TRIGGER, 1000 + k, 0});
  const std::size_t frame_bytes = prototype.frame.pixels.size();

  // Frames are copied outside the timed region: a camera hands over buffers it has filled.
  std::vector<SequencedFrame> ready(static_cast<std::size_t>(std::min<long>(count, 16)), prototype);
  std::uint64_t pauses = 0;
  double streamer_cpu = 0;
  std::thread board([&] {
    auto connection = server->accept(5s);
    if (!connection) die("accept: " + connection.error().message);
    std::thread producer([&] {
      for (long i = 0; i < count; ++i) {
        SequencedFrame item = ready[static_cast<std::size_t>(i) % ready.size()];
        item.sequence = static_cast<std::uint64_t>(i);
        if (queue.full()) pauses++;
        if (!queue.push(item, abort)) return;
      }
      queue.close();
    });
    const double cpu0 = thread_cpu_seconds();
    for (;;) {
      std::optional<SequencedFrame> item = queue.pop(50ms);
      if (!item) {
        if (queue.closed_and_empty()) break;
        continue;
      }
      const pb::FrameHeader header = make_frame_header(*item, true);
      if (auto s = connection->send_frame(header, std::as_bytes(std::span(item->frame.pixels))); !s) {
        die("send_frame: " + s.error().message);
      }
    }
    streamer_cpu = thread_cpu_seconds() - cpu0;
    producer.join();
    (void)connection->receive(5s);  // until the client closes
  });
  auto host = slproto::connect("127.0.0.1", server->port(), 5s);
  if (!host) die(host.error().message);
  const auto start = Clock::now();
  long received = 0;
  while (received < count) {
    auto m = host->receive(10s);
    if (!m) die("receive: " + m.error().message);
    if (const auto* f = m->get<pb::FrameHeader>()) {
      if (f->sequence() != static_cast<std::uint64_t>(received)) die("stream frame out of order");
      ++received;
    }
  }
  const double wall = std::chrono::duration<double>(Clock::now() - start).count();
  host->close();
  board.join();
  const double mb = static_cast<double>(frame_bytes) * static_cast<double>(count) * 1e-6;
  std::printf("| %d x %d mono8 (%.2f MB) | %ld | %.0f | %.0f | %.0f | %llu |\n", width, height,
              static_cast<double>(frame_bytes) * 1e-6, count, count / wall, mb / wall,
              streamer_cpu > 0 ? mb / streamer_cpu : 0.0, static_cast<unsigned long long>(pauses));
}

// The figures depend on what else runs: say how busy the machine was.
std::string machine_load() {
  std::ifstream in("/proc/loadavg");
  double one = 0;
  in >> one;
  char text[96];
  std::snprintf(text, sizeof text, "%u cores, load average %.1f (1 min)", std::thread::hardware_concurrency(), one);
  return text;
}

}  // namespace

int main(int argc, char** argv) {
  const Options o = parse(argc, argv);
  std::printf("bench_firmware on %s\n\n", machine_load().c_str());
  bench_scan(o);
  std::printf("## streamer path alone (queue -> header + send_frame -> loopback client)\n\n");
  std::printf(
      "| frame | frames | frames/s | MB/s (wall) | MB per streamer CPU-second | pushes that found the queue full |\n"
      "|---|---:|---:|---:|---:|---:|\n");
  bench_stream(640, 512, o.stream_frames * 4);
  bench_stream(2464, 2056, o.stream_frames);
  return 0;
}
