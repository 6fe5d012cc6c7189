#include "slproto/zstd_codec.hpp"

#include <zstd.h>

#include <string>

namespace slproto {
namespace {

// One compression / decompression context per thread: reusing them saves their allocation
// (about 1 MB for compression) per frame, and codecs are shared between threads.
struct Contexts {
  ZSTD_CCtx* compress = ZSTD_createCCtx();
  ZSTD_DCtx* decompress = ZSTD_createDCtx();
  Contexts() = default;
  Contexts(const Contexts&) = delete;
  Contexts& operator=(const Contexts&) = delete;
  ~Contexts() {
    ZSTD_freeCCtx(compress);
    ZSTD_freeDCtx(decompress);
  }
};
Contexts& contexts() {
  thread_local Contexts per_thread;
  return per_thread;
}

class ZstdCodec final : public FrameCodec {
 public:
  explicit ZstdCodec(int level) : level_(level) {}
  FrameCodecId id() const noexcept override { return FrameCodecId::zstd; }

  Status compress(std::span<const std::byte> raw, std::vector<std::byte>& out) const override {
    ZSTD_CCtx* context = contexts().compress;
    if (context == nullptr) return make_error(Errc::internal, "zstd: cannot create a compression context");
    out.resize(ZSTD_compressBound(raw.size()));
    // ZSTD_compressCCtx writes the content size into the frame header.
    const std::size_t n = ZSTD_compressCCtx(context, out.data(), out.size(), raw.data(), raw.size(), level_);
    if (ZSTD_isError(n)) return make_error(Errc::internal, std::string("zstd: ") + ZSTD_getErrorName(n));
    out.resize(n);
    return Ok{};
  }

  Status decompress(std::span<const std::byte> stored, std::span<std::byte> out) const override {
    const unsigned long long declared = ZSTD_getFrameContentSize(stored.data(), stored.size());
    if (declared == ZSTD_CONTENTSIZE_ERROR) return make_error(Errc::malformed, "not a zstd frame (corrupt payload)");
    if (declared != ZSTD_CONTENTSIZE_UNKNOWN && declared != out.size())
      return make_error(Errc::malformed, "zstd frame declares " + std::to_string(declared) +
                                             " decoded bytes, the record " + std::to_string(out.size()) +
                                             " (decoded size mismatch)");
    const std::size_t frame = ZSTD_findFrameCompressedSize(stored.data(), stored.size());
    if (ZSTD_isError(frame))
      return make_error(Errc::malformed, std::string("corrupt payload: ") + ZSTD_getErrorName(frame));
    if (frame != stored.size())
      return make_error(Errc::malformed, std::to_string(stored.size() - frame) + " bytes after the zstd frame");
    ZSTD_DCtx* context = contexts().decompress;
    if (context == nullptr) return make_error(Errc::internal, "zstd: cannot create a decompression context");
    const std::size_t n = ZSTD_decompressDCtx(context, out.data(), out.size(), stored.data(), stored.size());
    if (ZSTD_isError(n)) return make_error(Errc::malformed, std::string("corrupt payload: ") + ZSTD_getErrorName(n));
    if (n != out.size())
      return make_error(Errc::malformed, "decoded " + std::to_string(n) + " bytes, the record declares " +
                                             std::to_string(out.size()) + " (decoded size mismatch)");
    return Ok{};
  }

 private:
  int level_;
};

}  // namespace

const FrameCodec* zstd_codec() noexcept {
  static const ZstdCodec codec(1);
  return &codec;
}

std::unique_ptr<FrameCodec> make_zstd_codec(int level) { return std::make_unique<ZstdCodec>(level); }

const char* zstd_codec_description() noexcept {
  static const std::string text = std::string("libzstd ") + ZSTD_versionString();
  return text.c_str();
}

}  // namespace slproto
