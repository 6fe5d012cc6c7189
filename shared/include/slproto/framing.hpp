// Framing: how one control message (and, for frames, its raw pixel payload) travels as a
// record in a byte stream. Layout (all little-endian; docs/protocol.md is the reference):
//
//   offset size  field
//        0    4  magic "SLPF"
//        4    2  framing version (1; not the negotiated protocol version)
//        6    1  message type (MessageType)
//        7    1  flags (0 on the wire; bit 0 in capture files: payload compressed)
//        8    4  control length  (<= 1 MiB)   serialised protobuf message
//       12    4  payload length  (<= 256 MiB) raw bytes, only for MessageType::frame
//       16    4  control CRC32C over header bytes 0..15 followed by the control bytes
//       20    4  payload CRC32C over the payload bytes (0 for an empty payload)
//       24    4  reserved (must be 0)
//       28    4  header CRC32C over header bytes 0..27
//
// The header CRC lets a decoder reject a corrupt length before waiting for (or allocating)
// the bytes it claims; the payload CRC is computed once by the sender and doubles as
// FrameHeader.payload_crc32c.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "slproto/messages.hpp"
#include "slproto/result.hpp"

namespace slproto {

inline constexpr std::size_t wire_header_size = 32;
inline constexpr std::array<std::byte, 4> wire_magic{std::byte{'S'}, std::byte{'L'}, std::byte{'P'}, std::byte{'F'}};
inline constexpr std::uint32_t max_control_length = 1u << 20;
inline constexpr std::uint32_t max_payload_length = 256u << 20;
// Record flag, only in compressed capture files (slproto/capture.hpp) and only on frames: the
// payload is stored compressed. Never on the wire.
inline constexpr std::uint8_t record_flag_compressed = 0x01;

struct WireHeader {
  std::uint16_t version = framing_version;
  MessageType type = MessageType::heartbeat;
  std::uint8_t flags = 0;
  std::uint32_t control_length = 0;
  std::uint32_t payload_length = 0;
  std::uint32_t control_crc = 0;
  std::uint32_t payload_crc = 0;

  // Serialises, filling in the header CRC.
  std::array<std::byte, wire_header_size> serialize() const noexcept;
  // Parses and checks magic, header CRC, version, type, flags, reserved and both length
  // bounds. `stream_offset` is only used to say where in the stream a problem is.
  // `allowed_flags`: flag bits accepted (0 on the wire; record_flag_compressed, on frames
  // only, in a compressed capture).
  static Result<WireHeader> parse(std::span<const std::byte, wire_header_size> bytes, std::uint64_t stream_offset = 0,
                                  std::uint32_t payload_limit = max_payload_length, std::uint8_t allowed_flags = 0);
};

// CRC of header bytes 0..15 followed by the control bytes (the header's control_crc).
std::uint32_t control_crc(const WireHeader& header, std::span<const std::byte> control) noexcept;

// The bytes of one record except the payload: header + control. The payload (if any) follows
// on the wire unchanged; `payload_crc` must be crc32c(payload). Used by the transport to
// send the payload with writev straight from the caller's buffer.
Status encode_prefix(MessageType type, const google::protobuf::MessageLite& control, std::uint32_t payload_length,
                     std::uint32_t payload_crc, std::vector<std::byte>& out);

// A whole record (header + control + payload) appended to `out`. For small messages, tests,
// fuzz seeds and capture files; frames on the hot path use encode_prefix + writev.
Status encode(const Body& body, std::span<const std::byte> payload, std::vector<std::byte>& out);
template <ControlMessage T>
Status encode(const T& message, std::span<const std::byte> payload, std::vector<std::byte>& out) {
  return encode(Body{message}, payload, out);
}
template <ControlMessage T>
Result<std::vector<std::byte>> encode(const T& message, std::span<const std::byte> payload = {}) {
  std::vector<std::byte> out;
  if (Status status = encode(Body{message}, payload, out); !status) return status.error();
  return out;
}

// One decoded record. `control` and `payload` point into the decoder that produced it and
// stay valid until that decoder is fed again (Connection::receive, CaptureReader::next).
struct Message {
  WireHeader header;
  Body body;
  std::array<std::byte, wire_header_size> header_bytes{};  // as received
  std::span<const std::byte> control;
  std::span<const std::byte> payload;
  std::uint64_t stream_offset = 0;  // offset of the record's first byte in its stream

