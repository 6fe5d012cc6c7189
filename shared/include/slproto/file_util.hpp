// Small file helpers every part of slscan shares (board and host): the text of an errno, an
// atomic write and a bounded whole-file read. No exceptions: Status / Result name the file.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

#include "slproto/result.hpp"

namespace slproto {

// "No space left on device (errno 28)": strerror's words and the number a user can search.
std::string errno_text(int error);

// Writes `bytes` to path atomically: a temporary file in the same directory, fsync, rename.
// A crash or a full disk never leaves a half-written file under `path`.
Status write_file_atomically(const std::string& path, std::string_view bytes);

// The whole file as bytes; refuses files over `max_bytes` (a text file of ours is small: a
// bigger one is the wrong file, and reading it would take the memory a scan needs).
Result<std::string> read_whole_file(const std::string& path, std::size_t max_bytes = std::size_t{64} << 20);

}  // namespace slproto
