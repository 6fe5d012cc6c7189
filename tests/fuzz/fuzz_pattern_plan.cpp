// libFuzzer target: pattern plan JSON (parse_pattern_plan), as capture manifests and calibration files carry it.
#include "fuzz_text_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_pattern_plan_text(data, size);
  return 0;
}
