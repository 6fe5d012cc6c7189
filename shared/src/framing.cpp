#include "slproto/framing.hpp"

#include <algorithm>
#include <cstdio>
#include <cstring>

#include "slproto/crc32c.hpp"

namespace slproto {
namespace {

void put_u16(std::byte* p, std::uint16_t v) noexcept {
  p[0] = static_cast<std::byte>(v & 0xFF);
  p[1] = static_cast<std::byte>(v >> 8);
}
void put_u32(std::byte* p, std::uint32_t v) noexcept {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::byte>((v >> (8 * i)) & 0xFF);
}
std::uint16_t get_u16(const std::byte* p) noexcept {
  return static_cast<std::uint16_t>(std::to_integer<unsigned>(p[0]) | (std::to_integer<unsigned>(p[1]) << 8));
}
std::uint32_t get_u32(const std::byte* p) noexcept {
  std::uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= std::to_integer<std::uint32_t>(p[i]) << (8 * i);
  return v;
}

std::string at(std::uint64_t offset) { return " at stream offset " + std::to_string(offset); }

constexpr std::size_t header_crc_offset = 28;
constexpr std::size_t control_crc_prefix = 16;  // header bytes covered by the control CRC

Result<Body> parse_body(MessageType type, std::span<const std::byte> control) {
  Body body;
  switch (type) {
    case MessageType::hello:
      body.emplace<pb::Hello>();
      break;
    case MessageType::hello_reply:
      body.emplace<pb::HelloReply>();
      break;
    case MessageType::scan_request:
      body.emplace<pb::ScanRequest>();
      break;
    case MessageType::progress:
      body.emplace<pb::Progress>();
      break;
    case MessageType::frame:
      body.emplace<pb::FrameHeader>();
      break;
    case MessageType::scan_done:
      body.emplace<pb::ScanDone>();
      break;
    case MessageType::error:
      body.emplace<pb::Error>();
      break;
    case MessageType::abort:
      body.emplace<pb::Abort>();
      break;
    case MessageType::heartbeat:
      body.emplace<pb::Heartbeat>();
      break;
    case MessageType::status_request:
      body.emplace<pb::StatusRequest>();
      break;
    case MessageType::status_reply:
      body.emplace<pb::StatusReply>();
      break;
  }
  const bool parsed = std::visit(
      [&](auto& message) { return message.ParseFromArray(control.data(), static_cast<int>(control.size())); }, body);
  if (!parsed)
    return make_error(Errc::malformed, "control message does not parse as " + std::string(message_type_name(type)));
  return body;
}

}  // namespace

std::array<std::byte, wire_header_size> WireHeader::serialize() const noexcept {
  std::array<std::byte, wire_header_size> out{};
  std::copy(wire_magic.begin(), wire_magic.end(), out.begin());
  put_u16(&out[4], version);
  out[6] = static_cast<std::byte>(type);
  out[7] = static_cast<std::byte>(flags);
  put_u32(&out[8], control_length);
  put_u32(&out[12], payload_length);
  put_u32(&out[16], control_crc);
  put_u32(&out[20], payload_crc);
  put_u32(&out[24], 0);
  put_u32(&out[header_crc_offset], crc32c(out.data(), header_crc_offset));
  return out;
}

Result<WireHeader> WireHeader::parse(std::span<const std::byte, wire_header_size> bytes, std::uint64_t stream_offset,
                                     std::uint32_t payload_limit, std::uint8_t allowed_flags) {
  const std::byte* p = bytes.data();
  if (!std::equal(wire_magic.begin(), wire_magic.end(), p)) {
    char shown[16];
    std::snprintf(shown, sizeof shown, "%02x %02x %02x %02x", std::to_integer<unsigned>(p[0]),
                  std::to_integer<unsigned>(p[1]), std::to_integer<unsigned>(p[2]), std::to_integer<unsigned>(p[3]));
    return make_error(Errc::malformed,
                      std::string("record header: bad magic ") + shown + " (want \"SLPF\")" + at(stream_offset));
  }
  const std::uint32_t stored_crc = get_u32(p + header_crc_offset);
  const std::uint32_t actual_crc = crc32c(p, header_crc_offset);
  if (stored_crc != actual_crc)
    return make_error(Errc::bad_checksum, "record header: header CRC mismatch" + at(stream_offset));
  WireHeader header;
  header.version = get_u16(p + 4);
  if (header.version < min_framing_version || header.version > framing_version)
    return make_error(Errc::wrong_version, "record header: framing version " + std::to_string(header.version) +
                                               " not supported (this build reads " +
                                               std::to_string(min_framing_version) + ".." +
                                               std::to_string(framing_version) + ")" + at(stream_offset + 4));
  const auto type = std::to_integer<std::uint8_t>(p[6]);
  if (!is_known_message_type(type))
    return make_error(Errc::malformed,
                      "record header: unknown message type " + std::to_string(type) + at(stream_offset + 6));
  header.type = static_cast<MessageType>(type);
  header.flags = std::to_integer<std::uint8_t>(p[7]);
  if ((header.flags & ~allowed_flags) != 0 ||
      (header.flags != 0 && static_cast<MessageType>(type) != MessageType::frame))
    return make_error(Errc::malformed, "record header: flags " + std::to_string(header.flags) + " must be " +
                                           (allowed_flags == 0 ? std::string("0")
                                                               : "0, or " + std::to_string(allowed_flags) +
                                                                     " on a frame record of a compressed capture") +
                                           at(stream_offset + 7));
  header.control_length = get_u32(p + 8);
  header.payload_length = get_u32(p + 12);
  header.control_crc = get_u32(p + 16);
  header.payload_crc = get_u32(p + 20);
  if (get_u32(p + 24) != 0)
    return make_error(Errc::malformed, "record header: reserved field is not 0" + at(stream_offset + 24));
  if (header.control_length > max_control_length)
    return make_error(Errc::oversized, "record header: control length " + std::to_string(header.control_length) +
                                           " exceeds " + std::to_string(max_control_length) + at(stream_offset + 8));
  const std::uint32_t limit = std::min(payload_limit, max_payload_length);
  if (header.payload_length > limit)
    return make_error(Errc::oversized, "record header: payload length " + std::to_string(header.payload_length) +
                                           " exceeds " + std::to_string(limit) + at(stream_offset + 12));
  if (header.payload_length != 0 && header.type != MessageType::frame)
    return make_error(Errc::malformed, std::string("record header: a ") + message_type_name(header.type) +
                                           " record cannot carry a payload" + at(stream_offset + 12));
  if (header.payload_length == 0 && header.payload_crc != 0)
    return make_error(Errc::malformed, "record header: payload CRC set for an empty payload" + at(stream_offset + 20));
  return header;
}

std::uint32_t control_crc(const WireHeader& header, std::span<const std::byte> control) noexcept {
  const auto bytes = header.serialize();
  return crc32c(control, crc32c(bytes.data(), control_crc_prefix));
}

Status encode_prefix(MessageType type, const google::protobuf::MessageLite& control, std::uint32_t payload_length,
                     std::uint32_t payload_crc, std::vector<std::byte>& out) {
  const std::size_t control_size = control.ByteSizeLong();
  if (control_size > max_control_length)
    return make_error(Errc::oversized, std::string("encode: ") + message_type_name(type) + " control message of " +
                                           std::to_string(control_size) + " bytes exceeds " +
                                           std::to_string(max_control_length));
  if (payload_length > max_payload_length)
    return make_error(Errc::oversized, "encode: payload of " + std::to_string(payload_length) + " bytes exceeds " +
                                           std::to_string(max_payload_length));
  if (payload_length != 0 && type != MessageType::frame)
    return make_error(Errc::invalid_argument,
                      std::string("encode: a ") + message_type_name(type) + " record cannot carry a payload");
  WireHeader header;
  header.type = type;
  header.control_length = static_cast<std::uint32_t>(control_size);
  header.payload_length = payload_length;
  header.payload_crc = payload_length == 0 ? 0 : payload_crc;

  const std::size_t start = out.size();
  out.resize(start + wire_header_size + control_size);
  std::byte* control_bytes = out.data() + start + wire_header_size;
  if (control_size != 0 && !control.SerializeToArray(control_bytes, static_cast<int>(control_size))) {
    out.resize(start);
    return make_error(Errc::internal, std::string("encode: serialising ") + message_type_name(type) + " failed");
  }
  header.control_crc = control_crc(header, {control_bytes, control_size});
  const auto header_bytes = header.serialize();
  std::copy(header_bytes.begin(), header_bytes.end(), out.begin() + static_cast<std::ptrdiff_t>(start));
  return Ok{};
}

Status encode(const Body& body, std::span<const std::byte> payload, std::vector<std::byte>& out) {
  const MessageType type = type_of(body);
  if (payload.size() > max_payload_length)
    return make_error(Errc::oversized, "encode: payload of " + std::to_string(payload.size()) + " bytes exceeds " +
                                           std::to_string(max_payload_length));
  if (const auto* frame = std::get_if<pb::FrameHeader>(&body)) {
    if (Status status = check_frame_geometry(*frame, payload.size()); !status)
      return make_error(status.error().code, "encode: " + status.error().message);
  }
  const std::uint32_t payload_crc = crc32c(payload);
  if (const auto* frame = std::get_if<pb::FrameHeader>(&body);
      frame != nullptr && frame->payload_crc32c() != payload_crc) {
    pb::FrameHeader stamped = *frame;
    stamped.set_payload_crc32c(payload_crc);
    if (Status status = encode_prefix(type, stamped, static_cast<std::uint32_t>(payload.size()), payload_crc, out);
        !status)
      return status;
  } else if (Status status = encode_prefix(type, as_message_lite(body), static_cast<std::uint32_t>(payload.size()),
                                           payload_crc, out);
             !status) {
    return status;
  }
  out.insert(out.end(), payload.begin(), payload.end());
  return Ok{};
}

// ---- StreamDecoder

StreamDecoder::StreamDecoder(DecoderLimits limits) : limits_(limits) {
  limits_.max_control = std::min(limits_.max_control, max_control_length);
  limits_.max_payload = std::min(limits_.max_payload, max_payload_length);
}

void StreamDecoder::reset() noexcept {
  phase_ = Phase::header;
  filled_ = 0;
  running_crc_ = 0;
  ready_ = false;
  failed_ = false;
  record_offset_ = offset_;
}

void StreamDecoder::next() noexcept {
  if (!ready_) return;
  ready_ = false;
  phase_ = Phase::header;
  filled_ = 0;
  record_offset_ = offset_;
}

Status StreamDecoder::fail(Error error) {
  failed_ = true;
  return error;
}

std::span<std::byte> StreamDecoder::window(std::size_t max_chunk) {
  if (ready_ || failed_ || max_chunk == 0) return {};
  switch (phase_) {
    case Phase::header:
      return {header_bytes_.data() + filled_, std::min(max_chunk, wire_header_size - filled_)};
    case Phase::control: {
      const std::size_t chunk = std::min<std::size_t>(max_chunk, header_.control_length - filled_);
      if (control_.size() < filled_ + chunk) control_.resize(filled_ + chunk);
      return {control_.data() + filled_, chunk};
    }
    case Phase::payload: {
      const std::size_t chunk = std::min<std::size_t>(max_chunk, header_.payload_length - filled_);
      // Grows only as bytes arrive (a lying length costs nothing until the bytes exist), and
      // never shrinks, so a stream of equal frames reuses one buffer without re-zeroing.
      if (payload_.size() < filled_ + chunk) {
        if (payload_.capacity() < filled_ + chunk)
          payload_.reserve(std::max<std::size_t>(
              filled_ + chunk, std::min<std::size_t>(header_.payload_length, 2 * payload_.capacity())));
        payload_.resize(filled_ + chunk);
      }
      return {payload_.data() + filled_, chunk};
    }
  }
  return {};
}

Status StreamDecoder::commit(std::size_t n) {
  if (failed_) return make_error(Errc::internal, "stream decoder used after an error");
  if (ready_) return make_error(Errc::internal, "stream decoder fed before next() released the previous record");
  if (n == 0) return Ok{};
  switch (phase_) {
    case Phase::header:
      break;
    case Phase::control:
      running_crc_ = crc32c(control_.data() + filled_, n, running_crc_);
      break;
    case Phase::payload:
      running_crc_ = crc32c(payload_.data() + filled_, n, running_crc_);
      break;
  }
  filled_ += n;
  offset_ += n;
  // Zero-length parts complete immediately, so loop until a part is still waiting for bytes.
  while (!ready_) {
    const std::size_t need = phase_ == Phase::header    ? wire_header_size
                             : phase_ == Phase::control ? header_.control_length
                                                        : header_.payload_length;
    if (filled_ < need) break;
    if (Status status = complete_part(); !status) return fail(status.error());
  }
  return Ok{};
}

Status StreamDecoder::complete_part() {
  switch (phase_) {
    case Phase::header: {
      Result<WireHeader> header =
          WireHeader::parse(header_bytes_, record_offset_, limits_.max_payload, limits_.allowed_flags);
      if (!header) return std::move(header).error();
      if (header->control_length > limits_.max_control)
        return make_error(Errc::oversized, "record header: control length " + std::to_string(header->control_length) +
                                               " exceeds this reader's limit " + std::to_string(limits_.max_control) +
                                               at(record_offset_ + 8));
      header_ = *header;
      running_crc_ = crc32c(header_bytes_.data(), control_crc_prefix);
      phase_ = Phase::control;
      filled_ = 0;
      return Ok{};
    }
    case Phase::control: {
      if (running_crc_ != header_.control_crc)
        return make_error(Errc::bad_checksum, std::string("record: control CRC mismatch in ") +
                                                  message_type_name(header_.type) + " record" + at(record_offset_));
      running_crc_ = 0;
      phase_ = Phase::payload;
      filled_ = 0;
      return Ok{};
    }
    case Phase::payload: {
      if (running_crc_ != header_.payload_crc)
        return make_error(Errc::bad_checksum, std::string("record: payload CRC mismatch in ") +
                                                  message_type_name(header_.type) + " record" + at(record_offset_));
      const std::span<const std::byte> control{control_.data(), header_.control_length};
      Result<Body> body = parse_body(header_.type, control);
      if (!body) return make_error(Errc::malformed, body.error().message + at(record_offset_ + wire_header_size));
      const std::span<const std::byte> payload{payload_.data(), header_.payload_length};
      // A compressed payload (capture files only) is checked once decoded (decode_stored_record).
      const bool compressed = (header_.flags & record_flag_compressed) != 0;
      if (const auto* frame = std::get_if<pb::FrameHeader>(&*body); frame != nullptr && !compressed) {
        if (Status status = check_frame_geometry(*frame, payload.size()); !status)
          return make_error(status.error().code, status.error().message + at(record_offset_));
        if (frame->payload_crc32c() != header_.payload_crc)
          return make_error(Errc::bad_checksum,
                            "frame header: payload_crc32c differs from the record's payload CRC" + at(record_offset_));
      }
      message_.header = header_;
      message_.body = std::move(body).value();
      message_.header_bytes = header_bytes_;
      message_.control = control;
      message_.payload = payload;
      message_.stream_offset = record_offset_;
      ready_ = true;
      return Ok{};
    }
  }
  return Ok{};
}

Result<std::size_t> StreamDecoder::feed(std::span<const std::byte> bytes) {
  std::size_t consumed = 0;
  while (consumed < bytes.size() && !ready_) {
    if (failed_) return make_error(Errc::internal, "stream decoder used after an error");
    const std::span<std::byte> target = window(bytes.size() - consumed);
    if (target.empty()) break;
    std::memcpy(target.data(), bytes.data() + consumed, target.size());
    consumed += target.size();
    if (Status status = commit(target.size()); !status) return status.error();
  }
  return consumed;
}

std::string StreamDecoder::describe_partial() const {
  switch (phase_) {
    case Phase::header:
      return "record header: have " + std::to_string(filled_) + " of " + std::to_string(wire_header_size) + " bytes";
    case Phase::control:
      return std::string(message_type_name(header_.type)) + " control message: have " + std::to_string(filled_) +
             " of " + std::to_string(header_.control_length) + " bytes";
    case Phase::payload:
      return std::string(message_type_name(header_.type)) + " payload: have " + std::to_string(filled_) + " of " +
             std::to_string(header_.payload_length) + " bytes";
  }
  return {};
}

}  // namespace slproto
