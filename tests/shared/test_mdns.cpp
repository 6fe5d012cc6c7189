// mDNS/DNS-SD end to end: a private D-Bus and avahi-daemon (started here, as root, on a bus
// socket of our own so the machine's bus, if any, is untouched), slscand's publisher and slscan
// discover's browser finding it with its TXT records; and the message without a daemon.
// Skips (77) where it cannot run: not root, no avahi-daemon/dbus-daemon, or an avahi-daemon
// already running on this machine (one per machine: /run/avahi-daemon/pid).
#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <thread>

#include "slproto/discovery.hpp"
#include "slproto/mdns.hpp"

extern char** environ;

namespace {

using namespace slproto;
using namespace std::chrono_literals;
using ::testing::HasSubstr;
namespace fs = std::filesystem;

// A child process we started, ended by its pid when the test ends.
struct Child {
  pid_t pid = -1;
  Child() = default;
  Child(const std::vector<std::string>& argv, const std::string& log) {
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&actions, 1, 2);
    if (posix_spawn(&pid, args[0], &actions, nullptr, args.data(), environ) != 0) pid = -1;
    posix_spawn_file_actions_destroy(&actions);
  }
  Child(Child&& o) noexcept : pid(std::exchange(o.pid, -1)) {}
  Child& operator=(Child&& o) noexcept {
    std::swap(pid, o.pid);
    return *this;
  }
  bool running() const { return pid > 0 && ::waitpid(pid, nullptr, WNOHANG) == 0; }
  ~Child() {
    if (pid > 0) {
      ::kill(pid, SIGTERM);
      ::waitpid(pid, nullptr, 0);
    }
  }
};

bool wait_for(const std::function<bool()>& condition, std::chrono::milliseconds limit) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (condition()) return true;
    std::this_thread::sleep_for(50ms);
  }
  return condition();
}

