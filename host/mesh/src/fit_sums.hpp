// The weighted sums of the mesher's implicit fit (mesher.cpp, class Implicit) over a query's
// neighbours, compiled once per SIMD target and dispatched at run time by Google Highway: the
// fit's ~500 Gaussian weights and dozen sums per query were most of the mesh's time. Floats in
// the lanes (coordinates relative to the query, under a millimetre), doubles once reduced.
// Sums run lane by lane in the candidates' order, so a query's sums are the same on every run on
// one CPU; another SIMD width or FMA sums in another order (last bits of a vertex).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace slscan::mesh::detail {

// A query's candidate neighbours as arrays side by side, padded with far points so that the
// kernel reads whole vectors.
class FitCandidates {
 public:
  void clear();
  void push(const float p[3], const float n[3], float value, std::uint32_t index);
  std::size_t size() const { return index.size(); }
  // Pads to a multiple of the widest vector (call before fit_sums()).
  void pad();

  std::vector<float> x, y, z, nx, ny, nz, value;
  std::vector<std::uint32_t> index;  // in the cloud, for the nearest point's tie-break
};

struct FitQuery {
  float x[3] = {0, 0, 0};       // the point the fit is at
  float support2 = 0;           // squared radius of the support
  float inv_two_sigma2 = 0;     // the Gaussian's 1 / (2 sigma^2)
  float normal_gate = 0;        // cosine: the points whose normal is beyond it from the side count
  float facing[3] = {0, 0, 0};  // the side; zero: the nearest candidate's normal
  bool with_values = false;     // also the weighted mean of the candidates' values, either side
};

struct FitSums {
  bool any = false;        // a candidate within the support
  bool two_sided = false;  // a candidate within the support facing away from the side
  // Over the candidates within the support on the side, weights w = exp(-d^2 / (2 sigma^2)),
  // positions relative to the query.
  double weight = 0, pp = 0, pn = 0;
  double p[3] = {0, 0, 0}, n[3] = {0, 0, 0};
  // Over every candidate within the support, either side.
  double value_weight = 0, value_sum = 0;
};

// The sums at `query` over `candidates` (padded) with the best target the CPU runs.
FitSums fit_sums(const FitCandidates& candidates, const FitQuery& query);

}  // namespace slscan::mesh::detail
