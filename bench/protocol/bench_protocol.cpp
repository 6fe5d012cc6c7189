// Protocol throughput on full-resolution frames (2464 x 2056 mono8, 5.07 MB):
//   crc32c      hardware and portable CRC32C over one frame
//   loopback    server thread -> client thread over 127.0.0.1: send_frame (writev, CRC) and
//               receive (decode + CRC check), payload MB/s
//   capture     CaptureWriter::append of received frames (page cache) and fdatasync, then
//               CaptureReader over the same file
// Usage: bench_protocol [frames=300] [capture_dir=/tmp] [repeats=3]
// Prints the median of `repeats` runs (and min..max) for each figure.
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/transport.hpp"

namespace {

using namespace slproto;
using Clock = std::chrono::steady_clock;
constexpr std::uint32_t width = 2464, height = 2056;
constexpr std::size_t frame_bytes = std::size_t{width} * height;

double seconds_since(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// CPU time each side spent per payload byte: on a shared, loaded machine wall-clock MB/s
// says more about the neighbours than about us, so we also report bytes per CPU-second of
// the busier thread (the rate an otherwise idle 2-core machine would reach).
struct CpuCost {
  double sender_seconds = 0;
  double receiver_seconds = 0;
  std::uint64_t bytes = 0;
};

struct Figure {
  std::vector<double> runs;
  void print(const char* name, const char* unit) {
    std::sort(runs.begin(), runs.end());
    std::printf("%-34s %9.0f %s  (min %.0f, max %.0f, %zu runs)\n", name, runs[runs.size() / 2], unit, runs.front(),
                runs.back(), runs.size());
  }
};

std::vector<std::byte> make_image() {
  std::vector<std::byte> image(frame_bytes);
  std::uint32_t state = 1;
  for (auto& b : image) {
    state = state * 1664525u + 1013904223u;
    b = static_cast<std::byte>(state >> 24);
  }
  return image;
}

pb::FrameHeader frame_header(std::uint64_t sequence) {
  pb::FrameHeader header;
  header.set_scan_id(1);
  header.set_sequence(sequence);
  header.set_pattern_kind(pb::PATTERN_KIND_PHASE_STEP);
  set_frame_geometry(header, width, height, pb::PIXEL_FORMAT_MONO8);
  return header;
}

// Streams `frames` frames; if `capture` is set the client records them as they arrive.
// Returns payload MB/s seen by the client, or a negative number on failure.
double loopback(int frames, const std::vector<std::byte>& image, CaptureWriter* capture, CpuCost* cost = nullptr) {
  Result<Server> server = Server::listen("127.0.0.1", 0);
  if (!server) {
    std::fprintf(stderr, "listen: %s\n", server.error().message.c_str());
    return -1;
  }
  std::thread sender([&] {
    Result<Connection> board = server->accept(std::chrono::seconds(5));
    if (!board) return;
    const double cpu_start = thread_cpu_seconds();
    for (int i = 0; i < frames; ++i) {
      if (Status status = board->send_frame(frame_header(static_cast<std::uint64_t>(i)), image); !status) {
        std::fprintf(stderr, "send_frame: %s\n", status.error().message.c_str());
        return;
      }
    }
    if (cost != nullptr) cost->sender_seconds = thread_cpu_seconds() - cpu_start;
    (void)board->send(pb::ScanDone{});
    (void)board->receive(std::chrono::seconds(5));
  });
  Result<Connection> host = connect("127.0.0.1", server->port(), std::chrono::seconds(5));
  if (!host) {
    std::fprintf(stderr, "connect: %s\n", host.error().message.c_str());
    sender.join();
    return -1;
  }
  if (capture != nullptr) host->record_to(capture);
  std::uint64_t bytes = 0;
  Clock::time_point start;
  bool started = false;
  const double cpu_start = thread_cpu_seconds();
  while (true) {
    Result<Message> message = host->receive(std::chrono::seconds(10));
    if (!message) {
      std::fprintf(stderr, "receive: %s\n", message.error().message.c_str());
      break;
    }
    if (message->type() == MessageType::scan_done) break;
    if (!started) {  // time from the first frame's arrival: excludes connection set-up
      start = Clock::now();
      started = true;
      continue;
    }
    bytes += message->payload.size();
  }
  const double seconds = seconds_since(start);
  const double receiver_cpu = thread_cpu_seconds() - cpu_start;
  host->close();
  sender.join();
  if (cost != nullptr) {
    cost->receiver_seconds = receiver_cpu;
    cost->bytes = bytes + image.size();
  }
  return static_cast<double>(bytes) / 1e6 / seconds;
}

}  // namespace

int main(int argc, char** argv) {
  const int frames = argc > 1 ? std::atoi(argv[1]) : 300;
  const std::filesystem::path dir = argc > 2 ? argv[2] : "/tmp";
  const int repeats = argc > 3 ? std::atoi(argv[3]) : 3;
  const auto image = make_image();
  std::printf("frames of %u x %u mono8 (%.2f MB); %d frames per run; CRC32C hardware: %s\n", width, height,
              static_cast<double>(frame_bytes) / 1e6, frames, crc32c_hardware_accelerated() ? "yes" : "no");

  Figure crc_hw, crc_portable, stream, stream_cpu, sender_cpu, receiver_cpu, stream_recording, capture_write,
      capture_sync, capture_read;
  for (int r = 0; r < repeats; ++r) {
    auto start = Clock::now();
    std::uint32_t sink = 0;
    for (int i = 0; i < 20; ++i) sink ^= crc32c(image);
    crc_hw.runs.push_back(20.0 * static_cast<double>(frame_bytes) / 1e6 / seconds_since(start));
    start = Clock::now();
    for (int i = 0; i < 5; ++i) sink ^= crc32c_portable(image.data(), image.size());
    crc_portable.runs.push_back(5.0 * static_cast<double>(frame_bytes) / 1e6 / seconds_since(start));
    if (sink == 0x12345678u) std::printf(" ");  // keeps the loops from being optimised away

    CpuCost cost;
    stream.runs.push_back(loopback(frames, image, nullptr, &cost));
    const double mb = static_cast<double>(cost.bytes) / 1e6;
    stream_cpu.runs.push_back(mb / std::max(cost.sender_seconds, cost.receiver_seconds));
    sender_cpu.runs.push_back(mb / cost.sender_seconds);
    receiver_cpu.runs.push_back(mb / cost.receiver_seconds);

    const std::string path = (dir / "bench_protocol.slcap").string();
    {
      Result<CaptureWriter> writer = CaptureWriter::create(path);
      if (!writer) {
        std::fprintf(stderr, "%s\n", writer.error().message.c_str());
        return 1;
      }
      stream_recording.runs.push_back(loopback(frames, image, &*writer));
      // Write rate alone: append pre-encoded records as fast as the file takes them.
      std::vector<std::byte> record;
      if (Status status = encode(frame_header(0), image, record); !status) return 1;
      Result<CaptureWriter> direct = CaptureWriter::create(path + ".direct");
      if (!direct) return 1;
      start = Clock::now();
      for (int i = 0; i < frames; ++i)
        if (Status status = direct->append(record); !status) {
          std::fprintf(stderr, "%s\n", status.error().message.c_str());
          return 1;
        }
      const double write_seconds = seconds_since(start);
      capture_write.runs.push_back(static_cast<double>(direct->bytes_written()) / 1e6 / write_seconds);
      const std::uint64_t written = direct->bytes_written();
      start = Clock::now();
      if (Status status = direct->finish(); !status) return 1;
      capture_sync.runs.push_back(static_cast<double>(written) / 1e6 / (write_seconds + seconds_since(start)));
      (void)writer->finish();
    }
    {
      Result<CaptureReader> reader = CaptureReader::open(path + ".direct");
      if (!reader) return 1;
      start = Clock::now();
      std::uint64_t bytes = 0;
      while (true) {
        Result<const Message*> message = reader->next();
        if (!message || *message == nullptr) break;
        bytes += (*message)->payload.size();
      }
      capture_read.runs.push_back(static_cast<double>(bytes) / 1e6 / seconds_since(start));
    }
    std::filesystem::remove(path);
    std::filesystem::remove(path + ".direct");
  }
  crc_hw.print("crc32c (dispatch)", "MB/s");
  crc_portable.print("crc32c slicing-by-8", "MB/s");
  stream.print("loopback frame stream (wall)", "MB/s");
  sender_cpu.print("  sender: MB per CPU-second", "MB/s");
  receiver_cpu.print("  receiver: MB per CPU-second", "MB/s");
  stream_cpu.print("  bound by the busier thread", "MB/s");
  stream_recording.print("loopback stream + capture", "MB/s");
  capture_write.print("capture append (page cache)", "MB/s");
  capture_sync.print("capture append + fdatasync", "MB/s");
  capture_read.print("capture read (warm cache)", "MB/s");
  return 0;
}
