#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <unistd.h>

#include <csignal>
#include <filesystem>
#include <fstream>

#include "sample_messages.hpp"
#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"

namespace {

using namespace slproto;
using ::testing::HasSubstr;
namespace fs = std::filesystem;

class Capture : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slproto_capture_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
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

// Writes every sample record (two rounds) through a CaptureWriter; returns the record offsets.
std::vector<std::uint64_t> write_samples(const std::string& path) {
  Result<CaptureWriter> writer = CaptureWriter::create(path);
  EXPECT_TRUE(writer.ok()) << writer.error().message;
  std::vector<std::uint64_t> offsets;
  for (int round = 0; round < 2; ++round) {
    for (const auto& sample : samples::sample_records()) {
      std::vector<std::byte> record;
      EXPECT_TRUE(encode(sample.body, sample.payload, record).ok());
      offsets.push_back(writer->bytes_written());
      Status status = writer->append(record);
      EXPECT_TRUE(status.ok()) << status.error().message;
    }
  }
  Status status = writer->finish();
  EXPECT_TRUE(status.ok()) << status.error().message;
  return offsets;
}

TEST_F(Capture, RoundTripEveryMessageType) {
  const std::string file = path("scan.slcap");
  const auto offsets = write_samples(file);
  EXPECT_FALSE(fs::exists(file + ".partial"));
  Result<CaptureReader> reader = CaptureReader::open(file);
  ASSERT_TRUE(reader.ok()) << reader.error().message;
  EXPECT_EQ(reader->protocol_version(), framing_version);
  EXPECT_GT(reader->created_unix_ns(), 1'600'000'000'000'000'000ull);
  const auto samples = samples::sample_records();
  for (std::size_t i = 0; i < offsets.size(); ++i) {
    Result<const Message*> message = reader->next();
    ASSERT_TRUE(message.ok()) << message.error().message;
    ASSERT_NE(*message, nullptr) << "record " << i;
    const auto& sample = samples[i % samples.size()];
    EXPECT_EQ((*message)->type(), type_of(sample.body));
    EXPECT_EQ((*message)->stream_offset, offsets[i]);
    Body expected = sample.body;
    if (auto* frame = std::get_if<pb::FrameHeader>(&expected)) frame->set_payload_crc32c(crc32c(sample.payload));
    EXPECT_EQ(as_message_lite((*message)->body).SerializeAsString(), as_message_lite(expected).SerializeAsString());
    EXPECT_TRUE(std::equal((*message)->payload.begin(), (*message)->payload.end(), sample.payload.begin(),
                           sample.payload.end()));
  }
  Result<const Message*> end = reader->next();
  ASSERT_TRUE(end.ok());
  EXPECT_EQ(*end, nullptr);
  EXPECT_FALSE(reader->truncation().has_value());
  EXPECT_EQ(reader->records_read(), offsets.size());
}

TEST_F(Capture, AppendMessageWritesTheExactWireBytes) {
  std::vector<std::byte> stream;
  for (const auto& sample : samples::sample_records()) ASSERT_TRUE(encode(sample.body, sample.payload, stream).ok());
  StreamDecoder decoder;
  Result<CaptureWriter> writer = CaptureWriter::create(path("copy.slcap"));
  ASSERT_TRUE(writer.ok());
  std::span<const std::byte> rest = stream;
  while (!rest.empty()) {
    Result<std::size_t> consumed = decoder.feed(rest);
    ASSERT_TRUE(consumed.ok());
    rest = rest.subspan(*consumed);
    if (decoder.message_ready()) {
      ASSERT_TRUE(writer->append(decoder.message()).ok());
      decoder.next();
    }
  }
  ASSERT_TRUE(writer->finish().ok());
  const auto file = read_all(path("copy.slcap"));
  ASSERT_EQ(file.size(), capture_header_size + stream.size());
  EXPECT_TRUE(std::equal(stream.begin(), stream.end(), file.begin() + capture_header_size));
}

TEST_F(Capture, TruncationAtEveryByteReadsBackTheCompleteRecords) {
  const std::string file = path("full.slcap");
  const auto offsets = write_samples(file);
  const auto bytes = read_all(file);
  std::vector<std::uint64_t> ends(offsets.begin() + 1, offsets.end());
  ends.push_back(bytes.size());

  for (std::size_t cut = 0; cut <= bytes.size(); ++cut) {
    const std::span<const std::byte> prefix{bytes.data(), cut};
    std::size_t records = 0;
    auto result = read_capture_bytes(prefix, [&](const Message&) -> Status {
      ++records;
      return Ok{};
    });
    if (cut < capture_header_size) {
      ASSERT_FALSE(result.ok()) << "cut " << cut;
      EXPECT_EQ(result.error().code, Errc::truncated);
      continue;
    }
    ASSERT_TRUE(result.ok()) << "cut " << cut << ": " << result.error().message;
    const auto complete = static_cast<std::size_t>(
        std::count_if(ends.begin(), ends.end(), [&](std::uint64_t end) { return end <= cut; }));
    EXPECT_EQ(records, complete) << "cut " << cut;
    const bool at_record_end = cut == capture_header_size || std::find(ends.begin(), ends.end(), cut) != ends.end();
    ASSERT_EQ(result->has_value(), !at_record_end) << "cut " << cut;
    if (result->has_value()) {
      EXPECT_EQ((*result)->record_offset, complete == 0 ? capture_header_size : ends[complete - 1]) << "cut " << cut;
      EXPECT_EQ((*result)->file_size, cut);
      EXPECT_THAT((*result)->what, HasSubstr("have"));
    }
  }

  // The file reader agrees, on a few cuts through a header, a control message and a payload.
  const std::size_t frame_record = 4;
  for (std::uint64_t cut :
       {offsets[frame_record] + 10, offsets[frame_record] + wire_header_size + 3, ends[frame_record] - 1}) {
    const std::string cut_file = path("cut.slcap");
    write_all(cut_file, {bytes.data(), static_cast<std::size_t>(cut)});
    Result<CaptureReader> reader = CaptureReader::open(cut_file);
    ASSERT_TRUE(reader.ok()) << reader.error().message;
    std::size_t records = 0;
    while (true) {
      Result<const Message*> message = reader->next();
      ASSERT_TRUE(message.ok()) << message.error().message;
      if (*message == nullptr) break;
      ++records;
    }
    EXPECT_EQ(records, frame_record);
    ASSERT_TRUE(reader->truncation().has_value());
    EXPECT_EQ(reader->truncation()->record_offset, offsets[frame_record]);
    EXPECT_EQ(reader->truncation()->file_size, cut);
  }
}

TEST_F(Capture, CorruptionIsAnErrorWithTheFileOffset) {
  const std::string file = path("bad.slcap");
  const auto offsets = write_samples(file);
  auto bytes = read_all(file);
  const std::uint64_t frame = offsets[4];
  bytes[frame + wire_header_size + 40] ^= std::byte{0x20};  // inside the frame record
  write_all(file, bytes);
  Result<CaptureReader> reader = CaptureReader::open(file);
  ASSERT_TRUE(reader.ok());
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(reader->next().ok());
  Result<const Message*> bad = reader->next();
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code, Errc::bad_checksum);
  EXPECT_THAT(bad.error().message, HasSubstr("file offset " + std::to_string(frame)));
  EXPECT_FALSE(reader->next().ok()) << "a reader stays failed after corruption";

