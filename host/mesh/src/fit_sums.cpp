// The implicit fit's weighted sums (fit_sums.hpp), once per SIMD target: Highway's
// foreach_target.h includes this file again for each target it compiles (HWY_TARGET_INCLUDE).
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "fit_sums.cpp"
#include "fit_sums.hpp"

#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>
// clang-format off: per target, after highway.h (an -inl.h header, included once per target)
#include <hwy/contrib/math/math-inl.h>
// clang-format on

#include <limits>
#include <stdexcept>
#include <string>

HWY_BEFORE_NAMESPACE();
namespace slscan::mesh::detail {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// Lanes summed in double, in lane order.
template <class D, class V>
double lane_sum(D d, V v) {
  HWY_ALIGN float lanes[HWY_MAX_BYTES / sizeof(float)];
  hn::Store(v, d, lanes);
  double sum = 0;
  for (std::size_t k = 0; k < hn::Lanes(d); ++k) sum += static_cast<double>(lanes[k]);
  return sum;
}

FitSums FitSumsAt(const FitCandidates& c, const FitQuery& q) {
  const hn::ScalableTag<float> d;
  const std::size_t lanes = hn::Lanes(d);
  const std::size_t padded = c.x.size();
  if (padded % lanes != 0)
    throw std::logic_error("fit_sums: candidates padded for another SIMD target (" + std::to_string(padded) +
                           " floats, " + std::to_string(lanes) + " lanes)");
  const auto qx = hn::Set(d, q.x[0]), qy = hn::Set(d, q.x[1]), qz = hn::Set(d, q.x[2]);
  const auto support2 = hn::Set(d, q.support2);
  thread_local std::vector<float> d2;
  d2.resize(padded);
  FitSums sums;

  // Pass 1: the squared distances and the nearest within the support.
  auto nearest = hn::Set(d, std::numeric_limits<float>::infinity());
  for (std::size_t i = 0; i < padded; i += lanes) {
    const auto dx = hn::Sub(hn::LoadU(d, c.x.data() + i), qx);
    const auto dy = hn::Sub(hn::LoadU(d, c.y.data() + i), qy);
    const auto dz = hn::Sub(hn::LoadU(d, c.z.data() + i), qz);
    const auto r2 = hn::Add(hn::Add(hn::Mul(dx, dx), hn::Mul(dy, dy)), hn::Mul(dz, dz));
    hn::StoreU(r2, d, d2.data() + i);
    nearest = hn::Min(nearest, hn::IfThenElse(hn::Lt(r2, support2), r2, nearest));
  }
  const float nearest_d2 = hn::GetLane(hn::MinOfLanes(d, nearest));
  if (!(nearest_d2 < q.support2)) return sums;
  sums.any = true;

  // The side: given, or the nearest point's normal (of points at the same distance, the one
  // first in the cloud, as the tree's own nearest()).
  float side[3] = {q.facing[0], q.facing[1], q.facing[2]};
  if (side[0] == 0 && side[1] == 0 && side[2] == 0) {
    std::size_t best = padded;
    for (std::size_t i = 0; i < c.size(); ++i)
      if (d2[i] == nearest_d2 && (best == padded || c.index[i] < c.index[best])) best = i;
    side[0] = c.nx[best];
    side[1] = c.ny[best];
    side[2] = c.nz[best];
  }
  const auto sx = hn::Set(d, side[0]), sy = hn::Set(d, side[1]), sz = hn::Set(d, side[2]);
  const auto gate = hn::Set(d, q.normal_gate);
  const auto zero = hn::Zero(d);
  const auto minus_k = hn::Set(d, -q.inv_two_sigma2);
  const auto floor_arg = hn::Set(d, -80.0f);  // exp(-80) ~ 2e-35: in range, and far below a weight

  // Pass 2: the weights and sums.
  auto weight = zero, px = zero, py = zero, pz = zero, nx = zero, ny = zero, nz = zero, pp = zero, pn = zero;
  auto value_weight = zero, value_sum = zero;
  auto facing_away = hn::Lt(zero, zero);
  for (std::size_t i = 0; i < padded; i += lanes) {
    const auto r2 = hn::LoadU(d, d2.data() + i);
    const auto inside = hn::Lt(r2, support2);
    if (hn::AllFalse(d, inside)) continue;
    const auto ni_x = hn::LoadU(d, c.nx.data() + i), ni_y = hn::LoadU(d, c.ny.data() + i),
               ni_z = hn::LoadU(d, c.nz.data() + i);
    const auto agreement = hn::Add(hn::Add(hn::Mul(ni_x, sx), hn::Mul(ni_y, sy)), hn::Mul(ni_z, sz));
    facing_away = hn::Or(facing_away, hn::And(inside, hn::Lt(agreement, zero)));
    const auto w = hn::IfThenElseZero(inside, hn::Exp(d, hn::Max(hn::Mul(r2, minus_k), floor_arg)));
    if (q.with_values) {
      value_weight = hn::Add(value_weight, w);
      value_sum = hn::Add(value_sum, hn::IfThenElseZero(inside, hn::Mul(w, hn::LoadU(d, c.value.data() + i))));
    }
    const auto ws = hn::IfThenElseZero(hn::Gt(agreement, gate), w);
    const auto dx = hn::Sub(hn::LoadU(d, c.x.data() + i), qx);
    const auto dy = hn::Sub(hn::LoadU(d, c.y.data() + i), qy);
    const auto dz = hn::Sub(hn::LoadU(d, c.z.data() + i), qz);
    weight = hn::Add(weight, ws);
    px = hn::Add(px, hn::Mul(ws, dx));
    py = hn::Add(py, hn::Mul(ws, dy));
    pz = hn::Add(pz, hn::Mul(ws, dz));
    nx = hn::Add(nx, hn::Mul(ws, ni_x));
    ny = hn::Add(ny, hn::Mul(ws, ni_y));
    nz = hn::Add(nz, hn::Mul(ws, ni_z));
    pp = hn::Add(pp, hn::Mul(ws, r2));
    pn = hn::Add(pn, hn::Mul(ws, hn::Add(hn::Add(hn::Mul(dx, ni_x), hn::Mul(dy, ni_y)), hn::Mul(dz, ni_z))));
  }
  sums.two_sided = !hn::AllFalse(d, facing_away);
  sums.weight = lane_sum(d, weight);
  sums.p[0] = lane_sum(d, px);
  sums.p[1] = lane_sum(d, py);
  sums.p[2] = lane_sum(d, pz);
  sums.n[0] = lane_sum(d, nx);
  sums.n[1] = lane_sum(d, ny);
  sums.n[2] = lane_sum(d, nz);
  sums.pp = lane_sum(d, pp);
  sums.pn = lane_sum(d, pn);
  sums.value_weight = lane_sum(d, value_weight);
  sums.value_sum = lane_sum(d, value_sum);
  return sums;
}

std::size_t FitLanes() { return hn::Lanes(hn::ScalableTag<float>()); }

}  // namespace HWY_NAMESPACE
}  // namespace slscan::mesh::detail
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace slscan::mesh::detail {

HWY_EXPORT(FitSumsAt);
HWY_EXPORT(FitLanes);

FitSums fit_sums(const FitCandidates& candidates, const FitQuery& query) {
  return HWY_DYNAMIC_DISPATCH(FitSumsAt)(candidates, query);
}

void FitCandidates::clear() {
  for (auto* v : {&x, &y, &z, &nx, &ny, &nz, &value}) v->clear();
  index.clear();
}

void FitCandidates::push(const float p[3], const float n[3], float v, std::uint32_t i) {
  x.push_back(p[0]);
  y.push_back(p[1]);
  z.push_back(p[2]);
  nx.push_back(n[0]);
  ny.push_back(n[1]);
  nz.push_back(n[2]);
  value.push_back(v);
  index.push_back(i);
}

void FitCandidates::pad() {
  // The lanes of the target fit_sums() runs (HWY_MAX_BYTES here is the static target's).
  const std::size_t lanes = HWY_DYNAMIC_DISPATCH(FitLanes)();
  const std::size_t padded = (index.size() + lanes - 1) / lanes * lanes;
  // Far points, outside any support (finite: a zero weight times them is zero).
  const float far = 1e18f;
  for (auto* v : {&x, &y, &z}) v->resize(padded, far);
  for (auto* v : {&nx, &ny, &nz, &value}) v->resize(padded, 0.0f);
}

}  // namespace slscan::mesh::detail
#endif  // HWY_ONCE
