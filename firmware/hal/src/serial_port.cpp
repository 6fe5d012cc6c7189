#include "slscand/hal/serial_port.hpp"

#include <charconv>

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

bool parse_usb_id(std::string_view spec, int& vendor_id, int& product_id) {
  constexpr std::string_view prefix = "usb:";
  if (spec.substr(0, prefix.size()) != prefix) return false;
  spec.remove_prefix(prefix.size());
  const auto colon = spec.find(':');
  if (colon != 4 || spec.size() != 9) return false;
  auto parse_hex = [](std::string_view text, int& out) {
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), out, 16);
    return ec == std::errc{} && end == text.data() + text.size();
  };
  return parse_hex(spec.substr(0, 4), vendor_id) && parse_hex(spec.substr(5, 4), product_id);
}

Result<std::string> read_line(SerialPort& port, std::string& carry, Nanos deadline_ns, std::size_t max_line) {
  for (;;) {
    const auto newline = carry.find('\n');
    if (newline != std::string::npos) {
      std::string line = carry.substr(0, newline);
      carry.erase(0, newline + 1);
      while (!line.empty() && (line.back() == '\r' || line.back() == '\n')) line.pop_back();
      return line;
    }
    if (carry.size() > max_line) {
      // A device spewing bytes without newlines: keep the tail so a later line still parses.
      carry.erase(0, carry.size() - max_line / 2);
      return make_error(Errc::malformed,
                        "serial port " + port.name() + ": line longer than " + std::to_string(max_line) + " bytes");
    }
    const Nanos left = deadline_ns - monotonic_now_ns();
    if (left <= 0) return make_error(Errc::timeout, "serial port " + port.name() + ": no reply line in time");
    char buffer[128];
    auto n = port.read_some(buffer, left);
    if (!n) return std::move(n).error();
    carry.append(buffer, *n);
  }
}

}  // namespace slscand::hal
