#include "slproto/capture.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <utility>

#include "slproto/crc32c.hpp"
#include "slproto/file_util.hpp"

namespace slproto {
namespace {

constexpr std::array<std::byte, 8> capture_magic{std::byte{'S'}, std::byte{'L'},  std::byte{'C'},  std::byte{'A'},
                                                 std::byte{'P'}, std::byte{'\r'}, std::byte{'\n'}, std::byte{0x1a}};
constexpr std::size_t max_capture_header = 4096;

std::uint64_t get_le(const std::byte* p, int bytes) {
  std::uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v |= std::to_integer<std::uint64_t>(p[i]) << (8 * i);
  return v;
}
void put_le(std::byte* p, std::uint64_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) p[i] = static_cast<std::byte>((v >> (8 * i)) & 0xFF);
}

struct CaptureHeaderInfo {
  std::uint16_t format_version = 0;
  FrameCodecId codec = FrameCodecId::none;
  std::uint16_t protocol_version = 0;
  std::uint32_t header_length = 0;
  std::uint64_t created_unix_ns = 0;
};

Result<CaptureHeaderInfo> parse_capture_header(std::span<const std::byte> bytes, const std::string& name) {
  if (bytes.size() < capture_header_size)
    return make_error(Errc::truncated, name + ": capture file header: have " + std::to_string(bytes.size()) + " of " +
                                           std::to_string(capture_header_size) + " bytes");
  const std::byte* p = bytes.data();
  if (!std::equal(capture_magic.begin(), capture_magic.end(), p))
    return make_error(Errc::malformed, name + ": not a capture file (bad magic at offset 0)");
  if (get_le(p + 28, 4) != crc32c(p, 28))
    return make_error(Errc::bad_checksum, name + ": capture file header CRC mismatch (offset 28)");
  const auto format = static_cast<std::uint16_t>(get_le(p + 8, 2));
  if (format < capture_format_version_raw || format > capture_format_version)
    return make_error(Errc::wrong_version, name + ": capture format version " + std::to_string(format) +
                                               " not supported (this build reads " +
                                               std::to_string(capture_format_version_raw) + ".." +
                                               std::to_string(capture_format_version) + ") at offset 8");
  CaptureHeaderInfo info;
  info.format_version = format;
  if (format >= 2) {
    const auto codec = std::to_integer<std::uint8_t>(p[24]);
    if (codec > static_cast<std::uint8_t>(FrameCodecId::zstd))
      return make_error(Errc::unsupported, name + ": unknown frame codec " + std::to_string(codec) +
                                               " (this build knows 0 none, 1 zstd) at offset 24");
    if (get_le(p + 25, 3) != 0)
      return make_error(Errc::malformed, name + ": capture header reserved bytes 25..27 are not 0");
    info.codec = static_cast<FrameCodecId>(codec);
  }
  info.protocol_version = static_cast<std::uint16_t>(get_le(p + 10, 2));
  if (info.protocol_version < min_framing_version || info.protocol_version > framing_version)
    return make_error(Errc::wrong_version, name + ": records use framing version " +
                                               std::to_string(info.protocol_version) + ", this build reads " +
                                               std::to_string(min_framing_version) + ".." +
                                               std::to_string(framing_version) + " (offset 10)");
  info.header_length = static_cast<std::uint32_t>(get_le(p + 12, 4));
  if (info.header_length < capture_header_size || info.header_length > max_capture_header)
    return make_error(Errc::malformed, name + ": capture header length " + std::to_string(info.header_length) +
                                           " not in 32.." + std::to_string(max_capture_header) + " (offset 12)");
  info.created_unix_ns = get_le(p + 16, 8);
  return info;
}

Error at_record(const Message& stored, Errc code, const std::string& what) {
  return Error{code, "compressed frame record at offset " + std::to_string(stored.stream_offset) + ": " + what};
}

}  // namespace

const char* frame_codec_name(FrameCodecId id) noexcept {
  switch (id) {
    case FrameCodecId::none:
      return "none";
    case FrameCodecId::zstd:
      return "zstd";
  }
  return "unknown";
}

