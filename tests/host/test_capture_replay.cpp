// Replaying a capture trusts nothing it records (issue 17): the scan request is held to the
// limits a live scan has (at most 3600 views, known projectors) before anything is sized from
// it, and a capture that is not one consistent scan (a second request, frames before it, frames
// of a view, projector or pattern it does not have, a frame twice) is refused naming the byte
// offset of the offending record. The missing-frames report stays a few lines however much is
// missing.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>
#include <vector>

#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/framing.hpp"
#include "slproto/messages.hpp"
#include "slproto/pattern_plan.hpp"
#include "slscan/io/capture_replay.hpp"
#include "slscan/io/io_error.hpp"

namespace slscan::io {
namespace {

namespace fs = std::filesystem;

constexpr std::uint32_t kSide = 4;  // 4 x 4 mono8 frames: the checks are about the records, not pixels

slproto::pb::ScanRequest request(int views, const std::vector<std::uint32_t>& projectors = {0, 1}) {
  slproto::pb::ScanRequest r;
  r.set_scan_id(7);
  for (int i = 0; i < views; ++i) r.add_turntable_angles_deg(views > 1 ? 360.0 * i / views : 0.0);
  for (std::uint32_t p : projectors) r.add_projectors(p);
  *r.mutable_plan() = slproto::to_proto(slproto::PatternPlanConfig{});
  r.set_exposure_us(8333);
  r.set_pattern_period_us(10000);
  r.set_pixel_format(slproto::pb::PIXEL_FORMAT_MONO8);
  return r;
}

std::vector<std::byte> frame(std::uint32_t view, std::uint32_t projector, std::uint32_t pattern,
                             std::uint32_t exposure_index = 0) {
  slproto::pb::FrameHeader header;
  header.set_scan_id(7);
  header.set_view_index(view);
  header.set_projector_id(projector);
  header.set_pattern_index(pattern);
  header.set_exposure_index(exposure_index);
  slproto::set_frame_geometry(header, kSide, kSide);
  const std::vector<std::byte> pixels(kSide * kSide, std::byte{100});
  header.set_payload_crc32c(slproto::crc32c(pixels));
  std::vector<std::byte> record;
  EXPECT_TRUE(slproto::encode(header, pixels, record).ok());
  return record;
}

std::vector<std::byte> record_of(const slproto::pb::ScanRequest& r) {
  auto bytes = slproto::encode(r);
  EXPECT_TRUE(bytes.ok());
  return bytes.ok() ? *bytes : std::vector<std::byte>{};
}

class CaptureReplay : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_replay_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    path_ = (dir_ / "c.slcap").string();
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Writes the records as a capture and returns the byte offset of each.
  std::vector<std::uint64_t> write(const std::vector<std::vector<std::byte>>& records) {
    auto capture = slproto::CaptureWriter::create(path_);
    EXPECT_TRUE(capture.ok());
    std::vector<std::uint64_t> offsets;
    for (const auto& r : records) {
      offsets.push_back(capture->bytes_written());
      EXPECT_TRUE(capture->append(r).ok());
    }
    EXPECT_TRUE(capture->finish().ok());
    return offsets;
  }

  // The replay's error ("" when it succeeds), counting frames handed on.
  std::string replay_error(std::size_t* frames = nullptr) {
    std::size_t handed = 0;
    try {
      replay_capture(
          path_, [](const slproto::pb::ScanRequest&) {},
          [&](const slproto::pb::FrameHeader&, std::span<const std::byte>) { ++handed; });
    } catch (const IoError& e) {
      if (frames != nullptr) *frames = handed;
      return e.what();
    }
    if (frames != nullptr) *frames = handed;
    return "";
  }

