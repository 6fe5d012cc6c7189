#include "slscan/io/image_file.hpp"

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "slscan/io/io_error.hpp"

namespace slscan::io {
namespace {

namespace fs = std::filesystem;
using Bytes = std::span<const std::uint8_t>;

std::uint32_t big_endian(Bytes b, std::size_t at, int count) {
  std::uint32_t value = 0;
  for (int i = 0; i < count; ++i) value = (value << 8) | b[at + static_cast<std::size_t>(i)];
  return value;
}

std::uint32_t little_endian(Bytes b, std::size_t at, int count) {
  std::uint32_t value = 0;
  for (int i = count - 1; i >= 0; --i) value = (value << 8) | b[at + static_cast<std::size_t>(i)];
  return value;
}

bool starts_with(Bytes b, std::initializer_list<std::uint8_t> prefix) {
  if (b.size() < prefix.size()) return false;
  std::size_t i = 0;
  for (std::uint8_t byte : prefix)
    if (b[i++] != byte) return false;
  return true;
}

std::optional<ImageHeader> png_header(Bytes b) {
  // Signature, then the IHDR chunk first: length, "IHDR", width, height (big-endian).
  if (b.size() < 24 || !starts_with(b.subspan(12), {'I', 'H', 'D', 'R'})) return std::nullopt;
  return ImageHeader{"PNG", big_endian(b, 16, 4), big_endian(b, 20, 4)};
}

std::optional<ImageHeader> bmp_header(Bytes b) {
  if (b.size() < 22) return std::nullopt;
  const std::uint32_t info_size = little_endian(b, 14, 4);
  if (info_size == 12) return ImageHeader{"BMP", little_endian(b, 18, 2), little_endian(b, 20, 2)};  // OS/2 1.x
  if (b.size() < 26) return std::nullopt;
  // Signed: a negative height is a top-down bitmap.
  const auto width = static_cast<std::int32_t>(little_endian(b, 18, 4));
  const auto height = static_cast<std::int32_t>(little_endian(b, 22, 4));
  return ImageHeader{"BMP", static_cast<std::uint64_t>(std::abs(static_cast<std::int64_t>(width))),
                     static_cast<std::uint64_t>(std::abs(static_cast<std::int64_t>(height)))};
}

std::optional<ImageHeader> tiff_header(Bytes b) {
  // The first image file directory: ImageWidth (256), ImageLength (257), RowsPerStrip (278),
  // TileWidth (322) and TileLength (323), each SHORT or LONG.
  const bool little = b[0] == 'I';
  auto read = [&](std::size_t at, int count) {
    return little ? little_endian(b, at, count) : big_endian(b, at, count);
  };
  if (b.size() < 8) return std::nullopt;
  const std::size_t directory = read(4, 4);
  if (directory > b.size() || b.size() - directory < 2) return std::nullopt;
  const std::size_t entries = read(directory, 2);
  ImageHeader header{"TIFF", 0, 0};
  std::optional<std::uint32_t> width, height, rows_per_strip, tile_width, tile_height;
  for (std::size_t i = 0; i < entries; ++i) {
    const std::size_t at = directory + 2 + 12 * i;
    if (at > b.size() || b.size() - at < 12) break;  // libtiff reads no entry past the file's end either
    const std::uint32_t tag = read(at, 2), type = read(at + 2, 2);
    if (tag != 256 && tag != 257 && tag != 278 && tag != 322 && tag != 323) continue;
    if (type != 3 && type != 4) return std::nullopt;
    const std::uint32_t value = type == 3 ? read(at + 8, 2) : read(at + 8, 4);
    // libtiff keeps a tag's first entry and ignores its later duplicates; so must we, or the
    // size checked is not the size OpenCV allocates (a fuzzer's find).
    auto keep_first = [&](std::optional<std::uint32_t>& field) {
      if (!field) field = value;
    };
    if (tag == 256) keep_first(width);
    if (tag == 257) keep_first(height);
    if (tag == 278) keep_first(rows_per_strip);
    if (tag == 322) keep_first(tile_width);
    if (tag == 323) keep_first(tile_height);
  }
  if (!width || !height || *width == 0 || *height == 0) return std::nullopt;
  header.width = *width;
  header.height = *height;
  // OpenCV's block: a tile when the image is tiled (it has a TileWidth), else a strip of the
  // image's width; a size of 0 (or a strip of 2^32 - 1 rows, libtiff's "all") is the image's.
  const bool tiled = tile_width.has_value();
  header.block_width = tiled && *tile_width != 0 ? *tile_width : header.width;
  const std::uint32_t rows = tiled ? tile_height.value_or(0) : rows_per_strip.value_or(0);
  header.block_height = rows == 0 || (!tiled && rows == UINT32_MAX) ? header.height : rows;
  return header;
}

std::optional<ImageHeader> jpeg_header(Bytes b) {
  // Markers after SOI until the first start-of-frame (SOF0-SOF15 but DHT, JPG, DAC).
  std::size_t at = 2;
  while (at < b.size()) {
    if (b[at] != 0xFF) return std::nullopt;
    while (at < b.size() && b[at] == 0xFF) ++at;  // fill bytes
    if (at >= b.size()) return std::nullopt;
    const std::uint8_t marker = b[at++];
    if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD8)) continue;  // no length
    if (marker == 0xD9 || marker == 0xDA || b.size() - at < 2) return std::nullopt;
    const std::uint32_t length = big_endian(b, at, 2);
    if (length < 2) return std::nullopt;
    if (marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC) {
      if (b.size() - at < 7) return std::nullopt;
      return ImageHeader{"JPEG", big_endian(b, at + 5, 2), big_endian(b, at + 3, 2)};
    }
    at += length;
  }
  return std::nullopt;
}

