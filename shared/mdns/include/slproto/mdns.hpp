// mDNS/DNS-SD through avahi-daemon (libavahi-client): slscand publishes _slscan._tcp with its
// TXT records, `slscan discover` browses for them. Built only where libavahi-client is found
// (SLPROTO_HAVE_AVAHI); without it both sides say so and HOST:PORT still works.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "slproto/discovery.hpp"
#include "slproto/result.hpp"

namespace slproto {

// Keeps one service published while it lives. avahi-daemon may start later or restart: the
// publisher waits for it and publishes again (libavahi-client's "no fail" mode).
class MdnsPublisher {
 public:
  // name: the instance name ("slscan rpi on raspberrypi"); renamed "... #2" on a collision.
  static Result<std::unique_ptr<MdnsPublisher>> start(const std::string& name, std::uint16_t port,
                                                      const std::vector<std::string>& txt);
  ~MdnsPublisher();
  MdnsPublisher(const MdnsPublisher&) = delete;
  MdnsPublisher& operator=(const MdnsPublisher&) = delete;
  // "published as 'NAME'", "waiting for avahi-daemon", or the last error.
  std::string state() const;

  struct Impl;

 private:
  explicit MdnsPublisher(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

struct DiscoveredScanner {
  std::string instance;   // the DNS-SD instance name
  std::string host_name;  // "raspberrypi.local"
  std::string address;    // "192.168.1.30" or an IPv6 literal
  std::uint16_t port = 0;
  std::string interface;  // "eth0"
  std::vector<std::string> txt;
};

// Browses _slscan._tcp for up to `wait` (stops early once avahi-daemon has reported everything
// it knows and every service is resolved). Errc::unsupported without Avahi support in this
// build, Errc::disconnected naming the fix when avahi-daemon is not running.
Result<std::vector<DiscoveredScanner>> browse_scanners(std::chrono::milliseconds wait);

bool mdns_available() noexcept;  // built with libavahi-client

}  // namespace slproto
