#include <avahi-client/client.h>
#include <avahi-client/lookup.h>
#include <avahi-client/publish.h>
#include <avahi-common/alternative.h>
#include <avahi-common/error.h>
#include <avahi-common/malloc.h>
#include <avahi-common/simple-watch.h>
#include <avahi-common/strlst.h>
#include <avahi-common/thread-watch.h>
#include <avahi-common/timeval.h>
#include <net/if.h>

#include <mutex>

#include "slproto/mdns.hpp"

namespace slproto {

namespace {

const char* no_daemon_fix() {
  return "avahi-daemon is not running on this machine (install and start it: `sudo apt install avahi-daemon`, "
         "`sudo systemctl enable --now avahi-daemon`), or give the scanner as HOST:PORT";
}

AvahiStringList* to_string_list(const std::vector<std::string>& txt) {
  AvahiStringList* list = nullptr;
  for (auto it = txt.rbegin(); it != txt.rend(); ++it) list = avahi_string_list_add(list, it->c_str());
  return list;
}

}  // namespace

bool mdns_available() noexcept { return true; }

// ---- publishing: runs on Avahi's own thread (threaded poll); callbacks hold the poll lock.

struct MdnsPublisher::Impl {
  AvahiThreadedPoll* poll = nullptr;
  AvahiClient* client = nullptr;
  AvahiEntryGroup* group = nullptr;
  std::string name;
  std::uint16_t port = 0;
  std::vector<std::string> txt;
  mutable std::mutex mutex;
  std::string state = "waiting for avahi-daemon";

  void set_state(std::string s) {
    std::lock_guard lock(mutex);
    state = std::move(s);
  }

  void publish(AvahiClient* c) {
    if (group == nullptr) group = avahi_entry_group_new(c, &Impl::on_group, this);
    if (group == nullptr) {
      set_state(std::string("avahi_entry_group_new: ") + avahi_strerror(avahi_client_errno(c)));
      return;
    }
    if (!avahi_entry_group_is_empty(group)) return;
    AvahiStringList* list = to_string_list(txt);
    const int rc = avahi_entry_group_add_service_strlst(group, AVAHI_IF_UNSPEC, AVAHI_PROTO_UNSPEC,
                                                        static_cast<AvahiPublishFlags>(0), name.c_str(),
                                                        dns_sd_service_type, nullptr, nullptr, port, list);
    avahi_string_list_free(list);
    if (rc == AVAHI_ERR_COLLISION) {
      rename();
      publish(c);
      return;
    }
    if (rc < 0 || (avahi_entry_group_commit(group) < 0)) {
      set_state(std::string("publishing ") + name + ": " + avahi_strerror(rc < 0 ? rc : avahi_client_errno(c)));
      return;
    }
  }

  void rename() {
    char* alternative = avahi_alternative_service_name(name.c_str());
    name = alternative;
    avahi_free(alternative);
  }

  static void on_group(AvahiEntryGroup* g, AvahiEntryGroupState s, void* userdata) {
    auto* self = static_cast<Impl*>(userdata);
    switch (s) {
      case AVAHI_ENTRY_GROUP_ESTABLISHED:
        self->set_state("published as '" + self->name + "'");
        break;
      case AVAHI_ENTRY_GROUP_COLLISION:
        self->rename();
        avahi_entry_group_reset(g);
        self->publish(avahi_entry_group_get_client(g));
        break;
      case AVAHI_ENTRY_GROUP_FAILURE:
        self->set_state(std::string("publishing failed: ") +
                        avahi_strerror(avahi_client_errno(avahi_entry_group_get_client(g))));
        break;
      default:
        break;
    }
  }

