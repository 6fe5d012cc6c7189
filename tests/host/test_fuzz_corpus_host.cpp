// The host readers' fuzz corpora (PLY files, calibration capture manifests, --config files,
// import descriptions, foreign calibrations), crash reproducers
// included, through the fuzz targets' property checks in the ordinary suite.
#include <gtest/gtest.h>

#include "../fuzz/corpus_replay.hpp"
#include "../fuzz/fuzz_host_checks.hpp"
#include "../fuzz/fuzz_host_text_checks.hpp"
#include "../fuzz/fuzz_manifest_checks.hpp"

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

}  // namespace
