#include "slproto/result.hpp"

namespace slproto {

const char* errc_name(Errc code) noexcept {
  switch (code) {
    case Errc::ok:
      return "ok";
    case Errc::invalid_argument:
      return "invalid_argument";
    case Errc::malformed:
      return "malformed";
    case Errc::truncated:
      return "truncated";
    case Errc::oversized:
      return "oversized";
    case Errc::bad_checksum:
      return "bad_checksum";
    case Errc::wrong_version:
      return "wrong_version";
    case Errc::unsupported:
      return "unsupported";
    case Errc::io_error:
      return "io_error";
    case Errc::timeout:
      return "timeout";
    case Errc::disconnected:
      return "disconnected";
    case Errc::busy:
      return "busy";
    case Errc::aborted:
      return "aborted";
    case Errc::hardware:
      return "hardware";
    case Errc::unauthorized:
      return "unauthorized";
    case Errc::internal:
      return "internal";
  }
  return "unknown";
}

}  // namespace slproto
