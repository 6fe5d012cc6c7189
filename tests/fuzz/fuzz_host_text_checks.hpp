// Properties of the host's text parsers of outside data (issue 17): the `--config`
// reconstruction options, import sequence descriptions and foreign calibrations (OpenCV
// FileStorage XML/YAML, ROS camera_info, Kalibr camchain). Bad input ends in io::IoError or
// std::invalid_argument (exit 2, "bad input") with a message; anything else would be exit 5
// ("internal error") or a crash. Accepted calibrations pass check().
#pragma once

#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include "../../host/app/config.hpp"
#include "fuzz_checks.hpp"
#include "slscan/io/foreign_calibration.hpp"
#include "slscan/io/image_sequence_import.hpp"
#include "slscan/io/io_error.hpp"

namespace slproto::fuzz {

// Writes the input to a per-process scratch file named `name` and returns its path.
inline std::string scratch_file(const std::string& name, const std::uint8_t* bytes, std::size_t size) {
  static const std::filesystem::path folder = [] {
    auto dir = std::filesystem::temp_directory_path() / ("slscan-fuzz-host-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    return dir;
  }();
  const auto path = folder / name;
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes), static_cast<std::streamsize>(size));
  return path.string();
}

// Runs `parse`; only the documented bad-input errors, each with a message, may leave it.
template <class Parse>
void expect_only_bad_input_errors(Parse&& parse) {
  try {
    parse();
  } catch (const slscan::io::IoError& e) {
    if (std::string(e.what()).empty()) fuzz_fail("IoError without a message");
  } catch (const std::invalid_argument& e) {
    if (std::string(e.what()).empty()) fuzz_fail("invalid_argument without a message");
  }
}

// --config: load_config on the bytes as a file; what it accepts also serialises.
inline void check_reconstruction_config(const std::uint8_t* data, std::size_t size) {
  const std::string path = scratch_file("config.json", data, size);
  expect_only_bad_input_errors([&] {
    const auto options = slscan::app::load_config(path);
    (void)slscan::app::config_to_json(options).dump();
  });
}

// An import sequence description, parsed only (no image is read).
inline void check_sequence_description(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  expect_only_bad_input_errors(
      [&] { (void)slscan::io::parse_sequence_description(text, "/nonexistent-fuzz-folder", "seq.json"); });
}

// A foreign calibration file; the first byte picks its extension (FileStorage goes by it).
inline void check_foreign_calibration(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return;
  static const char* const names[] = {"calibration.xml", "calibration.yaml", "calibration.yml", "calibration.json"};
  const std::string path = scratch_file(names[data[0] % 4], data + 1, size - 1);
  expect_only_bad_input_errors([&] {
    slscan::io::ForeignCalibrationOptions options;
    options.projector_width = 1824;
    options.projector_height = 1140;
    const auto calibration = slscan::io::read_foreign_calibration_in_process(path, options);
    if (auto status = calibration.check(); !status) fuzz_fail("an accepted foreign calibration fails check()");
  });
}

}  // namespace slproto::fuzz