  static void on_client(AvahiClient* c, AvahiClientState s, void* userdata) {
    auto* self = static_cast<Impl*>(userdata);
    switch (s) {
      case AVAHI_CLIENT_S_RUNNING:
        self->publish(c);
        break;
      case AVAHI_CLIENT_S_COLLISION:
      case AVAHI_CLIENT_S_REGISTERING:
        // The host name changes: withdraw, publish again once the daemon runs.
        if (self->group != nullptr) avahi_entry_group_reset(self->group);
        break;
      case AVAHI_CLIENT_CONNECTING:
        // Also after the daemon went away, whose objects (our entry group) the client freed.
        self->group = nullptr;
        self->set_state("waiting for avahi-daemon");
        break;
      case AVAHI_CLIENT_FAILURE:
        // The daemon went away: with AVAHI_CLIENT_NO_FAIL the client reconnects by itself.
        self->set_state(std::string("avahi-daemon connection lost: ") + avahi_strerror(avahi_client_errno(c)));
        break;
    }
  }

  // Connects to avahi-daemon over the system D-Bus. With AVAHI_CLIENT_NO_FAIL the client waits
  // for a daemon that is not there yet, but not for D-Bus itself: without a bus, try again
  // every 2 s (on the poll thread), as a service started early in boot may find it.
  void connect() {
    int error = 0;
    client = avahi_client_new(avahi_threaded_poll_get(poll), AVAHI_CLIENT_NO_FAIL, &Impl::on_client, this, &error);
    if (client != nullptr) return;
    set_state(std::string("waiting for avahi-daemon (") + avahi_strerror(error) + ")");
    const AvahiPoll* api = avahi_threaded_poll_get(poll);
    timeval when{};
    avahi_elapse_time(&when, 2000, 0);
    api->timeout_new(api, &when, &Impl::on_retry, this);
  }
  static void on_retry(AvahiTimeout* timeout, void* userdata) {
    auto* self = static_cast<Impl*>(userdata);
    avahi_threaded_poll_get(self->poll)->timeout_free(timeout);
    self->connect();
  }

