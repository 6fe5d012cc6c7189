// Decode + triangulate one projector-view at full resolution (2464 x 2056, 19 frames, 96 MB),
// against the machine's memory floor measured in the same run: the time to just read the same
// bytes with the same threads. Frames come from the virtual rig (default scene "teacup") or,
// with --synthetic, from a smooth synthetic projector-coordinate map.
//
//   bench_pipeline [--scene NAME] [--synthetic] [--repeats N] [--threads N]
//
// Prints min and median over the repeats for: the memory floor, add_frame (copying 19 frames
// into the decoder), decode (finish), triangulate, and their sum; wall-clock, and the process
// CPU time of the same stage (all threads together), which a busy shared machine disturbs far
// less than the wall clock.
#include <sys/resource.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <numbers>
#include <string>
#include <vector>

#include "slscan/core/decode.hpp"
#include "slscan/core/triangulate.hpp"
#ifdef SLSCAN_BENCH_WITH_RIG
#include "slrig/rig.hpp"
#endif

namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// User + system CPU time of the whole process so far (every thread), ms.
double process_cpu_ms() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  auto ms = [](const timeval& t) {
    return 1e3 * static_cast<double>(t.tv_sec) + 1e-3 * static_cast<double>(t.tv_usec);
  };
  return ms(usage.ru_utime) + ms(usage.ru_stime);
}

struct Series {
  std::vector<double> ms;
  double min() const { return *std::min_element(ms.begin(), ms.end()); }
  double median() const {
    std::vector<double> s = ms;
    std::sort(s.begin(), s.end());
    return s[s.size() / 2];
  }
};

// Reads every byte of the frames (64-bit words, threads over blocks): the floor for any pass.
std::uint64_t read_all(const std::vector<std::vector<std::uint8_t>>& frames) {
  std::uint64_t total = 0;
  for (const auto& frame : frames) {
    const auto* words = reinterpret_cast<const std::uint64_t*>(frame.data());
    const std::size_t n = frame.size() / 8;
    total += tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, 1 << 14), std::uint64_t{0},
        [&](const tbb::blocked_range<std::size_t>& r, std::uint64_t acc) {
          for (std::size_t i = r.begin(); i < r.end(); ++i) acc += words[i];
          return acc;
        },
        [](std::uint64_t a, std::uint64_t b) { return a + b; });
  }
  return total;
}

}  // namespace

int main(int argc, char** argv) try {
  std::string scene_name = "teacup";
  bool synthetic = false;
  int repeats = 7, threads = 2;
  slscan::core::DecodeOptions decode_options;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--scene" && i + 1 < argc) {
      scene_name = argv[++i];
    } else if (arg == "--synthetic") {
      synthetic = true;
    } else if (arg == "--repeats" && i + 1 < argc) {
      repeats = std::max(1, std::stoi(argv[++i]));
    } else if (arg == "--threads" && i + 1 < argc) {
      threads = std::max(1, std::stoi(argv[++i]));
    } else if (arg == "--decode-quadratic-radius" && i + 1 < argc) {
      decode_options.quadratic_radius = std::stoi(argv[++i]);
    } else {
      std::fprintf(stderr,
                   "usage: bench_pipeline [--scene NAME] [--synthetic] [--repeats N] [--threads N] "
                   "[--decode-quadratic-radius Q]\n");
      return 2;
    }
  }
#ifndef SLSCAN_BENCH_WITH_RIG
  synthetic = true;
