// libFuzzer target: the reconstruction under an absurd-but-valid calibration and a replayed
// scan's turntable angles (fuzz_reconstruction_checks.hpp).
#include "fuzz_reconstruction_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_reconstruction(data, size);
  return 0;
}
