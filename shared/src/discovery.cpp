#include "slproto/discovery.hpp"

#include <charconv>

namespace slproto {

namespace {
constexpr std::size_t max_txt_record = 255;

std::string record(const std::string& key, const std::string& value) {
  std::string r = key + "=" + value;
  if (r.size() > max_txt_record) r.resize(max_txt_record);
  return r;
}

bool parse_u32(std::string_view text, std::uint32_t& out) {
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), out);
  return ec == std::errc() && end == text.data() + text.size() && !text.empty();
}
}  // namespace

std::vector<std::string> to_txt_records(const ScannerAdvert& advert) {
  return {record("txtvers", "1"),
          record("board", advert.board),
          record("version", advert.software_version),
          record("proto", std::to_string(advert.min_protocol) + "-" + std::to_string(advert.max_protocol)),
          record("token", advert.token_required ? "1" : "0"),
          record("sim", advert.simulated ? "1" : "0")};
}

Result<ScannerAdvert> from_txt_records(const std::vector<std::string>& records) {
  ScannerAdvert advert;
  bool have_board = false, have_proto = false;
  for (const auto& r : records) {
    const auto eq = r.find('=');
    const std::string key = r.substr(0, eq);
    const std::string value = eq == std::string::npos ? std::string() : r.substr(eq + 1);
    if (key == "board") {
      advert.board = value;
      have_board = !value.empty();
    } else if (key == "version") {
      advert.software_version = value;
    } else if (key == "proto") {
      const auto dash = value.find('-');
      if (dash == std::string::npos || !parse_u32(std::string_view(value).substr(0, dash), advert.min_protocol) ||
          !parse_u32(std::string_view(value).substr(dash + 1), advert.max_protocol) ||
          advert.min_protocol > advert.max_protocol || advert.min_protocol == 0)
        return make_error(Errc::malformed, "TXT record '" + r + "': proto must be MIN-MAX, e.g. proto=1-2");
      have_proto = true;
    } else if (key == "token") {
      advert.token_required = value == "1";
    } else if (key == "sim") {
      advert.simulated = value == "1";
    }
  }
  if (!have_board) return make_error(Errc::malformed, "TXT records have no board=NAME");
  if (!have_proto) return make_error(Errc::malformed, "TXT records have no proto=MIN-MAX");
  return advert;
}

}  // namespace slproto
