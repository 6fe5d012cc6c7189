// Branch-free float arctangent for the per-pixel decode loops: straight-line selects so the
// compiler vectorises the loop (std::atan2 is a scalar libm call). Cephes' atanf polynomial
// after reduction to |z| <= tan(pi/8); max error ~2e-7 rad, i.e. 3e-7 projector px at P = 8.
#pragma once

#include <cmath>
#include <numbers>

namespace slscan::core {

// atan2(y, x) taken into [0, 2 pi]; 0 for (0, 0).
inline float atan2_0_2pi(float y, float x) {
  constexpr float kPi = std::numbers::pi_v<float>;
  const float ax = std::fabs(x), ay = std::fabs(y);
  const float lo = ax < ay ? ax : ay;
  const float hi = ax < ay ? ay : ax;
  const float t = hi > 0.0f ? lo / hi : 0.0f;  // in [0, 1]
  const bool big = t > 0.41421356f;            // tan(pi/8)
  const float z = big ? (t - 1.0f) / (t + 1.0f) : t;
  const float z2 = z * z;
  const float poly = ((8.05374449538e-2f * z2 - 1.38776856032e-1f) * z2 + 1.99777106478e-1f) * z2 - 3.33329491539e-1f;
  float a = (big ? 0.25f * kPi : 0.0f) + z + z * z2 * poly;  // atan(t) in [0, pi/4]
  a = ay > ax ? 0.5f * kPi - a : a;
  a = x < 0.0f ? kPi - a : a;
  return y < 0.0f ? 2.0f * kPi - a : a;
}

}  // namespace slscan::core
