#include "png_writer.hpp"

#include <png.h>

#include <csetjmp>
#include <vector>

namespace slrig::tools {

namespace {

void append_bytes(png_structp png, png_bytep data, png_size_t length) {
  auto* out = static_cast<std::string*>(png_get_io_ptr(png));
  out->append(reinterpret_cast<const char*>(data), length);
}

void no_flush(png_structp) {}

}  // namespace

slproto::Result<std::string> encode_png_gray(int width, int height, int bit_depth,
                                             std::span<const std::uint8_t> pixels) {
  const std::size_t bytes_per_pixel = bit_depth == 16 ? 2 : 1;
  if ((bit_depth != 8 && bit_depth != 16) || width <= 0 || height <= 0 ||
      pixels.size() < static_cast<std::size_t>(width) * static_cast<std::size_t>(height) * bytes_per_pixel)
    return slproto::make_error(slproto::Errc::invalid_argument, "png: bad image size or bit depth");
  std::string out;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  if (png == nullptr) return slproto::make_error(slproto::Errc::internal, "png: cannot create writer");
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_write_struct(&png, nullptr);
    return slproto::make_error(slproto::Errc::internal, "png: cannot create info");
  }
  // Big-endian rows for 16-bit PNG; built before setjmp so no C++ object lives across longjmp.
  std::vector<std::uint8_t> swapped;
  if (bit_depth == 16) {
    swapped.resize(pixels.size());
    for (std::size_t i = 0; i + 1 < pixels.size(); i += 2) {
      swapped[i] = pixels[i + 1];
      swapped[i + 1] = pixels[i];
    }
  }
  const std::uint8_t* volatile base = bit_depth == 16 ? swapped.data() : pixels.data();
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return slproto::make_error(slproto::Errc::internal, "png: encoding failed");
  }
  png_set_write_fn(png, &out, append_bytes, no_flush);
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), bit_depth,
               PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_set_compression_level(png, 3);
  png_write_info(png, info);
  const std::size_t stride = static_cast<std::size_t>(width) * bytes_per_pixel;
  for (int y = 0; y < height; ++y)
    png_write_row(png, const_cast<png_bytep>(base + static_cast<std::size_t>(y) * stride));
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return out;
}

}  // namespace slrig::tools
