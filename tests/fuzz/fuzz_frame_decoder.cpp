// libFuzzer target: the incremental record decoder (StreamDecoder) on arbitrary bytes.
#include "fuzz_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_frame_decoder(data, size);
  return 0;
}
