// Inspection against a nominal shape (CAD mesh): coarse alignment, robust point-to-plane best
// fit, per-point signed deviation, histogram, percentiles and PASS / FAIL against a tolerance
// (docs/inspection.md, "Deviation from a nominal"). No I/O: host/io reads the nominal file.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "slscan/core/mesh.hpp"
#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

// Nominals are core::TriangleMesh (mesh.hpp), mm, triangles counter-clockwise seen from outside
// (the face normal (b - a) x (c - a) points out of the material): a deviation is positive where
// the scan lies outside the nominal. Vertex normals are not used.

// Vertices at exactly the same position merged into one (an STL's triangle soup becomes an
// indexed mesh); unused vertices dropped.
TriangleMesh weld_vertices(const TriangleMesh& mesh);

// What makes a mesh unusable as a nominal: no triangles, a non-finite vertex, an index out of
// range, a triangle of zero area, an edge shared by more than two triangles (non-manifold), two
// neighbours that disagree on orientation (the sign of a deviation would be meaningless; not
// checked with require_orientation false). Throws std::invalid_argument naming the first
// problem with its triangle / vertex index.
void check_nominal_mesh(const TriangleMesh& mesh, bool require_orientation = true);

// Winds every connected piece consistently, flooding from its first triangle (kept as the file
// has it) across the shared edges; returns how many triangles were turned. Checks the mesh
// first (check_nominal_mesh without orientation); a one-sided surface throws
// std::invalid_argument.
std::size_t orient_consistently(TriangleMesh& mesh);

// Exact closest-point queries on a nominal (an AABB tree over its triangles), with the sign of a
// distance from the angle-weighted pseudo-normal of the closest feature (face, edge or vertex),
// which is correct on edges and corners too (Baerentzen & Aanaes 2005).
class NominalSurface {
 public:
  // Checks the mesh and winds it consistently (orient_consistently), then turns a closed mesh
  // that is inside out (negative volume) outward.
  explicit NominalSurface(TriangleMesh mesh);
  ~NominalSurface();
  NominalSurface(NominalSurface&&) noexcept;
  NominalSurface& operator=(NominalSurface&&) noexcept;

  struct Closest {
    Eigen::Vector3d point = Eigen::Vector3d::Zero();         // on the surface
    Eigen::Vector3d face_normal = Eigen::Vector3d::UnitZ();  // of the closest triangle (point-to-plane)
    double signed_distance_mm = 0;                           // + outside (along the normals), - inside
    std::size_t triangle = 0;
  };
  // Thread-safe.
  Closest closest(const Eigen::Vector3d& query) const;

  const TriangleMesh& mesh() const;
  std::size_t reoriented_triangles() const;  // turned by orient_consistently
  Eigen::AlignedBox3d bounds() const;
  double area_mm2() const;
  // `count` points spread over the surface in proportion to area (deterministic for a seed).
  std::vector<Eigen::Vector3d> sample(std::size_t count, std::uint64_t seed) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The nominal file's unit. auto_detect compares the nominal's size with the scan's.
enum class NominalUnits : std::uint8_t { auto_detect, mm, m, in };

struct UnitsDecision {
  double scale_to_mm = 1;
  std::string units;   // "mm", "m", "in"
  std::string reason;  // how it was decided, for the report
};

// Robust extent (diagonal of the 1st-99th percentile box) of a point set, mm.
double robust_extent(const std::vector<Eigen::Vector3f>& points);

// auto_detect: the ratio scan extent / nominal extent picks the unit whose scale brings it into
// [0.3, 8) (a scan covers part of its nominal, or the part plus its fixture): mm, inches
// (x 25.4) or metres (x 1000). A ratio that fits none, or that sits within a factor 1.6 of the
// border between two, is refused with std::invalid_argument naming --nominal-units.
UnitsDecision decide_nominal_units(double scan_extent_mm, double nominal_extent, NominalUnits requested);

struct InspectOptions {
  std::optional<double> tolerance_mm;  // +-; unset = not judged
  double pass_share = 0.99;            // PASS when this share of the matched points is within tolerance
  // After the fit, points farther than this from the nominal belong to something else
  // (platform, fixture, strays): counted, left out of the figures.
  double max_distance_mm = 0.5;
  std::size_t fit_points = 20000;  // random subsample used by the alignment
  // Needed share of the fit points within max_distance_mm of the aligned nominal; below it the
  // scan and the nominal do not overlap (std::runtime_error).
  double min_overlap = 0.2;
  bool coarse_search = true;  // when the scan frame does not fit: PCA / centroid candidates
  int histogram_bins = 40;    // over +- display range
  std::uint64_t seed = 1;
};

struct Alignment {
  Eigen::Isometry3d nominal_from_scan = Eigen::Isometry3d::Identity();
  std::string method;  // "scan frame" or "principal axes, candidate k of n" / "centroids"
  int candidates_tried = 0;
  double fit_rms_mm = 0;        // robust point-to-plane RMS of the inliers at the last gate
  std::size_t fit_inliers = 0;  // of the fit points
  double rotation_deg = 0;      // of nominal_from_scan
  double translation_mm = 0;
  int iterations = 0;
};

struct DeviationStats {
  std::size_t points = 0;     // all scan points
  std::size_t matched = 0;    // within max_distance_mm: the figures are over these
  std::size_t unmatched = 0;  // farther: not on the part
  double mean_mm = 0, rms_mm = 0, std_mm = 0, min_mm = 0, max_mm = 0;
  double abs_p95_mm = 0, abs_p99_mm = 0;
  std::vector<std::pair<double, double>> percentiles_mm;  // (percent, value): 1, 5, 25, 50, 75, 95, 99
  std::optional<double> share_within;                     // with a tolerance
  std::optional<bool> pass;
};

struct Histogram {
  double range_mm = 0;  // bins cover [-range, +range]
  std::vector<std::size_t> counts;
  std::size_t below = 0, above = 0;  // outside the range (still matched)
};

struct InspectionResult {
  Alignment alignment;
  std::vector<float> deviation_mm;              // per scan point (signed); NaN where unmatched
  std::vector<Eigen::Vector3f> aligned_points;  // the scan in the nominal's frame
  DeviationStats stats;
  Histogram histogram;
  double display_range_mm = 0;  // colour scale +-: the tolerance, else p99 |d| rounded up
};

// Aligns `scan` onto `nominal` (mm, after unit scaling) and measures each point's signed
// deviation. Throws std::invalid_argument for an empty or non-finite scan, std::runtime_error
// when the scan does not overlap the nominal (the message says how much did).
InspectionResult inspect(const PointCloud& scan, const NominalSurface& nominal, const InspectOptions& options = {});

// Signed deviation of each point (already in the nominal's frame), NaN beyond max_distance_mm.
std::vector<float> signed_deviations(const std::vector<Eigen::Vector3f>& points, const NominalSurface& nominal,
                                     double max_distance_mm);

// Figures and histogram of deviations (NaN = unmatched).
DeviationStats deviation_stats(const std::vector<float>& deviation_mm, const InspectOptions& options);
Histogram deviation_histogram(const std::vector<float>& deviation_mm, double range_mm, int bins);

}  // namespace slscan::core
