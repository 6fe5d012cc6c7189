#include "slscan/core/mesh.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "cloud_filters_kdtree.hpp"

namespace slscan::core {
namespace {

// A regular grid of nodes; boundary nodes are held at chi = 0 (outside).
struct Grid {
  Eigen::Vector3d origin;
  double h = 1;
  int nx = 0, ny = 0, nz = 0;
  std::size_t size() const {
    return static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny) * static_cast<std::size_t>(nz);
  }
  std::size_t index(int x, int y, int z) const {
    return static_cast<std::size_t>(x) +
           static_cast<std::size_t>(nx) *
               (static_cast<std::size_t>(y) + static_cast<std::size_t>(ny) * static_cast<std::size_t>(z));
  }
  bool boundary(int x, int y, int z) const {
    return x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1;
  }
  Eigen::Vector3d position(int x, int y, int z) const { return origin + h * Eigen::Vector3d(x, y, z); }

  // Trilinear stencil of a point given in grid units (node coordinates). False outside.
  bool stencil(const Eigen::Vector3d& g, std::array<std::size_t, 8>& idx, std::array<double, 8>& w) const {
    const int x = static_cast<int>(std::floor(g.x())), y = static_cast<int>(std::floor(g.y())),
              z = static_cast<int>(std::floor(g.z()));
    if (x < 0 || y < 0 || z < 0 || x + 1 >= nx || y + 1 >= ny || z + 1 >= nz) return false;
    const double fx = g.x() - x, fy = g.y() - y, fz = g.z() - z;
    for (int c = 0; c < 8; ++c) {
      const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
      idx[static_cast<std::size_t>(c)] = index(x + dx, y + dy, z + dz);
      w[static_cast<std::size_t>(c)] = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy) * (dz ? fz : 1 - fz);
    }
    return true;
  }
  Eigen::Vector3d to_grid(const Eigen::Vector3d& p) const { return (p - origin) / h; }
  double sample(const std::vector<double>& f, const Eigen::Vector3d& p) const {
    std::array<std::size_t, 8> idx;
    std::array<double, 8> w;
    if (!stencil(to_grid(p), idx, w)) return 0;
    double v = 0;
    for (std::size_t c = 0; c < 8; ++c) v += w[c] * f[idx[c]];
    return v;
  }
};

// Screening term aggregated per grid cell: S = beta * sum w w^T and its right-hand side.
struct CellScreening {
  std::array<std::size_t, 8> idx;
  Eigen::Matrix<double, 8, 8> S;
};

// The system matrix: grid Laplacian (edge differences) plus the screening blocks, applied
// without assembling it.
struct PoissonOperator {
  const Grid& grid;
  const std::vector<CellScreening>& cells;

  void apply(const std::vector<double>& x, std::vector<double>& y) const {
    const int nx = grid.nx, ny = grid.ny, nz = grid.nz;
    const auto sx = std::size_t{1}, sy = static_cast<std::size_t>(nx),
               sz = static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny);
    tbb::parallel_for(tbb::blocked_range<int>(0, nz), [&](const tbb::blocked_range<int>& zs) {
      for (int z = zs.begin(); z < zs.end(); ++z)
        for (int yy = 0; yy < ny; ++yy)
          for (int xx = 0; xx < nx; ++xx) {
            const std::size_t i = grid.index(xx, yy, z);
            if (grid.boundary(xx, yy, z)) {
              y[i] = x[i];
              continue;
            }
            // Neighbours on the boundary hold 0, and x stays 0 there.
            y[i] = 6 * x[i] - x[i - sx] - x[i + sx] - x[i - sy] - x[i + sy] - x[i - sz] - x[i + sz];
          }
    });
    for (const auto& c : cells) {
      Eigen::Matrix<double, 8, 1> v;
      for (std::size_t k = 0; k < 8; ++k) v[static_cast<Eigen::Index>(k)] = x[c.idx[k]];
      const Eigen::Matrix<double, 8, 1> s = c.S * v;
      for (std::size_t k = 0; k < 8; ++k) y[c.idx[k]] += s[static_cast<Eigen::Index>(k)];
    }
  }
};

