// libFuzzer target: what the turntable's controller sends back: status lines and a whole GRBL session.
#include "fuzz_firmware_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_turntable_replies(data, size);
  return 0;
}
