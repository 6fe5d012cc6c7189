// libFuzzer target: an import sequence description (slscan import; host/io image_sequence_import.cpp).
#include "fuzz_host_text_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_sequence_description(data, size);
  return 0;
}