Status decode_stored_record(const Message& stored, const FrameCodec* codec, std::uint32_t max_payload,
                            std::vector<std::byte>& buffer, Message& out) {
  if ((stored.header.flags & record_flag_compressed) == 0) {
    out = stored;
    return Ok{};
  }
  if (codec == nullptr) return at_record(stored, Errc::unsupported, "no codec to decode it");
  const std::span<const std::byte> payload = stored.payload;
  if (payload.size() < compressed_payload_prefix)
    return at_record(stored, Errc::malformed,
                     "stored payload of " + std::to_string(payload.size()) + " bytes is shorter than its " +
                         std::to_string(compressed_payload_prefix) + "-byte prefix");
  const auto decoded_length = static_cast<std::uint32_t>(get_le(payload.data(), 4));
  const auto decoded_crc = static_cast<std::uint32_t>(get_le(payload.data() + 4, 4));
  const std::uint32_t limit = std::min(max_payload, max_payload_length);
  if (decoded_length > limit)
    return at_record(stored, Errc::oversized,
                     "declared decoded size " + std::to_string(decoded_length) + " exceeds the frame limit " +
                         std::to_string(limit) + " (not decoded)");
  if (buffer.size() < decoded_length) buffer.resize(decoded_length);
  const std::span<std::byte> decoded{buffer.data(), decoded_length};
  if (Status status = codec->decompress(payload.subspan(compressed_payload_prefix), decoded); !status)
    return at_record(stored, status.error().code,
                     std::string(frame_codec_name(codec->id())) + " payload: " + status.error().message);
  if (crc32c(decoded) != decoded_crc) return at_record(stored, Errc::bad_checksum, "decoded payload CRC mismatch");
  WireHeader header = stored.header;
  header.flags = 0;
  header.payload_length = decoded_length;
  header.payload_crc = decoded_crc;
  header.control_crc = control_crc(header, stored.control);
  out.header = header;
  out.header_bytes = header.serialize();
  out.body = stored.body;
  out.control = stored.control;
  out.payload = decoded;
  out.stream_offset = stored.stream_offset;
  if (const auto* frame = out.get<pb::FrameHeader>()) {
    if (Status status = check_frame_geometry(*frame, decoded.size()); !status)
      return at_record(stored, status.error().code, "decoded: " + status.error().message);
    if (frame->payload_crc32c() != decoded_crc)
      return at_record(stored, Errc::bad_checksum, "frame header: payload_crc32c differs from the decoded payload's");
  }
  return Ok{};
}

std::array<std::byte, capture_header_size> capture_file_header(std::uint64_t unix_ns, FrameCodecId codec) {
  std::array<std::byte, capture_header_size> out{};
  std::copy(capture_magic.begin(), capture_magic.end(), out.begin());
  put_le(&out[8], codec == FrameCodecId::none ? capture_format_version_raw : capture_format_version, 2);
  put_le(&out[10], framing_version, 2);
  put_le(&out[12], capture_header_size, 4);
  put_le(&out[16], unix_ns, 8);
  put_le(&out[24], static_cast<std::uint8_t>(codec), 4);
  put_le(&out[28], crc32c(out.data(), 28), 4);
  return out;
}

// ---- CaptureWriter

CaptureWriter::~CaptureWriter() {
  if (fd_ >= 0) (void)finish();
}
CaptureWriter::CaptureWriter(CaptureWriter&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)),
      path_(std::move(other.path_)),
      bytes_written_(other.bytes_written_),
      failed_(other.failed_),
      codec_(other.codec_),
      scratch_(std::move(other.scratch_)),
      payload_in_(other.payload_in_),
      payload_stored_(other.payload_stored_) {}
CaptureWriter& CaptureWriter::operator=(CaptureWriter&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) (void)finish();
    fd_ = std::exchange(other.fd_, -1);
    path_ = std::move(other.path_);
    bytes_written_ = other.bytes_written_;
    failed_ = other.failed_;
    codec_ = other.codec_;
    scratch_ = std::move(other.scratch_);
    payload_in_ = other.payload_in_;
    payload_stored_ = other.payload_stored_;
  }
  return *this;
}

Result<CaptureWriter> CaptureWriter::create(const std::string& path, CaptureWriterOptions options) {
  CaptureWriter writer;
  writer.path_ = path;
  writer.codec_ = options.codec;
  const std::string partial = writer.partial_path();
  writer.fd_ = ::open(partial.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (writer.fd_ < 0) return make_error(Errc::io_error, "cannot create capture " + partial + ": " + errno_text(errno));
  const auto now = std::chrono::system_clock::now().time_since_epoch();
  const std::uint64_t created =
      options.created_unix_ns != 0
          ? options.created_unix_ns
          : static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(now).count());
  const auto header = capture_file_header(created, writer.codec());
  if (Status status = writer.append(header); !status) {
    ::close(std::exchange(writer.fd_, -1));
    ::unlink(partial.c_str());
    return status.error();
  }
  return writer;
}

