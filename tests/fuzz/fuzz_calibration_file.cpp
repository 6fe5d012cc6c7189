// libFuzzer target: calibration files (parse_calibration), the JSON the host loads with --calib.
#include "fuzz_text_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_calibration_text(data, size);
  return 0;
}
