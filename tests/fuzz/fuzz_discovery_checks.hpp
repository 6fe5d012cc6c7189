// Properties of the mDNS / DNS-SD TXT records `slscan discover` reads from any host on the
// network (slproto/discovery.hpp). The input is the TXT record data as it comes off the wire:
// each record one length byte, then that many bytes (a cut last record is what is there).
// Refused: an error with a message. Accepted: an advert with a board and a protocol range
// 1 <= min <= max, which writes back to records that read as the same advert.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "fuzz_checks.hpp"
#include "slproto/discovery.hpp"

namespace slproto::fuzz {

inline void check_txt_records(const std::uint8_t* bytes, std::size_t size) {
  std::vector<std::string> records;
  for (std::size_t at = 0; at < size;) {
    const std::size_t length = bytes[at++];
    const std::size_t have = std::min(length, size - at);
    records.emplace_back(reinterpret_cast<const char*>(bytes + at), have);
    at += have;
  }
  const auto advert = from_txt_records(records);
  if (!advert) {
    if (advert.error().message.empty()) fuzz_fail("TXT records refused without a message");
    return;
  }
  if (advert->board.empty()) fuzz_fail("an advert without a board was accepted");
  if (advert->min_protocol == 0 || advert->min_protocol > advert->max_protocol)
    fuzz_fail("an advert with an impossible protocol range was accepted");
  const auto again = from_txt_records(to_txt_records(*advert));
  if (!again) fuzz_fail("an accepted advert does not read back from its own records");
  if (again->board != advert->board || again->software_version != advert->software_version ||
      again->min_protocol != advert->min_protocol || again->max_protocol != advert->max_protocol ||
      again->token_required != advert->token_required || again->simulated != advert->simulated)
    fuzz_fail("an accepted advert changes when written and read back");
}

}  // namespace slproto::fuzz