namespace {

// Writes every byte of the iovecs or reports why not; returns bytes written so far in `done`.
Status write_iov(int fd, iovec* iov, int count, std::size_t& done) {
  done = 0;
  while (count > 0) {
    const ssize_t n = ::writev(fd, iov, count);
    if (n < 0) {
      if (errno == EINTR) continue;
      const int error = errno;
      if (error == ENOSPC || error == EFBIG || error == EDQUOT)
        return make_error(Errc::io_error, "disk full or file too large: " + errno_text(error));
      return make_error(Errc::io_error, errno_text(error));
    }
    if (n == 0) return make_error(Errc::io_error, "write made no progress");
    done += static_cast<std::size_t>(n);
    auto left = static_cast<std::size_t>(n);
    while (count > 0 && left >= iov->iov_len) {
      left -= iov->iov_len;
      ++iov;
      --count;
    }
    if (count > 0) {
      iov->iov_base = static_cast<char*>(iov->iov_base) + left;
      iov->iov_len -= left;
    }
  }
  return Ok{};
}

}  // namespace

static Status append_iov(int fd, bool& failed, std::uint64_t& bytes_written, const std::string& name, iovec* iov,
                         int count) {
  if (fd < 0) return make_error(Errc::invalid_argument, "capture " + name + " is not open");
  if (failed) return make_error(Errc::io_error, "capture " + name + " failed earlier; nothing more is written");
  std::size_t done = 0;
  if (Status status = write_iov(fd, iov, count, done); !status) {
    failed = true;
    // Cut back to the last whole record so the file stays clean; the reader copes either way.
    const bool cut = ::ftruncate(fd, static_cast<off_t>(bytes_written)) == 0;
    return make_error(Errc::io_error, "writing capture " + name + " at offset " + std::to_string(bytes_written + done) +
                                          ": " + status.error().message +
                                          (cut ? "; file cut back to its last complete record at offset " +
                                                     std::to_string(bytes_written)
                                               : std::string()));
  }
  bytes_written += done;
  return Ok{};
}

Status CaptureWriter::append(std::span<const std::byte> stream_bytes) {
  iovec iov{const_cast<std::byte*>(stream_bytes.data()), stream_bytes.size()};  // writev only reads
  return append_iov(fd_, failed_, bytes_written_, partial_path(), &iov, 1);
}

Status CaptureWriter::append(const Message& message) {
  payload_in_ += message.payload.size();
  if (codec_ != nullptr && message.type() == MessageType::frame && !message.payload.empty() &&
      message.header.flags == 0 && fd_ >= 0 && !failed_) {
    if (Status status = codec_->compress(message.payload, scratch_); !status)
      return make_error(status.error().code, "compressing the frame record at stream offset " +
                                                 std::to_string(message.stream_offset) + " for " + partial_path() +
                                                 ": " + status.error().message);
    const std::uint64_t stored = compressed_payload_prefix + scratch_.size();
    if (stored < message.payload.size()) {  // else stored raw: incompressible (noise)
      std::array<std::byte, compressed_payload_prefix> prefix{};
      put_le(prefix.data(), message.payload.size(), 4);
      put_le(prefix.data() + 4, message.header.payload_crc, 4);
      WireHeader header = message.header;
      header.flags = record_flag_compressed;
      header.payload_length = static_cast<std::uint32_t>(stored);
      header.payload_crc = crc32c(scratch_, crc32c(prefix.data(), prefix.size()));
      header.control_crc = control_crc(header, message.control);
      const auto header_bytes = header.serialize();
      iovec iov[4] = {
          {const_cast<std::byte*>(header_bytes.data()), header_bytes.size()},
          {const_cast<std::byte*>(message.control.data()), message.control.size()},
          {prefix.data(), prefix.size()},
          {scratch_.data(), scratch_.size()},
      };
      payload_stored_ += stored;
      return append_iov(fd_, failed_, bytes_written_, partial_path(), iov, 4);
    }
  }
  payload_stored_ += message.payload.size();
  iovec iov[3] = {
      {const_cast<std::byte*>(message.header_bytes.data()), message.header_bytes.size()},
      {const_cast<std::byte*>(message.control.data()), message.control.size()},
      {const_cast<std::byte*>(message.payload.data()), message.payload.size()},
  };
  return append_iov(fd_, failed_, bytes_written_, partial_path(), iov, 3);
}

