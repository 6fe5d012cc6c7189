// Capture files: a recorded scan is the record stream itself, exactly as it arrived, after a
// 32-byte file header (docs/protocol.md, "Capture file"):
//
//   offset size  field
//        0    8  magic "SLCAP\r\n\x1a"
//        8    2  file format version (1)
//       10    2  protocol version of the records
//       12    4  header length (32; records start here)
//       16    8  creation time, Unix ns (informational)
//       24    4  reserved (0)
//       28    4  CRC32C over bytes 0..27
//
// A file cut short by a crash or a full disk reads back up to its last complete record, and
// the reader says where and what was cut.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>

#include "slproto/framing.hpp"
#include "slproto/result.hpp"

namespace slproto {

inline constexpr std::size_t capture_header_size = 32;
inline constexpr std::uint16_t capture_format_version = 1;

// The file header bytes for a capture created at `unix_ns`.
std::array<std::byte, capture_header_size> capture_file_header(std::uint64_t unix_ns);

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
  static Result<CaptureWriter> create(const std::string& path);

  // Appends bytes exactly as received from the stream (normally whole records).
  Status append(std::span<const std::byte> stream_bytes);
  // Appends one decoded record's wire bytes (header + control + payload) with one writev.
  Status append(const Message& message);

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

  // Opens and checks the file header (magic, CRC, versions).
  static Result<CaptureReader> open(const std::string& path, DecoderLimits limits = {});

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
};

// Reads a capture from memory (the fuzz target, tests): the same checks as CaptureReader.
// Calls `on_record` for each complete record; returns the truncation, if any.
Result<std::optional<CaptureTruncation>> read_capture_bytes(std::span<const std::byte> file_bytes,
                                                            const std::function<Status(const Message&)>& on_record,
                                                            DecoderLimits limits = {});

}  // namespace slproto
