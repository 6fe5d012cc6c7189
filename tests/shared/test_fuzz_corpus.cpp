// Replays the committed fuzz seed corpus (and any crash reproducers added to it) through the
// fuzz targets' property checks, so they run in every build, not only the fuzz preset.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "../fuzz/fuzz_checks.hpp"
#include "../fuzz/fuzz_discovery_checks.hpp"
#include "../fuzz/fuzz_text_checks.hpp"

namespace {

namespace fs = std::filesystem;

std::vector<std::uint8_t> read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::size_t replay(const std::string& target, void (*check)(const std::uint8_t*, std::size_t)) {
  const fs::path dir = fs::path(SLSCAN_SOURCE_DIR) / "tests" / "fuzz" / "corpus" / target;
  std::size_t files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const auto bytes = read_file(entry.path());
    SCOPED_TRACE(entry.path().string());
    check(bytes.data(), bytes.size());  // aborts on a violated property
    ++files;
  }
  return files;
}

TEST(FuzzCorpus, FrameDecoderSeedsPassTheProperties) {
  EXPECT_GE(replay("frame_decoder", slproto::fuzz::check_frame_decoder), 10u);
}

TEST(FuzzCorpus, CaptureReaderSeedsPassTheProperties) {
  EXPECT_GE(replay("capture_reader", slproto::fuzz::check_capture_reader), 3u);
}

TEST(FuzzCorpus, PatternPlanAndCalibrationSeedsPassTheProperties) {
  EXPECT_GE(replay("pattern_plan", slproto::fuzz::check_pattern_plan_text), 3u);
  EXPECT_GE(replay("calibration_file", slproto::fuzz::check_calibration_text), 2u);
}

TEST(FuzzCorpus, TxtRecordSeedsPassTheProperties) {
  EXPECT_GE(replay("txt_records", slproto::fuzz::check_txt_records), 6u);
}

TEST(FuzzCorpus, SeedsDecodeAsIntended) {
  // The seeds must exercise the success paths, not only rejections.
  const fs::path dir = fs::path(SLSCAN_SOURCE_DIR) / "tests" / "fuzz" / "corpus" / "frame_decoder";
  const auto stream = read_file(dir / "stream_all_types");
  const auto summary =
      slproto::fuzz::decode_stream({reinterpret_cast<const std::byte*>(stream.data()), stream.size()}, 0);
  EXPECT_EQ(summary.records, 9u);
  EXPECT_FALSE(summary.failed);
  const auto corrupt = read_file(dir / "stream_corrupt");
  EXPECT_TRUE(
      slproto::fuzz::decode_stream({reinterpret_cast<const std::byte*>(corrupt.data()), corrupt.size()}, 0).failed);
}

}  // namespace