#endif
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));

  slproto::RigCalibration calibration;
  std::vector<std::vector<std::uint8_t>> frames;
  const slproto::PatternPlan plan;
  const auto setup_start = Clock::now();
  if (!synthetic) {
#ifdef SLSCAN_BENCH_WITH_RIG
    auto scene = slrig::scene_preset(scene_name, slrig::RigSize::full);
    if (!scene) {
      std::fprintf(stderr, "bench_pipeline: %s\n", scene.error().message.c_str());
      return 1;
    }
    calibration = slrig::ground_truth_calibration(*scene);
    const slrig::ViewRenderer renderer(*scene, scene->view_angles_deg.at(0), 0);
    frames.assign(plan.size(), std::vector<std::uint8_t>(renderer.frame_bytes()));
    for (std::size_t p = 0; p < plan.size(); ++p) renderer.render(slproto::ProjectorSide::left, p, frames[p]);
#endif
  } else {
    // The default rig's geometry, approximately: camera 2464 x 2056, projector 180 mm to the left.
    calibration.camera = {2464, 2056, 5300, 5300, 1231.5, 1027.5, {-0.08, 0.012, 2e-4, -1.5e-4, 0}};
    auto& projector = calibration.projectors[0];
    projector.intrinsics = {1140, 912, 2400, 2400, 569.5, 860.0, {0.02, -0.01, 0, 0, 0}};
    projector.cam_from_proj = slproto::RigidTransform::rotation_about_axis({0, 1, 0}, {0, 0, 0}, 0.4);
    projector.cam_from_proj.t = {-180, 0, 0};
    calibration.projectors[1] = projector;
    const int w = 2464, h = 2056;
    frames.assign(plan.size(), std::vector<std::uint8_t>(static_cast<std::size_t>(w * h)));
    for (std::size_t p = 0; p < plan.size(); ++p)
      for (int v = 0; v < h; ++v)
        for (int u = 0; u < w; ++u) {
          const double x = 20.0 + 0.44 * u + 0.01 * v;
          const double value =
              plan.value(p, plan[p].kind == slproto::PatternKind::phase_step ? x : std::floor(x + 0.5));
          frames[p][(static_cast<std::size_t>(v) * static_cast<std::size_t>(w)) + static_cast<std::size_t>(u)] =
              static_cast<std::uint8_t>(std::lround(10 + 180 * value));
        }
  }
  const int width = calibration.camera.width, height = calibration.camera.height;
  std::printf("setup (%s frames): %.0f ms\n", synthetic ? "synthetic" : scene_name.c_str(), ms_since(setup_start));

  auto start = Clock::now();
  const auto rays =
      std::make_shared<const slscan::core::CameraRayTable>(slscan::core::CameraRayTable::build(calibration.camera));
  std::printf("camera ray table (once per calibration): %.0f ms\n", ms_since(start));
  const slscan::core::ProjectorTriangulator triangulator(rays, calibration.projectors[0], plan.config().axis);
  slscan::core::ProjectorViewDecoder decoder(plan, width, height, decode_options);
  slscan::core::DecodedView decoded;
  slscan::core::OrganizedCloud cloud;

  Series floor, copy, decode, triangulate, total;
  Series decode_cpu, triangulate_cpu;
  std::uint64_t sink = 0;
  slscan::core::TriangulateCounts counts;
  for (int r = 0; r < repeats; ++r) {
    start = Clock::now();
    sink += read_all(frames);
    floor.ms.push_back(ms_since(start));

    start = Clock::now();
    for (std::size_t p = 0; p < plan.size(); ++p)
      decoder.add_frame(p, frames[p].data(), static_cast<std::size_t>(width));
    copy.ms.push_back(ms_since(start));
    double cpu = process_cpu_ms();
    start = Clock::now();
    decoder.finish(decoded);
    decode.ms.push_back(ms_since(start));
    decode_cpu.ms.push_back(process_cpu_ms() - cpu);
    cpu = process_cpu_ms();
    start = Clock::now();
    counts = triangulator.triangulate(decoded, cloud);
    triangulate.ms.push_back(ms_since(start));
    triangulate_cpu.ms.push_back(process_cpu_ms() - cpu);
    total.ms.push_back(copy.ms.back() + decode.ms.back() + triangulate.ms.back());
  }
  const double mb = static_cast<double>(plan.size()) * width * height / 1e6;
  std::printf("%d x %d, %zu frames (%.1f MB), %d threads, %d repeats; min / median ms\n", width, height, plan.size(),
              mb, threads, repeats);
  auto line = [&](const char* name, const Series& s) {
    std::printf("  %-28s %8.2f / %8.2f   (%.1f x floor)\n", name, s.min(), s.median(), s.median() / floor.median());
  };
  line("memory floor (read 96 MB)", floor);
  line("add_frame x 19 (copy)", copy);
  line("decode (finish)", decode);
  line("triangulate", triangulate);
  line("decode + triangulate", Series{[&] {
         std::vector<double> v;
         for (std::size_t i = 0; i < decode.ms.size(); ++i) v.push_back(decode.ms[i] + triangulate.ms[i]);
         return v;
       }()});
  line("total incl. copy", total);
  std::printf("  CPU time, all threads (min / median ms): decode %.1f / %.1f, triangulate %.1f / %.1f\n",
              decode_cpu.min(), decode_cpu.median(), triangulate_cpu.min(), triangulate_cpu.median());
  std::printf("decoded %zu of %zu pixels, triangulated %zu (checksum %llu)\n", decoded.counts.valid,
              decoded.coordinate.size(), counts.valid, static_cast<unsigned long long>(sink % 1000));
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_pipeline: %s\n", e.what());
  return 1;
}