bool is_space(std::uint8_t c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f'; }

std::optional<ImageHeader> pnm_header(Bytes b) {
  // "P1".."P6", then width and height as decimal text, with '#' comments to the line's end.
  std::size_t at = 2;
  auto number = [&]() -> std::optional<std::uint64_t> {
    while (at < b.size()) {
      if (b[at] == '#') {
        while (at < b.size() && b[at] != '\n' && b[at] != '\r') ++at;
      } else if (is_space(b[at])) {
        ++at;
      } else {
        break;
      }
    }
    std::uint64_t value = 0;
    const std::size_t first = at;
    while (at < b.size() && b[at] >= '0' && b[at] <= '9') {
      if (at - first >= 12) return std::nullopt;  // beyond any size we would accept
      value = value * 10 + (b[at++] - '0');
    }
    if (at == first || at >= b.size()) return std::nullopt;
    // OpenCV's PxM reader (ReadNumber) takes the character after a number as its end, whatever
    // it is: "6684#98666" is a width of 6684 and a height of 98666 to it, not a comment. Read
    // the same way, or the size checked here is not the size OpenCV allocates (found by fuzzing).
    ++at;
    return value;
  };
  const auto width = number();
  if (!width) return std::nullopt;
  const auto height = number();
  if (!height) return std::nullopt;
  return ImageHeader{"PNM", *width, *height};
}

std::string size_text(std::uint64_t width, std::uint64_t height) {
  return std::to_string(width) + " x " + std::to_string(height);
}

}  // namespace

std::optional<ImageHeader> read_image_header(std::span<const std::uint8_t> bytes) {
  if (starts_with(bytes, {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'})) return png_header(bytes);
  if (starts_with(bytes, {'B', 'M'})) return bmp_header(bytes);
  if (starts_with(bytes, {'I', 'I', 42, 0}) || starts_with(bytes, {'M', 'M', 0, 42})) return tiff_header(bytes);
  // The signatures OpenCV's decoder of each format claims (JPEG's third byte, the white space after
  // a PNM's magic): a file accepted here goes to that decoder, never on to another (Debian's
  // OpenCV also has GDAL's, which tests every file no decoder before it claimed).
  if (starts_with(bytes, {0xFF, 0xD8, 0xFF})) return jpeg_header(bytes);
  if (bytes.size() >= 3 && bytes[0] == 'P' && bytes[1] >= '1' && bytes[1] <= '6' && is_space(bytes[2]))
    return pnm_header(bytes);
  return std::nullopt;
}

cv::Mat decode_image(std::span<const std::uint8_t> bytes, const std::string& what, const ImageLimits& limits) {
  if (bytes.size() > limits.max_file_bytes)
    throw IoError(what + ": " + std::to_string(bytes.size()) + " bytes, more than the " +
                  std::to_string(limits.max_file_bytes) + " an image file may have");
  const auto header = read_image_header(bytes);
  if (!header) throw IoError(what + ": not a PNG, BMP, TIFF, JPEG or PNM image, or its header is cut short");
  const std::string format = header->format;
  if (header->width == 0 || header->height == 0)
    throw IoError(what + ": the " + format + " header gives a size of " + size_text(header->width, header->height) +
                  " pixels");
  if (header->width > limits.max_pixels || header->height > limits.max_pixels ||
      header->width * header->height > limits.max_pixels)
    throw IoError(what + ": the " + format + " header gives " + size_text(header->width, header->height) +
                  " pixels, more than the " + std::to_string(limits.max_pixels) + " an image may have");
  if (header->block_width > limits.max_pixels || header->block_height > limits.max_pixels ||
      header->block_width * header->block_height > limits.max_pixels)
    throw IoError(what + ": the " + format + " header gives strips or tiles of " +
                  size_text(header->block_width, header->block_height) + " pixels, more than the " +
                  std::to_string(limits.max_pixels) + " an image may have");
  cv::Mat image;
  try {
    // imdecode reads the buffer and never writes it.
    const cv::Mat buffer(1, static_cast<int>(bytes.size()), CV_8U, const_cast<std::uint8_t*>(bytes.data()));
    image = cv::imdecode(buffer, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    throw IoError(what + ": unreadable " + format + " image (OpenCV: " + e.err + ")");
  }
  if (image.empty()) throw IoError(what + ": a " + format + " image that OpenCV cannot decode (cut short or corrupt?)");
  if (static_cast<std::uint64_t>(image.cols) != header->width ||
      static_cast<std::uint64_t>(image.rows) != header->height)
    throw IoError(what + ": decodes to " + size_text(image.cols, image.rows) + " pixels, its " + format +
                  " header says " + size_text(header->width, header->height));
  return image;
}

cv::Mat read_image_file(const std::string& path, const std::string& what, const ImageLimits& limits) {
  std::error_code error;
  if (!fs::is_regular_file(path, error)) throw IoError(what + ": no such image file");
  const std::uintmax_t size = fs::file_size(path, error);
  if (error) throw IoError(what + ": cannot read its size (" + error.message() + ")");
  if (size > limits.max_file_bytes)
    throw IoError(what + ": " + std::to_string(size) + " bytes, more than the " +
                  std::to_string(limits.max_file_bytes) + " an image file may have");
  std::vector<std::uint8_t> bytes(static_cast<std::size_t>(size));
  std::ifstream in(path, std::ios::binary);
  if (!in || !in.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(bytes.size())))
    throw IoError(what + ": cannot read the image file");
  return decode_image(bytes, what, limits);
}

}  // namespace slscan::io
