// Virtual-rig throughput at full resolution (2464 x 2056): the target is one view
// (constructor: rays cast once, shadows once per projector; then 19 frames per projector,
// 38 in all) in <= 3 s on the 2-core build machine.
// Run: build/<dir>/bench/rig/bench_rig   (docs/virtual-rig.md records the figures)
#include <benchmark/benchmark.h>

#include <vector>

#include "slrig/rig.hpp"

namespace {

slrig::Scene full_scene(const char* name) {
  slrig::Scene scene = slrig::scene_preset(name, slrig::RigSize::full).value();
  scene.sensor.noise = true;
  return scene;
}

// The whole view: construct, then every pattern of both projectors.
void BM_FullView(benchmark::State& state, const char* name) {
  const slrig::Scene scene = full_scene(name);
  const slproto::PatternPlan plan(scene.pattern_plan);
  std::vector<std::uint8_t> frame;
  for (auto _ : state) {
    const slrig::ViewRenderer renderer(scene, 60, 1);
    frame.resize(renderer.frame_bytes());
    for (auto side : {slproto::ProjectorSide::left, slproto::ProjectorSide::right})
      for (std::size_t i = 0; i < plan.size(); ++i) renderer.render(side, i, frame);
    benchmark::DoNotOptimize(frame.data());
  }
  state.counters["frames"] = static_cast<double>(2 * plan.size());
}

void BM_CastView(benchmark::State& state, const char* name) {
  const slrig::Scene scene = full_scene(name);
  for (auto _ : state) {
    const slrig::ViewRenderer renderer(scene, 60, 1);
    benchmark::DoNotOptimize(renderer.ground_truth().points.data());
  }
}

void BM_Frame(benchmark::State& state, bool noise) {
  slrig::Scene scene = full_scene("ballbar");
  scene.sensor.noise = noise;
  const slrig::ViewRenderer renderer(scene, 60, 1);
  std::vector<std::uint8_t> frame(renderer.frame_bytes());
  std::size_t i = 0;
  for (auto _ : state) {
    renderer.render(slproto::ProjectorSide::left, 11 + (i++ % 8), frame);
    benchmark::DoNotOptimize(frame.data());
  }
  state.SetBytesProcessed(static_cast<std::int64_t>(state.iterations()) * static_cast<std::int64_t>(frame.size()));
}

BENCHMARK_CAPTURE(BM_FullView, ballbar, "ballbar")->Unit(benchmark::kMillisecond)->Iterations(3)->UseRealTime();
BENCHMARK_CAPTURE(BM_FullView, blade, "blade")->Unit(benchmark::kMillisecond)->Iterations(2)->UseRealTime();
// The checkerboard: the only textured surface, so the only scene paying for pixel-area albedo.
BENCHMARK_CAPTURE(BM_FullView, calibration, "calibration")->Unit(benchmark::kMillisecond)->Iterations(2)->UseRealTime();
BENCHMARK_CAPTURE(BM_CastView, ballbar, "ballbar")->Unit(benchmark::kMillisecond)->Iterations(3)->UseRealTime();
BENCHMARK_CAPTURE(BM_CastView, teacup, "teacup")->Unit(benchmark::kMillisecond)->Iterations(2)->UseRealTime();
BENCHMARK_CAPTURE(BM_Frame, noise, true)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(BM_Frame, exact, false)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