  ~Impl() {
    if (poll != nullptr) avahi_threaded_poll_stop(poll);
    if (client != nullptr) avahi_client_free(client);  // frees the entry group too
    if (poll != nullptr) avahi_threaded_poll_free(poll);
  }
};

MdnsPublisher::MdnsPublisher(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
MdnsPublisher::~MdnsPublisher() = default;

std::string MdnsPublisher::state() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->state;
}

Result<std::unique_ptr<MdnsPublisher>> MdnsPublisher::start(const std::string& name, std::uint16_t port,
                                                            const std::vector<std::string>& txt) {
  auto impl = std::make_unique<Impl>();
  impl->name = name;
  impl->port = port;
  impl->txt = txt;
  impl->poll = avahi_threaded_poll_new();
  if (impl->poll == nullptr) return make_error(Errc::internal, "mDNS: avahi_threaded_poll_new failed");
  impl->connect();  // before the poll thread runs: no lock needed yet
  if (avahi_threaded_poll_start(impl->poll) < 0)
    return make_error(Errc::internal, "mDNS: cannot start Avahi's event thread");
  return std::unique_ptr<MdnsPublisher>(new MdnsPublisher(std::move(impl)));
}

// ---- browsing: synchronous, on the calling thread (simple poll).

namespace {

struct Browse {
  AvahiSimplePoll* poll = nullptr;
  AvahiClient* client = nullptr;
  std::vector<DiscoveredScanner> found;
  int pending = 0;
  bool all_for_now = false;
  std::string failure;
};

void on_resolved(AvahiServiceResolver* r, AvahiIfIndex interface, AvahiProtocol, AvahiResolverEvent event,
                 const char* name, const char*, const char*, const char* host_name, const AvahiAddress* address,
                 std::uint16_t port, AvahiStringList* txt, AvahiLookupResultFlags, void* userdata) {
  auto* browse = static_cast<Browse*>(userdata);
  if (event == AVAHI_RESOLVER_FOUND) {
    DiscoveredScanner s;
    s.instance = name;
    s.host_name = host_name;
    char text[AVAHI_ADDRESS_STR_MAX];
    avahi_address_snprint(text, sizeof text, address);
    s.address = text;
    s.port = port;
    char ifname[IF_NAMESIZE] = {};
    if (if_indextoname(static_cast<unsigned>(interface), ifname) != nullptr) s.interface = ifname;
    for (AvahiStringList* t = txt; t != nullptr; t = avahi_string_list_get_next(t))
      s.txt.emplace(s.txt.begin(), reinterpret_cast<const char*>(avahi_string_list_get_text(t)),
                    avahi_string_list_get_size(t));
    // One entry per instance and address family is enough (IPv4 and IPv6 of one board).
    bool duplicate = false;
    for (const auto& other : browse->found)
      duplicate =
          duplicate || (other.instance == s.instance && other.host_name == s.host_name &&
                        (other.address.find(':') == std::string::npos) == (s.address.find(':') == std::string::npos));
    if (!duplicate) browse->found.push_back(std::move(s));
  }
  browse->pending--;
  avahi_service_resolver_free(r);
}

void on_browse(AvahiServiceBrowser*, AvahiIfIndex interface, AvahiProtocol protocol, AvahiBrowserEvent event,
               const char* name, const char* type, const char* domain, AvahiLookupResultFlags, void* userdata) {
  auto* browse = static_cast<Browse*>(userdata);
  switch (event) {
    case AVAHI_BROWSER_NEW:
      if (avahi_service_resolver_new(browse->client, interface, protocol, name, type, domain, AVAHI_PROTO_UNSPEC,
                                     static_cast<AvahiLookupFlags>(0), on_resolved, browse) != nullptr)
        browse->pending++;
      break;
    case AVAHI_BROWSER_ALL_FOR_NOW:
      browse->all_for_now = true;
      break;
    case AVAHI_BROWSER_FAILURE:
      browse->failure = avahi_strerror(avahi_client_errno(browse->client));
      break;
    default:
      break;
  }
}

}  // namespace

Result<std::vector<DiscoveredScanner>> browse_scanners(std::chrono::milliseconds wait) {
  Browse browse;
  browse.poll = avahi_simple_poll_new();
  if (browse.poll == nullptr) return make_error(Errc::internal, "mDNS: avahi_simple_poll_new failed");
  int error = 0;
  browse.client =
      avahi_client_new(avahi_simple_poll_get(browse.poll), static_cast<AvahiClientFlags>(0), nullptr, nullptr, &error);
  if (browse.client == nullptr) {
    avahi_simple_poll_free(browse.poll);
    if (error == AVAHI_ERR_NO_DAEMON)
      return make_error(Errc::disconnected, std::string("mDNS discovery: ") + no_daemon_fix());
    return make_error(Errc::io_error, std::string("mDNS discovery: ") + avahi_strerror(error));
  }
  AvahiServiceBrowser* browser =
      avahi_service_browser_new(browse.client, AVAHI_IF_UNSPEC, AVAHI_PROTO_UNSPEC, dns_sd_service_type, nullptr,
                                static_cast<AvahiLookupFlags>(0), on_browse, &browse);
  if (browser == nullptr) {
    const std::string why = avahi_strerror(avahi_client_errno(browse.client));
    avahi_client_free(browse.client);
    avahi_simple_poll_free(browse.poll);
    return make_error(Errc::io_error, "mDNS discovery: cannot browse " + std::string(dns_sd_service_type) + ": " + why);
  }
  const auto deadline = std::chrono::steady_clock::now() + wait;
  // ALL_FOR_NOW comes after the daemon's cache was replayed; answers from the network that
  // arrive after it still count until the deadline unless everything is resolved by then.
  const auto settle = std::chrono::steady_clock::now() + std::min(wait, std::chrono::milliseconds(1500));
  while (browse.failure.empty()) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= deadline) break;
    if (browse.all_for_now && browse.pending == 0 && now >= settle) break;
    if (avahi_simple_poll_iterate(browse.poll, 50) != 0) break;
  }
  avahi_service_browser_free(browser);
  avahi_client_free(browse.client);
  avahi_simple_poll_free(browse.poll);
  if (!browse.failure.empty()) return make_error(Errc::io_error, "mDNS discovery: " + browse.failure);
  return std::move(browse.found);
}

}  // namespace slproto
