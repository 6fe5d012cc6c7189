// libFuzzer target: the `--config` reconstruction options file (host/app/config.cpp).
#include "fuzz_host_text_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_reconstruction_config(data, size);
  return 0;
}
