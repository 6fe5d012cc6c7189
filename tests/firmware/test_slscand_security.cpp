// slscand's network policy helpers (docs/security.md): which addresses are loopback, which
// token files are accepted, and when a start is refused.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "slscand/app/security.hpp"

namespace {

namespace fs = std::filesystem;
using slscand::check_listen_policy;
using slscand::is_loopback_address;
using slscand::read_token_file;

class TokenFile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscand-token-" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string write(const std::string& name, const std::string& text, mode_t mode) {
    const fs::path path = dir_ / name;
    std::ofstream(path) << text;
    ::chmod(path.c_str(), mode);
    return path.string();
  }
  fs::path dir_;
};

TEST(Loopback, OnlyLoopbackAddressesAreLoopback) {
  for (const char* a : {"127.0.0.1", "127.1.2.3", "::1", "::ffff:127.0.0.1", "localhost"})
    EXPECT_TRUE(is_loopback_address(a)) << a;
  for (const char* a :
       {"0.0.0.0", "::", "192.168.1.20", "10.0.0.1", "::ffff:10.0.0.1", "scanner.local", "128.0.0.1", ""})
    EXPECT_FALSE(is_loopback_address(a)) << a;
}

TEST(ListenPolicy, NetworkWithoutTokenIsRefusedWithWhatToDo) {
  EXPECT_TRUE(check_listen_policy("127.0.0.1", false, false).ok());
  EXPECT_TRUE(check_listen_policy("0.0.0.0", true, false).ok());
  EXPECT_TRUE(check_listen_policy("0.0.0.0", false, true).ok());
  const auto refused = check_listen_policy("192.168.1.20", false, false);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("refusing to listen on 192.168.1.20 without a token"), std::string::npos);
  EXPECT_NE(refused.error().message.find("--token-file"), std::string::npos);
  EXPECT_NE(refused.error().message.find("--insecure-no-token"), std::string::npos);
}

TEST_F(TokenFile, OwnerOnlyFileWithALongTokenIsRead) {
  EXPECT_EQ(*read_token_file(write("ok", "  0123456789abcdef-xyz \r\nsecond line\n", 0600)), "0123456789abcdef-xyz");
  // systemd's LoadCredential= copies are read-only to their owner.
  EXPECT_EQ(*read_token_file(write("credential", "0123456789abcdef", 0400)), "0123456789abcdef");
}

TEST_F(TokenFile, GroupOrWorldAccessIsRefusedNamingTheMode) {
  for (const mode_t mode : {0640, 0604, 0660, 0610, 0601}) {
    const auto token = read_token_file(write("open", "0123456789abcdef-xyz\n", mode));
    ASSERT_FALSE(token.ok()) << std::oct << mode;
    EXPECT_NE(token.error().message.find("chmod 600"), std::string::npos) << token.error().message;
    EXPECT_NE(token.error().message.find((dir_ / "open").string()), std::string::npos) << token.error().message;
  }
}

TEST_F(TokenFile, EmptyShortMissingAndNonRegularFilesAreRefused) {
  auto message = [](const slproto::Result<std::string>& r) {
    return r.ok() ? std::string("accepted") : r.error().message;
  };
  EXPECT_NE(message(read_token_file(write("empty", "", 0600))).find("empty"), std::string::npos);
  EXPECT_NE(message(read_token_file(write("blank", "  \n", 0600))).find("empty"), std::string::npos);
  EXPECT_NE(message(read_token_file(write("short", "abc123\n", 0600))).find("at least 16"), std::string::npos);
  EXPECT_NE(message(read_token_file((dir_ / "missing").string())).find("cannot open"), std::string::npos);
  EXPECT_NE(message(read_token_file(dir_.string())).find("not a regular file"), std::string::npos);
  // A link is not followed: its target's mode and owner are what the checks are about.
  const std::string target = write("target", "0123456789abcdef-xyz\n", 0600);
  fs::create_symlink(target, dir_ / "link");
  EXPECT_FALSE(read_token_file((dir_ / "link").string()).ok());
}

}  // namespace