double dot(const std::vector<double>& a, const std::vector<double>& b) {
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, a.size(), 1 << 15), 0.0,
      [&](const tbb::blocked_range<std::size_t>& r, double s) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) s += a[i] * b[i];
        return s;
      },
      [](double p, double q) { return p + q; });
}

// Jacobi-preconditioned conjugate gradient from the initial x.
std::pair<int, double> solve_cg(const PoissonOperator& A, const std::vector<double>& diag, const std::vector<double>& b,
                                std::vector<double>& x, int max_iterations, double tolerance) {
  const std::size_t n = b.size();
  std::vector<double> r(n), z(n), p(n), q(n);
  A.apply(x, q);
  for (std::size_t i = 0; i < n; ++i) r[i] = b[i] - q[i];
  const double b_norm = std::sqrt(dot(b, b));
  if (b_norm == 0) return {0, 0.0};
  for (std::size_t i = 0; i < n; ++i) z[i] = r[i] / diag[i];
  p = z;
  double rz = dot(r, z);
  double rel = std::sqrt(dot(r, r)) / b_norm;
  int it = 0;
  while (it < max_iterations && rel > tolerance) {
    A.apply(p, q);
    const double alpha = rz / dot(p, q);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1 << 15), [&](const tbb::blocked_range<std::size_t>& rg) {
      for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
        x[i] += alpha * p[i];
        r[i] -= alpha * q[i];
        z[i] = r[i] / diag[i];
      }
    });
    const double rz_next = dot(r, z);
    const double beta = rz_next / rz;
    rz = rz_next;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1 << 15), [&](const tbb::blocked_range<std::size_t>& rg) {
      for (std::size_t i = rg.begin(); i < rg.end(); ++i) p[i] = z[i] + beta * p[i];
    });
    rel = std::sqrt(dot(r, r)) / b_norm;
    ++it;
  }
  return {it, rel};
}

struct Samples {
  std::vector<Eigen::Vector3d> points, normals;
  std::vector<double> area;
};

// Builds the grid for the given cell size and solves for chi, starting from `initial` (a
// coarser solution) when given. Returns chi on the grid's nodes.
struct Solution {
  Grid grid;
  std::vector<double> chi;
  int iterations = 0;
  double residual = 0;
};