Status CaptureWriter::finish() {
  if (fd_ < 0) return make_error(Errc::invalid_argument, "capture " + path_ + " is not open");
  const int fd = std::exchange(fd_, -1);
  const std::string partial = partial_path();
  if (failed_) {
    ::close(fd);
    return make_error(Errc::io_error, "capture " + partial + " is incomplete after a write error; left as it is");
  }
  if (::fdatasync(fd) != 0) {
    const int error = errno;
    ::close(fd);
    return make_error(Errc::io_error, "flushing capture " + partial + ": " + errno_text(error));
  }
  if (::close(fd) != 0) return make_error(Errc::io_error, "closing capture " + partial + ": " + errno_text(errno));
  if (::rename(partial.c_str(), path_.c_str()) != 0)
    return make_error(Errc::io_error, "renaming " + partial + " to " + path_ + ": " + errno_text(errno));
  return Ok{};
}

// ---- CaptureReader

CaptureReader::~CaptureReader() {
  if (fd_ >= 0) ::close(fd_);
}
CaptureReader::CaptureReader(CaptureReader&& other) noexcept { *this = std::move(other); }
CaptureReader& CaptureReader::operator=(CaptureReader&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(other.fd_, -1);
    path_ = std::move(other.path_);
    decoder_ = std::move(other.decoder_);
    file_size_ = other.file_size_;
    created_unix_ns_ = other.created_unix_ns_;
    records_read_ = other.records_read_;
    protocol_version_ = other.protocol_version_;
    truncation_ = std::move(other.truncation_);
    at_end_ = other.at_end_;
    error_ = std::move(other.error_);
    format_version_ = other.format_version_;
    codec_id_ = other.codec_id_;
    codec_ = other.codec_;
    max_payload_ = other.max_payload_;
    decoded_ = std::move(other.decoded_);
    decoded_message_ = std::move(other.decoded_message_);
    payload_stored_ = other.payload_stored_;
    payload_decoded_ = other.payload_decoded_;
  }
  return *this;
}

namespace {

Status check_codec(const CaptureHeaderInfo& info, const FrameCodec* codec, const std::string& name) {
  if (info.codec == FrameCodecId::none) return Ok{};
  if (codec == nullptr || codec->id() != info.codec)
    return make_error(Errc::unsupported, name + ": frames are compressed with " + frame_codec_name(info.codec) +
                                             " (header offset 24) and this program has no " +
                                             frame_codec_name(info.codec) + " codec");
  return Ok{};
}

}  // namespace

Result<CaptureReader> CaptureReader::open(const std::string& path, DecoderLimits limits, const FrameCodec* codec) {
  CaptureReader reader;
  reader.path_ = path;
  reader.max_payload_ = limits.max_payload;
  reader.fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (reader.fd_ < 0) return make_error(Errc::io_error, "cannot open capture " + path + ": " + errno_text(errno));
  struct stat info {};
  if (::fstat(reader.fd_, &info) != 0) return make_error(Errc::io_error, "stat " + path + ": " + errno_text(errno));
  reader.file_size_ = static_cast<std::uint64_t>(info.st_size);
  std::array<std::byte, capture_header_size> header{};
  const ssize_t n = ::pread(reader.fd_, header.data(), header.size(), 0);
  if (n < 0) return make_error(Errc::io_error, "reading " + path + ": " + errno_text(errno));
  Result<CaptureHeaderInfo> parsed = parse_capture_header({header.data(), static_cast<std::size_t>(n)}, path);
  if (!parsed) return std::move(parsed).error();
  if (Status status = check_codec(*parsed, codec, path); !status) return status.error();
  reader.format_version_ = parsed->format_version;
  reader.codec_id_ = parsed->codec;
  reader.codec_ = codec;
  limits.allowed_flags = parsed->codec == FrameCodecId::none ? 0 : record_flag_compressed;
  reader.decoder_ = StreamDecoder(limits);
  if (parsed->header_length > reader.file_size_)
    return make_error(Errc::truncated, path + ": capture file header of " + std::to_string(parsed->header_length) +
                                           " bytes but the file has " + std::to_string(reader.file_size_));
  if (::lseek(reader.fd_, parsed->header_length, SEEK_SET) < 0)
    return make_error(Errc::io_error, "seek in " + path + ": " + errno_text(errno));
  reader.protocol_version_ = parsed->protocol_version;
  reader.created_unix_ns_ = parsed->created_unix_ns;
  reader.decoder_.set_stream_offset(parsed->header_length);
  return reader;
}

