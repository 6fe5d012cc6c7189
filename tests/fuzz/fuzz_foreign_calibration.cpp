// libFuzzer target: foreign calibrations (host/io foreign_calibration.cpp): OpenCV FileStorage
// XML / YAML (SLStudio, plain stereo), ROS camera_info and Kalibr camchain YAML.
#include "fuzz_host_text_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_foreign_calibration(data, size);
  return 0;
}
