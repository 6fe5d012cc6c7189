// The typed view of slproto's control messages: which protobuf message each record type
// carries, a variant over all of them, and conversions between the wire messages and the
// library's own types (PatternPlanConfig, Errc).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "slproto/pattern_plan.hpp"
#include "slproto/result.hpp"
#include "slproto/slproto.pb.h"

namespace slproto {

// Highest and lowest protocol version (the message set, negotiated by Hello.protocol_version)
// this build speaks. 2 added StatusRequest/StatusReply; a build still speaks 1 with peers that
// know nothing newer, and then sends them only version-1 messages.
inline constexpr std::uint16_t protocol_version = 2;
inline constexpr std::uint16_t min_protocol_version = 1;
// The protocol version that introduced each message that is not in every version.
inline constexpr std::uint16_t status_protocol_version = 2;

// Version of the record layout (the 32-byte wire header's version field and a capture file's
// record version). It is not the protocol version: the layout has not changed since 1, and
// keeping it apart is what lets two builds with different protocol ranges read each other's
// Hello and say which versions they speak instead of failing on the first header.
inline constexpr std::uint16_t framing_version = 1;
inline constexpr std::uint16_t min_framing_version = 1;

// The record type byte of the wire header. Values are part of the wire format: never reuse.
enum class MessageType : std::uint8_t {
  hello = 1,
  hello_reply = 2,
  scan_request = 3,
  progress = 4,
  frame = 5,  // pb::FrameHeader + raw pixel payload
  scan_done = 6,
  error = 7,
  abort = 8,
  heartbeat = 9,
  status_request = 10,  // protocol >= 2
  status_reply = 11,    // protocol >= 2
};
inline constexpr std::uint8_t max_message_type = 11;

const char* message_type_name(MessageType type) noexcept;
bool is_known_message_type(std::uint8_t value) noexcept;

// One alternative per MessageType, in MessageType order (index = type - 1).
using Body = std::variant<pb::Hello, pb::HelloReply, pb::ScanRequest, pb::Progress, pb::FrameHeader, pb::ScanDone,
                          pb::Error, pb::Abort, pb::Heartbeat, pb::StatusRequest, pb::StatusReply>;

template <class T>
struct message_type_of;
template <>
struct message_type_of<pb::Hello> {
  static constexpr MessageType value = MessageType::hello;
};
template <>
struct message_type_of<pb::HelloReply> {
  static constexpr MessageType value = MessageType::hello_reply;
};
template <>
struct message_type_of<pb::ScanRequest> {
  static constexpr MessageType value = MessageType::scan_request;
};
template <>
struct message_type_of<pb::Progress> {
  static constexpr MessageType value = MessageType::progress;
};
template <>
struct message_type_of<pb::FrameHeader> {
  static constexpr MessageType value = MessageType::frame;
};
template <>
struct message_type_of<pb::ScanDone> {
  static constexpr MessageType value = MessageType::scan_done;
};
template <>
struct message_type_of<pb::Error> {
  static constexpr MessageType value = MessageType::error;
};
template <>
struct message_type_of<pb::Abort> {
  static constexpr MessageType value = MessageType::abort;
};
template <>
struct message_type_of<pb::Heartbeat> {
  static constexpr MessageType value = MessageType::heartbeat;
};
template <>
struct message_type_of<pb::StatusRequest> {
  static constexpr MessageType value = MessageType::status_request;
};
template <>
struct message_type_of<pb::StatusReply> {
  static constexpr MessageType value = MessageType::status_reply;
};
template <class T>
inline constexpr MessageType message_type_v = message_type_of<T>::value;

template <class T>
concept ControlMessage = requires {
  message_type_of<T>::value;
};

MessageType type_of(const Body& body) noexcept;
// NOLINTNEXTLINE(bugprone-exception-escape): a Body is never valueless (messages.cpp)
const google::protobuf::MessageLite& as_message_lite(const Body& body) noexcept;

// Bytes per pixel of a pixel format (1 for mono8, 2 for mono10/12), 0 if unknown.
int bytes_per_pixel(pb::PixelFormat format) noexcept;
const char* pixel_format_name(pb::PixelFormat format) noexcept;

// Checks the frame header's geometry against the payload size: known pixel format,
// 0 < width, height <= 65535, stride_bytes >= width * bytes_per_pixel,
// payload_size == stride_bytes * height. The message names the offending field.
Status check_frame_geometry(const pb::FrameHeader& header, std::size_t payload_size);

// Fills width/height/format/stride for a tightly packed image (stride = width * bpp).
void set_frame_geometry(pb::FrameHeader& header, std::uint32_t width, std::uint32_t height,
                        pb::PixelFormat format = pb::PIXEL_FORMAT_MONO8);

// Pattern plan <-> wire. from_proto runs PatternPlanConfig::check() and names the bad field.
pb::PatternPlanConfig to_proto(const PatternPlanConfig& config);
Result<PatternPlanConfig> from_proto(const pb::PatternPlanConfig& config);

// Checks a scan request a board could start: at least one angle (each finite, in
// [-360, 360]), at least one projector (ids < projector_count, no duplicates), a valid
// plan, exposure_us > 0, pattern_period_us >= exposure_us, a known pixel format; a bracket of
// at most kMaxExposureBracket distinct exposures, each > 0 and <= pattern_period_us.
Status check_scan_request(const pb::ScanRequest& request, std::uint32_t projector_count = 2);

// More exposures per view than any HDR scheme uses (Gocator: 5, Xema: 6): a bigger bracket is
// a mistake that would multiply the scan's frames.
inline constexpr int kMaxExposureBracket = 8;

// The exposures (us) a request captures every view at, in capture order: its bracket, or
// exposure_us alone. FrameHeader.exposure_index indexes this list.
std::vector<std::uint32_t> exposures_of(const pb::ScanRequest& request);

// Error <-> wire. Unknown codes become Errc::internal with the number in the text.
pb::Error to_proto(const Error& error, std::uint64_t scan_id = 0, bool fatal = false);
Error from_proto(const pb::Error& error);
Errc errc_from_wire(std::uint32_t code) noexcept;

}  // namespace slproto
