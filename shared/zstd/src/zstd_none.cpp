// Built without libzstd: no codec; a compressed capture is refused with that reason.
#include "slproto/zstd_codec.hpp"

namespace slproto {

const FrameCodec* zstd_codec() noexcept { return nullptr; }
std::unique_ptr<FrameCodec> make_zstd_codec(int) { return nullptr; }
const char* zstd_codec_description() noexcept {
  return "built without libzstd (install libzstd-dev and configure again)";
}

}  // namespace slproto
