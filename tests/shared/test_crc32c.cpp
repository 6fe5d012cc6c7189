#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include "slproto/crc32c.hpp"

namespace {

using slproto::crc32c;
using slproto::crc32c_portable;

std::vector<unsigned char> pseudo_random(std::size_t size, std::uint32_t seed) {
  std::vector<unsigned char> data(size);
  for (auto& b : data) {
    seed = seed * 1664525u + 1013904223u;
    b = static_cast<unsigned char>(seed >> 24);
  }
  return data;
}

TEST(Crc32c, KnownVectors) {
  // RFC 3720 (iSCSI) check value and test patterns.
  const std::string check = "123456789";
  EXPECT_EQ(crc32c(check.data(), check.size()), 0xE3069283u);
  EXPECT_EQ(crc32c_portable(check.data(), check.size()), 0xE3069283u);
  std::vector<unsigned char> zeros(32, 0x00), ones(32, 0xFF), ascending(32);
  for (int i = 0; i < 32; ++i) ascending[static_cast<std::size_t>(i)] = static_cast<unsigned char>(i);
  EXPECT_EQ(crc32c(zeros.data(), zeros.size()), 0x8A9136AAu);
  EXPECT_EQ(crc32c(ones.data(), ones.size()), 0x62A8AB43u);
  EXPECT_EQ(crc32c(ascending.data(), ascending.size()), 0x46DD794Eu);
  EXPECT_EQ(crc32c(nullptr, 0), 0u);
}

TEST(Crc32c, HardwareAndPortableAgreeAtEveryLengthAndAlignment) {
  const auto data = pseudo_random(3 * 2048 * 3 + 100, 7);
  // Lengths around the 3 x 2048-byte interleaving blocks and odd tails, at every alignment.
  std::vector<std::size_t> lengths;
  for (std::size_t n = 0; n < 80; ++n) lengths.push_back(n);
  for (std::size_t n : {6143u, 6144u, 6145u, 12287u, 12288u, 12289u, 18431u, 18432u, 18433u}) lengths.push_back(n);
  for (std::size_t offset = 0; offset < 8; ++offset) {
    for (std::size_t n : lengths) {
      ASSERT_EQ(crc32c(data.data() + offset, n, 0x12345678u), crc32c_portable(data.data() + offset, n, 0x12345678u))
          << "length " << n << " offset " << offset;
    }
  }
}

TEST(Crc32c, ChainsAcrossSplits) {
  const auto data = pseudo_random(50000, 3);
  const std::uint32_t whole = crc32c(data.data(), data.size());
  for (std::size_t split : {0u, 1u, 7u, 4096u, 6144u, 20001u, 50000u}) {
    const std::uint32_t first = crc32c(data.data(), split);
    EXPECT_EQ(crc32c(data.data() + split, data.size() - split, first), whole) << "split at " << split;
  }
}

TEST(Crc32c, DetectsEverySingleBitFlip) {
  auto data = pseudo_random(257, 11);
  const std::uint32_t clean = crc32c(data.data(), data.size());
  for (std::size_t bit = 0; bit < data.size() * 8; ++bit) {
    data[bit / 8] ^= static_cast<unsigned char>(1u << (bit % 8));
    ASSERT_NE(crc32c(data.data(), data.size()), clean) << "bit " << bit;
    data[bit / 8] ^= static_cast<unsigned char>(1u << (bit % 8));
  }
}

}  // namespace