  MessageType type() const noexcept { return header.type; }
  template <ControlMessage T>
  const T* get() const noexcept {
    return std::get_if<T>(&body);
  }
  // Header + control + payload length: the record's size on the wire.
  std::uint64_t wire_size() const noexcept {
    return wire_header_size + std::uint64_t{header.control_length} + header.payload_length;
  }
};

struct DecoderLimits {
  std::uint32_t max_control = max_control_length;
  std::uint32_t max_payload = max_payload_length;
  std::uint8_t allowed_flags = 0;  // record flags accepted (capture files set record_flag_compressed)
};

// Incremental decoder of a record stream with bounded memory: it never holds more than one
// record (header + control + payload, each bounded by DecoderLimits) and grows its buffers
// only as bytes actually arrive. Once it reports an error it stays failed (the stream has
// lost its framing); reset() starts over.
//
// Two ways to feed it:
//  * feed(bytes): copies from any buffer, consuming at most up to the end of one record;
//  * window() / commit(n): the caller reads (e.g. from a socket or file) straight into the
//    decoder's buffer: no intermediate copy of the payload.
// After either returns with message_ready(), take the record with message() and call
// next() before feeding more.
class StreamDecoder {
 public:
  explicit StreamDecoder(DecoderLimits limits = {});

  // Consumes bytes until the current record is complete (or the input is used up) and
  // returns how many it consumed. Errors: malformed, wrong_version, oversized, bad_checksum.
  Result<std::size_t> feed(std::span<const std::byte> bytes);

  // Where the next bytes of the stream go; never empty while no record is ready. Its size is
  // exactly what the current part (header, control or payload) still needs, at most
  // `max_chunk` bytes.
  std::span<std::byte> window(std::size_t max_chunk = std::size_t{1} << 24);
  // Declares that n bytes were written at the start of window(); validates what completed.
  Status commit(std::size_t n);

  bool message_ready() const noexcept { return ready_; }
  // The ready record, parsed. Valid until next()/feed()/commit()/reset().
  const Message& message() const noexcept { return message_; }
  // Moves on to the next record (keeps the buffers' capacity for reuse).
  void next() noexcept;

  // True when no record is partly received (the stream is at a record boundary).
  bool at_boundary() const noexcept { return !ready_ && phase_ == Phase::header && filled_ == 0; }
  // Offset in the stream of the next byte the decoder expects.
  std::uint64_t stream_offset() const noexcept { return offset_; }
  // Offset of the first byte of the record being assembled (or ready).
  std::uint64_t record_offset() const noexcept { return record_offset_; }
  // Describes what the partial record is missing ("payload: have 100 of 5065984 bytes"),
  // for truncation messages.
  std::string describe_partial() const;
  // Sets the stream offset used in messages (e.g. past a capture file header).
  void set_stream_offset(std::uint64_t offset) noexcept { offset_ = offset, record_offset_ = offset; }

  bool failed() const noexcept { return failed_; }
  void reset() noexcept;

 private:
  enum class Phase : std::uint8_t { header, control, payload };
  Status complete_part();
  Status fail(Error error);

  DecoderLimits limits_;
  Phase phase_ = Phase::header;
  std::array<std::byte, wire_header_size> header_bytes_{};
  std::vector<std::byte> control_;
  std::vector<std::byte> payload_;
  std::size_t filled_ = 0;  // bytes of the current part received
  std::uint32_t running_crc_ = 0;
  WireHeader header_;
  Message message_;
  std::uint64_t offset_ = 0;
  std::uint64_t record_offset_ = 0;
  bool ready_ = false;
  bool failed_ = false;
};

}  // namespace slproto
