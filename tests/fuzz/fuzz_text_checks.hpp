// Properties of the text parsers that read files a user (or an attacker) hands us: pattern
// plans and calibration files (slproto). A parse either succeeds or returns an error with a
// message; what succeeds must format and parse back to the same thing (so a file we write is
// always one we read). Shared with the corpus replay test in tests/shared.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "fuzz_checks.hpp"
#include "slproto/calibration.hpp"
#include "slproto/pattern_plan.hpp"

namespace slproto::fuzz {

inline std::string_view as_text(const std::uint8_t* bytes, std::size_t size) {
  return {reinterpret_cast<const char*>(bytes), size};
}

inline void check_pattern_plan_text(const std::uint8_t* bytes, std::size_t size) {
  Result<PatternPlanConfig> config = parse_pattern_plan(as_text(bytes, size), "fuzz");
  if (!config) {
    if (config.error().message.empty()) fuzz_fail("pattern plan error without a message");
    return;
  }
  if (!config->check()) fuzz_fail("parse_pattern_plan accepted a plan its own check() rejects");
  const std::string text = format_pattern_plan(*config);
  Result<PatternPlanConfig> again = parse_pattern_plan(text, "fuzz-reformatted");
  if (!again) fuzz_fail("a formatted pattern plan does not parse");
  if (format_pattern_plan(*again) != text) fuzz_fail("pattern plan format/parse is not a fixed point");
  // The plan it describes must be constructible (the decoder and sequencer build it).
  Result<PatternPlan> plan = PatternPlan::make(*config);
  if (!plan) fuzz_fail("a checked pattern plan cannot be built");
  if (plan->size() == 0) fuzz_fail("a valid pattern plan has no frames");
  for (std::size_t i = 0; i < plan->size(); ++i) {
    for (const double coord : {0.0, 0.5 * config->coded_extent(), config->coded_extent() - 1.0}) {
      const float v = plan->value(i, coord);
      if (!(v >= 0.0f && v <= 1.0f)) fuzz_fail("pattern value outside [0, 1]");
    }
  }
}

inline void check_calibration_text(const std::uint8_t* bytes, std::size_t size) {
  Result<RigCalibration> calibration = parse_calibration(as_text(bytes, size), "fuzz");
  if (!calibration) {
    if (calibration.error().message.empty()) fuzz_fail("calibration error without a message");
    return;
  }
  if (!calibration->check()) fuzz_fail("parse_calibration accepted a calibration its own check() rejects");
  const std::string text = format_calibration(*calibration);
  Result<RigCalibration> again = parse_calibration(text, "fuzz-reformatted");
  if (!again) fuzz_fail("a formatted calibration does not parse");
  if (format_calibration(*again) != text) fuzz_fail("calibration format/parse is not a fixed point");
}

}  // namespace slproto::fuzz
