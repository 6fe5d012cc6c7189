// Grey-scale PNG encoding into memory (libpng), so files can be written atomically.
#pragma once

#include <cstdint>
#include <span>
#include <string>

#include "slproto/result.hpp"

namespace slrig::tools {

// 8-bit (bit_depth 8) or 16-bit (bit_depth 16, pixels as native uint16 pairs, little-endian
// bytes in `pixels`) grey image to PNG bytes.
slproto::Result<std::string> encode_png_gray(int width, int height, int bit_depth,
                                             std::span<const std::uint8_t> pixels);

}  // namespace slrig::tools
