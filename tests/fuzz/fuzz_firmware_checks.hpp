// Properties of the firmware-side parsers of outside data: board files (TOML), scene files
// (JSON), mesh files a scene names (PLY/OBJ/STL) and the turntable's serial replies (GRBL).
// Shared with the corpus replay test in tests/firmware.
#pragma once

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "fuzz_text_checks.hpp"
#include "scene_build.hpp"  // firmware/rig/src: load_mesh_file
#include "slrig/rig.hpp"
#include "slscand/hal/board.hpp"
#include "slscand/hal/grbl/grbl_turntable.hpp"

namespace slproto::fuzz {

inline void check_board_text(const std::uint8_t* bytes, std::size_t size) {
  const std::string text(as_text(bytes, size));
  Result<slscand::hal::BoardConfig> board = slscand::hal::parse_board(text, "fuzz.toml");
  if (!board) {
    if (board.error().message.empty()) fuzz_fail("board error without a message");
    return;
  }
  if (!board->check()) fuzz_fail("parse_board accepted a board its own check() rejects");
}

inline void check_scene_text(const std::uint8_t* bytes, std::size_t size) {
  Result<slrig::Scene> scene = slrig::parse_scene(as_text(bytes, size), "fuzz");
  if (!scene) {
    if (scene.error().message.empty()) fuzz_fail("scene error without a message");
    return;
  }
  if (!slrig::check_scene(*scene)) fuzz_fail("parse_scene accepted a scene check_scene rejects");
  const std::string text = slrig::format_scene(*scene);
  Result<slrig::Scene> again = slrig::parse_scene(text, "fuzz-reformatted");
  if (!again) fuzz_fail("a formatted scene does not parse");
  if (slrig::format_scene(*again) != text) fuzz_fail("scene format/parse is not a fixed point");
  // The host reads a sim scan with the scene's exact calibration: it must be a valid one.
  if (!slrig::ground_truth_calibration(*scene).check()) fuzz_fail("a valid scene has an invalid calibration");
}

// The first byte picks the format (the loader goes by the file's extension).
inline void check_mesh_file(const std::uint8_t* bytes, std::size_t size) {
  if (size == 0) return;
  static const char* const extensions[] = {".ply", ".stl", ".obj"};
  const char* ext = extensions[bytes[0] % 3];
  const int fd = ::memfd_create("mesh", MFD_CLOEXEC);
  if (fd < 0) return;
  if (size > 1 && ::write(fd, bytes + 1, size - 1) != static_cast<ssize_t>(size - 1)) fuzz_fail("memfd write");
  // load_mesh_file needs a name with the extension: a symlink to the memfd gives it one.
  const std::string link = "/tmp/slscan-fuzz-mesh-" + std::to_string(::getpid()) + ext;
  std::filesystem::remove(link);
  std::filesystem::create_symlink("/proc/self/fd/" + std::to_string(fd), link);
  auto mesh = slrig::detail::load_mesh_file(link);
  std::filesystem::remove(link);
  ::close(fd);
  if (!mesh) {
    if (mesh.error().message.empty()) fuzz_fail("mesh error without a message");
    return;
  }
  if (mesh->empty()) fuzz_fail("load_mesh_file returned no triangles without an error");
  for (const auto& t : *mesh) {
    for (const auto& v : {t.a, t.b, t.c}) {
      if (!std::isfinite(v.x) || !std::isfinite(v.y) || !std::isfinite(v.z)) fuzz_fail("mesh vertex not finite");
    }
  }
}

// A serial port whose replies are the fuzz input, in chunks; once the input is used up it
// fails (as an unplugged adapter does), so no driver loop waits on a real timeout.
class FuzzSerialPort final : public slscand::hal::SerialPort {
 public:
  FuzzSerialPort(const std::uint8_t* bytes, std::size_t size) : data_(reinterpret_cast<const char*>(bytes), size) {}
  std::string name() const override { return "fuzz-tty"; }
  Status write_all(std::string_view bytes, slscand::Nanos) override {
    written_ += bytes.size();
    return Ok{};
  }
  Result<std::size_t> read_some(std::span<char> buffer, slscand::Nanos) override {
    if (position_ >= data_.size()) return make_error(Errc::io_error, "fuzz-tty: input exhausted");
    // Chunk sizes vary with the position so lines are split at every place in some run.
    const std::size_t chunk = std::min({buffer.size(), data_.size() - position_, 1 + position_ % 61});
    std::copy_n(data_.data() + position_, chunk, buffer.data());
    position_ += chunk;
    return chunk;
  }
  Status discard_input() override { return Ok{}; }

 private:
  std::string_view data_;
  std::size_t position_ = 0;
  std::size_t written_ = 0;
};

inline void check_turntable_replies(const std::uint8_t* bytes, std::size_t size) {
  using namespace slscand::hal;
  using slscand::kMilli;
  // Every line on its own through the status parser.
  const std::string text(as_text(bytes, size));
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t end = std::min(text.find('\n', start), text.size());
    auto status = parse_grbl_status(text.substr(start, end - start));
    if (status && !std::isfinite(status->angle_deg)) fuzz_fail("GRBL status with a non-finite angle");
    if (!status && status.error().message.empty()) fuzz_fail("GRBL status error without a message");
    start = end + 1;
  }
  // The whole input as the controller's side of a session: connect, home, move, status.
  GrblOptions options;
  options.reply_timeout_ns = 200 * kMilli;
  options.banner_timeout_ns = 200 * kMilli;
  options.stall_timeout_ns = 200 * kMilli;
  options.poll_interval_ns = kMilli;
  auto table = GrblTurntable::connect(std::make_unique<FuzzSerialPort>(bytes, size), options);
  if (!table) {
    if (table.error().message.empty()) fuzz_fail("turntable connect error without a message");
    return;
  }
  if (auto s = (*table)->home(200 * kMilli); !s && s.error().message.empty()) fuzz_fail("home: no message");
  std::atomic<bool> cancel{false};
  auto reached = (*table)->rotate_to(90.0, 300 * kMilli, &cancel);
  if (reached) {
    if (std::abs(*reached - 90.0) > options.tolerance_deg) fuzz_fail("rotate_to accepted an angle out of tolerance");
  } else if (reached.error().message.empty()) {
    fuzz_fail("rotate_to error without a message");
  }
  auto status = (*table)->status();
  if (status && !std::isfinite(status->angle_deg)) fuzz_fail("status with a non-finite angle");
}

}  // namespace slproto::fuzz
