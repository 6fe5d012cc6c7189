// Error handling for slproto and the firmware: no exceptions cross these APIs. A Result carries
// either a value or an Error whose message names what was wrong and where.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <variant>

namespace slproto {

enum class Errc : std::uint16_t {
  ok = 0,
  invalid_argument = 1,  // a caller passed something impossible (bad plan, bad size)
  malformed = 2,         // bytes that do not parse
  truncated = 3,         // input ended before a complete item
  oversized = 4,         // a length beyond the protocol's bounds
  bad_checksum = 5,      // CRC mismatch
  wrong_version = 6,     // protocol or file version we do not speak
  unsupported = 7,       // a valid request this build or board can't do
  io_error = 8,          // read/write/open failed (errno in the message)
  timeout = 9,           // a deadline passed
  disconnected = 10,     // the peer went away
  busy = 11,             // a scan is already running
  aborted = 12,          // stopped on request
  hardware = 13,         // a device misbehaved (turntable, camera, projector)
  unauthorized = 14,     // missing or wrong token
  internal = 15,         // a bug: should not happen
};

const char* errc_name(Errc code) noexcept;

struct Error {
  Errc code = Errc::internal;
  std::string message;
};

template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : state_(std::move(value)) {}      // NOLINT(google-explicit-constructor)
  Result(Error error) : state_(std::move(error)) {}  // NOLINT(google-explicit-constructor)

  bool ok() const noexcept { return state_.index() == 0; }
  explicit operator bool() const noexcept { return ok(); }

  T& value() & { return std::get<0>(state_); }
  const T& value() const& { return std::get<0>(state_); }
  T&& value() && { return std::get<0>(std::move(state_)); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

  const Error& error() const& { return std::get<1>(state_); }
  Error&& error() && { return std::get<1>(std::move(state_)); }

 private:
  std::variant<T, Error> state_;
};

struct Ok {};

// Result<void> spelled as Status: success carries nothing.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(Ok) {}                                                     // NOLINT(google-explicit-constructor)
  Status(Error error) : error_(std::move(error)), failed_(true) {}  // NOLINT(google-explicit-constructor)
  bool ok() const noexcept { return !failed_; }
  explicit operator bool() const noexcept { return ok(); }
  const Error& error() const { return error_; }

 private:
  Error error_;
  bool failed_ = false;
};

inline Error make_error(Errc code, std::string message) { return Error{code, std::move(message)}; }

}  // namespace slproto
