#include "detect.hpp"

#include <cmath>
#include <cstdio>
#include <numbers>
#include <optional>

#include "slscan/io/io_error.hpp"

namespace slscan::app {

using nlohmann::json;

core::ProjectorViewReport evaluate_imported(const io::ImportedSequence& sequence,
                                            const slproto::RigCalibration& calibration) {
  core::ReconstructionOptions options;
  options.decode.bit_depth = sequence.bit_depth;
  options.decode.smoothing_radius = sequence.plan.config().phase_steps > 0 ? 2 : 0;
  options.remove_flying_pixels = false;
  options.denoise_turntable = false;
  options.remove_outliers = false;
  options.smooth_depth = false;
  options.register_views = false;
  options.select_best_views = false;
  options.build_mesh = false;
  options.max_pending_projector_views = 1;
  slproto::RigCalibration rig = calibration;
  rig.pattern_plan = sequence.plan.config();
  core::ScanReconstructor reconstructor(rig, sequence.plan, sequence.width, sequence.height, options);
  const int bytes_per_pixel = sequence.bit_depth > 8 ? 2 : 1;
  for (std::size_t p = 0; p < sequence.frames.size(); ++p) {
    core::FrameInfo info;
    info.pattern_index = p;
    info.bytes_per_pixel = bytes_per_pixel;
    info.stride_bytes = static_cast<std::size_t>(sequence.width) * static_cast<std::size_t>(bytes_per_pixel);
    reconstructor.add_frame(info, std::as_bytes(std::span(sequence.frames[p])));
  }
  const core::ScanResult result = reconstructor.finish();
  if (result.views.empty()) throw std::logic_error("import check: the view was not reconstructed");
  return result.views.front().projectors[0];
}

namespace {

bool has_finding(const core::DecodeChecks& c, std::initializer_list<const char*> checks) {
  for (const auto& f : c.findings)
    for (const char* name : checks)
      if (f.check == name) return true;
  return false;
}

double decoded_share(const core::ProjectorViewReport& report) {
  const auto& d = report.decode;
  const std::size_t contrasted = d.valid + d.low_modulation + d.out_of_range;
  return contrasted ? static_cast<double>(d.valid) / static_cast<double>(contrasted) : 0.0;
}

}  // namespace

double stage_score(const std::string& stage, const core::ProjectorViewReport& report) {
  const auto& c = report.checks;
  const auto& d = report.decode;
  if (stage == "gray")
    return decoded_share(report) * (c.has_gray ? c.gray_continuity : 1.0) *
           (has_finding(c, {"gray_order"}) ? 0.5 : 1.0);
  if (stage == "phase")
    return decoded_share(report) * (c.has_phase ? std::clamp(c.sinusoid_share, 0.0, 1.0) : 1.0) *
           (c.has_direction ? c.phase_direction_agreement : 1.0) *
           (has_finding(c, {"gray_order", "phase_frames", "phase_direction"}) ? 0.5 : 1.0);
  if (stage == "offset")
    return decoded_share(report) * (c.has_offset ? 0.5 + 0.5 * std::cos(c.phase_offset_rad) : 1.0) *
           (c.has_complementary ? c.complementary_agreement : 1.0);
  if (stage == "geometry") {
    const double shading = std::isfinite(report.shading_correlation) ? report.shading_correlation : 0.0;
    return (d.valid ? std::min(1.0, static_cast<double>(report.triangulate.valid) / static_cast<double>(d.valid))
                    : 0.0) *
           std::max(0.05, 0.5 + 0.5 * shading);
  }
  return consistency_score(report);
}

double consistency_score(const core::ProjectorViewReport& report) {
  const auto& c = report.checks;
  const auto& d = report.decode;
  double score = decoded_share(report);
  score *= d.valid ? std::min(1.0, static_cast<double>(report.triangulate.valid) / static_cast<double>(d.valid)) : 0.0;
  if (c.has_gray) score *= c.gray_continuity;
  if (c.has_phase) score *= std::clamp(c.sinusoid_share, 0.0, 1.0);
  if (c.has_direction) score *= c.phase_direction_agreement;
  if (c.has_complementary) score *= c.complementary_agreement;
  if (c.has_offset) score *= 0.5 + 0.5 * std::cos(c.phase_offset_rad);
  if (c.flagged()) score *= 0.5;
  return score;
}

namespace {

std::string fixed(double v, int digits) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*f", digits, v);
  return buffer;
}

// The file list at `node` (a list or {pattern, first, count}) as an explicit list of names.
std::vector<std::string> names_of(const json& node) {
  std::vector<std::string> out;
  if (node.is_array()) {
    for (const auto& n : node) out.push_back(n.get<std::string>());
    return out;
  }
  const std::string pattern = node.at("pattern").get<std::string>();
  const int first = node.value("first", 0);
  for (int i = 0; i < node.at("count").get<int>(); ++i) {
    std::vector<char> buffer(pattern.size() + 32);
    std::snprintf(buffer.data(), buffer.size(), pattern.c_str(), first + i);
    out.emplace_back(buffer.data());
  }
  return out;
}

class Evaluator {
 public:
  explicit Evaluator(const DetectInput& input) : input_(input) {}