Solution solve_level(const Samples& s, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int resolution,
                     const PoissonOptions& options, const Solution* coarse) {
  Solution out;
  Grid& g = out.grid;
  const Eigen::Vector3d extent = hi - lo;
  g.h = extent.maxCoeff() / resolution;
  // Two empty cells beyond the padded bounds keep every sample's stencil off the boundary.
  g.origin = lo - Eigen::Vector3d::Constant(2 * g.h);
  g.nx = static_cast<int>(std::ceil(extent.x() / g.h)) + 5;
  g.ny = static_cast<int>(std::ceil(extent.y() / g.h)) + 5;
  g.nz = static_cast<int>(std::ceil(extent.z() / g.h)) + 5;
  const std::size_t n = g.size();

  // Right-hand side: minus the divergence of the splatted field V = -n * area / h^3 (the
  // indicator's gradient points inward), in the edge-difference form of the normal equations.
  std::vector<double> b(n, 0.0);
  std::unordered_map<std::size_t, std::size_t> cell_of;  // cell's lowest node -> screening block
  std::vector<CellScreening> cells;
  for (std::size_t k = 0; k < s.points.size(); ++k) {
    const Eigen::Vector3d gp = g.to_grid(s.points[k]);
    for (int d = 0; d < 3; ++d) {
      // Edges along d have their midpoints at node + 0.5 e_d.
      Eigen::Vector3d ge = gp;
      ge[d] -= 0.5;
      std::array<std::size_t, 8> idx;
      std::array<double, 8> w;
      if (!g.stencil(ge, idx, w)) continue;
      const std::size_t step = d == 0   ? 1
                               : d == 1 ? static_cast<std::size_t>(g.nx)
                                        : static_cast<std::size_t>(g.nx) * static_cast<std::size_t>(g.ny);
      const double hv = -s.normals[k][d] * s.area[k] / (g.h * g.h);  // h * V_e
      for (std::size_t c = 0; c < 8; ++c) {
        // Edge from node a = idx to node b = idx + step: energy (x_b - x_a - hV)^2.
        b[idx[c] + step] += w[c] * hv;
        b[idx[c]] -= w[c] * hv;
      }
    }
  }
  // Screening: beta per sample so that a fully sampled cell weighs alpha, whatever the density.
  std::vector<Eigen::Vector3d> gps(s.points.size());
  std::size_t occupied = 0;
  {
    std::unordered_map<std::size_t, int> seen;
    for (std::size_t k = 0; k < s.points.size(); ++k) {
      gps[k] = g.to_grid(s.points[k]);
      const Eigen::Vector3d f = gps[k].array().floor().matrix();
      seen[g.index(static_cast<int>(f.x()), static_cast<int>(f.y()), static_cast<int>(f.z()))] = 1;
    }
    occupied = seen.size();
  }
  std::vector<double> chi(n, 0.0);
  const double beta_unit =
      options.screening_weight * static_cast<double>(occupied) / static_cast<double>(s.points.size());
  // The iso value is not known until chi is; screen toward 0.5, the indicator's midpoint.
  for (std::size_t k = 0; k < s.points.size(); ++k) {
    std::array<std::size_t, 8> idx;
    std::array<double, 8> w;
    if (!g.stencil(gps[k], idx, w)) continue;
    auto [it, inserted] = cell_of.try_emplace(idx[0], cells.size());
    if (inserted) {
      CellScreening c;
      c.idx = idx;
      c.S.setZero();
      cells.push_back(c);
    }
    CellScreening& c = cells[it->second];
    Eigen::Matrix<double, 8, 1> wv;
    for (std::size_t q = 0; q < 8; ++q) wv[static_cast<Eigen::Index>(q)] = w[q];
    c.S.noalias() += beta_unit * wv * wv.transpose();
    for (std::size_t q = 0; q < 8; ++q) b[idx[q]] += beta_unit * w[q] * 0.5;
  }
  std::vector<double> diag(n, 6.0);
  for (int z = 0; z < g.nz; ++z)
    for (int y = 0; y < g.ny; ++y)
      for (int x = 0; x < g.nx; ++x)
        if (g.boundary(x, y, z)) {
          diag[g.index(x, y, z)] = 1.0;
          b[g.index(x, y, z)] = 0.0;
        }
  for (const auto& c : cells)
    for (std::size_t q = 0; q < 8; ++q)
      diag[c.idx[q]] += c.S(static_cast<Eigen::Index>(q), static_cast<Eigen::Index>(q));
  if (coarse) {
    for (int z = 1; z + 1 < g.nz; ++z)
      for (int y = 1; y + 1 < g.ny; ++y)
        for (int x = 1; x + 1 < g.nx; ++x)
          chi[g.index(x, y, z)] = coarse->grid.sample(coarse->chi, g.position(x, y, z));
  }
  const PoissonOperator A{g, cells};
  const auto [iterations, residual] = solve_cg(A, diag, b, chi, options.max_cg_iterations, options.cg_tolerance);
  out.chi = std::move(chi);
  out.iterations = iterations;
  out.residual = residual;
  return out;
}

// Marching tetrahedra over the Freudenthal split of each cell (6 tetrahedra around the main
// diagonal): neighbouring cells split shared faces the same way, so the surface is closed.
constexpr int kTets[6][4] = {{0, 1, 3, 7}, {0, 1, 5, 7}, {0, 2, 3, 7}, {0, 2, 6, 7}, {0, 4, 5, 7}, {0, 4, 6, 7}};

struct Extractor {
  const Grid& g;
  const std::vector<double>& f;
  double iso;
  TriangleMesh mesh;
  std::unordered_map<std::uint64_t, std::uint32_t> edge_vertex;

