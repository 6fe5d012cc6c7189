// The zstd frame codec for compressed captures (slproto/capture.hpp). A library of its own,
// linked by the host only: the firmware links slproto and never sees libzstd (its cross
// sysroots have none). Built without libzstd, zstd_codec() is nullptr and readers of a
// compressed capture say that the codec is missing.
#pragma once

#include <memory>

#include "slproto/capture.hpp"

namespace slproto {

// The process-wide zstd codec (level 1: fast enough to keep up with the camera while
// recording), or nullptr in a build without libzstd.
const FrameCodec* zstd_codec() noexcept;

// A zstd codec at another compression level (benchmarks; 1..19), or nullptr without libzstd.
// The caller owns it.
std::unique_ptr<FrameCodec> make_zstd_codec(int level);

// "libzstd 1.5.4" or "built without libzstd".
const char* zstd_codec_description() noexcept;

}  // namespace slproto
