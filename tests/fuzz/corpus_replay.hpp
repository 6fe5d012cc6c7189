// Replays a committed fuzz corpus (seeds and crash reproducers) through a target's property
// check, so every build's test suite (and the ASan one) runs them, not only the fuzz preset.
#pragma once

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace slproto::fuzz {

inline std::size_t replay_corpus(const std::string& target, void (*check)(const std::uint8_t*, std::size_t)) {
  const std::filesystem::path dir = std::filesystem::path(SLSCAN_SOURCE_DIR) / "tests" / "fuzz" / "corpus" / target;
  std::size_t files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    std::ifstream in(entry.path(), std::ios::binary);
    const std::vector<std::uint8_t> bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    check(bytes.data(), bytes.size());  // aborts, naming the property, when one is violated
    ++files;
  }
  return files;
}

}  // namespace slproto::fuzz
