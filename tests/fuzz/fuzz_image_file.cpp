// libFuzzer target: an image file of a camera frame (slscan import, calibration capture folders;
// host/io image_file.cpp, then OpenCV's PNG, BMP, TIFF, JPEG and PNM decoders).
#include "fuzz_image_checks.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  slproto::fuzz::check_image_file(data, size);
  return 0;
}
