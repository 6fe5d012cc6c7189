#include <algorithm>
#include <cctype>

#include "slscand/hal/gpiod/gpiod_chip.hpp"

namespace slscand::hal {

GpiodChipSpec parse_gpiod_chip_spec(const std::string& chip) {
  GpiodChipSpec spec;
  if (chip.empty()) return spec;
  if (chip.front() == '/') {
    spec.path = chip;
  } else if (chip.rfind("gpiochip", 0) == 0) {
    spec.path = "/dev/" + chip;
  } else if (std::all_of(chip.begin(), chip.end(),
                         [](char c) { return std::isdigit(static_cast<unsigned char>(c)); })) {
    spec.path = "/dev/gpiochip" + chip;
  } else {
    spec.label = chip;
  }
  return spec;
}

}  // namespace slscand::hal
