// The io layer's one exception and its atomic write: every reader and writer of files
// (PLY, STL, OBJ, 3MF, captures, calibrations, descriptions, reports) reports through IoError.
#pragma once

#include <stdexcept>
#include <string>
#include <string_view>

namespace slscan::io {

// Any file problem: the message names the file and what was wrong (and where, for parsing).
class IoError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Writes bytes to path through a temporary file + rename; throws IoError.
void write_file_atomically(const std::string& path, std::string_view bytes);

}  // namespace slscan::io
