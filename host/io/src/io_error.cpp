#include "slscan/io/io_error.hpp"

#include "slproto/file_util.hpp"

namespace slscan::io {

void write_file_atomically(const std::string& path, std::string_view bytes) {
  if (auto status = slproto::write_file_atomically(path, bytes); !status) throw IoError(status.error().message);
}

}  // namespace slscan::io
