// The host readers' fuzz corpora (PLY files, calibration capture manifests, --config files,
// import descriptions, foreign calibrations, absurd-but-valid calibrations through the
// reconstruction), crash reproducers
// included, through the fuzz targets' property checks in the ordinary suite.
#include <gtest/gtest.h>

#include "../fuzz/corpus_replay.hpp"
#include "../fuzz/fuzz_host_checks.hpp"
#include "../fuzz/fuzz_host_text_checks.hpp"
#include "../fuzz/fuzz_manifest_checks.hpp"
#include "../fuzz/fuzz_reconstruction_checks.hpp"

namespace {

using slproto::fuzz::replay_corpus;

TEST(FuzzCorpusHost, PlyFilesIncludingTheFaceIndexCrasher) {
  EXPECT_GE(replay_corpus("ply", slproto::fuzz::check_ply_bytes), 3u);
}

TEST(FuzzCorpusHost, CalibrationManifests) {
  EXPECT_GE(replay_corpus("calibration_manifest", slproto::fuzz::check_calibration_manifest), 1u);
}

TEST(FuzzCorpusHost, ReconstructionConfigs) {
  EXPECT_GE(replay_corpus("reconstruction_config", slproto::fuzz::check_reconstruction_config), 5u);
}

TEST(FuzzCorpusHost, SequenceDescriptions) {
  EXPECT_GE(replay_corpus("sequence_description", slproto::fuzz::check_sequence_description), 5u);
}

TEST(FuzzCorpusHost, ForeignCalibrations) {
  EXPECT_GE(replay_corpus("foreign_calibration", slproto::fuzz::check_foreign_calibration), 4u);
}

// camera.fx = 1e20 passed check() and crashed the view selection (issue 17, case 2).
TEST(FuzzCorpusHost, AbsurdButValidCalibrationsThroughTheReconstruction) {
  EXPECT_GE(replay_corpus("reconstruction", slproto::fuzz::check_reconstruction), 8u);
  // The sane seed reconstructs (else the target would only test its early returns).
  std::ifstream in(std::filesystem::path(SLSCAN_SOURCE_DIR) / "tests/fuzz/corpus/reconstruction/seed-three-views-60deg",
                   std::ios::binary);
  const std::vector<std::uint8_t> seed{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  EXPECT_GT(slproto::fuzz::reconstruct_checked(seed.data(), seed.size()), 500u);
}

}  // namespace
