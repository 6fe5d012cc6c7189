// What a scanner announces over mDNS/DNS-SD (service type _slscan._tcp): its TXT records, built
// by slscand and read by `slscan discover`. Pure data: the Avahi calls live in firmware/app
// (publishing) and host/app (browsing).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "slproto/result.hpp"

namespace slproto {

inline constexpr const char* dns_sd_service_type = "_slscan._tcp";

struct ScannerAdvert {
  std::string board;             // board file's name, e.g. "rpi"
  std::string software_version;  // "slscand 0.2.0"
  std::uint32_t min_protocol = 0;
  std::uint32_t max_protocol = 0;
  bool token_required = false;
  bool simulated = false;
};

// "txtvers=1", "board=rpi", "version=slscand 0.2.0", "proto=1-2", "token=1", "sim=0". Each
// record is at most 255 bytes (DNS-SD): longer values are cut.
std::vector<std::string> to_txt_records(const ScannerAdvert& advert);

// Reads what to_txt_records wrote; unknown keys are ignored (later releases may add some).
// Errors name the record: a missing board or proto, a proto that is not "MIN-MAX".
Result<ScannerAdvert> from_txt_records(const std::vector<std::string>& records);

}  // namespace slproto
