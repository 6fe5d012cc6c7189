// Compressed captures: ratio, compression and decompression speed of the frame codec on the
// frames of real captures (docs/scale.md). Usage:
//   bench_capture_codec CAPTURE.slcap... [--levels 1,3] [--json out.json]
// For each capture and zstd level: every frame payload is compressed and decompressed in
// memory (one thread, the CPU the recording and the reprocess use), timed apart from reading
// the file; the decoded bytes are checked against the original.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "slproto/capture.hpp"
#include "slproto/zstd_codec.hpp"

using namespace slproto;
using Clock = std::chrono::steady_clock;

int main(int argc, char** argv) {
  std::vector<std::string> captures;
  std::vector<int> levels{1, 3};
  std::string json_path;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--levels" && i + 1 < argc) {
      levels.clear();
      std::string list = argv[++i];
      for (std::size_t start = 0; start < list.size();) {
        const std::size_t comma = std::min(list.find(',', start), list.size());
        levels.push_back(std::stoi(list.substr(start, comma - start)));
        start = comma + 1;
      }
    } else if (arg == "--json" && i + 1 < argc) {
      json_path = argv[++i];
    } else {
      captures.push_back(arg);
    }
  }
  if (captures.empty() || zstd_codec() == nullptr) {
    std::fprintf(stderr, "usage: bench_capture_codec CAPTURE.slcap... [--levels 1,3] [--json out.json] (%s)\n",
                 zstd_codec_description());
    return 1;
  }
  nlohmann::json report = nlohmann::json::array();
  std::printf("%-40s %5s %7s %9s %8s %12s %12s\n", "capture", "level", "frames", "raw MB", "ratio", "compress MB/s",
              "decode MB/s");
  for (const auto& path : captures) {
    std::vector<std::vector<std::byte>> frames;
    auto reader = CaptureReader::open(path, {}, zstd_codec());
    if (!reader) {
      std::fprintf(stderr, "%s\n", reader.error().message.c_str());
      return 2;
    }
    for (;;) {
      auto next = reader->next();
      if (!next) {
        std::fprintf(stderr, "%s\n", next.error().message.c_str());
        return 2;
      }
      if (*next == nullptr) break;
      if ((*next)->type() == MessageType::frame) frames.emplace_back((*next)->payload.begin(), (*next)->payload.end());
    }
    double raw = 0;
    for (const auto& f : frames) raw += static_cast<double>(f.size());
    for (int level : levels) {
      const auto codec = make_zstd_codec(level);
      std::vector<std::vector<std::byte>> packed(frames.size());
      const auto t0 = Clock::now();
      for (std::size_t i = 0; i < frames.size(); ++i)
        if (!codec->compress(frames[i], packed[i])) return 3;
      const auto t1 = Clock::now();
      std::vector<std::byte> out;
      for (std::size_t i = 0; i < frames.size(); ++i) {
        out.resize(frames[i].size());
        if (Status s = codec->decompress(packed[i], out); !s) {
          std::fprintf(stderr, "decode: %s\n", s.error().message.c_str());
          return 3;
        }
      }
      const auto t2 = Clock::now();
      for (std::size_t i = 0; i < frames.size(); ++i) {  // check outside the timing
        out.resize(frames[i].size());
        (void)codec->decompress(packed[i], out);
        if (out != frames[i]) {
          std::fprintf(stderr, "frame %zu does not decode to itself\n", i);
          return 4;
        }
      }
      double stored = 0;
      for (const auto& p : packed) stored += static_cast<double>(p.size() + compressed_payload_prefix);
      const double compress_s = std::chrono::duration<double>(t1 - t0).count();
      const double decode_s = std::chrono::duration<double>(t2 - t1).count();
      std::printf("%-40s %5d %7zu %9.1f %8.2f %12.0f %12.0f\n", path.c_str(), level, frames.size(), raw / 1e6,
                  raw / stored, raw / 1e6 / compress_s, raw / 1e6 / decode_s);
      report.push_back({{"capture", path},
                        {"level", level},
                        {"frames", frames.size()},
                        {"raw_bytes", raw},
                        {"stored_bytes", stored},
                        {"ratio", raw / stored},
                        {"compress_mb_s", raw / 1e6 / compress_s},
                        {"decode_mb_s", raw / 1e6 / decode_s}});
    }
  }
  if (!json_path.empty()) {
    std::FILE* f = std::fopen(json_path.c_str(), "w");
    if (f == nullptr) return 2;
    std::fputs(report.dump(2).c_str(), f);
    std::fclose(f);
  }
  return 0;
}
