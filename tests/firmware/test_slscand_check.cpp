// slscand --check and slscand's configuration file: the sim board passes every check; a real
// board file on a machine without its devices (this one) gets each missing item named with its
// fix; permission and network problems are reported as such.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "slproto/transport.hpp"
#include "slscand/app/check.hpp"
#include "slscand/app/config.hpp"
#include "slscand/app/security.hpp"

namespace {

using namespace slscand;
using ::testing::HasSubstr;
namespace fs = std::filesystem;

hal::BoardConfig board_file(const std::string& name) {
  auto board = hal::load_board(std::string(SLSCAN_SOURCE_DIR) + "/boards/" + name);
  EXPECT_TRUE(board.ok()) << board.error().message;
  return *board;
}

// Real-time needs CAP_SYS_NICE / CAP_IPC_LOCK or rlimits: root (CI) has them, a developer's
// account may not, and that is an environment fact rather than a sim board problem.
bool realtime_may_be_missing(const CheckItem& item) {
  return ::geteuid() != 0 && (item.name == "real-time scheduling" || item.name == "memory locking");
}

struct TempDir {
  fs::path path = fs::temp_directory_path() / ("slscand_check_" + std::to_string(::getpid()));
  TempDir() { fs::create_directories(path); }
  ~TempDir() { fs::remove_all(path); }
  fs::path write(const std::string& name, const std::string& text, fs::perms perms = fs::perms(0600)) const {
    const fs::path file = path / name;
    std::ofstream(file) << text;
    fs::permissions(file, perms);
    return file;
  }
};

TEST(SlscandCheck, SimBoardPassesEveryCheck) {
  CheckOptions options;
  options.port = 0;  // any free port: the check must not depend on 7878 being free here
  const CheckReport report = check_board(board_file("sim.toml"), options);
  const std::string text = report.to_text();
  for (const auto& item : report.items) {
    if (realtime_may_be_missing(item)) continue;
    EXPECT_EQ(item.state, CheckState::ok) << item.name << ": " << item.detail;
  }
  for (const char* name :
       {"backends", "gpio chip 'sim-gpio'", "gpio lines projector.left", "gpio lines projector.right",
        "camera 'virtual'", "camera controls", "serial port 'pty'", "turntable answer", "real-time scheduling",
        "memory locking", "network bind 127.0.0.1:0", "token"})
    EXPECT_NE(report.find(name), nullptr) << "no item " << name << " in\n" << text;
  EXPECT_THAT(text, HasSubstr("turntable answer: GRBL answered; angle 0.00 deg"));
  EXPECT_THAT(text, HasSubstr("token: none: loopback only, no token needed"));
  if (::geteuid() == 0) {
    EXPECT_THAT(text, HasSubstr("all 12 checks passed"));
  }
}

TEST(SlscandCheck, RaspberryPiBoardOnAMachineWithoutItsDevicesListsEachMissingItemWithItsFix) {
  hal::BoardConfig board = board_file("rpi.toml");
  CheckOptions options;
  options.port = 0;
  const CheckReport report = check_board(board, options);
  const std::string text = report.to_text();
  EXPECT_FALSE(report.all_ok());

  const CheckItem* chip = report.find("gpio chip 'pinctrl-bcm2711'");
  ASSERT_NE(chip, nullptr) << text;
  EXPECT_EQ(chip->state, CheckState::missing);
  EXPECT_THAT(chip->fix, HasSubstr("gpiodetect"));
  EXPECT_EQ(report.find("gpio lines projector.left")->state, CheckState::skipped);

  const CheckItem* camera = report.find("camera 'auto'");
  ASSERT_NE(camera, nullptr) << text;
  EXPECT_EQ(camera->state, CheckState::missing);
  EXPECT_THAT(camera->fix, ::testing::AnyOf(HasSubstr("--list-cameras"), HasSubstr("built with")));
  EXPECT_EQ(report.find("camera controls")->state, CheckState::skipped);

  const CheckItem* serial = report.find("serial port 'usb:1a86:7523'");
  ASSERT_NE(serial, nullptr) << text;
  EXPECT_EQ(serial->state, CheckState::missing);
  EXPECT_THAT(serial->fix, ::testing::AnyOf(HasSubstr("/dev/serial/by-id"), HasSubstr("built with")));
  EXPECT_EQ(report.find("turntable answer")->state, CheckState::skipped);

  // rpi.toml listens on 0.0.0.0: without a token that is a finding, not a detail.
  const CheckItem* token = report.find("token");
  ASSERT_NE(token, nullptr);
  EXPECT_EQ(token->state, CheckState::missing);
  EXPECT_THAT(token->fix, HasSubstr("token_file"));

  // Every missing item carries a fix, printed under it.
  for (const auto& item : report.items) {
    if (item.state == CheckState::missing) {
      EXPECT_FALSE(item.fix.empty()) << item.name;
    }
  }
  EXPECT_THAT(text, HasSubstr("[MISSING] gpio chip 'pinctrl-bcm2711'"));
  EXPECT_THAT(text, HasSubstr("          fix: `gpiodetect`"));
  EXPECT_THAT(text, HasSubstr("checks missing: see the fixes above"));
}

TEST(SlscandCheck, CpuPinningToACpuThisMachineLacksIsMissing) {
  hal::BoardConfig board = board_file("sim.toml");
  board.cpu = 4095;
  CheckOptions options;
  options.port = 0;
  const CheckReport report = check_board(board, options);
  const CheckItem* pin = report.find("cpu pinning");
  ASSERT_NE(pin, nullptr);
  EXPECT_EQ(pin->state, CheckState::missing);
  EXPECT_THAT(pin->fix, HasSubstr("[realtime] cpu"));
}

TEST(SlscandCheck, PortInUseAndABadTokenFileAreMissingWithTheirFixes) {
  auto busy = slproto::Server::listen("127.0.0.1", 0);
  ASSERT_TRUE(busy.ok());
  TempDir dir;
  const fs::path open_token = dir.write("token", "abc\n", fs::perms(0644));
  CheckOptions options;
  options.port = busy->port();
  options.token_file = open_token.string();
  const CheckReport report = check_board(board_file("sim.toml"), options);
  const CheckItem* bind = report.find("network bind");
  ASSERT_NE(bind, nullptr);
  EXPECT_EQ(bind->state, CheckState::missing);
  EXPECT_THAT(bind->fix, HasSubstr("systemctl status slscand"));
  const CheckItem* token = report.find("token");
  ASSERT_NE(token, nullptr);
  EXPECT_EQ(token->state, CheckState::missing);
  EXPECT_THAT(token->detail, HasSubstr("mode 0644"));
  EXPECT_THAT(token->fix, HasSubstr("chmod 600 " + open_token.string()));
  EXPECT_FALSE(report.all_ok());

  options.token_file = (dir.path / "absent").string();
  const CheckReport absent = check_board(board_file("sim.toml"), options);
  EXPECT_THAT(absent.find("token")->fix, HasSubstr("head -c 32 /dev/urandom"));
}

TEST(SlscandConfig, ParsesEveryKeyAndResolvesTheBoardNextToTheFile) {
  auto config = parse_daemon_config(
      "board = \"boards/rpi.toml\"\nbind_address = \"0.0.0.0\"\nport = 7000\ntoken_file = \"/etc/slscan/token\"\n"
      "timing_log_dir = \"/var/lib/slscand\"\nrealtime = false\n",
      "/etc/slscan/slscand.toml");
  ASSERT_TRUE(config.ok()) << config.error().message;
  EXPECT_EQ(config->board, "/etc/slscan/boards/rpi.toml");
  EXPECT_EQ(config->bind_address, "0.0.0.0");
  EXPECT_EQ(config->port, 7000);
  EXPECT_EQ(config->token_file, "/etc/slscan/token");
  EXPECT_EQ(config->timing_log_dir, "/var/lib/slscand");
  EXPECT_EQ(config->realtime, false);

  auto minimal = parse_daemon_config("board = \"/usr/share/slscan/boards/sim.toml\"\n", "c.toml");
  ASSERT_TRUE(minimal.ok());
  EXPECT_FALSE(minimal->bind_address.has_value());
  EXPECT_FALSE(minimal->port.has_value());
  EXPECT_TRUE(minimal->token_file.empty());
}

TEST(SlscandConfig, ErrorsNameTheFileLineAndKey) {
  auto error_of = [](const std::string& text) {
    auto config = parse_daemon_config(text, "/etc/slscan/slscand.toml");
    return config.ok() ? std::string("accepted") : config.error().message;
  };
  EXPECT_EQ(error_of("board = \"b.toml\"\nprot = 7000\n"),
            "/etc/slscan/slscand.toml:2: unknown key 'prot' (known: board, bind_address, port, token_file, "
            "timing_log_dir, realtime, mdns)");
  EXPECT_EQ(error_of("board = \"b.toml\"\nport = 70000\n"),
            "/etc/slscan/slscand.toml:2: port must be an integer in 0..65535");
  EXPECT_EQ(error_of("board = \"b.toml\"\nrealtime = \"yes\"\n"),
            "/etc/slscan/slscand.toml:2: realtime must be true or false");
  EXPECT_EQ(error_of("port = 7000\n"), "/etc/slscan/slscand.toml: no 'board' (the board file slscand drives)");
  EXPECT_THAT(error_of("board = \n"), HasSubstr("/etc/slscan/slscand.toml:1:"));
}

TEST(SlscandConfig, TokenFileMustBePrivateAndNonEmpty) {
  TempDir dir;
  auto good = read_token_file(dir.write("good", "s3cret-s3cret-s3cret  \n").string());
  ASSERT_TRUE(good.ok()) << good.error().message;
  EXPECT_EQ(*good, "s3cret-s3cret-s3cret");
  auto readable = read_token_file(dir.write("readable", "s3cret-s3cret-s3cret\n", fs::perms(0640)).string());
  ASSERT_FALSE(readable.ok());
  EXPECT_THAT(readable.error().message, HasSubstr("mode 0640 lets the group or others access the token"));
  auto empty = read_token_file(dir.write("empty", "\n").string());
  ASSERT_FALSE(empty.ok());
  EXPECT_THAT(empty.error().message, HasSubstr("empty; write a random token"));
  auto missing = read_token_file((dir.path / "nothing").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_THAT(missing.error().message, HasSubstr("No such file"));
}

TEST(SlscandConfig, PackagedDefaultConfigurationParses) {
  auto config = load_daemon_config(std::string(SLSCAN_SOURCE_DIR) + "/packaging/slscand.toml");
  ASSERT_TRUE(config.ok()) << config.error().message;
  EXPECT_EQ(config->board, "/usr/share/slscan/boards/rpi.toml");
  EXPECT_EQ(config->token_file, "/etc/slscan/token");
}

}  // namespace
