// Properties of the image reader of outside frames (host/io image_file.cpp; issue 17, case 15):
// whatever the bytes, decode_image ends in an IoError with a message, or in an image of the
// size its header declares, within the limits, which were checked before anything was decoded.
#pragma once

#include <cstdint>
#include <span>
#include <string>

#include "fuzz_checks.hpp"
#include "slscan/io/image_file.hpp"
#include "slscan/io/io_error.hpp"

namespace slproto::fuzz {

// Small limits keep a run fast; the checks are the same at any limits.
inline constexpr slscan::io::ImageLimits kFuzzImageLimits{std::uint64_t{1} << 22, std::uint64_t{1} << 24};

inline void check_image_file(const std::uint8_t* data, std::size_t size) {
  const std::span<const std::uint8_t> bytes(data, size);
  try {
    const cv::Mat image = slscan::io::decode_image(bytes, "fuzz.img", kFuzzImageLimits);
    const auto header = slscan::io::read_image_header(bytes);
    if (!header) fuzz_fail("an image without a readable header was decoded");
    if (static_cast<std::uint64_t>(image.cols) != header->width ||
        static_cast<std::uint64_t>(image.rows) != header->height)
      fuzz_fail("the decoded image's size differs from its header's");
    if (image.total() > kFuzzImageLimits.max_pixels) fuzz_fail("an image beyond the pixel limit was decoded");
  } catch (const slscan::io::IoError& e) {
    if (std::string(e.what()).rfind("fuzz.img: ", 0) != 0) fuzz_fail("an image error that does not name the file");
  }
}

}  // namespace slproto::fuzz