Result<const Message*> CaptureReader::next() {
  if (error_) return *error_;
  if (fd_ < 0) return make_error(Errc::invalid_argument, "capture reader is not open");
  if (at_end_) return static_cast<const Message*>(nullptr);
  decoder_.next();
  while (true) {
    const std::span<std::byte> window = decoder_.window(std::size_t{1} << 24);
    const ssize_t n = ::read(fd_, window.data(), window.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      error_ = make_error(Errc::io_error, "reading " + path_ + " at offset " +
                                              std::to_string(decoder_.stream_offset()) + ": " + errno_text(errno));
      return *error_;
    }
    if (n == 0) {
      at_end_ = true;
      if (!decoder_.at_boundary())
        truncation_ =
            CaptureTruncation{decoder_.record_offset(), decoder_.stream_offset(), decoder_.describe_partial()};
      return static_cast<const Message*>(nullptr);
    }
    if (Status status = decoder_.commit(static_cast<std::size_t>(n)); !status) {
      std::string text = status.error().message;
      const std::string stream_word = "stream offset";
      if (auto pos = text.find(stream_word); pos != std::string::npos)
        text.replace(pos, stream_word.size(), "file offset");
      error_ = make_error(status.error().code, path_ + ": " + text);
      return *error_;
    }
    if (decoder_.message_ready()) {
      ++records_read_;
      const Message& stored = decoder_.message();
      payload_stored_ += stored.payload.size();
      if ((stored.header.flags & record_flag_compressed) == 0) {
        payload_decoded_ += stored.payload.size();
        return &stored;
      }
      if (Status status = decode_stored_record(stored, codec_, max_payload_, decoded_, decoded_message_); !status) {
        error_ = make_error(status.error().code, path_ + ": " + status.error().message);
        return *error_;
      }
      payload_decoded_ += decoded_message_.payload.size();
      return &decoded_message_;
    }
  }
}

Result<std::optional<CaptureTruncation>> read_capture_bytes(std::span<const std::byte> file_bytes,
                                                            const std::function<Status(const Message&)>& on_record,
                                                            DecoderLimits limits, const FrameCodec* codec) {
  Result<CaptureHeaderInfo> parsed = parse_capture_header(file_bytes, "capture");
  if (!parsed) return std::move(parsed).error();
  if (Status status = check_codec(*parsed, codec, "capture"); !status) return status.error();
  limits.allowed_flags = parsed->codec == FrameCodecId::none ? 0 : record_flag_compressed;
  std::vector<std::byte> buffer;
  Message decoded;
  if (parsed->header_length > file_bytes.size())
    return make_error(Errc::truncated, "capture: file header of " + std::to_string(parsed->header_length) +
                                           " bytes but the data has " + std::to_string(file_bytes.size()));
  StreamDecoder decoder(limits);
  decoder.set_stream_offset(parsed->header_length);
  std::span<const std::byte> rest = file_bytes.subspan(parsed->header_length);
  while (!rest.empty()) {
    Result<std::size_t> consumed = decoder.feed(rest);
    if (!consumed) return make_error(consumed.error().code, "capture: " + consumed.error().message);
    rest = rest.subspan(*consumed);
    if (decoder.message_ready()) {
      const Message& stored = decoder.message();
      if ((stored.header.flags & record_flag_compressed) == 0) {
        if (Status status = on_record(stored); !status) return status.error();
      } else {
        if (Status status = decode_stored_record(stored, codec, limits.max_payload, buffer, decoded); !status)
          return make_error(status.error().code, "capture: " + status.error().message);
        if (Status status = on_record(decoded); !status) return status.error();
      }
      decoder.next();
    }
  }
  if (!decoder.at_boundary())
    return std::optional<CaptureTruncation>(
        CaptureTruncation{decoder.record_offset(), file_bytes.size(), decoder.describe_partial()});
  return std::optional<CaptureTruncation>();
}

}  // namespace slproto
