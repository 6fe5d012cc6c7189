#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstring>

#include "sample_messages.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/framing.hpp"

namespace {

using namespace slproto;
using slproto::samples::sample_records;
using ::testing::HasSubstr;

std::vector<std::byte> encode_record(const Body& body, std::span<const std::byte> payload) {
  std::vector<std::byte> out;
  Status status = encode(body, payload, out);
  EXPECT_TRUE(status.ok()) << status.error().message;
  return out;
}

std::string serialized(const Body& body) { return as_message_lite(body).SerializeAsString(); }

// Expected body after a round trip: frames come back with payload_crc32c filled in.
Body stamped(const Body& body, std::span<const std::byte> payload) {
  Body copy = body;
  if (auto* frame = std::get_if<pb::FrameHeader>(&copy)) frame->set_payload_crc32c(crc32c(payload));
  return copy;
}

// Re-serialises a header with one field changed and a valid header CRC, to reach the checks
// that come after the CRC.
void patch_header(std::vector<std::byte>& record, std::size_t offset, std::uint32_t value, int bytes) {
  for (int i = 0; i < bytes; ++i)
    record[offset + static_cast<std::size_t>(i)] = static_cast<std::byte>(value >> (8 * i));
  const std::uint32_t crc = crc32c(record.data(), 28);
  for (int i = 0; i < 4; ++i) record[28 + static_cast<std::size_t>(i)] = static_cast<std::byte>(crc >> (8 * i));
}

// Feeds a whole stream (several records allowed) and returns the error it must produce.
Error decode_error(std::span<const std::byte> bytes, DecoderLimits limits = {}) {
  StreamDecoder decoder(limits);
  while (true) {
    Result<std::size_t> consumed = decoder.feed(bytes);
    if (!consumed.ok()) {
      EXPECT_TRUE(decoder.failed());
      return consumed.error();
    }
    bytes = bytes.subspan(*consumed);
    if (decoder.message_ready()) {
      decoder.next();
    } else if (bytes.empty()) {
      ADD_FAILURE() << "expected an error, the decoder took every byte (" << decoder.describe_partial() << ")";
      return {};
    }
  }
}

TEST(Framing, RoundTripEveryMessageTypeWholeAndByteByByte) {
  for (const auto& sample : sample_records()) {
    const MessageType type = type_of(sample.body);
    SCOPED_TRACE(message_type_name(type));
    const auto record = encode_record(sample.body, sample.payload);

    StreamDecoder whole;
    Result<std::size_t> consumed = whole.feed(record);
    ASSERT_TRUE(consumed.ok()) << consumed.error().message;
    EXPECT_EQ(*consumed, record.size());
    ASSERT_TRUE(whole.message_ready());
    const Message& message = whole.message();
    EXPECT_EQ(message.type(), type);
    EXPECT_EQ(message.body.index(), sample.body.index());
    EXPECT_EQ(serialized(message.body), serialized(stamped(sample.body, sample.payload)));
    ASSERT_EQ(message.payload.size(), sample.payload.size());
    EXPECT_TRUE(std::equal(message.payload.begin(), message.payload.end(), sample.payload.begin()));
    EXPECT_EQ(message.wire_size(), record.size());
    EXPECT_EQ(message.stream_offset, 0u);
    EXPECT_TRUE(std::equal(message.header_bytes.begin(), message.header_bytes.end(), record.begin()));

    StreamDecoder bytewise;
    for (std::size_t i = 0; i < record.size(); ++i) {
      ASSERT_FALSE(bytewise.message_ready()) << "ready early at byte " << i;
      Result<std::size_t> one = bytewise.feed({record.data() + i, 1});
      ASSERT_TRUE(one.ok()) << one.error().message;
      ASSERT_EQ(*one, 1u);
    }
    ASSERT_TRUE(bytewise.message_ready());
    EXPECT_EQ(serialized(bytewise.message().body), serialized(message.body));
  }
}

TEST(Framing, StreamOfAllTypesInOddChunksKeepsOffsets) {
  std::vector<std::byte> stream;
  std::vector<std::uint64_t> offsets;
  const auto samples = sample_records();
  for (int round = 0; round < 3; ++round)
    for (const auto& sample : samples) {
      offsets.push_back(stream.size());
      Status status = encode(sample.body, sample.payload, stream);
      ASSERT_TRUE(status.ok());
    }
  for (std::size_t chunk : {1u, 3u, 31u, 32u, 33u, 1000u, 100000u}) {
    StreamDecoder decoder;
    std::size_t position = 0, index = 0;
    while (position < stream.size()) {
      const std::size_t n = std::min(chunk, stream.size() - position);
      Result<std::size_t> consumed = decoder.feed({stream.data() + position, n});
      ASSERT_TRUE(consumed.ok()) << consumed.error().message;
      position += *consumed;
      if (decoder.message_ready()) {
        ASSERT_LT(index, offsets.size());
        EXPECT_EQ(decoder.message().stream_offset, offsets[index]);
        EXPECT_EQ(decoder.message().type(), type_of(samples[index % samples.size()].body));
        ++index;
        decoder.next();
      }
    }
    EXPECT_EQ(index, offsets.size()) << "chunk " << chunk;
    EXPECT_TRUE(decoder.at_boundary());
  }
}

TEST(Framing, TruncationAtEveryByteIsIncompleteNeverAnError) {
  for (const auto& sample : sample_records()) {
    SCOPED_TRACE(message_type_name(type_of(sample.body)));
    const auto record = encode_record(sample.body, sample.payload);
    for (std::size_t cut = 0; cut < record.size(); ++cut) {
      StreamDecoder decoder;
      Result<std::size_t> consumed = decoder.feed({record.data(), cut});
      ASSERT_TRUE(consumed.ok()) << "cut " << cut << ": " << consumed.error().message;
      EXPECT_EQ(*consumed, cut);
      EXPECT_FALSE(decoder.message_ready()) << "cut " << cut;
      EXPECT_EQ(decoder.at_boundary(), cut == 0);
      if (cut > 0) {
        EXPECT_THAT(decoder.describe_partial(), HasSubstr("have")) << "cut " << cut;
      }
    }
  }
}

TEST(Framing, EverySingleBitFlipIsRejected) {
  for (const auto& sample : sample_records()) {
    SCOPED_TRACE(message_type_name(type_of(sample.body)));
    auto record = encode_record(sample.body, sample.payload);
    for (std::size_t bit = 0; bit < record.size() * 8; ++bit) {
      record[bit / 8] ^= static_cast<std::byte>(1u << (bit % 8));
      StreamDecoder decoder;
      Result<std::size_t> consumed = decoder.feed(record);
      // The header CRC covers the lengths, so even a flipped length is an error at once,
      // never a wait for bytes that will not come.
      EXPECT_FALSE(decoder.message_ready()) << "bit " << bit << " flipped and the record still decoded";
      ASSERT_FALSE(consumed.ok()) << "bit " << bit << " flipped and the decoder did not notice";
      const Errc code = consumed.error().code;
      EXPECT_TRUE(code == Errc::bad_checksum || code == Errc::malformed)
          << "bit " << bit << ": " << consumed.error().message;
      record[bit / 8] ^= static_cast<std::byte>(1u << (bit % 8));
    }
  }
}

TEST(Framing, HeaderFlipsAreCaughtByTheHeaderCrcBeforeWaitingForData) {
  auto record = encode_record(samples::sample_frame_header(), samples::sample_payload(21));
  record[13] ^= std::byte{0x10};  // payload length high bits: would claim ~1 MiB more
  const Error error = decode_error(record);
  EXPECT_EQ(error.code, Errc::bad_checksum);
  EXPECT_THAT(error.message, HasSubstr("header CRC"));
  EXPECT_THAT(error.message, HasSubstr("offset 0"));
}

TEST(Framing, PayloadAndControlCorruptionNameTheRecordAndOffset) {
  std::vector<std::byte> stream = encode_record(samples::sample_heartbeat(), {});
  const std::size_t second = stream.size();
  Status status = encode(samples::sample_frame_header(), samples::sample_payload(21), stream);
  ASSERT_TRUE(status.ok());
  auto bad_payload = stream;
  bad_payload.back() ^= std::byte{1};
  Error error = decode_error(bad_payload);
  EXPECT_EQ(error.code, Errc::bad_checksum);
  EXPECT_THAT(error.message,
              HasSubstr("payload CRC mismatch in frame record at stream offset " + std::to_string(second)));
  auto bad_control = stream;
  bad_control[second + wire_header_size + 2] ^= std::byte{4};
  error = decode_error(bad_control);
  EXPECT_EQ(error.code, Errc::bad_checksum);
  EXPECT_THAT(error.message,
              HasSubstr("control CRC mismatch in frame record at stream offset " + std::to_string(second)));
}

TEST(Framing, VersionMismatchIsRejected) {
  for (std::uint32_t version : {0u, 2u, 0xFFFFu}) {
    auto record = encode_record(samples::sample_hello(), {});
    patch_header(record, 4, version, 2);
    const Error error = decode_error(record);
    EXPECT_EQ(error.code, Errc::wrong_version);
    EXPECT_THAT(error.message, HasSubstr("framing version " + std::to_string(version)));
    EXPECT_THAT(error.message, HasSubstr("offset 4"));
  }
}

TEST(Framing, OversizedLengthsAreRejectedFromTheHeaderAlone) {
  auto control = encode_record(samples::sample_progress(), {});
  patch_header(control, 8, max_control_length + 1, 4);
  Error error = decode_error({control.data(), wire_header_size});  // nothing after the header
  EXPECT_EQ(error.code, Errc::oversized);
  EXPECT_THAT(error.message, HasSubstr("control length 1048577"));

  auto payload = encode_record(samples::sample_frame_header(), samples::sample_payload(21));
  patch_header(payload, 12, max_payload_length + 1, 4);
  error = decode_error({payload.data(), wire_header_size});
  EXPECT_EQ(error.code, Errc::oversized);
  EXPECT_THAT(error.message, HasSubstr("payload length 268435457"));

  // A reader may set tighter limits (e.g. the fuzz targets, a board with little memory).
  auto frame = encode_record(samples::sample_frame_header(), samples::sample_payload(21));
  error = decode_error(frame, DecoderLimits{max_control_length, 20});
  EXPECT_EQ(error.code, Errc::oversized);
  error = decode_error(frame, DecoderLimits{8, max_payload_length});
  EXPECT_EQ(error.code, Errc::oversized);
}

TEST(Framing, StructuralErrorsAreMalformed) {
  auto base = encode_record(samples::sample_abort(), {});
  auto magic = base;
  magic[0] = std::byte{'X'};
  EXPECT_EQ(decode_error(magic).code, Errc::malformed);
  EXPECT_THAT(decode_error(magic).message, HasSubstr("bad magic"));

  auto type = base;
  patch_header(type, 6, 0, 1);
  EXPECT_THAT(decode_error(type).message, HasSubstr("unknown message type 0"));
  patch_header(type, 6, 200, 1);
  EXPECT_THAT(decode_error(type).message, HasSubstr("unknown message type 200"));

  auto flags = base;
  patch_header(flags, 7, 1, 1);
  EXPECT_THAT(decode_error(flags).message, HasSubstr("flags"));

  auto reserved = base;
  patch_header(reserved, 24, 5, 4);
  EXPECT_THAT(decode_error(reserved).message, HasSubstr("reserved"));

  auto payload_on_abort = base;
  patch_header(payload_on_abort, 12, 4, 4);
  EXPECT_THAT(decode_error(payload_on_abort).message, HasSubstr("abort record cannot carry a payload"));
}

TEST(Framing, ControlBytesThatDoNotParseAreMalformed) {
  // A control message with a valid CRC but invalid protobuf: a field with wire type 7.
  const std::vector<std::byte> garbage{std::byte{0x0F}, std::byte{0x01}};
  WireHeader header;
  header.type = MessageType::progress;
  header.control_length = static_cast<std::uint32_t>(garbage.size());
  header.control_crc = control_crc(header, garbage);
  const auto header_bytes = header.serialize();
  std::vector<std::byte> record(header_bytes.begin(), header_bytes.end());
  record.insert(record.end(), garbage.begin(), garbage.end());
  const Error error = decode_error(record);
  EXPECT_EQ(error.code, Errc::malformed);
  EXPECT_THAT(error.message, HasSubstr("does not parse as progress"));
  EXPECT_THAT(error.message, HasSubstr("offset 32"));
}

TEST(Framing, FrameGeometryMustMatchThePayload) {
  pb::FrameHeader header = samples::sample_frame_header(7, 3);
  std::vector<std::byte> out;
  Status status = encode(header, samples::sample_payload(20), out);  // 7 x 3 needs 21
  ASSERT_FALSE(status.ok());
  EXPECT_THAT(status.error().message, HasSubstr("stride_bytes * height = 21"));

  header.set_stride_bytes(6);
  status = encode(header, samples::sample_payload(18), out);
  ASSERT_FALSE(status.ok());
  EXPECT_THAT(status.error().message, HasSubstr("stride_bytes 6 < width"));

  // Padded rows and 16-bit pixels are fine.
  pb::FrameHeader mono12 = samples::sample_frame_header();
  set_frame_geometry(mono12, 5, 4, pb::PIXEL_FORMAT_MONO12);
  mono12.set_stride_bytes(16);
  EXPECT_TRUE(encode(mono12, samples::sample_payload(64), out).ok());

  // A decoder also checks, for frames built by someone else: bypass encode's check.
  pb::FrameHeader lying = samples::sample_frame_header(7, 3);
  lying.set_height(4);
  const auto payload = samples::sample_payload(21);
  std::vector<std::byte> record;
  ASSERT_TRUE(encode_prefix(MessageType::frame, lying, 21, crc32c(payload), record).ok());
  record.insert(record.end(), payload.begin(), payload.end());
  const Error error = decode_error(record);
  EXPECT_EQ(error.code, Errc::malformed);
  EXPECT_THAT(error.message, HasSubstr("payload has 21 bytes"));
}

TEST(Framing, EncodeRefusesPayloadsOnControlMessagesAndOversizedControl) {
  std::vector<std::byte> out;
  const auto payload = samples::sample_payload(4);
  Status status = encode(samples::sample_hello(), payload, out);
  ASSERT_FALSE(status.ok());
  EXPECT_EQ(status.error().code, Errc::invalid_argument);

  pb::Progress big;
  big.set_text(std::string(max_control_length, 'x'));
  status = encode(big, {}, out);
  ASSERT_FALSE(status.ok());
  EXPECT_EQ(status.error().code, Errc::oversized);
  EXPECT_TRUE(out.empty());
}

TEST(Framing, PayloadBufferIsReusedAcrossFrames) {
  std::vector<std::byte> stream;
  for (std::uint32_t seed = 0; seed < 3; ++seed)
    ASSERT_TRUE(encode(samples::sample_frame_header(64, 64), samples::sample_payload(4096, seed), stream).ok());
  StreamDecoder decoder;
  const std::byte* first_payload = nullptr;
  std::size_t position = 0;
  for (std::uint32_t seed = 0; seed < 3; ++seed) {
    Result<std::size_t> consumed = decoder.feed({stream.data() + position, stream.size() - position});
    ASSERT_TRUE(consumed.ok());
    position += *consumed;
    ASSERT_TRUE(decoder.message_ready());
    const auto expected = samples::sample_payload(4096, seed);
    EXPECT_TRUE(std::equal(decoder.message().payload.begin(), decoder.message().payload.end(), expected.begin()));
    if (first_payload == nullptr) first_payload = decoder.message().payload.data();
    EXPECT_EQ(decoder.message().payload.data(), first_payload);
    decoder.next();
  }
}

TEST(Framing, DecoderStaysFailedUntilReset) {
  auto record = encode_record(samples::sample_heartbeat(), {});
  auto bad = record;
  bad[0] = std::byte{0};
  StreamDecoder decoder;
  EXPECT_FALSE(decoder.feed(bad).ok());
  EXPECT_FALSE(decoder.feed(record).ok());
  decoder.reset();
  Result<std::size_t> consumed = decoder.feed(record);
  ASSERT_TRUE(consumed.ok());
  EXPECT_TRUE(decoder.message_ready());
}

TEST(Messages, PatternPlanRoundTripAndValidation) {
  PatternPlanConfig config;
  config.axis = CodingAxis::rows;
  config.period_px = 16;
  config.phase_steps = 4;
  config.complementary_bit = false;
  Result<PatternPlanConfig> back = from_proto(to_proto(config));
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(*back, config);

  // The later fields: inverse Gray frames and SLStudio's convention survive the round trip.
  PatternPlanConfig gray_only;
  gray_only.phase_steps = 0;
  gray_only.period_px = 2;
  gray_only.complementary_bit = false;
  gray_only.inverse_gray = true;
  gray_only.gray_low_bits = GrayLowBits::slstudio_parity;
  back = from_proto(to_proto(gray_only));
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(*back, gray_only);
  // A capture written before them has neither field: it reads as no inverse, centre.
  pb::PatternPlanConfig old = to_proto(config);
  old.clear_inverse_gray();
  old.clear_gray_low_bits();
  ASSERT_TRUE(from_proto(old).ok());
  EXPECT_FALSE(from_proto(old)->inverse_gray);
  EXPECT_EQ(from_proto(old)->gray_low_bits, GrayLowBits::centre);
  pb::PatternPlanConfig unknown = to_proto(gray_only);
  unknown.set_gray_low_bits(static_cast<pb::GrayLowBits>(7));
  ASSERT_FALSE(from_proto(unknown).ok());
  EXPECT_THAT(from_proto(unknown).error().message, HasSubstr("gray_low_bits 7 is unknown"));

  pb::PatternPlanConfig zero;  // proto3 defaults: every field 0
  EXPECT_FALSE(from_proto(zero).ok());
  pb::PatternPlanConfig huge = to_proto(PatternPlanConfig{});
  huge.set_projector_width(0xFFFFFFFFu);
  Result<PatternPlanConfig> bad = from_proto(huge);
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message, HasSubstr("projector_width"));
}

