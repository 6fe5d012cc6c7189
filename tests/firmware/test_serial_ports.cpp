// Serial port helpers and the libserialport backend's behaviour without a UART: USB id specs,
// port enumeration, and the clear refusal of a pseudo-terminal (its real-UART tests run in
// the VM, docs/hardware.md).
#include <gtest/gtest.h>

#include "slscand/hal/serial_port.hpp"
#include "slscand/hal/sim/turntable_emulator.hpp"

using namespace slscand::hal;

TEST(UsbId, Parses) {
  int vid = 0, pid = 0;
  ASSERT_TRUE(parse_usb_id("usb:1a86:7523", vid, pid));
  EXPECT_EQ(vid, 0x1a86);
  EXPECT_EQ(pid, 0x7523);
  EXPECT_FALSE(parse_usb_id("/dev/ttyUSB0", vid, pid));
  EXPECT_FALSE(parse_usb_id("usb:1a86", vid, pid));
  EXPECT_FALSE(parse_usb_id("usb:1a86:75zz", vid, pid));
  EXPECT_FALSE(parse_usb_id("usb:1a861:7523", vid, pid));
}

TEST(TermiosSpeed, StandardRatesOnly) {
  EXPECT_TRUE(termios_speed(115200).ok());
  EXPECT_TRUE(termios_speed(9600).ok());
  EXPECT_FALSE(termios_speed(0).ok());
  EXPECT_FALSE(termios_speed(115201).ok());
}

#if defined(SLSCAND_HAVE_LIBSERIALPORT)
TEST(LibSerialPort, EnumerationWorksWithoutPorts) {
  auto ports = list_serial_ports();
  ASSERT_TRUE(ports.ok()) << ports.error().message;
  for (const auto& port : *ports) EXPECT_FALSE(port.path.empty());
}

TEST(LibSerialPort, PathsPassThroughAndUnknownUsbIdIsNamed) {
  auto path = resolve_serial_port("/dev/ttyS1");
  ASSERT_TRUE(path.ok());
  EXPECT_EQ(*path, "/dev/ttyS1");
  auto usb = resolve_serial_port("usb:ffff:fffe");
  ASSERT_FALSE(usb.ok());
  EXPECT_NE(usb.error().message.find("ffff:fffe"), std::string::npos) << usb.error().message;
}

TEST(LibSerialPort, PseudoTerminalIsRefusedWithAHint) {
  auto emulator = sim::TurntableEmulator::start();
  ASSERT_TRUE(emulator.ok());
  auto port = open_libserialport_port((*emulator)->slave_path(), 115200);
  ASSERT_FALSE(port.ok());
  EXPECT_NE(port.error().message.find((*emulator)->slave_path()), std::string::npos);
  EXPECT_NE(port.error().message.find("termios"), std::string::npos) << port.error().message;
}

TEST(LibSerialPort, MissingPortIsNamed) {
  auto port = open_libserialport_port("/dev/ttyNOPE7", 115200);
  ASSERT_FALSE(port.ok());
  EXPECT_NE(port.error().message.find("/dev/ttyNOPE7"), std::string::npos);
}
#endif
