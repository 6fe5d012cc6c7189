// Helpers shared by the rig tests: closed-form scenes and a small reference decoder written
// from docs/conventions.md (independent of the renderer's code).
#pragma once

#include <cmath>
#include <cstdint>
#include <numbers>
#include <vector>

#include "slrig/rig.hpp"

namespace slrig::test {

inline Scene small_rig_without_objects() {
  Scene scene = scene_preset("plane", RigSize::small).value();
  scene.objects.clear();
  scene.sensor.noise = false;
  return scene;
}

// A plane object in the camera frame, normal `n` (unit), through point `p0`, big enough to
// fill the view.
inline SceneObject camera_frame_plane(const Vec3& n, const Vec3& p0, double size = 3000) {
  SceneObject o;
  o.kind = ObjectKind::plane;
  o.name = "test plane";
  o.on_turntable = false;
  o.width = o.height = size;
  o.albedo = 0.8;
  // Frame with z = n.
  const Vec3 helper = std::abs(n[0]) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
  Vec3 x{helper[1] * n[2] - helper[2] * n[1], helper[2] * n[0] - helper[0] * n[2], helper[0] * n[1] - helper[1] * n[0]};
  const double len = std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
  for (double& c : x) c /= len;
  const Vec3 y{n[1] * x[2] - n[2] * x[1], n[2] * x[0] - n[0] * x[2], n[0] * x[1] - n[1] * x[0]};
  o.table_from_object.R = {x[0], y[0], n[0], x[1], y[1], n[1], x[2], y[2], n[2]};
  o.table_from_object.t = p0;
  return o;
}

struct Frames {
  int width = 0, height = 0;
  std::vector<std::vector<std::uint16_t>> images;  // one per pattern, values in DN
};

inline Frames render_all(const ViewRenderer& renderer, ProjectorSide side, const slproto::PatternPlan& plan,
                         int bit_depth) {
  Frames f;
  f.width = renderer.width();
  f.height = renderer.height();
  std::vector<std::uint8_t> buffer(renderer.frame_bytes());
  const std::size_t n = static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height);
  for (std::size_t i = 0; i < plan.size(); ++i) {
    renderer.render(side, plan, i, buffer);
    std::vector<std::uint16_t> image(n);
    for (std::size_t p = 0; p < n; ++p)
      image[p] = bit_depth > 8 ? static_cast<std::uint16_t>(buffer[2 * p] | (buffer[2 * p + 1] << 8)) : buffer[p];
    f.images.push_back(std::move(image));
  }
  return f;
}

// Reference decoder (docs/conventions.md): returns the projector coordinate per pixel, NaN
// where the contrast is below `min_contrast` DN.
inline std::vector<double> reference_decode(const Frames& f, const slproto::PatternPlan& plan, double min_contrast) {
  const auto& c = plan.config();
  const double P = c.period_px;
  const int N = c.phase_steps;
  const int white = plan.index_of(slproto::PatternKind::white), black = plan.index_of(slproto::PatternKind::black);
  const int comp = plan.index_of(slproto::PatternKind::complementary_bit);
  const int phase0 = plan.index_of(slproto::PatternKind::phase_step, 0);
  const std::size_t n = f.images[0].size();
  std::vector<double> out(n, std::nan(""));
  const double two_pi = 2 * std::numbers::pi;
  for (std::size_t p = 0; p < n; ++p) {
    const double w = f.images[static_cast<std::size_t>(white)][p], b = f.images[static_cast<std::size_t>(black)][p];
    if (w - b < min_contrast) continue;
    const double threshold = 0.5 * (w + b);
    std::uint32_t gray = 0;
    for (int bit = 0; bit < c.gray_bits(); ++bit) {
      const int idx = plan.index_of(slproto::PatternKind::gray_bit, bit);
      gray = (gray << 1) | (f.images[static_cast<std::size_t>(idx)][p] > threshold ? 1u : 0u);
    }
    const std::uint32_t k = slproto::gray_to_binary(gray);
    const std::uint32_t gray_h = (gray << 1) | (f.images[static_cast<std::size_t>(comp)][p] > threshold ? 1u : 0u);
    const std::uint32_t h = slproto::gray_to_binary(gray_h);
    const double k2 = std::floor((h + 1) / 2.0);
    double s = 0, co = 0;
    for (int step = 0; step < N; ++step) {
      const double v = f.images[static_cast<std::size_t>(phase0 + step)][p];
      s += v * std::sin(two_pi * step / N);
      co += v * std::cos(two_pi * step / N);
    }
    double phi = std::atan2(-s, co);
    if (phi < 0) phi += two_pi;
    double order = k;
    if (phi < std::numbers::pi / 2)
      order = k2;
    else if (phi >= 1.5 * std::numbers::pi)
      order = k2 - 1;
    out[p] = (phi + two_pi * order) * P / two_pi;
  }
  return out;
}

}  // namespace slrig::test
