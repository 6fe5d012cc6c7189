// Capture files: a recorded scan is the record stream itself, exactly as it arrived, after a
// 32-byte file header (docs/protocol.md, "Capture file"):
//
//   offset size  field
//        0    8  magic "SLCAP\r\n\x1a"
//        8    2  file format version (1: raw; 2: frame codec in byte 24)
//       10    2  protocol version of the records
//       12    4  header length (32; records start here)
//       16    8  creation time, Unix ns (informational)
//       24    1  frame codec (version 2; 0 none, 1 zstd), 0 in version 1
//       25    3  reserved (0)
//       28    4  CRC32C over bytes 0..27
//
// A file cut short by a crash or a full disk reads back up to its last complete record, and
// the reader says where and what was cut.
//
// Compressed captures (version 2, codec != 0): a frame record may be stored with its payload
// compressed (record flag `record_flag_compressed`). Its stored payload is
//   u32 decoded length, u32 CRC32C of the decoded payload, then the codec's bytes;
// the record's payload length and payload CRC are those of the stored bytes (checked as for any
// record). The reader decodes it (declared length bounded by the frame limit, decoded length
// and CRC checked) and hands out the record exactly as it was received: the same header,
// control and payload bytes as in a raw capture. The codec itself is not part of slproto (the
// firmware links slproto and has no use for it): the host passes one in (slproto_zstd).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "slproto/framing.hpp"
#include "slproto/result.hpp"

namespace slproto {

inline constexpr std::size_t capture_header_size = 32;
inline constexpr std::uint16_t capture_format_version = 2;      // the newest this build reads
inline constexpr std::uint16_t capture_format_version_raw = 1;  // written for raw captures
inline constexpr std::size_t compressed_payload_prefix = 8;     // decoded length + decoded CRC

enum class FrameCodecId : std::uint8_t { none = 0, zstd = 1 };
const char* frame_codec_name(FrameCodecId id) noexcept;  // "none", "zstd", "unknown"

// A lossless payload codec for capture files (implemented outside slproto: slproto_zstd).
class FrameCodec {
 public:
  virtual ~FrameCodec() = default;
  virtual FrameCodecId id() const noexcept = 0;
  // Replaces `out` with the compressed form of `raw`.
  virtual Status compress(std::span<const std::byte> raw, std::vector<std::byte>& out) const = 0;
  // Decodes `stored` into exactly out.size() bytes: an error for corrupt data or for data that
  // decodes to any other size (never writes past `out`).
  virtual Status decompress(std::span<const std::byte> stored, std::span<std::byte> out) const = 0;
};

// The file header bytes for a capture created at `unix_ns` (version 1 for raw, 2 otherwise).
std::array<std::byte, capture_header_size> capture_file_header(std::uint64_t unix_ns,
                                                               FrameCodecId codec = FrameCodecId::none);

struct CaptureWriterOptions {
  const FrameCodec* codec = nullptr;  // nullptr: a raw capture (format version 1)
  std::uint64_t created_unix_ns = 0;  // 0: now
};

class CaptureWriter {
 public:
  CaptureWriter() = default;
  ~CaptureWriter();  // finish() if still open, ignoring its error (call finish() to see it)
  CaptureWriter(CaptureWriter&&) noexcept;
  CaptureWriter& operator=(CaptureWriter&&) noexcept;
  CaptureWriter(const CaptureWriter&) = delete;
  CaptureWriter& operator=(const CaptureWriter&) = delete;

  // Creates `path + ".partial"` and writes the file header; finish() renames it to `path`,
  // so a capture under its final name is always complete, and a crash leaves a .partial file
  // that still reads back up to its last complete record.
  // With a codec, frame payloads are stored compressed (each frame whose compressed form is
  // smaller; the others raw).
  static Result<CaptureWriter> create(const std::string& path, CaptureWriterOptions options = {});

  // Appends bytes exactly as received from the stream (normally whole records; never
  // compressed: use append(Message) for frames).
  Status append(std::span<const std::byte> stream_bytes);
  // Appends one decoded record's wire bytes (header + control + payload) with one writev; a
  // frame is compressed first when the writer has a codec.
  Status append(const Message& message);
  FrameCodecId codec() const noexcept { return codec_ == nullptr ? FrameCodecId::none : codec_->id(); }
  // Payload bytes given to append(Message) and stored for them (equal for a raw capture).
  std::uint64_t payload_bytes_in() const noexcept { return payload_in_; }
  std::uint64_t payload_bytes_stored() const noexcept { return payload_stored_; }