  fs::path dir_;
  std::string path_;
};

TEST_F(CaptureReplay, AConsistentCaptureReplays) {
  write({record_of(request(2)), frame(0, 0, 0), frame(0, 1, 0), frame(1, 0, 3)});
  std::size_t frames = 0;
  EXPECT_EQ(replay_error(&frames), "");
  EXPECT_EQ(frames, 3u);
}

// HDR (docs/hdr.md): a bracket's frames fill one slot per exposure; an exposure index the request
// has no place for, or a bracket the protocol refuses, is named at its record.
TEST_F(CaptureReplay, ABracketedCaptureTakesOneFramePerExposureAndRefusesOthers) {
  auto bracketed = request(1);
  for (const std::uint32_t us : {8333u, 1000u}) bracketed.add_exposure_bracket_us(us);
  std::size_t frames = 0;
  write({record_of(bracketed), frame(0, 0, 0, 0), frame(0, 0, 0, 1), frame(0, 1, 3, 1)});
  EXPECT_EQ(replay_error(&frames), "");
  EXPECT_EQ(frames, 3u);

  auto offsets = write({record_of(bracketed), frame(0, 0, 0, 1), frame(0, 0, 0, 2)});
  EXPECT_NE(replay_error().find("record at offset " + std::to_string(offsets[2]) +
                                ": frame (view 0, projector 0, pattern 0) has exposure index 2 but the scan request "
                                "has a bracket of 2 exposures"),
            std::string::npos)
      << replay_error();
  write({record_of(request(1)), frame(0, 0, 0, 1)});
  EXPECT_NE(replay_error().find("has exposure index 1 but the scan request has no exposure bracket"), std::string::npos)
      << replay_error();
  offsets = write({record_of(bracketed), frame(0, 0, 0, 1), frame(0, 0, 0, 1)});
  EXPECT_NE(replay_error().find("repeats the frame at offset " + std::to_string(offsets[1])), std::string::npos)
      << replay_error();

  auto too_long = request(1);
  for (const std::uint32_t us : {8333u, 20000u}) too_long.add_exposure_bracket_us(us);
  write({record_of(too_long)});
  EXPECT_NE(replay_error().find("exposure_bracket_us[1] = 20000 is longer than pattern_period_us 10000"),
            std::string::npos)
      << replay_error();
  auto zero = request(1);
  for (const std::uint32_t us : {0u, 1000u}) zero.add_exposure_bracket_us(us);
  write({record_of(zero)});
  EXPECT_NE(replay_error().find("exposure_bracket_us[0] = 0 is 0"), std::string::npos) << replay_error();
}

// Issue 17 case 3: a 180 KB capture whose request named 20000 views x 20000 projectors made
// reprocessing allocate 3.7 GB. It is refused at the request, before anything is sized from it.
TEST_F(CaptureReplay, ARequestBeyondTheLimitsIsRefusedBeforeAnythingIsSized) {
  std::vector<std::uint32_t> many(20000);
  for (std::size_t i = 0; i < many.size(); ++i) many[i] = static_cast<std::uint32_t>(i % 2);
  write({record_of(request(20000, many)), frame(0, 0, 0)});
  const std::string error = replay_error();
  EXPECT_NE(error.find(path_ + ": record at offset "), std::string::npos) << error;
  EXPECT_NE(error.find("20000 turntable angles (at most 3600)"), std::string::npos) << error;

  write({record_of(request(3, many)), frame(0, 0, 0)});
  EXPECT_NE(replay_error().find("projectors[2] = 0 repeats"), std::string::npos) << replay_error();
  write({record_of(request(3, {0, 7})), frame(0, 0, 0)});
  EXPECT_NE(replay_error().find("projectors[1] = 7"), std::string::npos) << replay_error();

  // An angle of 1e308 is shown in a few digits, not 309.
  auto huge = request(2);
  huge.set_turntable_angles_deg(1, 1e308);
  write({record_of(huge)});
  const std::string angle = replay_error();
  EXPECT_NE(angle.find("turntable_angles_deg[1] = 1e+308 is not a finite angle"), std::string::npos) << angle;
  EXPECT_LT(angle.size(), 300u) << angle;
}

// Issue 17 case 11: duplicate frames, a second scan request and frames of a view the request
// does not have were replayed with exit 0 and no word.
TEST_F(CaptureReplay, AnInconsistentCaptureIsRefusedAtTheOffendingRecord) {
  auto offsets = write({record_of(request(2)), frame(0, 0, 0), frame(0, 0, 1), frame(0, 0, 0)});
  std::size_t frames = 0;
  std::string error = replay_error(&frames);
  EXPECT_NE(
      error.find(path_ + ": record at offset " + std::to_string(offsets[3]) +
                 ": frame (view 0, projector 0, pattern 0) repeats the frame at offset " + std::to_string(offsets[1])),
      std::string::npos)
      << error;
  EXPECT_EQ(frames, 2u);  // nothing of the repeated frame reached the reconstruction

  offsets = write({record_of(request(2)), frame(0, 0, 0), record_of(request(2)), frame(1, 0, 0)});
  error = replay_error();
  EXPECT_NE(error.find("record at offset " + std::to_string(offsets[2]) +
                       ": a second scan request (the first is at offset " + std::to_string(offsets[0]) + ")"),
            std::string::npos)
      << error;

  offsets = write({record_of(request(2)), frame(0, 0, 0), frame(2, 0, 0)});
  error = replay_error();
  EXPECT_NE(error.find("record at offset " + std::to_string(offsets[2]) +
                       ": frame (view 2, projector 0, pattern 0) is of a view the scan request"),
            std::string::npos)
      << error;
  EXPECT_NE(error.find("it has 2 views"), std::string::npos) << error;

  write({record_of(request(2, {1})), frame(0, 0, 0)});
  EXPECT_NE(replay_error().find("is of a projector the scan request"), std::string::npos) << replay_error();

  const std::size_t plan_size = slproto::PatternPlan(slproto::PatternPlanConfig{}).size();
  write({record_of(request(1)), frame(0, 0, static_cast<std::uint32_t>(plan_size))});
  EXPECT_NE(replay_error().find("is beyond the scan request's pattern plan of " + std::to_string(plan_size)),
            std::string::npos)
      << replay_error();

  auto bad_angle = frame(0, 0, 0);
  {
    // The same frame with a reported angle of 1e308: re-encode it.
    slproto::pb::FrameHeader header;
    header.set_scan_id(7);
    header.set_reported_angle_deg(1e308);
    slproto::set_frame_geometry(header, kSide, kSide);
    const std::vector<std::byte> pixels(kSide * kSide, std::byte{100});
    header.set_payload_crc32c(slproto::crc32c(pixels));
    bad_angle.clear();
    ASSERT_TRUE(slproto::encode(header, pixels, bad_angle).ok());
  }
  write({record_of(request(1)), bad_angle});
  EXPECT_NE(replay_error().find("frame (view 0, projector 0, pattern 0) has a turntable angle of 1e+308 deg"),
            std::string::npos)
      << replay_error();

  offsets = write({frame(0, 0, 0), record_of(request(1))});
  error = replay_error();
  EXPECT_NE(error.find("record at offset " + std::to_string(offsets[0]) +
                       ": frame (view 0, projector 0, pattern 0) comes before the scan request"),
            std::string::npos)
      << error;
}

TEST(MissingFrames, TheReportIsAFewLinesHoweverMuchIsMissing) {
  const auto r = request(3600);
  const std::size_t plan_size = slproto::PatternPlan(slproto::PatternPlanConfig{}).size();
  std::vector<slproto::pb::FrameHeader> received(3);
  received[0].set_view_index(0);
  received[0].set_projector_id(1);
  received[1].set_view_index(99999);  // not of the request: counted nowhere
  received[2].set_projector_id(5);
  const auto missing = describe_missing_frames(r, received);
  ASSERT_EQ(missing.size(), 21u);
  EXPECT_EQ(missing[0], "view 0 projector 0: 0 of " + std::to_string(plan_size) + " frames");
  EXPECT_EQ(missing[1], "view 0 projector 1: 1 of " + std::to_string(plan_size) + " frames");
  EXPECT_EQ(missing.back(), "and " + std::to_string(2 * 3600 - 20) + " more (view, projector) pairs, " +
                                std::to_string((2 * 3600 - 20) * plan_size) + " frames in all");
  // A request beyond the limits (what replay refuses) gives one line, not one per pair.
  slproto::pb::ScanRequest lying = request(20000);
  for (int i = 0; i < 20000; ++i) lying.add_projectors(0);
  EXPECT_EQ(describe_missing_frames(lying, {}).size(), 1u);
  EXPECT_TRUE(describe_missing_frames(request(1), {}).size() == 2u);
}

}  // namespace
}  // namespace slscan::io