  // Every bit flip anywhere in the records area is caught (in memory, all offsets).
  auto clean = read_all(path("bad.slcap"));
  clean[frame + wire_header_size + 40] ^= std::byte{0x20};
  for (std::size_t bit = capture_header_size * 8; bit < clean.size() * 8; bit += 7) {
    clean[bit / 8] ^= static_cast<std::byte>(1u << (bit % 8));
    auto result = read_capture_bytes(clean, [](const Message&) -> Status { return Ok{}; });
    EXPECT_FALSE(result.ok()) << "bit " << bit;
    clean[bit / 8] ^= static_cast<std::byte>(1u << (bit % 8));
  }
}

TEST_F(Capture, FileHeaderChecks) {
  const std::string file = path("header.slcap");
  write_samples(file);
  const auto good = read_all(file);
  auto reject = [&](std::vector<std::byte> bytes, Errc code, const std::string& text) {
    write_all(file, bytes);
    Result<CaptureReader> reader = CaptureReader::open(file);
    ASSERT_FALSE(reader.ok());
    EXPECT_EQ(reader.error().code, code) << reader.error().message;
    EXPECT_THAT(reader.error().message, HasSubstr(text));
  };
  auto magic = good;
  magic[1] = std::byte{'X'};
  reject(magic, Errc::malformed, "not a capture file");
  auto crc = good;
  crc[16] ^= std::byte{1};
  reject(crc, Errc::bad_checksum, "header CRC");
  auto with_crc = [](std::vector<std::byte> bytes) {
    const std::uint32_t value = crc32c(bytes.data(), 28);
    for (int i = 0; i < 4; ++i) bytes[28 + static_cast<std::size_t>(i)] = static_cast<std::byte>(value >> (8 * i));
    return bytes;
  };
  auto format = good;
  format[8] = std::byte{3};
  reject(with_crc(format), Errc::wrong_version, "capture format version 3");
  auto protocol = good;
  protocol[10] = std::byte{9};
  reject(with_crc(protocol), Errc::wrong_version, "framing version 9");
  reject({good.begin(), good.begin() + 10}, Errc::truncated, "have 10 of 32 bytes");

  Result<CaptureReader> missing = CaptureReader::open(path("does-not-exist.slcap"));
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, Errc::io_error);
  EXPECT_THAT(missing.error().message, HasSubstr("does-not-exist.slcap"));
}

