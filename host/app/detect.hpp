// Checking an imported capture against its description, and finding the description's
// conventions from the data (`slscan import --detect`, docs/real-data.md).
//
// The import decodes and triangulates the one projector-view it is given (as `reprocess`
// would) and runs the decoder's self-checks on it. --detect tries, stage by stage, the
// conventions a description can get wrong and keeps what the data agrees with best:
//   1. the Gray frames: gray.bit_order, and the list one frame earlier or later (a pattern list);
//   2. the phase frames: the shift direction (list 0, N-1, ..., 1), one frame more or fewer (a
//      pattern list);
//   3. the phase origin: phase.offset_steps / phase.offset_rad as the check measures it;
//   4. the geometry: axis and the calibration's pose direction.
// Every candidate's score is the product of its consistency measures (Gray continuity, the
// sinusoid share and phase/Gray direction agreement, the complementary agreement, the share of
// decoded pixels that triangulate, the share of contrasted pixels that decode), halved when a
// check still flags it.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "run.hpp"
#include "slproto/calibration.hpp"
#include "slscan/io/foreign_calibration.hpp"
#include "slscan/io/image_sequence_import.hpp"

namespace slscan::app {

// A projector-view of an imported sequence, decoded and triangulated with `calibration`
// (no cleanup): its counts and self-checks.
core::ProjectorViewReport evaluate_imported(const io::ImportedSequence& sequence,
                                            const slproto::RigCalibration& calibration);

// The score above, in [0, 1]; and a stage's own part of it ("gray": Gray continuity, "phase":
// the phase frames' sinusoid and direction, "offset": the phase origin against the Gray code,
// "geometry": the triangulated share), each halved while that stage's check still flags.
double consistency_score(const core::ProjectorViewReport& report);
double stage_score(const std::string& stage, const core::ProjectorViewReport& report);

struct DetectCandidate {
  std::string stage;  // "gray", "phase", "offset", "geometry", "result"
  std::string label;  // "bit_order lsb_first, first 2"
  double score = 0;
  bool chosen = false;
  std::string note;  // the first finding, or why the candidate could not be read
};

struct DetectResult {
  nlohmann::json description;  // the corrected description (image paths as in the input)
  io::PoseDirection pose_direction = io::PoseDirection::proj_from_cam;
  std::vector<DetectCandidate> candidates;
  core::ProjectorViewReport final_report;
  bool consistent = false;  // the chosen description passes every self-check
};

struct DetectInput {
  nlohmann::json description;  // as the user wrote it
  std::string base_dir;        // its folder (file names resolve against it)
  std::string origin;          // for messages
  std::vector<std::string> calibration_paths;
  io::ForeignCalibrationOptions calibration_options;
};

DetectResult detect_conventions(const DetectInput& input, const Console& console);

// The candidates as a table for a terminal.
std::string format_detect_table(const std::vector<DetectCandidate>& candidates);

}  // namespace slscan::app
