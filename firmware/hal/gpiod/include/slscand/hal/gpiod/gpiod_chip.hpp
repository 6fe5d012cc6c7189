// libgpiod GPIO backend. One of two implementations is compiled, chosen at configure time
// from `pkg-config --modversion libgpiod`: SLSCAND_GPIOD_API 1 (libgpiod 1.6, Debian 12) or 2
// (libgpiod 2.x, Raspberry Pi OS and newer distributions). The pure request-building pieces
// are exposed so they can be tested without a GPIO chip.
#pragma once

#include <memory>
#include <string>

#include "slscand/hal/gpio.hpp"

#if SLSCAND_GPIOD_API == 2
struct gpiod_line_config;
#endif

namespace slscand::hal {

// `chip`: "gpiochip0", "/dev/gpiochip0", "0", or a chip label such as "pinctrl-bcm2711".
Result<std::unique_ptr<GpioChip>> open_gpiod_chip(const std::string& chip);

// How `chip` will be looked up: a device path, or a label to search for among /dev/gpiochip*.
struct GpiodChipSpec {
  std::string path;   // set when the spec names a device
  std::string label;  // set when it names a label
};
GpiodChipSpec parse_gpiod_chip_spec(const std::string& chip);

#if SLSCAND_GPIOD_API == 1
// libgpiod v1 requests one line at a time: the request type and flags for one line.
struct GpiodV1LineRequest {
  int request_type = 0;
  int flags = 0;
};
GpiodV1LineRequest gpiod_v1_request_for(const LineSettings& line);
#else
struct GpiodLineConfigDeleter {
  void operator()(gpiod_line_config* config) const noexcept;
};
using GpiodLineConfigPtr = std::unique_ptr<gpiod_line_config, GpiodLineConfigDeleter>;
// libgpiod v2 requests all lines at once from a line config with per-offset settings.
Result<GpiodLineConfigPtr> gpiod_v2_line_config(const LineRequestConfig& config);
#endif

}  // namespace slscand::hal