TEST_F(Capture, PartialFileUntilFinishAndReadableAfterACrash) {
  const std::string file = path("live.slcap");
  Result<CaptureWriter> writer = CaptureWriter::create(file);
  ASSERT_TRUE(writer.ok());
  std::vector<std::byte> record;
  ASSERT_TRUE(encode(samples::sample_progress(), {}, record).ok());
  ASSERT_TRUE(writer->append(record).ok());
  // Half of a frame record, as if the process died mid-write.
  std::vector<std::byte> frame;
  ASSERT_TRUE(encode(samples::sample_frame_header(), samples::sample_payload(21), frame).ok());
  ASSERT_TRUE(writer->append(std::span(frame).first(frame.size() / 2)).ok());
  EXPECT_FALSE(fs::exists(file));
  ASSERT_TRUE(fs::exists(writer->partial_path()));

  Result<CaptureReader> reader = CaptureReader::open(writer->partial_path());
  ASSERT_TRUE(reader.ok());
  Result<const Message*> first = reader->next();
  ASSERT_TRUE(first.ok() && *first != nullptr);
  EXPECT_EQ((*first)->type(), MessageType::progress);
  Result<const Message*> end = reader->next();
  ASSERT_TRUE(end.ok());
  EXPECT_EQ(*end, nullptr);
  ASSERT_TRUE(reader->truncation().has_value());
  EXPECT_EQ(reader->truncation()->record_offset, capture_header_size + record.size());
  EXPECT_THAT(reader->truncation()->what, HasSubstr("frame"));
}

TEST_F(Capture, DiskFullIsAClearErrorAndTheFileEndsOnARecord) {
  // RLIMIT_FSIZE stands in for a full disk: writes past it fail with EFBIG (SIGXFSZ ignored).
  const std::string file = path("full-disk.slcap");
  struct rlimit old_limit {};
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old_limit), 0);
  auto* old_handler = std::signal(SIGXFSZ, SIG_IGN);
  struct rlimit small = old_limit;
  small.rlim_cur = 20000;
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);

  Result<CaptureWriter> writer = CaptureWriter::create(file);
  std::optional<Error> failure;
  std::uint64_t complete_bytes = 0;
  int records = 0;
  if (writer.ok()) {
    pb::FrameHeader header = samples::sample_frame_header(64, 48);
    std::vector<std::byte> record;
    ASSERT_TRUE(encode(header, samples::sample_payload(64 * 48), record).ok());
    for (int i = 0; i < 20 && !failure; ++i) {
      Status status = writer->append(record);
      if (!status.ok()) {
        failure = status.error();
      } else {
        complete_bytes = writer->bytes_written();
        ++records;
      }
    }
  }
  setrlimit(RLIMIT_FSIZE, &old_limit);
  std::signal(SIGXFSZ, old_handler);

  ASSERT_TRUE(writer.ok()) << writer.error().message;
  ASSERT_TRUE(failure.has_value()) << "20 records of 3 kB fit under a 20 kB limit?";
  EXPECT_EQ(failure->code, Errc::io_error);
  EXPECT_THAT(failure->message, HasSubstr("File too large"));
  EXPECT_THAT(failure->message, HasSubstr(writer->partial_path()));
  EXPECT_THAT(failure->message, HasSubstr("cut back to its last complete record"));
  Status more = writer->append(std::span<const std::byte>{});
  EXPECT_FALSE(more.ok()) << "a failed writer refuses further appends";
  Status finish = writer->finish();
  EXPECT_FALSE(finish.ok());
  EXPECT_FALSE(fs::exists(file)) << "an incomplete capture never gets the final name";

  Result<CaptureReader> reader = CaptureReader::open(writer->partial_path());
  ASSERT_TRUE(reader.ok()) << reader.error().message;
  int read_back = 0;
  while (true) {
    Result<const Message*> message = reader->next();
    ASSERT_TRUE(message.ok()) << message.error().message;
    if (*message == nullptr) break;
    ++read_back;
  }
  EXPECT_EQ(read_back, records);
  EXPECT_FALSE(reader->truncation().has_value());
  EXPECT_EQ(fs::file_size(writer->partial_path()), complete_bytes);
}

TEST_F(Capture, CreateInAMissingDirectoryFails) {
  Result<CaptureWriter> writer = CaptureWriter::create(path("no/such/dir/x.slcap"));
  ASSERT_FALSE(writer.ok());
  EXPECT_EQ(writer.error().code, Errc::io_error);
  EXPECT_THAT(writer.error().message, HasSubstr("x.slcap.partial"));
}

}  // namespace
