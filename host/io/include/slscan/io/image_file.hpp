// Camera frames from image files (imported sequences, calibration capture folders): the one
// place where outside image bytes reach OpenCV's decoders. The size an image declares is read
// from its header and checked before a pixel is decoded, because OpenCV 4.6 would otherwise
// allocate up to a gigapixel (8 GB for 16-bit RGBA) for a file of a few dozen bytes; and only
// the formats a camera's frames come in are handed to it (docs/security.md, "Limits").
#pragma once

#include <cstdint>
#include <opencv2/core/mat.hpp>
#include <optional>
#include <span>
#include <string>

namespace slscan::io {

struct ImageLimits {
  std::uint64_t max_pixels = std::uint64_t{1} << 27;      // 134 MP: beyond any camera we drive
  std::uint64_t max_file_bytes = std::uint64_t{1} << 30;  // 1 GiB: a 134 MP 16-bit RGBA TIFF is 1 GiB
};

// The header's word on an image: its format and size, before any pixel is decoded.
struct ImageHeader {
  const char* format = "";  // "PNG", "BMP", "TIFF", "JPEG", "PNM"
  std::uint64_t width = 0, height = 0;
  // A TIFF's strip or tile: OpenCV 4.6 allocates one such block besides the image, sized from
  // RowsPerStrip or TileWidth x TileLength alone (up to 1 GB, whatever the image's size).
  std::uint64_t block_width = 0, block_height = 0;
};

// The header of a PNG, BMP, TIFF, JPEG or PNM (P1-P6) image, or nullopt when the bytes start
// as none of them or the header is cut before the size.
std::optional<ImageHeader> read_image_header(std::span<const std::uint8_t> bytes);

// Decodes an image as stored (channels, 8 or 16 bit, as cv::IMREAD_UNCHANGED), after checking
// its format and declared size against `limits`; throws IoError starting with `what`.
cv::Mat decode_image(std::span<const std::uint8_t> bytes, const std::string& what, const ImageLimits& limits = {});

// decode_image of a file's bytes; `what` names the file in every message.
cv::Mat read_image_file(const std::string& path, const std::string& what, const ImageLimits& limits = {});

}  // namespace slscan::io
