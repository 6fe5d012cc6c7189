// A byte-stream serial port: the turntable driver talks to this, never to a device API.
// Implementations: termios (UARTs, USB-serial and pseudo-terminals) and libserialport (which
// adds port enumeration and USB VID/PID lookup but cannot open a pty).
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "slproto/result.hpp"
#include "slscand/hal/clock.hpp"

namespace slscand::hal {

using slproto::Result;
using slproto::Status;

class SerialPort {
 public:
  virtual ~SerialPort() = default;
  virtual std::string name() const = 0;
  virtual Status write_all(std::string_view bytes, Nanos timeout_ns) = 0;
  // Reads what is available, waiting up to `timeout_ns` for the first byte; 0 on timeout.
  virtual Result<std::size_t> read_some(std::span<char> buffer, Nanos timeout_ns) = 0;
  virtual Status discard_input() = 0;
};

// termios: raw 8N1, no flow control, at `baud` (one of the standard rates).
Result<std::unique_ptr<SerialPort>> open_termios_port(const std::string& path, int baud);
// The termios speed constant for a baud rate, or an error naming the rate.
Result<unsigned> termios_speed(int baud);

struct SerialPortInfo {
  std::string path;
  std::string description;
  int usb_vendor_id = -1;  // -1 when not a USB device
  int usb_product_id = -1;
  std::string usb_serial;
};

#if defined(SLSCAND_HAVE_LIBSERIALPORT)
Result<std::unique_ptr<SerialPort>> open_libserialport_port(const std::string& path, int baud);
Result<std::vector<SerialPortInfo>> list_serial_ports();
// "usb:1a86:7523" -> the first port with that VID:PID; other strings are paths.
Result<std::string> resolve_serial_port(const std::string& spec);
#endif

// Parses "usb:VVVV:PPPP" (hex); false when `spec` is not of that form.
bool parse_usb_id(std::string_view spec, int& vendor_id, int& product_id);

// Reads one line (without the trailing \r\n) from `port`, keeping surplus bytes in `carry`.
// Errc::timeout when no complete line arrives before the absolute `deadline_ns`.
Result<std::string> read_line(SerialPort& port, std::string& carry, Nanos deadline_ns, std::size_t max_line = 256);

}  // namespace slscand::hal