  std::uint32_t vertex_on(std::size_t a, std::size_t b, const Eigen::Vector3d& pa, const Eigen::Vector3d& pb) {
    if (a > b) return vertex_on(b, a, pb, pa);
    const std::uint64_t key = static_cast<std::uint64_t>(a) * g.size() + b;
    auto [it, inserted] = edge_vertex.try_emplace(key, static_cast<std::uint32_t>(mesh.vertices.size()));
    if (inserted) {
      const double fa = f[a], fb = f[b];
      const double t = std::clamp((iso - fa) / (fb - fa), 0.0, 1.0);
      mesh.vertices.push_back((pa + t * (pb - pa)).cast<float>());
    }
    return it->second;
  }

  void emit(std::array<std::uint32_t, 3> tri, const std::array<Eigen::Vector3d, 3>& mid,
            const Eigen::Vector3d& outward) {
    // Orientation from the edge midpoints: never degenerate, unlike the interpolated vertices.
    if ((mid[1] - mid[0]).cross(mid[2] - mid[0]).dot(outward) < 0) std::swap(tri[1], tri[2]);
    mesh.triangles.push_back(tri);
  }

  void run() {
    for (int z = 0; z + 1 < g.nz; ++z)
      for (int y = 0; y + 1 < g.ny; ++y)
        for (int x = 0; x + 1 < g.nx; ++x) {
          std::array<std::size_t, 8> idx;
          std::array<Eigen::Vector3d, 8> pos;
          int inside = 0;
          for (int c = 0; c < 8; ++c) {
            const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
            idx[static_cast<std::size_t>(c)] = g.index(x + dx, y + dy, z + dz);
            inside += f[idx[static_cast<std::size_t>(c)]] > iso;
          }
          if (inside == 0 || inside == 8) continue;
          for (int c = 0; c < 8; ++c)
            pos[static_cast<std::size_t>(c)] = g.position(x + (c & 1), y + ((c >> 1) & 1), z + ((c >> 2) & 1));
          for (const auto& tet : kTets) tetrahedron(tet, idx, pos);
        }
  }

  void tetrahedron(const int (&tet)[4], const std::array<std::size_t, 8>& idx,
                   const std::array<Eigen::Vector3d, 8>& pos) {
    std::array<int, 4> in{}, out{};
    int ni = 0, no = 0;
    for (int k = 0; k < 4; ++k) {
      const int c = tet[k];
      if (f[idx[static_cast<std::size_t>(c)]] > iso)
        in[static_cast<std::size_t>(ni++)] = c;
      else
        out[static_cast<std::size_t>(no++)] = c;
    }
    if (ni == 0 || no == 0) return;
    auto P = [&](int c) { return pos[static_cast<std::size_t>(c)]; };
    auto I = [&](int c) { return idx[static_cast<std::size_t>(c)]; };
    auto V = [&](int a, int b) { return vertex_on(I(a), I(b), P(a), P(b)); };
    auto M = [&](int a, int b) { return Eigen::Vector3d(0.5 * (P(a) + P(b))); };
    Eigen::Vector3d cin = Eigen::Vector3d::Zero(), cout = Eigen::Vector3d::Zero();
    for (int k = 0; k < ni; ++k) cin += P(in[static_cast<std::size_t>(k)]) / ni;
    for (int k = 0; k < no; ++k) cout += P(out[static_cast<std::size_t>(k)]) / no;
    const Eigen::Vector3d outward = cout - cin;
    if (ni == 1 || no == 1) {
      const int single = ni == 1 ? in[0] : out[0];
      const auto& others = ni == 1 ? out : in;
      emit({V(single, others[0]), V(single, others[1]), V(single, others[2])},
           {M(single, others[0]), M(single, others[1]), M(single, others[2])}, outward);
    } else {
      const int i1 = in[0], i2 = in[1], o1 = out[0], o2 = out[1];
      // Quad i1o1 - i1o2 - i2o2 - i2o1 (a cycle around the tetrahedron), split in two.
      emit({V(i1, o1), V(i1, o2), V(i2, o2)}, {M(i1, o1), M(i1, o2), M(i2, o2)}, outward);
      emit({V(i1, o1), V(i2, o2), V(i2, o1)}, {M(i1, o1), M(i2, o2), M(i2, o1)}, outward);
    }
  }
};

}  // namespace

