// Multi-view registration (pipeline stage 5): every view brought into the turntable frame of
// view 0, first by the calibrated turntable motion T(theta) computed directly for each angle,
// then by point-to-plane ICP refined jointly over all views (neighbouring pairs plus the
// closing pair), so errors do not accumulate around the circle.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "slproto/calibration.hpp"
#include "slscan/core/interruption.hpp"
#include "slscan/core/point_cloud.hpp"

namespace slscan::core {

Eigen::Isometry3d to_isometry(const slproto::RigidTransform& transform);
slproto::RigidTransform to_rigid_transform(const Eigen::Isometry3d& transform);

// table_from_view for a view taken at table angle `angle_deg`: the object turned by +angle, so
// a point seen in that view's camera frame is turned back by -angle about the calibrated axis
// and expressed in the turntable frame (of angle 0).
Eigen::Isometry3d coarse_table_from_view(const slproto::TurntableCalibration& turntable, double angle_deg);

// Rotation angle (deg) and translation length (mm) of a rigid transform.
double rotation_angle_deg(const Eigen::Isometry3d& transform);
double translation_mm(const Eigen::Isometry3d& transform);

struct IcpOptions {
  // Correspondence gate in stages, coarse to fine: one wide gate leaves overlap-edge points
  // pulling the solution; narrowing it converges to the noise floor.
  std::vector<double> gates_mm{2.0, 0.5, 0.2};
  double max_normal_angle_deg = 30;  // source and target normals must agree this well
  int max_iterations_per_stage = 20;
  double converged_rotation_deg = 5e-4;  // a stage ends when every update is below both
  double converged_translation_mm = 5e-4;
  // ... or when the objective (residuals and turntable prior, as an RMS) fell by less than this
  // fraction over the last iteration (after the sixth): the poses then move within their own
  // uncertainty.
  double converged_relative_rms = 1e-4;
  std::size_t source_points_per_view = 20000;  // random subsample of each view's points
  // Sources per view in the stages before the last: the wide gates only need the pose to
  // within a fraction of the next gate, which a quarter of the points gives at a quarter of
  // the cost. 0: all source_points_per_view in every stage.
  std::size_t early_stage_points_per_view = 5000;
  double outlier_mad_factor = 3.0;  // per pair, drop residuals beyond this many robust sigmas
  std::uint64_t seed = 1;
};

struct IcpResult {
  Eigen::Isometry3d target_from_source = Eigen::Isometry3d::Identity();
  double residual_rms_mm = 0;  // point-to-plane, at the last gate
  std::size_t correspondences = 0;
  int iterations = 0;
};

// Pairwise symmetric point-to-plane ICP (the residual is measured along the mean of the source
// and target normals). Both clouds need normals; throws
// std::invalid_argument otherwise, std::runtime_error if too few correspondences are found.
IcpResult icp_point_to_plane(const PointCloud& source, const PointCloud& target,
                             const Eigen::Isometry3d& initial_target_from_source, const IcpOptions& options = {});

enum class RefinementMode {
  // All views at once over every neighbouring pair and the closing pair, with the poses a
  // turntable gives: one axis (the calibrated one, corrected by a small tilt and shift shared by
  // all views) and one angle correction per view.
  turntable,
  joint,       // as turntable, but 6 free degrees of freedom per view (a part moved by hand, a wobbling table)
  sequential,  // each view onto its predecessor, chained (what joint refinement improves on)
};

// "turntable", "joint", "sequential": the config's and report's word for the mode.
const char* refinement_mode_name(RefinementMode mode);

struct RegistrationOptions {
  IcpOptions icp;
  RefinementMode mode = RefinementMode::turntable;
  bool close_loop = true;  // pair the last view with view 0 when the views span the circle
  // Joint mode: how far (1 sigma) the calibrated turntable pose of a view is trusted. Each
  // view's deviation from it is penalised as a measurement of that uncertainty, weighed
  // against the ICP residuals. Where the surfaces pin a pose down (almost everywhere) the
  // data outweighs the prior by orders of magnitude; where they don't (a ball bar turning
  // about its own axis, a cylinder sliding along itself) the view stays at the turntable pose
  // instead of sliding. <= 0 turns the prior off.
  double turntable_prior_deg = 0.05;
  double turntable_prior_mm = 0.05;
  // How messages name the views: views[i] is the capture's view view_numbers[i] (when views were
  // left out, positions and numbers differ); empty: by position. The caller's, not a config field.
  std::vector<int> view_numbers;
};

struct ViewRegistration {
  Eigen::Isometry3d coarse_table_from_view = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d table_from_view = Eigen::Isometry3d::Identity();
  double correction_deg = 0;  // of table_from_view * coarse^-1, i.e. what ICP changed
  double correction_mm = 0;
  double angle_correction_deg = 0;  // turntable mode: added to the reported angle (view 0: 0)
  double residual_rms_mm = 0;       // over this view's correspondences with its neighbours
  std::size_t correspondences = 0;
};

struct PairResidual {
  int view_a = 0, view_b = 0;
  double rms_mm = 0;  // symmetric point-to-plane RMS at the last gate, after registration
  std::size_t correspondences = 0;
};

struct RegistrationResult {
  std::vector<ViewRegistration> views;
  std::vector<PairResidual> pairs;  // (i, i+1) for each neighbour, then (last, 0) if closed
  int iterations = 0;
  RefinementMode mode = RefinementMode::turntable;
  // Turntable mode: how far the data moved the rotation axis from the calibrated one.
  double axis_tilt_deg = 0, axis_shift_mm = 0;
};

// `views[i]` is view i's cloud in its camera frame, with normals; `angles_deg[i]` its table
// angle. View 0 is held at its coarse pose. Throws std::invalid_argument naming the view on bad
// input (sizes, missing normals, non-finite points), std::runtime_error if a pair of views has
// too little overlap to register. `interrupt` is called per ICP iteration (Ctrl-C); what it
// throws ends the registration.
RegistrationResult register_views(const std::vector<PointCloud>& views, const std::vector<double>& angles_deg,
                                  const slproto::TurntableCalibration& turntable,
                                  const RegistrationOptions& options = {}, const InterruptionPoint& interrupt = {});

// register_views over the views that have points. A view whose cloud is empty (nothing left
// above the platform: an empty table, a view the projectors did not light) keeps its coarse
// pose and no correspondences; the result has one entry per view in the given order, and its
// pairs are numbered by position in `views`. Throws std::runtime_error when fewer than two views
// have points, and what register_views throws.
RegistrationResult register_views_with_points(const std::vector<PointCloud>& views,
                                              const std::vector<double>& angles_deg,
                                              const slproto::TurntableCalibration& turntable,
                                              const RegistrationOptions& options = {},
                                              const InterruptionPoint& interrupt = {});

}  // namespace slscan::core
