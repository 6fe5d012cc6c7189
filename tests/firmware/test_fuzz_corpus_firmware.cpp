// The firmware-side fuzz corpora (board, scene and mesh files, turntable replies), crash
// reproducers included, through the fuzz targets' property checks in the ordinary suite.
#include <gtest/gtest.h>

#include "../fuzz/corpus_replay.hpp"
#include "../fuzz/fuzz_firmware_checks.hpp"

namespace {

using slproto::fuzz::replay_corpus;

TEST(FuzzCorpusFirmware, BoardFilesIncludingTomlCrashers) {
  EXPECT_GE(replay_corpus("board_file", slproto::fuzz::check_board_text), 6u);
}

TEST(FuzzCorpusFirmware, TomlInputsThatCrashedTomlppAreRefusedWithTheirLine) {
  for (const char* text : {"[#", "name = \"x\"\n[[[s]]]\n", "[\n", "2\xcd\x8c"}) {
    auto board = slscand::hal::parse_board(text, "crash.toml");
    ASSERT_FALSE(board.ok()) << text;
    EXPECT_NE(board.error().message.find("crash.toml:"), std::string::npos) << board.error().message;
  }
  auto non_ascii = slscand::hal::parse_board("# caf\xc3\xa9\n", "b.toml");
  ASSERT_FALSE(non_ascii.ok());
  EXPECT_NE(non_ascii.error().message.find("b.toml:1:6: non-ASCII byte 0xC3"), std::string::npos)
      << non_ascii.error().message;
}

TEST(FuzzCorpusFirmware, SceneFilesIncludingTheNumberOverflowCrasher) {
  EXPECT_GE(replay_corpus("scene_file", slproto::fuzz::check_scene_text), 5u);
  auto scene = slrig::parse_scene("{\"ambient\": 1e999999}", "s.json");
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.error().message.find("s.json: not valid JSON"), std::string::npos) << scene.error().message;
}

TEST(FuzzCorpusFirmware, MeshFilesIncludingTheNanListCrasher) {
  EXPECT_GE(replay_corpus("mesh_file", slproto::fuzz::check_mesh_file), 6u);
}

TEST(FuzzCorpusFirmware, TurntableTranscripts) {
  EXPECT_GE(replay_corpus("turntable_replies", slproto::fuzz::check_turntable_replies), 3u);
}

}  // namespace