MeshResult poisson_mesh(const PointCloud& cloud, const PoissonOptions& options) {
  if (options.resolution < 8 || options.resolution > 1024)
    throw std::invalid_argument("poisson_mesh: resolution must be in [8, 1024], got " +
                                std::to_string(options.resolution));
  if (!(options.padding_ratio >= 0) || !(options.screening_weight >= 0) || options.area_neighbors < 2 ||
      options.max_cg_iterations < 1 || !(options.cg_tolerance > 0) || !(options.density_trim_ratio >= 0))
    throw std::invalid_argument(
        "poisson_mesh: padding_ratio, screening_weight, density_trim_ratio must be >= 0, "
        "area_neighbors >= 2, max_cg_iterations >= 1, cg_tolerance > 0");
  if (cloud.normals.size() != cloud.size())
    throw std::invalid_argument("poisson_mesh: the cloud has " + std::to_string(cloud.normals.size()) +
                                " normals for " + std::to_string(cloud.size()) +
                                " points (oriented normals are required)");
  if (cloud.size() < 16)
    throw std::invalid_argument("poisson_mesh: needs at least 16 points, got " + std::to_string(cloud.size()));
  Samples s;
  s.points.reserve(cloud.size());
  s.normals.reserve(cloud.size());
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(INFINITY), hi = Eigen::Vector3d::Constant(-INFINITY);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.points[i].allFinite())
      throw std::invalid_argument("poisson_mesh: point " + std::to_string(i) + " of the " +
                                  std::to_string(cloud.size()) + "-point model is not finite");
    const float len = cloud.normals[i].norm();
    if (!std::isfinite(len) || len < 1e-6f)
      throw std::invalid_argument("poisson_mesh: normal " + std::to_string(i) + " of the " +
                                  std::to_string(cloud.size()) + "-point model is zero or not finite");
    s.points.push_back(cloud.points[i].cast<double>());
    s.normals.push_back((cloud.normals[i] / len).cast<double>());
    lo = lo.cwiseMin(s.points.back());
    hi = hi.cwiseMax(s.points.back());
  }
  // Each sample's share of the surface, pi r_k^2 / k from its k-th neighbour distance: the
  // field must not grow where the points are denser.
  {
    const detail::KdTree tree(cloud.points);
    const auto k = static_cast<std::size_t>(options.area_neighbors) + 1;
    s.area.resize(cloud.size());
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, cloud.size(), 1024), [&](const tbb::blocked_range<std::size_t>& r) {
          std::vector<std::uint32_t> idx(k);
          std::vector<float> d2(k);
          for (std::size_t i = r.begin(); i < r.end(); ++i) {
            const std::size_t found = tree.knn(cloud.points[i], k, idx.data(), d2.data());
            s.area[i] = std::numbers::pi * static_cast<double>(d2[found - 1]) / static_cast<double>(found - 1);
          }
        });
  }
  const Eigen::Vector3d extent =
      (hi - lo).cwiseMax(Eigen::Vector3d::Constant(1e-6 * std::max(1.0, (hi - lo).maxCoeff())));
  const Eigen::Vector3d pad = extent * options.padding_ratio;
  const Eigen::Vector3d box_lo = lo - pad, box_hi = lo + extent + pad;

  // Coarse to fine: each level starts from the previous one's solution, so CG only has to
  // remove the fine-scale error (a cascadic multigrid).
  std::vector<int> levels{options.resolution};
  while (levels.back() > 32) levels.push_back(levels.back() / 2);
  std::reverse(levels.begin(), levels.end());
  Solution solution;
  MeshResult result;
  for (std::size_t l = 0; l < levels.size(); ++l) {
    Solution next = solve_level(s, box_lo, box_hi, levels[l], options, l ? &solution : nullptr);
    result.cg_iterations += next.iterations;
    solution = std::move(next);
  }
  result.cg_relative_residual = solution.residual;
  if (!(solution.residual <= std::max(options.cg_tolerance * 100, 1e-3)))
    throw std::runtime_error("poisson_mesh: the solver stopped at relative residual " +
                             std::to_string(solution.residual) + " after " + std::to_string(result.cg_iterations) +
                             " iterations");
  const Grid& g = solution.grid;
  result.grid_nodes = {g.nx, g.ny, g.nz};
  result.cell_mm = g.h;
  double weighted = 0, total = 0;
  for (std::size_t k = 0; k < s.points.size(); ++k) {
    weighted += s.area[k] * g.sample(solution.chi, s.points[k]);
    total += s.area[k];
  }
  result.iso_value = weighted / total;
  // Nudge nodes sitting exactly on the iso value off it: keeps every vertex strictly inside
  // its edge, so the triangles stay well defined.
  std::vector<double> f = solution.chi;
  for (auto& v : f)
    if (v == result.iso_value) v = std::nextafter(v, -INFINITY);
  Extractor ex{g, f, result.iso_value, {}, {}};
  ex.run();
  TriangleMesh mesh = std::move(ex.mesh);

  if (options.density_trim_ratio > 0 && !mesh.triangles.empty()) {
    // Sample density splatted onto the nodes and spread by two box blurs (about 2 cells).
    std::vector<double> density(g.size(), 0.0);
    for (const auto& p : s.points) {
      std::array<std::size_t, 8> idx;
      std::array<double, 8> w;
      if (g.stencil(g.to_grid(p), idx, w))
        for (std::size_t c = 0; c < 8; ++c) density[idx[c]] += w[c];
    }
    for (int pass = 0; pass < 2; ++pass) {
      for (int axis = 0; axis < 3; ++axis) {
        std::vector<double> blurred(density.size(), 0.0);
        const std::size_t step = axis == 0   ? 1
                                 : axis == 1 ? static_cast<std::size_t>(g.nx)
                                             : static_cast<std::size_t>(g.nx) * static_cast<std::size_t>(g.ny);
        for (int z = 1; z + 1 < g.nz; ++z)
          for (int y = 1; y + 1 < g.ny; ++y)
            for (int x = 1; x + 1 < g.nx; ++x) {
              const std::size_t i = g.index(x, y, z);
              blurred[i] = (density[i - step] + density[i] + density[i + step]) / 3.0;
            }
        density = std::move(blurred);
      }
    }
    std::vector<double> at_samples(s.points.size());
    for (std::size_t k = 0; k < s.points.size(); ++k) at_samples[k] = g.sample(density, s.points[k]);
    auto mid = at_samples.begin() + static_cast<std::ptrdiff_t>(at_samples.size() / 2);
    std::nth_element(at_samples.begin(), mid, at_samples.end());
    const double threshold = options.density_trim_ratio * *mid;
    std::vector<std::uint8_t> keep_vertex(mesh.vertices.size());
    for (std::size_t v = 0; v < mesh.vertices.size(); ++v)
      keep_vertex[v] = g.sample(density, mesh.vertices[v].cast<double>()) >= threshold;
    std::vector<std::array<std::uint32_t, 3>> kept;
    for (const auto& t : mesh.triangles)
      if (keep_vertex[t[0]] && keep_vertex[t[1]] && keep_vertex[t[2]]) kept.push_back(t);
    result.trimmed_triangles = mesh.triangles.size() - kept.size();
    // Drop the vertices no triangle uses any more.
    std::vector<std::uint32_t> remap(mesh.vertices.size(), UINT32_MAX);
    std::vector<Eigen::Vector3f> vertices;
    for (auto& t : kept)
      for (auto& v : t) {
        if (remap[v] == UINT32_MAX) {
          remap[v] = static_cast<std::uint32_t>(vertices.size());
          vertices.push_back(mesh.vertices[v]);
        }
        v = remap[v];
      }
    mesh.vertices = std::move(vertices);
    mesh.triangles = std::move(kept);
  }
  // Vertex normals: minus the gradient of chi (smooth, unlike the normals of marching
  // tetrahedra's thin triangles); the area-weighted triangle normal where the gradient vanishes.
  mesh.normals.assign(mesh.vertices.size(), Eigen::Vector3f::Zero());
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3f n =
        (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    for (auto v : t) mesh.normals[v] += n;
  }
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mesh.vertices.size(), 1024),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t i = r.begin(); i < r.end(); ++i) {
                        const Eigen::Vector3d p = mesh.vertices[i].cast<double>();
                        Eigen::Vector3d grad;
                        for (int d = 0; d < 3; ++d) {
                          Eigen::Vector3d e = Eigen::Vector3d::Zero();
                          e[d] = 0.5 * g.h;
                          grad[d] = g.sample(solution.chi, p + e) - g.sample(solution.chi, p - e);
                        }
                        Eigen::Vector3f n = mesh.normals[i];
                        if (grad.norm() > 0 && (-grad).cast<float>().dot(n) > 0) n = (-grad).cast<float>();
                        const float len = n.norm();
                        mesh.normals[i] = len > 0 ? Eigen::Vector3f(n / len) : Eigen::Vector3f::UnitZ();
                      }
                    });
  result.mesh = std::move(mesh);
  return result;
}

