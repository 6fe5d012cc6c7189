// Writes the inputs of the batch tests (tests/integration/test_slurm_batch.sh): small-rig
// ball-bar captures of a few views each, as `slscan scan` records them (the request, the frames,
// the end), one of them zstd-compressed; the rig's calibration; a config without the mesh.
//   make_batch_captures OUTDIR   ->  OUTDIR/{a,b,c}.slcap, calib.json, config.json
//   make_batch_captures --full OUTDIR  ->  OUTDIR/full.slcap (the full rig, 6 views, raw) and
//                                          calib.json, config.json: the figures of docs/scale.md
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "slproto/calibration_file.hpp"
#include "slproto/capture.hpp"
#include "slproto/crc32c.hpp"
#include "slproto/framing.hpp"
#include "slproto/zstd_codec.hpp"
#include "slrig/rig.hpp"

namespace {

bool fail(const std::string& what) {
  std::fprintf(stderr, "make_batch_captures: %s\n", what.c_str());
  return false;
}

bool append(slproto::CaptureWriter& capture, const std::vector<std::byte>& record) {
  slproto::StreamDecoder decoder;
  if (auto consumed = decoder.feed(record); !consumed || !decoder.message_ready())
    return fail("record does not decode");
  if (auto status = capture.append(decoder.message()); !status) return fail(status.error().message);
  return true;
}

bool write_capture(const slrig::Scene& scene, const std::vector<int>& views, const std::string& path,
                   const slproto::FrameCodec* codec, std::uint32_t scan_id) {
  const slproto::PatternPlan plan(scene.pattern_plan);
  slproto::pb::ScanRequest request;
  request.set_scan_id(scan_id);
  for (int view : views) request.add_turntable_angles_deg(scene.view_angles_deg[static_cast<std::size_t>(view)]);
  request.add_projectors(0);
  request.add_projectors(1);
  *request.mutable_plan() = slproto::to_proto(scene.pattern_plan);
  request.set_exposure_us(8333);
  request.set_pattern_period_us(10000);
  request.set_pixel_format(slproto::pb::PIXEL_FORMAT_MONO8);
  auto capture = slproto::CaptureWriter::create(path, {codec, 1'700'000'000'000'000'000ull + scan_id});
  if (!capture) return fail(capture.error().message);
  auto bytes = slproto::encode(request);
  if (!bytes || !append(*capture, *bytes)) return false;
  std::uint64_t sequence = 0;
  for (std::size_t i = 0; i < views.size(); ++i) {
    const double angle = scene.view_angles_deg[static_cast<std::size_t>(views[i])];
    const slrig::ViewRenderer renderer(scene, angle, views[i]);
    std::vector<std::uint8_t> pixels(renderer.frame_bytes());
    for (std::uint32_t side = 0; side < 2; ++side)
      for (std::size_t pattern = 0; pattern < plan.size(); ++pattern) {
        renderer.render(static_cast<slproto::ProjectorSide>(side), pattern, pixels);
        slproto::pb::FrameHeader header;
        header.set_scan_id(scan_id);
        header.set_view_index(static_cast<std::uint32_t>(i));
        header.set_commanded_angle_deg(angle);
        header.set_reported_angle_deg(angle);
        header.set_projector_id(side);
        header.set_pattern_index(static_cast<std::uint32_t>(pattern));
        header.set_sequence(sequence++);
        slproto::set_frame_geometry(header, static_cast<std::uint32_t>(renderer.width()),
                                    static_cast<std::uint32_t>(renderer.height()));
        const std::span<const std::byte> payload(reinterpret_cast<const std::byte*>(pixels.data()), pixels.size());
        header.set_payload_crc32c(slproto::crc32c(payload));
        std::vector<std::byte> record;
        if (auto status = slproto::encode(header, payload, record); !status) return fail(status.error().message);
        if (!append(*capture, record)) return false;
      }
  }
  slproto::pb::ScanDone done;
  done.set_scan_id(scan_id);
  done.set_frames_sent(sequence);
  auto done_bytes = slproto::encode(done);
  if (!done_bytes || !append(*capture, *done_bytes)) return false;
  if (auto status = capture->finish(); !status) return fail(status.error().message);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  const bool full = argc == 3 && std::string(argv[1]) == "--full";
  if (argc != 2 && !full) {
    std::fprintf(stderr, "usage: make_batch_captures [--full] OUTDIR\n");
    return 1;
  }
  const std::filesystem::path dir = argv[argc - 1];
  std::filesystem::create_directories(dir);
  auto scene = slrig::scene_preset("ballbar", full ? slrig::RigSize::full : slrig::RigSize::small);
  if (!scene) return fail(scene.error().message), 2;
  if (auto status = slproto::save_calibration((dir / "calib.json").string(), slrig::ground_truth_calibration(*scene));
      !status)
    return fail(status.error().message), 2;
  std::ofstream(dir / "config.json") << R"({"mesh": {"enabled": false}})";
  if (full) return write_capture(*scene, {0, 1, 2, 3, 4, 5}, (dir / "full.slcap").string(), nullptr, 9) ? 0 : 2;
  const slproto::FrameCodec* zstd = slproto::zstd_codec();
  if (!write_capture(*scene, {0, 1}, (dir / "a.slcap").string(), nullptr, 1) ||
      !write_capture(*scene, {2, 3}, (dir / "b.slcap").string(), nullptr, 2) ||
      !write_capture(*scene, {4, 5}, (dir / "c.slcap").string(), zstd, 3))
    return 2;
  std::printf("%s: a.slcap b.slcap c.slcap (c: %s), calib.json, config.json\n", dir.c_str(),
              zstd != nullptr ? "zstd" : "raw: no zstd in this build");
  return 0;
}
