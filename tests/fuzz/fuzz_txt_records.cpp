// libFuzzer target: the mDNS / DNS-SD TXT records `slscan discover` reads from the network
// (fuzz_discovery_checks.hpp).
#include "fuzz_discovery_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_txt_records(data, size);
  return 0;
}
