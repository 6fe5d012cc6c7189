// libFuzzer target: PLY files the host reads (slscan measure, compare).
#include "fuzz_host_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_ply_bytes(data, size);
  return 0;
}
