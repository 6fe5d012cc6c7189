// Properties of the calibration capture manifest reader (host/io/calibration_capture_files):
// bad input ends in an IoError with a message. Shared with the corpus replay test in tests/host.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "fuzz_checks.hpp"
#include "slscan/io/calibration_capture_files.hpp"
#include "slscan/io/io_error.hpp"

namespace slproto::fuzz {

inline void check_calibration_manifest(const std::uint8_t* bytes, std::size_t size) {
  // One small image every frame of a manifest may name ("a.png"), so parsing goes on past
  // the first frame to the size, bit-depth and completeness checks.
  static const std::filesystem::path folder = [] {
    auto dir = std::filesystem::temp_directory_path() / ("slscan-fuzz-manifest-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    cv::imwrite((dir / "a.png").string(), cv::Mat(4, 6, CV_8UC1, cv::Scalar(128)));
    return dir;
  }();
  {
    std::ofstream out(folder / "manifest.json", std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(bytes), static_cast<std::streamsize>(size));
  }
  try {
    const auto capture = slscan::io::read_calibration_capture(folder.string());
    if (capture.frames.empty()) fuzz_fail("a calibration capture without frames was accepted");
  } catch (const slscan::io::IoError& e) {
    if (std::string(e.what()).empty()) fuzz_fail("manifest error without a message");
  }
}

}  // namespace slproto::fuzz
