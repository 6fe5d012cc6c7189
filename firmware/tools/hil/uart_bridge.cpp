// slscan_hil_uart_bridge SOCKET: the host end of the HIL VM's /dev/ttyS1 (scripts/hil-vm.sh).
// Listens on a unix socket that qemu's `-serial unix:SOCKET` connects to, and joins it to the
// GRBL turntable emulator (the same one the sim board and the protocol tests use) on its pty.
// Prints every line the guest sent ("UART> ..."), and on qemu's exit a summary the script
// checks: "BRIDGE lines=N angle=A silent=0|1". The line "$HIL-SILENT" (never forwarded) makes
// the bridge stop answering, as a dead controller would, for the guest's timeout check.
#include <fcntl.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <string>

#include "slscand/hal/sim/turntable_emulator.hpp"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: slscan_hil_uart_bridge SOCKET\n");
    return 2;
  }
  auto emulator = slscand::hal::sim::TurntableEmulator::start(360);
  if (!emulator) {
    std::fprintf(stderr, "uart bridge: %s\n", emulator.error().message.c_str());
    return 1;
  }
  const int pty = open((*emulator)->slave_path().c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
  termios tio{};
  if (pty < 0 || tcgetattr(pty, &tio) != 0) {
    std::fprintf(stderr, "uart bridge: cannot open %s: %s\n", (*emulator)->slave_path().c_str(), std::strerror(errno));
    return 1;
  }
  cfmakeraw(&tio);
  tcsetattr(pty, TCSANOW, &tio);

  const int server = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::snprintf(address.sun_path, sizeof address.sun_path, "%s", argv[1]);
  unlink(argv[1]);
  if (bind(server, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 || listen(server, 1) != 0) {
    std::fprintf(stderr, "uart bridge: cannot listen on %s: %s\n", argv[1], std::strerror(errno));
    return 1;
  }
  std::printf("BRIDGE listening\n");
  std::fflush(stdout);
  const int guest = accept(server, nullptr, nullptr);
  if (guest < 0) return 1;

  bool silent = false;
  const std::string kMarker = "$HIL-SILENT\n";
  std::string line, held;
  char buffer[4096];
  for (;;) {
    pollfd fds[2] = {{guest, POLLIN, 0}, {pty, POLLIN, 0}};
    if (poll(fds, 2, 1000) < 0 && errno != EINTR) break;
    if (fds[0].revents & (POLLIN | POLLHUP | POLLERR)) {
      const ssize_t n = read(guest, buffer, sizeof buffer);
      if (n <= 0) break;  // qemu exited
      std::string forward;
      for (ssize_t i = 0; i < n; ++i) {
        const char c = buffer[i];
        // Hold back what could still be the control line; GRBL's realtime '?' and Ctrl-X come
        // without a newline, so the marker may follow them on the same "line".
        held += c;
        while (!held.empty() && kMarker.compare(0, held.size(), held) != 0) {
          forward += held.front();
          held.erase(0, 1);
        }
        if (held == kMarker) {
          silent = true;
          held.clear();
        }
        if (c == '\n' || c == '\r') {
          if (!line.empty()) std::printf("UART> %s\n", line.c_str());
          line.clear();
        } else if (c >= 0x20 && c < 0x7f) {
          line += c;
        }
      }
      if (!silent && !forward.empty()) (void)!write(pty, forward.data(), forward.size());
    }
    if (fds[1].revents & POLLIN) {
      const ssize_t n = read(pty, buffer, sizeof buffer);
      if (n > 0 && !silent) (void)!write(guest, buffer, static_cast<std::size_t>(n));
    }
  }
  std::printf("BRIDGE lines=%llu angle=%.3f silent=%d\n",
              static_cast<unsigned long long>((*emulator)->lines_received()), (*emulator)->angle_deg(), silent ? 1 : 0);
  std::fflush(stdout);
  close(guest);
  close(pty);
  close(server);
  unlink(argv[1]);
  return 0;
}
