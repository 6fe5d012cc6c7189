// Writes the seed corpora of the fuzz targets (committed under tests/fuzz/corpus/):
//   make_fuzz_corpus <output dir>   -> <dir>/frame_decoder/*, <dir>/capture_reader/*,
//   <dir>/pattern_plan/*, <dir>/calibration_file/* and, with the virtual rig, <dir>/scene_file/*.
// The other targets' seeds (board files, meshes, PLY, turntable transcripts, manifests) are
// small hand-written or copied files committed as they are.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "../shared/sample_messages.hpp"
#include "slproto/calibration.hpp"
#include "slproto/capture.hpp"
#include "slproto/framing.hpp"
#if defined(SLSCAN_FUZZ_CORPUS_RIG)
#include "slrig/rig.hpp"
#endif

namespace {

using namespace slproto;

void write_file(const std::filesystem::path& path, std::span<const std::byte> bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

void write_text(const std::filesystem::path& path, const std::string& text) {
  std::filesystem::create_directories(path.parent_path());
  write_file(path, std::as_bytes(std::span(text)));
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s <corpus dir>\n", argv[0]);
    return 2;
  }
  const std::filesystem::path root = argv[1];
  const auto decoder_dir = root / "frame_decoder";
  const auto capture_dir = root / "capture_reader";
  std::filesystem::create_directories(decoder_dir);
  std::filesystem::create_directories(capture_dir);

  std::vector<std::byte> stream;
  for (const auto& sample : samples::sample_records()) {
    std::vector<std::byte> record;
    if (Status status = encode(sample.body, sample.payload, record); !status) {
      std::fprintf(stderr, "%s\n", status.error().message.c_str());
      return 1;
    }
    write_file(decoder_dir / (std::string("record_") + message_type_name(type_of(sample.body))), record);
    stream.insert(stream.end(), record.begin(), record.end());
  }
  // A 16-bit frame with padded rows, an all-types stream, a cut stream and a corrupted one.
  pb::FrameHeader mono12 = samples::sample_frame_header();
  set_frame_geometry(mono12, 5, 3, pb::PIXEL_FORMAT_MONO12);
  mono12.set_stride_bytes(12);
  std::vector<std::byte> padded;
  if (!encode(mono12, samples::sample_payload(36, 5), padded).ok()) return 1;
  write_file(decoder_dir / "record_frame_mono12_padded", padded);
  write_file(decoder_dir / "stream_all_types", stream);
  write_file(decoder_dir / "stream_cut", std::span(stream).first(stream.size() - 5));
  auto corrupt = stream;
  corrupt[stream.size() / 2] ^= std::byte{0x40};
  write_file(decoder_dir / "stream_corrupt", corrupt);

  const auto header = capture_file_header(1'700'000'000'000'000'000ull);
  std::vector<std::byte> capture(header.begin(), header.end());
  write_file(capture_dir / "header_only", capture);
  capture.insert(capture.end(), stream.begin(), stream.end());
  write_file(capture_dir / "all_types", capture);
  write_file(capture_dir / "cut_in_frame", std::span(capture).first(capture.size() - 200));
  PatternPlanConfig plan;
  write_text(root / "pattern_plan" / "default", format_pattern_plan(plan));
  plan.axis = CodingAxis::rows;
  plan.inverse_gray = true;
  write_text(root / "pattern_plan" / "rows_inverse_gray", format_pattern_plan(plan));
  plan.phase_steps = 0;
  plan.gray_low_bits = GrayLowBits::slstudio_parity;
  write_text(root / "pattern_plan" / "gray_only_slstudio", format_pattern_plan(plan));

#if defined(SLSCAN_FUZZ_CORPUS_RIG)
  for (const char* name : {"sphere", "ballbar"}) {
    auto scene = slrig::scene_preset(name, slrig::RigSize::small);
    if (!scene) return 1;
    write_text(root / "scene_file" / name, slrig::format_scene(*scene));
    write_text(root / "calibration_file" / name, format_calibration(slrig::ground_truth_calibration(*scene)));
  }
#endif
  std::printf("corpus written to %s\n", root.c_str());
  return 0;
}
