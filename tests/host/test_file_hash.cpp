// SHA-256 of files (slscan/session/file_hash.hpp): the digest itself against a published test
// vector, a file read in several chunks against the same bytes hashed at once, the hash on a
// thread of its own, and its errors.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <string>

#include "slscan/io/io_error.hpp"
#include "slscan/session/file_hash.hpp"

namespace slscan::session {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

class FileHash : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("slscan_file_hash_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string write(const std::string& name, const std::string& bytes) {
    const fs::path path = dir_ / name;
    std::ofstream(path, std::ios::binary) << bytes;
    return path.string();
  }
  fs::path dir_;
};

// FIPS 180-2's long message: one million 'a'.
TEST_F(FileHash, AMillionAsGiveThePublishedDigest) {
  const std::string path = write("a.bin", std::string(1'000'000, 'a'));
  EXPECT_EQ(sha256_file(path), "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
  BackgroundSha256 background(path);
  EXPECT_EQ(background.get(), "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

// 8 MB chunks: a 21 MB file is read in three, the last one short; the digest must be that of
// the bytes hashed in one piece.
TEST_F(FileHash, AFileReadInChunksHashesAsItsBytesAtOnce) {
  std::string bytes(21 * 1024 * 1024 + 123, '\0');
  for (std::size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<char>((i * 2654435761u) >> 13);
  const std::string path = write("chunks.bin", bytes);
  const std::string expected = sha256_text(bytes);
  EXPECT_EQ(sha256_file(path), expected);
  BackgroundSha256 background(path);
  EXPECT_EQ(background.get(), expected);
  EXPECT_EQ(sha256_text(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
}

TEST_F(FileHash, AMissingFileIsNamedWhenTheBackgroundHashIsAskedFor) {
  const std::string path = (dir_ / "nothing-here.slcap").string();
  EXPECT_THAT([&] { sha256_file(path); }, ::testing::ThrowsMessage<io::IoError>(HasSubstr(path)));
  BackgroundSha256 background(path);
  EXPECT_THAT([&] { background.get(); }, ::testing::ThrowsMessage<io::IoError>(HasSubstr(path)));
}

TEST_F(FileHash, AStopEndsTheReadWithAnErrorNeverADigest) {
  const std::string path = write("stopped.bin", std::string(1000, 'x'));
  const std::atomic<bool> stop{true};
  EXPECT_THAT([&] { sha256_file(path, &stop); },
              ::testing::ThrowsMessage<io::IoError>(::testing::AllOf(HasSubstr(path), HasSubstr("stopped"))));
}

// A run that fails before it needs the hash (a bad capture, Ctrl-C) drops the hash unasked:
// the destructor stops the read and joins the thread, whatever it was doing.
TEST_F(FileHash, DroppingTheBackgroundHashUnaskedReturns) {
  const std::string path = write("big.bin", std::string(std::size_t{40} << 20, 'b'));
  for (int i = 0; i < 3; ++i) BackgroundSha256 dropped(path);
  BackgroundSha256 missing((dir_ / "absent").string());  // its error is never asked for
  SUCCEED();
}

}  // namespace
}  // namespace slscan::session
