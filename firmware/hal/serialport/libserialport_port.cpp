// libserialport serial backend: what it adds over termios is port enumeration and USB
// VID/PID lookup, so a board file can say `port = "usb:1a86:7523"` and survive ttyUSB
// renumbering. It cannot open a pseudo-terminal (sysfs lookup + TIOCMGET), so its tests that
// need a port run in the VM on a real 16550 UART (docs/hardware.md).
#include <libserialport.h>

#include <algorithm>

#include "slscand/hal/serial_port.hpp"

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

namespace {

std::string sp_error_text(sp_return code) {
  if (code == SP_ERR_FAIL) {
    char* message = sp_last_error_message();
    std::string text = message != nullptr ? message : "unknown failure";
    sp_free_error_message(message);
    return text;
  }
  switch (code) {
    case SP_ERR_ARG:
      return "invalid argument";
    case SP_ERR_MEM:
      return "out of memory";
    case SP_ERR_SUPP:
      return "not supported";
    default:
      return "error " + std::to_string(static_cast<int>(code));
  }
}

class LibSerialPort final : public SerialPort {
 public:
  LibSerialPort(sp_port* port, std::string path) : port_(port), path_(std::move(path)) {}
  ~LibSerialPort() override {
    sp_close(port_);
    sp_free_port(port_);
  }
  LibSerialPort(const LibSerialPort&) = delete;
  LibSerialPort& operator=(const LibSerialPort&) = delete;

  std::string name() const override { return path_; }

  Status write_all(std::string_view bytes, Nanos timeout_ns) override {
    const unsigned ms = static_cast<unsigned>(std::max<Nanos>(1, timeout_ns / kMilli));
    const sp_return n = sp_blocking_write(port_, bytes.data(), bytes.size(), ms);
    if (n < 0) return make_error(Errc::io_error, "serial port " + path_ + ": write failed: " + sp_error_text(n));
    if (static_cast<std::size_t>(n) != bytes.size()) {
      return make_error(Errc::timeout, "serial port " + path_ + ": write timed out");
    }
    return slproto::Ok{};
  }

  Result<std::size_t> read_some(std::span<char> buffer, Nanos timeout_ns) override {
    // Wait for the first byte, then take whatever else is already there.
    const unsigned ms = static_cast<unsigned>(std::max<Nanos>(0, (timeout_ns + kMilli - 1) / kMilli));
    sp_return n =
        ms == 0 ? sp_nonblocking_read(port_, buffer.data(), 1) : sp_blocking_read(port_, buffer.data(), 1, ms);
    if (n < 0) return make_error(Errc::io_error, "serial port " + path_ + ": read failed: " + sp_error_text(n));
    if (n == 0) return std::size_t{0};
    const sp_return more = sp_nonblocking_read(port_, buffer.data() + 1, buffer.size() - 1);
    if (more < 0) return make_error(Errc::io_error, "serial port " + path_ + ": read failed: " + sp_error_text(more));
    return static_cast<std::size_t>(n + more);
  }

  Status discard_input() override {
    const sp_return rv = sp_flush(port_, SP_BUF_INPUT);
    if (rv != SP_OK) return make_error(Errc::io_error, "serial port " + path_ + ": flush failed: " + sp_error_text(rv));
    return slproto::Ok{};
  }

 private:
  sp_port* port_;
  std::string path_;
};

}  // namespace

Result<std::unique_ptr<SerialPort>> open_libserialport_port(const std::string& path, int baud) {
  if (baud <= 0) return make_error(Errc::invalid_argument, "serial port " + path + ": baud rate must be positive");
  sp_port* port = nullptr;
  sp_return rv = sp_get_port_by_name(path.c_str(), &port);
  if (rv != SP_OK) {
    return make_error(Errc::io_error, "serial port " + path + " not found by libserialport: " + sp_error_text(rv) +
                                          " (pseudo-terminals are not supported; use the termios backend)");
  }
  rv = sp_open(port, SP_MODE_READ_WRITE);
  if (rv != SP_OK) {
    const std::string text = sp_error_text(rv);
    sp_free_port(port);
    return make_error(Errc::io_error, "cannot open serial port " + path + ": " + text);
  }
  sp_port_config* config = nullptr;
  rv = sp_new_config(&config);
  if (rv == SP_OK) {
    sp_set_config_baudrate(config, baud);
    sp_set_config_bits(config, 8);
    sp_set_config_parity(config, SP_PARITY_NONE);
    sp_set_config_stopbits(config, 1);
    sp_set_config_flowcontrol(config, SP_FLOWCONTROL_NONE);
    rv = sp_set_config(port, config);
    sp_free_config(config);
  }
  if (rv != SP_OK) {
    const std::string text = sp_error_text(rv);
    sp_close(port);
    sp_free_port(port);
    return make_error(Errc::io_error,
                      "cannot configure serial port " + path + " at " + std::to_string(baud) + " baud: " + text);
  }
  return std::unique_ptr<SerialPort>(new LibSerialPort(port, path));
}

Result<std::vector<SerialPortInfo>> list_serial_ports() {
  sp_port** ports = nullptr;
  const sp_return rv = sp_list_ports(&ports);
  if (rv != SP_OK) return make_error(Errc::io_error, "cannot list serial ports: " + sp_error_text(rv));
  std::vector<SerialPortInfo> out;
  for (sp_port** p = ports; *p != nullptr; ++p) {
    SerialPortInfo info;
    info.path = sp_get_port_name(*p);
    const char* description = sp_get_port_description(*p);
    info.description = description != nullptr ? description : "";
    if (sp_get_port_transport(*p) == SP_TRANSPORT_USB) {
      int vid = -1, pid = -1;
      if (sp_get_port_usb_vid_pid(*p, &vid, &pid) == SP_OK) {
        info.usb_vendor_id = vid;
        info.usb_product_id = pid;
      }
      const char* serial = sp_get_port_usb_serial(*p);
      info.usb_serial = serial != nullptr ? serial : "";
    }
    out.push_back(std::move(info));
  }
  sp_free_port_list(ports);
  return out;
}

Result<std::string> resolve_serial_port(const std::string& spec) {
  int vid = 0, pid = 0;
  if (!parse_usb_id(spec, vid, pid)) return spec;
  auto ports = list_serial_ports();
  if (!ports) return std::move(ports).error();
  for (const auto& port : *ports) {
    if (port.usb_vendor_id == vid && port.usb_product_id == pid) return port.path;
  }
  return make_error(Errc::io_error, "no serial port with USB id " + spec.substr(4) + " is connected (" +
                                        std::to_string(ports->size()) + " ports found)");
}

}  // namespace slscand::hal
