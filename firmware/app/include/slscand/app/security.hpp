// slscand's network policy (docs/security.md): it listens on loopback unless told otherwise,
// and on any other address only with a shared token read from a file only its owner can read,
// unless the operator explicitly opts out.
#pragma once

#include <string>

#include "slproto/result.hpp"

namespace slscand {

// Shortest token accepted: 16 characters of a random string are out of reach of guessing over
// a network at the rate a handshake allows.
inline constexpr std::size_t kMinTokenLength = 16;

// True for 127.0.0.0/8, ::1, ::ffff:127.x.x.x and "localhost"; every other address (the
// wildcards 0.0.0.0 and :: included) reaches the network.
bool is_loopback_address(const std::string& address);

// Reads a token file: its first line without surrounding blanks. Refused, with the reason and
// the path: a file that cannot be read, is not a regular file, is group- or world-accessible
// (any bit of 077: `chmod 600` it), is owned by someone other than root or this process's user,
// or holds no token of at least kMinTokenLength characters. systemd's LoadCredential= files
// (0400, owned by the service's user or root) pass.
slproto::Result<std::string> read_token_file(const std::string& path);

// Whether slscand may listen on `address` with or without a token; the error says what to do.
slproto::Status check_listen_policy(const std::string& address, bool have_token, bool insecure_no_token);

}  // namespace slscand
