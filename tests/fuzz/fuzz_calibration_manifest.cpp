// libFuzzer target: the manifest.json of a calibration capture folder (slscan calibrate).
#include "fuzz_manifest_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_calibration_manifest(data, size);
  return 0;
}
