// termios serial port: works on real UARTs, USB-serial adapters and pseudo-terminals alike,
// which is why the turntable protocol tests run through it against a pty emulator.
#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "slproto/file_util.hpp"
#include "slscand/hal/serial_port.hpp"

namespace slscand::hal {

using slproto::Errc;
using slproto::errno_text;
using slproto::make_error;

namespace {

int poll_ms(Nanos timeout_ns) {
  if (timeout_ns <= 0) return 0;
  return static_cast<int>((timeout_ns + kMilli - 1) / kMilli);
}

class TermiosSerialPort final : public SerialPort {
 public:
  TermiosSerialPort(int fd, std::string path) : fd_(fd), path_(std::move(path)) {}
  ~TermiosSerialPort() override { ::close(fd_); }
  TermiosSerialPort(const TermiosSerialPort&) = delete;
  TermiosSerialPort& operator=(const TermiosSerialPort&) = delete;

  std::string name() const override { return path_; }

  Status write_all(std::string_view bytes, Nanos timeout_ns) override {
    const Nanos deadline = monotonic_now_ns() + timeout_ns;
    while (!bytes.empty()) {
      const ssize_t n = ::write(fd_, bytes.data(), bytes.size());
      if (n > 0) {
        bytes.remove_prefix(static_cast<std::size_t>(n));
        continue;
      }
      if (n < 0 && errno != EAGAIN && errno != EINTR) {
        return make_error(Errc::io_error, "serial port " + path_ + ": write failed: " + errno_text(errno));
      }
      const Nanos left = deadline - monotonic_now_ns();
      if (left <= 0) return make_error(Errc::timeout, "serial port " + path_ + ": write timed out");
      pollfd pfd{fd_, POLLOUT, 0};
      ::poll(&pfd, 1, poll_ms(left));
    }
    return slproto::Ok{};
  }

  Result<std::size_t> read_some(std::span<char> buffer, Nanos timeout_ns) override {
    pollfd pfd{fd_, POLLIN, 0};
    int ready = 0;
    do {
      ready = ::poll(&pfd, 1, poll_ms(timeout_ns));
    } while (ready < 0 && errno == EINTR);
    if (ready < 0) return make_error(Errc::io_error, "serial port " + path_ + ": poll failed: " + errno_text(errno));
    if (ready == 0) return std::size_t{0};
    if ((pfd.revents & POLLIN) == 0 && (pfd.revents & (POLLHUP | POLLERR)) != 0) {
      return make_error(Errc::disconnected, "serial port " + path_ + ": the other end hung up");
    }
    const ssize_t n = ::read(fd_, buffer.data(), buffer.size());
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) return std::size_t{0};
      return make_error(Errc::io_error, "serial port " + path_ + ": read failed: " + errno_text(errno));
    }
    if (n == 0) return make_error(Errc::disconnected, "serial port " + path_ + ": end of file");
    return static_cast<std::size_t>(n);
  }

  Status discard_input() override {
    if (::tcflush(fd_, TCIFLUSH) != 0) {
      return make_error(Errc::io_error, "serial port " + path_ + ": tcflush failed: " + errno_text(errno));
    }
    return slproto::Ok{};
  }

 private:
  int fd_;
  std::string path_;
};

}  // namespace

Result<unsigned> termios_speed(int baud) {
  switch (baud) {
    case 9600:
      return unsigned{B9600};
    case 19200:
      return unsigned{B19200};
    case 38400:
      return unsigned{B38400};
    case 57600:
      return unsigned{B57600};
    case 115200:
      return unsigned{B115200};
    case 230400:
      return unsigned{B230400};
    case 460800:
      return unsigned{B460800};
    case 921600:
      return unsigned{B921600};
    default:
      break;
  }
  return make_error(Errc::invalid_argument,
                    "unsupported baud rate " + std::to_string(baud) +
                        " (expected 9600, 19200, 38400, 57600, 115200, 230400, 460800 or 921600)");
}

Result<std::unique_ptr<SerialPort>> open_termios_port(const std::string& path, int baud) {
  auto speed = termios_speed(baud);
  if (!speed) return std::move(speed).error();
  const int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    return make_error(Errc::io_error, "cannot open serial port " + path + ": " + errno_text(errno));
  }
  termios tio{};
  if (::tcgetattr(fd, &tio) != 0) {
    const int err = errno;
    ::close(fd);
    return make_error(Errc::io_error, path + " is not a serial port (tcgetattr: " + errno_text(err) + ")");
  }
  ::cfmakeraw(&tio);
  tio.c_cflag |= CLOCAL | CREAD;
  tio.c_cflag &= ~static_cast<tcflag_t>(CRTSCTS | CSTOPB | PARENB);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  ::cfsetispeed(&tio, static_cast<speed_t>(*speed));
  ::cfsetospeed(&tio, static_cast<speed_t>(*speed));
  if (::tcsetattr(fd, TCSANOW, &tio) != 0) {
    const int err = errno;
    ::close(fd);
    return make_error(Errc::io_error, "cannot configure serial port " + path + ": " + errno_text(err));
  }
  return std::unique_ptr<SerialPort>(new TermiosSerialPort(fd, path));
}

}  // namespace slscand::hal
