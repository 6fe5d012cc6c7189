#include "slscand/hal/gpio.hpp"

#include <set>

namespace slscand::hal {

using slproto::Errc;
using slproto::make_error;

namespace {
std::string line_label(const LineSettings& line) {
  return line.name.empty() ? "line " + std::to_string(line.offset)
                           : line.name + " (line " + std::to_string(line.offset) + ")";
}
}  // namespace

Status LineRequestConfig::check() const {
  if (lines.empty()) return make_error(Errc::invalid_argument, "GPIO request '" + consumer + "' has no lines");
  std::set<unsigned> seen;
  for (const auto& line : lines) {
    if (!seen.insert(line.offset).second) {
      return make_error(Errc::invalid_argument,
                        "GPIO request '" + consumer + "': " + line_label(line) + " is requested twice");
    }
    if (line.direction == LineDirection::output && line.edges != EdgeDetection::none) {
      return make_error(Errc::invalid_argument, "GPIO request '" + consumer + "': " + line_label(line) +
                                                    " is an output but asks for edge detection");
    }
  }
  return slproto::Ok{};
}

const LineSettings* LineRequestConfig::find(unsigned offset) const {
  for (const auto& line : lines) {
    if (line.offset == offset) return &line;
  }
  return nullptr;
}

std::string gpio_chip_path(const std::string& chip) {
  if (chip.find('/') != std::string::npos) return chip;
  return "/dev/" + chip;
}

}  // namespace slscand::hal
