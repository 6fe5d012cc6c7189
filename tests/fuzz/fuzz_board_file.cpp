// libFuzzer target: board files (TOML, parse_board), what slscand reads at start-up.
#include "fuzz_firmware_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_board_text(data, size);
  return 0;
}