  // Flushes to disk (fsync) and renames the .partial file to its final name.
  Status finish();
  bool is_open() const noexcept { return fd_ >= 0; }
  std::uint64_t bytes_written() const noexcept { return bytes_written_; }
  const std::string& path() const noexcept { return path_; }
  std::string partial_path() const { return path_ + ".partial"; }

 private:
  int fd_ = -1;
  std::string path_;
  std::uint64_t bytes_written_ = 0;
  bool failed_ = false;
  const FrameCodec* codec_ = nullptr;
  std::vector<std::byte> scratch_;
  std::uint64_t payload_in_ = 0, payload_stored_ = 0;
};

struct CaptureTruncation {
  std::uint64_t record_offset = 0;  // file offset where the incomplete record starts
  std::uint64_t file_size = 0;
  std::string what;  // e.g. "payload: have 1000 of 5065984 bytes"
};

class CaptureReader {
 public:
  CaptureReader() = default;
  ~CaptureReader();
  CaptureReader(CaptureReader&&) noexcept;
  CaptureReader& operator=(CaptureReader&&) noexcept;
  CaptureReader(const CaptureReader&) = delete;
  CaptureReader& operator=(const CaptureReader&) = delete;

  // Opens and checks the file header (magic, CRC, versions). A compressed capture needs its
  // codec (`codec`, e.g. slproto::zstd_codec()); without it, open() says which is missing.
  static Result<CaptureReader> open(const std::string& path, DecoderLimits limits = {},
                                    const FrameCodec* codec = nullptr);

  // The next record, or nullptr at the end of the file. A file that ends inside a record is
  // not an error here: next() returns nullptr and truncation() says where. Corrupt records
  // (bad CRC, bad framing) are errors naming the file offset; after one, next() keeps failing.
  // The returned message is valid until the next call.
  Result<const Message*> next();

  // Set once next() has hit the end of a file cut inside a record.
  const std::optional<CaptureTruncation>& truncation() const noexcept { return truncation_; }
  std::uint16_t protocol_version() const noexcept { return protocol_version_; }
  std::uint64_t created_unix_ns() const noexcept { return created_unix_ns_; }
  std::uint64_t records_read() const noexcept { return records_read_; }
  std::uint16_t format_version() const noexcept { return format_version_; }
  FrameCodecId codec() const noexcept { return codec_id_; }
  // Payload bytes as stored in the file and as decoded, over the records read so far.
  std::uint64_t payload_bytes_stored() const noexcept { return payload_stored_; }
  std::uint64_t payload_bytes_decoded() const noexcept { return payload_decoded_; }

 private:
  int fd_ = -1;
  std::string path_;
  StreamDecoder decoder_;
  std::uint64_t file_size_ = 0;
  std::uint64_t created_unix_ns_ = 0;
  std::uint64_t records_read_ = 0;
  std::uint16_t protocol_version_ = 0;
  std::optional<CaptureTruncation> truncation_;
  bool at_end_ = false;
  std::optional<Error> error_;
  std::uint16_t format_version_ = 0;
  FrameCodecId codec_id_ = FrameCodecId::none;
  const FrameCodec* codec_ = nullptr;
  std::uint32_t max_payload_ = max_payload_length;
  std::vector<std::byte> decoded_;
  Message decoded_message_;
  std::uint64_t payload_stored_ = 0, payload_decoded_ = 0;
};

// Reads a capture from memory (the fuzz target, tests): the same checks as CaptureReader.
// Calls `on_record` for each complete record; returns the truncation, if any.
Result<std::optional<CaptureTruncation>> read_capture_bytes(std::span<const std::byte> file_bytes,
                                                            const std::function<Status(const Message&)>& on_record,
                                                            DecoderLimits limits = {},
                                                            const FrameCodec* codec = nullptr);

// A stored record as the record that was received: for a compressed frame record (flag
// record_flag_compressed) decodes the payload into `buffer` and fills `out` with the original
// header, control and payload; otherwise `out` is a copy of `stored`. `max_payload` bounds the
// declared decoded length. Errors name the record's offset.
Status decode_stored_record(const Message& stored, const FrameCodec* codec, std::uint32_t max_payload,
                            std::vector<std::byte>& buffer, Message& out);

}  // namespace slproto
