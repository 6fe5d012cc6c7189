// Built when libavahi-client is not available (e.g. a cross sysroot without it).
#include "slproto/mdns.hpp"

namespace slproto {

bool mdns_available() noexcept { return false; }

struct MdnsPublisher::Impl {};
MdnsPublisher::MdnsPublisher(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
MdnsPublisher::~MdnsPublisher() = default;
std::string MdnsPublisher::state() const { return "not built"; }

Result<std::unique_ptr<MdnsPublisher>> MdnsPublisher::start(const std::string&, std::uint16_t,
                                                            const std::vector<std::string>&) {
  return make_error(Errc::unsupported, "mDNS: this build has no Avahi support (libavahi-client-dev was not found)");
}

Result<std::vector<DiscoveredScanner>> browse_scanners(std::chrono::milliseconds) {
  return make_error(Errc::unsupported,
                    "mDNS discovery: this slscan was built without Avahi (libavahi-client-dev): give the scanner as "
                    "HOST:PORT");
}

}  // namespace slproto