  struct Outcome {
    bool ok = false;
    double score = 0;
    std::string note;
    core::ProjectorViewReport report;
  };

  Outcome evaluate(const json& description, io::PoseDirection pose, const std::string& stage = "result") {
    Outcome out;
    try {
      const io::SequenceDescription d =
          io::parse_sequence_description(description.dump(), input_.base_dir, input_.origin);
      io::ForeignCalibrationOptions options = input_.calibration_options;
      options.pose_direction = pose;
      options.projector_width = d.plan.projector_width;
      options.projector_height = d.plan.projector_height;
      options.camera_width = d.camera_width;
      options.camera_height = d.camera_height;
      options.more_paths.assign(input_.calibration_paths.begin() + 1, input_.calibration_paths.end());
      if (!d.calibration_keys.empty()) options.keys = io::calibration_keys_from(d.calibration_keys, input_.origin);
      const slproto::RigCalibration calibration = io::read_foreign_calibration(input_.calibration_paths.at(0), options);
      const io::ImportedSequence sequence = io::read_image_sequence(d, &cache_);
      if (sequence.width != calibration.camera.width || sequence.height != calibration.camera.height)
        throw io::IoError("the calibration's camera is not the images' size");
      out.report = evaluate_imported(sequence, calibration);
      out.ok = true;
      out.score = stage_score(stage, out.report);
      if (out.report.checks.flagged()) out.note = out.report.checks.findings.front().message();
      if (stage == "geometry") out.note = "shading " + fixed(out.report.shading_correlation, 3) + "; " + out.note;
    } catch (const std::exception& e) {
      out.note = e.what();
    }
    return out;
  }

 private:
  const DetectInput& input_;
  io::ImageCache cache_;
};

}  // namespace