TEST(Messages, ScanRequestChecksNameTheField) {
  EXPECT_TRUE(check_scan_request(samples::sample_scan_request()).ok());
  auto request = samples::sample_scan_request();
  request.add_projectors(1);
  EXPECT_THAT(check_scan_request(request).error().message, HasSubstr("projectors[2] = 1 repeats"));
  request = samples::sample_scan_request();
  request.set_turntable_angles_deg(1, std::numeric_limits<double>::quiet_NaN());
  EXPECT_THAT(check_scan_request(request).error().message, HasSubstr("turntable_angles_deg[1]"));
  request = samples::sample_scan_request();
  request.set_pattern_period_us(10);
  EXPECT_THAT(check_scan_request(request).error().message, HasSubstr("pattern_period_us"));
  request = samples::sample_scan_request();
  EXPECT_THAT(check_scan_request(request, 1).error().message, HasSubstr("board has 1 projector"));
  request.clear_plan();
  EXPECT_THAT(check_scan_request(request).error().message, HasSubstr("no pattern plan"));
}

TEST(Messages, ErrorCodesSurviveTheWire) {
  const Error original = make_error(Errc::unauthorized, "bad token");
  const Error back = from_proto(to_proto(original, 7, true));
  EXPECT_EQ(back.code, Errc::unauthorized);
  EXPECT_EQ(back.message, "bad token");
  pb::Error unknown;
  unknown.set_code(999);
  unknown.set_text("future error");
  EXPECT_EQ(from_proto(unknown).code, Errc::internal);
  EXPECT_THAT(from_proto(unknown).message, HasSubstr("999"));
}

}  // namespace
