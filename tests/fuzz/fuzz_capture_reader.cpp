// libFuzzer target: capture files (file header + record stream), in memory and through
// CaptureReader on a memfd.
#include "fuzz_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_capture_reader(data, size);
  return 0;
}
