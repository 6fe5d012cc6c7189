// The properties the fuzz targets check, shared with the corpus replay test in tests/shared so
// the committed corpus also runs in the ordinary (and ASan) test suite. A violated property
// calls fuzz_fail(), which aborts: libFuzzer records the input as a crash.
#pragma once

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <string>
#include <vector>

#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/framing.hpp"

namespace slproto::fuzz {

[[noreturn]] inline void fuzz_fail(const char* what) {
  std::fprintf(stderr, "fuzz property violated: %s\n", what);
  std::abort();
}

// Tight limits keep each run's memory small; the decoder logic is the same at any limit.
inline constexpr DecoderLimits fuzz_limits{64u << 10, 4u << 20};

struct DecodeSummary {
  std::size_t records = 0;
  bool failed = false;
  Errc code = Errc::ok;
  std::uint64_t end_offset = 0;
};

// Decodes `data` as a record stream, fed in chunks whose sizes come from `chunk_seed`, and
// checks every record it yields: re-encoding it and decoding again gives the same message.
inline DecodeSummary decode_stream(std::span<const std::byte> data, std::uint32_t chunk_seed) {
  StreamDecoder decoder(fuzz_limits);
  DecodeSummary summary;
  std::vector<std::byte> reencoded;
  std::uint32_t state = chunk_seed | 1u;
  while (!data.empty()) {
    state = state * 1664525u + 1013904223u;
    const std::size_t chunk = chunk_seed == 0 ? data.size() : 1 + (state >> 24) % 97;
    Result<std::size_t> consumed = decoder.feed(data.first(std::min(chunk, data.size())));
    if (!consumed) {
      if (!decoder.failed()) fuzz_fail("decoder returned an error but is not failed");
      if (consumed.error().message.empty()) fuzz_fail("error without a message");
      summary.failed = true;
      summary.code = consumed.error().code;
      break;
    }
    data = data.subspan(*consumed);
    if (!decoder.message_ready()) continue;
    const Message& message = decoder.message();
    if (message.wire_size() != decoder.stream_offset() - message.stream_offset) fuzz_fail("wire_size mismatch");
    if (message.payload.size() != message.header.payload_length) fuzz_fail("payload size mismatch");
    if (type_of(message.body) != message.type()) fuzz_fail("body type differs from header type");
    reencoded.clear();
    if (Status status = encode(message.body, message.payload, reencoded); !status)
      fuzz_fail("a decoded record does not re-encode");
    StreamDecoder again(fuzz_limits);
    Result<std::size_t> second = again.feed(reencoded);
    if (!second || !again.message_ready() || *second != reencoded.size())
      fuzz_fail("re-encoded record does not decode");
    if (as_message_lite(again.message().body).SerializeAsString() != as_message_lite(message.body).SerializeAsString())
      fuzz_fail("round trip changed the control message");
    if (!std::equal(again.message().payload.begin(), again.message().payload.end(), message.payload.begin(),
                    message.payload.end()))
      fuzz_fail("round trip changed the payload");
    ++summary.records;
    decoder.next();
  }
  summary.end_offset = decoder.stream_offset();
  return summary;
}

// Mutations almost never keep three CRCs valid, so on its own the fuzzer would rarely get
// past them to the protobuf parsing and the geometry checks. This rewrites every CRC of the
// records in `stream` (as far as the bytes reach) so the mutated content itself is tested.
inline void repair_crcs(std::span<std::byte> stream) {
  auto get_u32 = [](const std::byte* p) {
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= std::to_integer<std::uint32_t>(p[i]) << (8 * i);
    return v;
  };
  auto put_u32 = [](std::byte* p, std::uint32_t v) {
    for (int i = 0; i < 4; ++i) p[i] = static_cast<std::byte>(v >> (8 * i));
  };
  std::size_t position = 0;
  while (position + wire_header_size <= stream.size()) {
    std::byte* header = stream.data() + position;
    const std::uint64_t control_length = get_u32(header + 8);
    const std::uint64_t payload_length = get_u32(header + 12);
    const std::uint64_t end = position + wire_header_size + control_length + payload_length;
    if (end <= stream.size()) {
      std::byte* control = header + wire_header_size;
      put_u32(header + 16, crc32c(control, control_length, crc32c(header, 16)));
      put_u32(header + 20, crc32c(control + control_length, payload_length));
    }
    put_u32(header + 28, crc32c(header, 28));
    if (end > stream.size()) break;
    position = end;
  }
}

inline void check_stream(std::span<const std::byte> data) {
  const DecodeSummary whole = decode_stream(data, 0);
  const DecodeSummary pieces = decode_stream(data, static_cast<std::uint32_t>(data.size() * 2654435761u));
  // How the bytes are split must not change what is decoded.
  if (whole.records != pieces.records || whole.failed != pieces.failed || whole.code != pieces.code)
    fuzz_fail("decoding depends on how the input is chunked");
}

inline void check_frame_decoder(const std::uint8_t* bytes, std::size_t size) {
  const std::span<const std::byte> data{reinterpret_cast<const std::byte*>(bytes), size};
  check_stream(data);
  std::vector<std::byte> repaired(data.begin(), data.end());
  repair_crcs(repaired);
  check_stream(repaired);
}

inline void check_capture_bytes(std::span<const std::byte> data) {
  const auto* bytes = data.data();
  const std::size_t size = data.size();
  std::size_t memory_records = 0;
  auto in_memory = read_capture_bytes(
      data,
      [&](const Message& message) -> Status {
        if (message.payload.size() != message.header.payload_length) fuzz_fail("payload size mismatch");
        ++memory_records;
        return Ok{};
      },
      fuzz_limits);
  if (!in_memory && in_memory.error().message.empty()) fuzz_fail("error without a message");

  // The file reader must agree with the in-memory one on the same bytes.
  const int fd = ::memfd_create("capture", MFD_CLOEXEC);
  if (fd < 0) return;
  if (size != 0 && ::write(fd, bytes, size) != static_cast<ssize_t>(size)) fuzz_fail("memfd write");
  const std::string path = "/proc/self/fd/" + std::to_string(fd);
  Result<CaptureReader> reader = CaptureReader::open(path, fuzz_limits);
  std::size_t file_records = 0;
  bool file_failed = !reader.ok();
  if (reader) {
    while (true) {
      Result<const Message*> message = reader->next();
      if (!message) {
        file_failed = true;
        if (reader->next().ok()) fuzz_fail("reader recovered after an error");
        break;
      }
      if (*message == nullptr) break;
      ++file_records;
    }
  }
  ::close(fd);
  if (file_failed != !in_memory.ok()) fuzz_fail("file and memory readers disagree on failure");
  if (file_records != memory_records) fuzz_fail("file and memory readers disagree on record count");
  if (in_memory.ok() && reader.ok() && in_memory->has_value() != reader->truncation().has_value())
    fuzz_fail("file and memory readers disagree on truncation");
  if (in_memory.ok() && in_memory->has_value() && reader.ok() &&
      (*in_memory)->record_offset != reader->truncation()->record_offset)
    fuzz_fail("file and memory readers disagree on where the file is cut");
}

inline void check_capture_reader(const std::uint8_t* bytes, std::size_t size) {
  const std::span<const std::byte> data{reinterpret_cast<const std::byte*>(bytes), size};
  check_capture_bytes(data);
  if (size >= capture_header_size) {  // again with every CRC made valid (see repair_crcs)
    std::vector<std::byte> repaired(data.begin(), data.end());
    const std::uint32_t crc = crc32c(repaired.data(), 28);
    for (int i = 0; i < 4; ++i) repaired[28 + static_cast<std::size_t>(i)] = static_cast<std::byte>(crc >> (8 * i));
    repair_crcs(std::span(repaired).subspan(capture_header_size));
    check_capture_bytes(repaired);
  }
}

}  // namespace slproto::fuzz
