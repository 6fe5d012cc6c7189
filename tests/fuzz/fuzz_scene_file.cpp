// libFuzzer target: virtual-rig scene files (JSON, parse_scene).
#include "fuzz_firmware_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_scene_text(data, size);
  return 0;
}
