// Compressed captures (format version 2, zstd frames): lossless round trip, old files still
// read, and corrupt, mismatched and over-sized compressed payloads refused with their offset.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

#include "sample_messages.hpp"
#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/zstd_codec.hpp"

namespace {

using namespace slproto;
using ::testing::HasSubstr;
namespace fs = std::filesystem;

constexpr std::uint64_t created = 1'700'000'000'123'456'789ull;

class CaptureZstd : public ::testing::Test {
 protected:
  void SetUp() override {
    if (zstd_codec() == nullptr) GTEST_SKIP() << zstd_codec_description();
    dir_ = fs::temp_directory_path() / ("slproto_capture_zstd_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!dir_.empty()) fs::remove_all(dir_);
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  fs::path dir_;
};

std::vector<std::byte> read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::vector<char> chars((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::vector<std::byte> bytes(chars.size());
  std::memcpy(bytes.data(), chars.data(), chars.size());
  return bytes;
}
void write_all(const std::string& path, std::span<const std::byte> bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

// A frame like a camera's: a smooth fringe plus a little noise (compresses), or pure noise
// (does not: stored raw).
std::vector<std::byte> frame_payload(std::uint32_t width, std::uint32_t height, bool noise_only, unsigned seed) {
  std::mt19937 random(seed);
  std::vector<std::byte> pixels(std::size_t{width} * height);
  for (std::uint32_t y = 0; y < height; ++y)
    for (std::uint32_t x = 0; x < width; ++x) {
      const int value = noise_only
                            ? static_cast<int>(random() & 0xFF)
                            : 128 + static_cast<int>(100 * std::sin(x * 0.07 + seed)) + static_cast<int>(random() % 3);
      pixels[std::size_t{y} * width + x] = static_cast<std::byte>(std::clamp(value, 0, 255));
    }
  return pixels;
}

struct Record {
  std::vector<std::byte> wire;  // header + control + payload as received
};

// Sample records of every type, then frames (compressible, one of noise).
std::vector<Record> records() {
  std::vector<Record> out;
  for (const auto& sample : samples::sample_records()) {
    Record record;
    EXPECT_TRUE(encode(sample.body, sample.payload, record.wire).ok());
    out.push_back(std::move(record));
  }
  for (unsigned i = 0; i < 4; ++i) {
    pb::FrameHeader header = samples::sample_frame_header(320, 200);
    header.set_pattern_index(i);
    Record record;
    EXPECT_TRUE(encode(header, frame_payload(320, 200, i == 2, i), record.wire).ok());
    out.push_back(std::move(record));
  }
  return out;
}

// Writes the records through a writer (append(Message), as Connection::record_to does).
void write_capture(const std::string& file, const std::vector<Record>& list, const FrameCodec* codec) {
  Result<CaptureWriter> writer = CaptureWriter::create(file, {codec, created});
  ASSERT_TRUE(writer.ok()) << writer.error().message;
  for (const auto& record : list) {
    StreamDecoder decoder;
    ASSERT_TRUE(decoder.feed(record.wire).ok());
    ASSERT_TRUE(decoder.message_ready());
    Status status = writer->append(decoder.message());
    ASSERT_TRUE(status.ok()) << status.error().message;
  }
  Status status = writer->finish();
  ASSERT_TRUE(status.ok()) << status.error().message;
}

struct ReadBack {
  std::vector<std::vector<std::byte>> records;
  std::vector<std::uint64_t> offsets;
  std::optional<Error> error;
};
ReadBack read_capture(const std::string& file, const FrameCodec* codec, DecoderLimits limits = {}) {
  ReadBack out;
  Result<CaptureReader> reader = CaptureReader::open(file, limits, codec);
  if (!reader) {
    out.error = reader.error();
    return out;
  }
  for (;;) {
    Result<const Message*> next = reader->next();
    if (!next) {
      out.error = next.error();
      return out;
    }
    if (*next == nullptr) break;
    const Message& m = **next;
    std::vector<std::byte> wire(m.header_bytes.begin(), m.header_bytes.end());
    wire.insert(wire.end(), m.control.begin(), m.control.end());
    wire.insert(wire.end(), m.payload.begin(), m.payload.end());
    out.records.push_back(std::move(wire));
    out.offsets.push_back(m.stream_offset);
  }
  return out;
}

// Recomputes a stored record's payload CRC, control CRC and header CRC after a test edited it,
// so the framing accepts it and the codec's own checks are what is exercised.
void refresh_crcs(std::vector<std::byte>& file, std::uint64_t offset) {
  std::span<const std::byte, wire_header_size> header_bytes{file.data() + offset, wire_header_size};
  Result<WireHeader> header = WireHeader::parse(header_bytes, offset, max_payload_length, record_flag_compressed);
  ASSERT_TRUE(header.ok()) << header.error().message;
  const std::byte* control = file.data() + offset + wire_header_size;
  header->payload_crc = crc32c(control + header->control_length, header->payload_length);
  header->control_crc = control_crc(*header, {control, header->control_length});
  const auto bytes = header->serialize();
  std::copy(bytes.begin(), bytes.end(), file.begin() + static_cast<std::ptrdiff_t>(offset));
}

std::uint32_t get_u32(const std::byte* p) {
  std::uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= std::to_integer<std::uint32_t>(p[i]) << (8 * i);
  return v;
}
void put_u32(std::byte* p, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::byte>((v >> (8 * i)) & 0xFF);
}

// The first stored record that is compressed: its offset in the file.
std::uint64_t first_compressed_record(const std::string& file) {
  const ReadBack back = read_capture(file, zstd_codec());
  const auto bytes = read_all(file);
  for (std::uint64_t offset : back.offsets)
    if ((std::to_integer<unsigned>(bytes[offset + 7]) & record_flag_compressed) != 0) return offset;
  ADD_FAILURE() << "no compressed record in " << file;
  return 0;
}

TEST_F(CaptureZstd, CompressedCaptureReadsBackEveryRecordExactlyAsReceived) {
  const auto list = records();
  write_capture(path("raw.slcap"), list, nullptr);
  write_capture(path("zstd.slcap"), list, zstd_codec());
  const auto raw = read_all(path("raw.slcap"));
  const auto packed = read_all(path("zstd.slcap"));
  EXPECT_EQ(std::to_integer<int>(raw[8]), 1) << "a raw capture stays format version 1 (older readers read it)";
  EXPECT_EQ(std::to_integer<int>(packed[8]), 2);
  EXPECT_EQ(std::to_integer<int>(packed[24]), static_cast<int>(FrameCodecId::zstd));
  EXPECT_LT(packed.size() * 20, raw.size() * 19) << "fringe frames compress";

  for (const std::string name : {"raw.slcap", "zstd.slcap"}) {
    const ReadBack back = read_capture(path(name), zstd_codec());
    ASSERT_FALSE(back.error) << back.error->message;
    ASSERT_EQ(back.records.size(), list.size());
    for (std::size_t i = 0; i < list.size(); ++i) EXPECT_EQ(back.records[i], list[i].wire) << name << " record " << i;
  }
  // The noise frame is stored raw, the others compressed.
  Result<CaptureReader> reader = CaptureReader::open(path("zstd.slcap"), {}, zstd_codec());
  ASSERT_TRUE(reader.ok());
  EXPECT_EQ(reader->codec(), FrameCodecId::zstd);
  int compressed = 0, frames = 0;
  for (std::uint64_t offset : read_capture(path("zstd.slcap"), zstd_codec()).offsets) {
    if (std::to_integer<int>(packed[offset + 6]) != static_cast<int>(MessageType::frame)) continue;
    ++frames;
    compressed += std::to_integer<int>(packed[offset + 7]) & record_flag_compressed;
  }
  EXPECT_GE(frames, 5);
  EXPECT_EQ(compressed, 3) << "three fringe frames compressed; the sample and noise frames stored raw";
}

TEST_F(CaptureZstd, ConvertingBackGivesTheRawFileByteForByte) {
  const auto list = records();
  write_capture(path("raw.slcap"), list, nullptr);
  write_capture(path("zstd.slcap"), list, zstd_codec());
  Result<CaptureReader> reader = CaptureReader::open(path("zstd.slcap"), {}, zstd_codec());
  ASSERT_TRUE(reader.ok());
  Result<CaptureWriter> writer = CaptureWriter::create(path("back.slcap"), {nullptr, reader->created_unix_ns()});
  ASSERT_TRUE(writer.ok());
  for (;;) {
    auto next = reader->next();
    ASSERT_TRUE(next.ok()) << next.error().message;
    if (*next == nullptr) break;
    ASSERT_TRUE(writer->append(**next).ok());
  }
  ASSERT_TRUE(writer->finish().ok());
  EXPECT_EQ(read_all(path("back.slcap")), read_all(path("raw.slcap")));
}

TEST_F(CaptureZstd, ReadersWithoutTheCodecSaySoAndInMemoryReadingAgrees) {
  write_capture(path("zstd.slcap"), records(), zstd_codec());
  Result<CaptureReader> reader = CaptureReader::open(path("zstd.slcap"));
  ASSERT_FALSE(reader.ok());
  EXPECT_EQ(reader.error().code, Errc::unsupported);
  EXPECT_THAT(reader.error().message, HasSubstr("compressed with zstd"));

  const auto bytes = read_all(path("zstd.slcap"));
  std::vector<std::vector<std::byte>> seen;
  auto result = read_capture_bytes(
      bytes,
      [&](const Message& m) -> Status {
        std::vector<std::byte> wire(m.header_bytes.begin(), m.header_bytes.end());
        wire.insert(wire.end(), m.control.begin(), m.control.end());
        wire.insert(wire.end(), m.payload.begin(), m.payload.end());
        seen.push_back(std::move(wire));
        return Ok{};
      },
      {}, zstd_codec());
  ASSERT_TRUE(result.ok()) << result.error().message;
  EXPECT_EQ(seen, read_capture(path("zstd.slcap"), zstd_codec()).records);
}

TEST_F(CaptureZstd, FlagsAreRefusedInRawCapturesAndOnTheWire) {
  write_capture(path("zstd.slcap"), records(), zstd_codec());
  auto bytes = read_all(path("zstd.slcap"));
  const std::uint64_t offset = first_compressed_record(path("zstd.slcap"));
  // The same records under a version 1 header: the flag is not allowed there.
  bytes[8] = std::byte{1};
  bytes[24] = std::byte{0};
  put_u32(&bytes[28], crc32c(bytes.data(), 28));
  write_all(path("v1.slcap"), bytes);
  const ReadBack back = read_capture(path("v1.slcap"), zstd_codec());
  ASSERT_TRUE(back.error);
  EXPECT_THAT(back.error->message, HasSubstr("flags 1 must be 0"));
  EXPECT_THAT(back.error->message, HasSubstr("offset " + std::to_string(offset + 7)));
}

TEST_F(CaptureZstd, CorruptCompressedPayloadIsAnErrorNamingTheRecord) {
  write_capture(path("zstd.slcap"), records(), zstd_codec());
  const std::uint64_t offset = first_compressed_record(path("zstd.slcap"));
  auto bytes = read_all(path("zstd.slcap"));
  Result<WireHeader> header = WireHeader::parse(std::span<const std::byte, wire_header_size>(&bytes[offset], 32),
                                                offset, max_payload_length, record_flag_compressed);
  ASSERT_TRUE(header.ok());
  const std::uint64_t payload = offset + wire_header_size + header->control_length;
  // A flipped byte inside the zstd data: the stored CRC catches it first.
  auto flipped = bytes;
  flipped[payload + compressed_payload_prefix + header->payload_length / 2] ^= std::byte{0x5a};
  write_all(path("flipped.slcap"), flipped);
  ReadBack back = read_capture(path("flipped.slcap"), zstd_codec());
  ASSERT_TRUE(back.error);
  EXPECT_EQ(back.error->code, Errc::bad_checksum);
  EXPECT_THAT(back.error->message, HasSubstr("payload CRC mismatch"));
  EXPECT_THAT(back.error->message, HasSubstr("offset " + std::to_string(offset)));
  // The same with its CRCs recomputed (corrupt when written): zstd or the decoded CRC catches it.
  refresh_crcs(flipped, offset);
  write_all(path("flipped.slcap"), flipped);
  back = read_capture(path("flipped.slcap"), zstd_codec());
  ASSERT_TRUE(back.error);
  EXPECT_THAT(back.error->message, HasSubstr("compressed frame record at offset " + std::to_string(offset)));
  // Garbage instead of a zstd frame.
  auto garbage = bytes;
  for (std::uint64_t i = payload + compressed_payload_prefix; i < payload + header->payload_length; ++i)
    garbage[i] = std::byte{0x33};
  refresh_crcs(garbage, offset);
  write_all(path("garbage.slcap"), garbage);
  back = read_capture(path("garbage.slcap"), zstd_codec());
  ASSERT_TRUE(back.error);
  EXPECT_THAT(back.error->message, HasSubstr("compressed frame record at offset " + std::to_string(offset) + ": zstd"));
  EXPECT_THAT(back.error->message, HasSubstr("corrupt"));
}

TEST_F(CaptureZstd, DecodedSizeMismatchAndZstdBombAreRefusedBeforeDecoding) {
  write_capture(path("zstd.slcap"), records(), zstd_codec());
  const std::uint64_t offset = first_compressed_record(path("zstd.slcap"));
  const auto bytes = read_all(path("zstd.slcap"));
  Result<WireHeader> header = WireHeader::parse(std::span<const std::byte, wire_header_size>(&bytes[offset], 32),
                                                offset, max_payload_length, record_flag_compressed);
  ASSERT_TRUE(header.ok());
  const std::uint64_t payload = offset + wire_header_size + header->control_length;
  const std::uint32_t decoded = get_u32(&bytes[payload]);
  EXPECT_EQ(decoded, 320u * 200u);
  for (const std::uint32_t wrong : {decoded - 1, decoded + 1}) {
    auto edited = bytes;
    put_u32(&edited[payload], wrong);
    refresh_crcs(edited, offset);
    write_all(path("size.slcap"), edited);
    const ReadBack back = read_capture(path("size.slcap"), zstd_codec());
    ASSERT_TRUE(back.error) << wrong;
    EXPECT_THAT(back.error->message, HasSubstr("compressed frame record at offset " + std::to_string(offset)));
    EXPECT_THAT(back.error->message, HasSubstr("decoded size mismatch"));
  }
  // A bomb: a declared size over the frame limit is refused without allocating it.
  auto bomb = bytes;
  put_u32(&bomb[payload], 0xF0000000u);
  refresh_crcs(bomb, offset);
  write_all(path("bomb.slcap"), bomb);
  ReadBack back = read_capture(path("bomb.slcap"), zstd_codec());
  ASSERT_TRUE(back.error);
  EXPECT_EQ(back.error->code, Errc::oversized);
  EXPECT_THAT(back.error->message, HasSubstr("compressed frame record at offset " + std::to_string(offset) +
                                             ": declared decoded size 4026531840 exceeds the frame limit " +
                                             std::to_string(max_payload_length)));
  // A reader with a lower limit applies it to the decoded size too.
  DecoderLimits limits;
  limits.max_payload = header->payload_length + 100;  // the stored size passes, the decoded does not
  back = read_capture(path("zstd.slcap"), zstd_codec(), limits);
  ASSERT_TRUE(back.error);
  EXPECT_THAT(back.error->message, HasSubstr("exceeds the frame limit " + std::to_string(limits.max_payload)));
  // A stored payload shorter than its prefix.
  auto short_payload = bytes;
  header->payload_length = 4;
  header->payload_crc = crc32c(&short_payload[payload], 4);
  header->control_crc = control_crc(*header, {&short_payload[offset + 32], header->control_length});
  const auto serialized = header->serialize();
  std::copy(serialized.begin(), serialized.end(), short_payload.begin() + static_cast<std::ptrdiff_t>(offset));
  short_payload.resize(payload + 4);
  write_all(path("short.slcap"), short_payload);
  back = read_capture(path("short.slcap"), zstd_codec());
  ASSERT_TRUE(back.error);
  EXPECT_THAT(back.error->message, HasSubstr("shorter than its 8-byte prefix"));
}

TEST_F(CaptureZstd, UnknownCodecInTheHeaderIsRefused) {
  write_capture(path("zstd.slcap"), records(), zstd_codec());
  auto bytes = read_all(path("zstd.slcap"));
  bytes[24] = std::byte{7};
  put_u32(&bytes[28], crc32c(bytes.data(), 28));
  write_all(path("codec7.slcap"), bytes);
  const ReadBack back = read_capture(path("codec7.slcap"), zstd_codec());
  ASSERT_TRUE(back.error);
  EXPECT_THAT(back.error->message, HasSubstr("unknown frame codec 7"));
  EXPECT_THAT(back.error->message, HasSubstr("offset 24"));
}

}  // namespace