DetectResult detect_conventions(const DetectInput& input, const Console& console) {
  DetectResult result;
  Evaluator evaluator(input);
  json best = input.description;
  io::PoseDirection pose = input.calibration_options.pose_direction;
  Evaluator::Outcome best_outcome = evaluator.evaluate(best, pose);

  // Tries the candidates of one stage (the first is the current best) and keeps the highest
  // score; a tie keeps the earlier candidate.
  auto stage = [&](const std::string& name, const std::vector<std::pair<std::string, json>>& candidates,
                   const std::vector<io::PoseDirection>& poses = {}) {
    const std::size_t first_row = result.candidates.size();
    std::optional<std::size_t> winner;
    double winner_score = -1;
    for (std::size_t i = 0; i < candidates.size(); ++i) {
      const io::PoseDirection p = poses.empty() ? pose : poses[i];
      const Evaluator::Outcome o = evaluator.evaluate(candidates[i].second, p, name);
      console.progress({"detect " + name, i + 1, candidates.size(), "candidates", {}});
      result.candidates.push_back({name, candidates[i].first, o.ok ? o.score : 0.0, false, o.note});
      if (o.ok && o.score > winner_score + 1e-9) {
        winner_score = o.score;
        winner = i;
      }
    }
    console.end_progress();
    if (!winner) return;
    result.candidates[first_row + *winner].chosen = true;
    best = candidates[*winner].second;
    if (!poses.empty()) pose = poses[*winner];
  };
  // best_outcome must describe `best`: re-evaluate after each stage to be sure (cheap enough).
  auto settle = [&] { best_outcome = evaluator.evaluate(best, pose); };

  // 1. Gray frames: bit order, and a pattern list one frame earlier or later.
  {
    std::vector<std::pair<std::string, json>> candidates;
    const json& gray = best.at("gray");
    const std::string order = gray.value("bit_order", std::string("msb_first"));
    const std::string other = order == "msb_first" ? "lsb_first" : "msb_first";
    candidates.push_back({"as described (" + order + ")", best});
    json flipped = best;
    flipped["gray"]["bit_order"] = other;
    candidates.push_back({"bit_order " + other, flipped});
    const bool pattern = gray.contains("files") && gray["files"].is_object();
    if (pattern)
      for (int shift : {-1, 1})
        for (const std::string& o : {order, other}) {
          json c = best;
          c["gray"]["bit_order"] = o;
          const int first = gray["files"].value("first", 0) + shift;
          if (first < 0) continue;
          c["gray"]["files"]["first"] = first;
          if (gray.contains("inverse_files") && gray["inverse_files"].is_object())
            c["gray"]["inverse_files"]["first"] = gray["inverse_files"].value("first", 0) + shift;
          candidates.push_back({"bit_order " + o + ", gray.files.first " + std::to_string(first), c});
        }
    stage("gray", candidates);
    settle();
  }

  // 2. Phase frames: direction, and one frame more or fewer (a pattern list).
  if (best.contains("phase")) {
    std::vector<std::pair<std::string, json>> candidates;
    candidates.push_back({"as described", best});
    const json files = best["phase"].at("files");
    auto reversed = [](std::vector<std::string> names) {
      if (names.size() > 1) std::reverse(names.begin() + 1, names.end());
      return names;
    };
    std::vector<std::vector<std::string>> lists{names_of(files)};
    std::vector<std::string> labels{""};
    if (files.is_object())
      for (int d : {1, -1}) {
        json f = files;
        const int count = files.at("count").get<int>() + d;
        if (count < 3) continue;
        f["count"] = count;
        lists.push_back(names_of(f));
        labels.push_back(std::to_string(count) + " frames");
      }
    for (std::size_t i = 0; i < lists.size(); ++i)
      for (const bool reverse : {false, true}) {
        if (i == 0 && !reverse) continue;
        json c = best;
        c["phase"]["files"] = reverse ? reversed(lists[i]) : lists[i];
        c["phase"].erase("offset_steps");  // a count or direction change makes the old rotation meaningless
        std::string label = labels[i];
        if (reverse) label += std::string(label.empty() ? "" : ", ") + "opposite shift direction (0, N-1, ..., 1)";
        candidates.push_back({label, c});
      }
    stage("phase", candidates);
    settle();

    // 3. The phase origin: as the check measures it, in whole steps and what is left.
    const auto& checks = best_outcome.report.checks;
    if (best_outcome.ok && checks.has_offset && checks.phase_offset_consistency >= 0.5) {
      const json& phase = best["phase"];
      const int n = static_cast<int>(names_of(phase.at("files")).size());
      const double step = 2 * std::numbers::pi / n;
      const double old_rad = phase.value("offset_rad", 0.0);
      const int old_steps = phase.value("offset_steps", 0);
      double data = old_rad - step * old_steps + checks.phase_offset_rad;
      data = std::remainder(data, 2 * std::numbers::pi);
      const int s = static_cast<int>(((std::lround(-data / step) % n) + n) % n);
      const double rest = std::remainder(data + step * s, 2 * std::numbers::pi);
      std::vector<std::pair<std::string, json>> offsets;
      offsets.push_back(
          {"as described (offset_steps " + std::to_string(old_steps) + ", offset_rad " + fixed(old_rad, 3) + ")",
           best});
      json whole = best;
      whole["phase"]["offset_steps"] = s;
      whole["phase"]["offset_rad"] = std::abs(rest) > 0.05 ? std::round(rest * 1000) / 1000 : 0.0;
      if (whole["phase"]["offset_rad"] == 0.0) whole["phase"].erase("offset_rad");
      if (s == 0) whole["phase"].erase("offset_steps");
      offsets.push_back(
          {"offset_steps " + std::to_string(s) + ", offset_rad " + fixed(whole["phase"].value("offset_rad", 0.0), 3),
           whole});
      json continuous = best;
      continuous["phase"].erase("offset_steps");
      continuous["phase"]["offset_rad"] = std::round(data * 1000) / 1000;
      offsets.push_back({"offset_rad " + fixed(data, 3), continuous});
      stage("offset", offsets);
      settle();
    }
  }

  // 4. Geometry: the coding axis and the pose direction.
  {
    const std::string axis = best.value("axis", std::string("columns"));
    const std::string other_axis = axis == "columns" ? "rows" : "columns";
    const io::PoseDirection other_pose =
        pose == io::PoseDirection::proj_from_cam ? io::PoseDirection::cam_from_proj : io::PoseDirection::proj_from_cam;
    auto pose_name = [](io::PoseDirection p) {
      return std::string(p == io::PoseDirection::proj_from_cam ? "proj_from_cam" : "cam_from_proj");
    };
    json flipped = best;
    flipped["axis"] = other_axis;
    std::vector<std::pair<std::string, json>> candidates{
        {"axis " + axis + ", pose " + pose_name(pose), best},
        {"axis " + axis + ", pose " + pose_name(other_pose), best},
        {"axis " + other_axis + ", pose " + pose_name(pose), flipped},
        {"axis " + other_axis + ", pose " + pose_name(other_pose), flipped}};
    stage("geometry", candidates, {pose, other_pose, pose, other_pose});
    settle();
  }

  result.description = best;
  result.pose_direction = pose;
  result.final_report = best_outcome.report;
  result.consistent = best_outcome.ok && !best_outcome.report.checks.flagged();
  result.candidates.push_back({"result", result.consistent ? "consistent" : "still inconsistent",
                               best_outcome.ok ? consistency_score(best_outcome.report) : 0.0, result.consistent,
                               best_outcome.note});
  return result;
}

std::string format_detect_table(const std::vector<DetectCandidate>& candidates) {
  std::string out = "stage     score  chosen  candidate\n";
  for (const auto& c : candidates) {
    char line[64];
    std::snprintf(line, sizeof line, "%-8s  %5.3f  %-6s  ", c.stage.c_str(), c.score, c.chosen ? "*" : "");
    out += line + c.label;
    if (!c.note.empty()) out += "  (" + c.note + ")";
    out += "\n";
  }
  return out;
}

}  // namespace slscan::app
