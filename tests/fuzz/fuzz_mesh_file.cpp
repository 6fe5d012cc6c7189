// libFuzzer target: mesh files a scene names (PLY, OBJ, STL; the first byte picks which).
#include "fuzz_firmware_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_mesh_file(data, size);
  return 0;
}