std::string read_all(const fs::path& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

class Mdns : public ::testing::Test {
 protected:
  fs::path dir = fs::temp_directory_path() / ("slscan_mdns_" + std::to_string(::getpid()));
  std::string bus;

  void SetUp() override {
    if (!mdns_available()) GTEST_SKIP() << "built without libavahi-client";
    fs::create_directories(dir);
    bus = "unix:path=" + (dir / "bus").string();
    ::setenv("DBUS_SYSTEM_BUS_ADDRESS", bus.c_str(), 1);  // libdbus: avahi-daemon and our clients
  }
  void TearDown() override {
    ::unsetenv("DBUS_SYSTEM_BUS_ADDRESS");
    fs::remove_all(dir);
  }

  // Starts dbus-daemon + avahi-daemon on the private bus; false (and a skip reason) if it can't.
  bool start_daemons(Child& dbus, Child& avahi, std::string& why) {
    if (::geteuid() != 0 || !fs::exists("/usr/sbin/avahi-daemon") || !fs::exists("/usr/bin/dbus-daemon")) {
      why = "needs root, /usr/sbin/avahi-daemon and /usr/bin/dbus-daemon";
      return false;
    }
    if (fs::exists("/run/avahi-daemon/pid")) {
      why = "an avahi-daemon already runs on this machine (/run/avahi-daemon/pid)";
      return false;
    }
    std::ofstream(dir / "bus.conf")
        << "<!DOCTYPE busconfig PUBLIC \"-//freedesktop//DTD D-BUS Bus Configuration 1.0//EN\"\n"
           " \"http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd\">\n"
           "<busconfig><type>system</type><listen>"
        << bus
        << "</listen><auth>EXTERNAL</auth>"
           "<policy context=\"default\"><allow user=\"*\"/><allow own=\"*\"/>"
           "<allow send_destination=\"*\" eavesdrop=\"true\"/><allow receive_sender=\"*\"/></policy></busconfig>\n";
    std::ofstream(dir / "avahi.conf") << "[server]\nuse-ipv4=yes\nuse-ipv6=no\nenable-dbus=yes\n"
                                         "[wide-area]\nenable-wide-area=no\n"
                                         "[publish]\npublish-hinfo=no\npublish-workstation=no\n";
    dbus = Child({"/usr/bin/dbus-daemon", "--config-file=" + (dir / "bus.conf").string(), "--nofork"},
                 (dir / "dbus.log").string());
    if (!wait_for([&] { return fs::exists(dir / "bus"); }, 5s)) {
      why = "dbus-daemon did not start: " + read_all(dir / "dbus.log");
      return false;
    }
    avahi = Child({"/usr/sbin/avahi-daemon", "-f", (dir / "avahi.conf").string(), "--no-chroot", "--no-drop-root",
                   "--no-rlimits"},
                  (dir / "avahi.log").string());
    if (!wait_for([&] { return read_all(dir / "avahi.log").find("Server startup complete") != std::string::npos; },
                  10s)) {
      why = "avahi-daemon did not start: " + read_all(dir / "avahi.log");
      return false;
    }
    return true;
  }
};

TEST_F(Mdns, WithoutADaemonBrowsingSaysWhatToDo) {
  // The private bus socket does not exist yet: no D-Bus, so no avahi-daemon either.
  auto found = browse_scanners(1s);
  ASSERT_FALSE(found.ok());
  EXPECT_EQ(found.error().code, Errc::disconnected);
  EXPECT_THAT(found.error().message, HasSubstr("avahi-daemon is not running"));
  EXPECT_THAT(found.error().message, HasSubstr("HOST:PORT"));

  // The publisher does not fail: it waits for the daemon (the service may start before it).
  auto publisher = MdnsPublisher::start("slscan test", 7878, {"board=x", "proto=1-2"});
  ASSERT_TRUE(publisher.ok()) << publisher.error().message;
  EXPECT_THAT((*publisher)->state(), ::testing::StartsWith("waiting for avahi-daemon"));
}

TEST_F(Mdns, PublishedScannerIsDiscoveredWithItsTxtRecords) {
  Child dbus, avahi;
  std::string why;
  // The publisher starts first, as slscand may at boot before avahi-daemon.
  const std::string instance = "slscan test " + std::to_string(::getpid());
  ScannerAdvert advert{"bench-rig", "slscand 9.9.9", 1, 2, true, true};
  auto publisher = MdnsPublisher::start(instance, 47878, to_txt_records(advert));
  ASSERT_TRUE(publisher.ok()) << publisher.error().message;
  if (!start_daemons(dbus, avahi, why)) GTEST_SKIP() << why;

  ASSERT_TRUE(wait_for([&] { return (*publisher)->state().rfind("published", 0) == 0; }, 10s))
      << (*publisher)->state() << "\n"
      << read_all(dir / "avahi.log");
  EXPECT_EQ((*publisher)->state(), "published as '" + instance + "'");

  auto found = browse_scanners(5s);
  ASSERT_TRUE(found.ok()) << found.error().message;
  const DiscoveredScanner* mine = nullptr;
  for (const auto& s : *found)
    if (s.instance == instance) mine = &s;
  ASSERT_NE(mine, nullptr) << found->size() << " scanners found, not ours\n" << read_all(dir / "avahi.log");
  EXPECT_EQ(mine->port, 47878);
  EXPECT_FALSE(mine->address.empty());
  auto back = from_txt_records(mine->txt);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->board, "bench-rig");
  EXPECT_EQ(back->software_version, "slscand 9.9.9");
  EXPECT_EQ(back->max_protocol, 2u);
  EXPECT_TRUE(back->token_required);

  // Withdrawn when the publisher goes (slscand stops): a new browse no longer sees it.
  publisher->reset();
  ASSERT_TRUE(wait_for(
      [&] {
        auto again = browse_scanners(2s);
        if (!again) return false;
        for (const auto& s : *again)
          if (s.instance == instance) return false;
        return true;
      },
      10s));
}

}  // namespace