const char* mesh_mode_name(MeshMode mode) { return mode == MeshMode::raw ? "raw" : "watertight"; }

bool parse_mesh_mode(const std::string& name, MeshMode& mode) {
  if (name == "raw")
    mode = MeshMode::raw;
  else if (name == "watertight")
    mode = MeshMode::watertight;
  else
    return false;
  return true;
}

void MeshOptions::check() const {
  auto positive = [](double v, const char* name) {
    if (!(v > 0) || !std::isfinite(v)) throw std::invalid_argument(std::string("mesh.") + name + " must be > 0");
  };
  if (!(cell_mm >= 0) || !std::isfinite(cell_mm))
    throw std::invalid_argument("mesh.cell_mm must be >= 0 (0: from the point spacing)");
  positive(cell_spacing_factor, "cell_spacing_factor");
  if (!(min_cell_mm >= 0) || !std::isfinite(min_cell_mm) || min_cell_mm > 100)
    throw std::invalid_argument("mesh.min_cell_mm must be in [0, 100] mm (0: no floor)");
  positive(kernel_factor, "kernel_factor");
  positive(trim_factor, "trim_factor");
  if (min_neighbors < 1) throw std::invalid_argument("mesh.min_neighbors must be >= 1");
  if (!(adaptivity >= 0 && adaptivity <= 1)) throw std::invalid_argument("mesh.adaptivity must be in [0, 1]");
  if (!(min_piece_fraction >= 0 && min_piece_fraction <= 1))
    throw std::invalid_argument("mesh.min_piece_fraction must be in [0, 1]");
  if (!(fill_holes_mm >= 0) || !std::isfinite(fill_holes_mm))
    throw std::invalid_argument("mesh.fill_holes_mm must be >= 0");
}

MeshTopology mesh_topology(const TriangleMesh& mesh) {
  // Each undirected edge: how many triangles use it, and the net direction of traversal.
  std::unordered_map<std::uint64_t, std::pair<int, int>> edges;
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t a = t[static_cast<std::size_t>(k)], b = t[static_cast<std::size_t>((k + 1) % 3)];
      const std::uint64_t key = (static_cast<std::uint64_t>(std::min(a, b)) << 32) | std::max(a, b);
      auto& e = edges[key];
      ++e.first;
      e.second += a < b ? 1 : -1;
    }
  MeshTopology topo;
  topo.edges = edges.size();
  for (const auto& [key, e] : edges) {
    if (e.first == 1) ++topo.boundary_edges;
    if (e.first > 2) ++topo.non_manifold_edges;
    if (e.first == 2 && e.second != 0) ++topo.inconsistent_edges;
  }
  return topo;
}

}  // namespace slscan::core
