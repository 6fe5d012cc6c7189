#include "slscan/core/registration.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>

#include "slproto/number_text.hpp"
#include "slscan/core/detail/nearest_tree.hpp"
#include "turntable_poses.hpp"

namespace slscan::core {
namespace {

constexpr double kDegPerRad = 180.0 / std::numbers::pi;

void check_view(const PointCloud& cloud, const std::string& name) {
  if (cloud.size() == 0) throw std::invalid_argument(name + " is empty (no points to register)");
  if (cloud.normals.size() != cloud.size())
    throw std::invalid_argument(name + " has " + std::to_string(cloud.normals.size()) + " normals for " +
                                std::to_string(cloud.size()) + " points (registration needs one per point)");
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (!cloud.points[i].allFinite())
      throw std::invalid_argument(name + ": point " + std::to_string(i) + " of " + std::to_string(cloud.size()) +
                                  " is not finite");
}

void check_options(const IcpOptions& o) {
  if (o.gates_mm.empty()) throw std::invalid_argument("ICP options: gates_mm is empty");
  for (double g : o.gates_mm)
    if (!(g > 0)) throw std::invalid_argument("ICP options: every gate must be > 0 mm");
  if (!(o.max_normal_angle_deg > 0 && o.max_normal_angle_deg <= 180))
    throw std::invalid_argument("ICP options: max_normal_angle_deg must be in (0, 180]");
  if (o.max_iterations_per_stage < 1) throw std::invalid_argument("ICP options: max_iterations_per_stage must be >= 1");
  if (o.source_points_per_view < 6) throw std::invalid_argument("ICP options: source_points_per_view must be >= 6");
  if (!(o.outlier_mad_factor > 0)) throw std::invalid_argument("ICP options: outlier_mad_factor must be > 0");
  if (!(o.converged_relative_rms >= 0 && o.converged_relative_rms < 1))
    throw std::invalid_argument("ICP options: converged_relative_rms must be in [0, 1)");
}

// One view as ICP sees it: its cloud (own frame), a nearest-point tree over it, and the subsample of
// points it sends as sources.
struct ViewData {
  const PointCloud* cloud = nullptr;
  std::unique_ptr<detail::NearestTree> tree;
  std::vector<std::uint32_t> samples;
};

struct Correspondence {
  Eigen::Vector3d a, b, m;  // source point, target point, mean of both normals: table frame
  double r = 0;             // m . (a - b)
};

// Simultaneous point-to-plane adjustment of N poses over directed view pairs (source -> target).
// Each pose is perturbed on the left, T <- (I + [w]x, v) T, so a point a = T p moves by w x a + v.
class JointIcp {
 public:
  JointIcp(std::vector<ViewData>& views, std::vector<Eigen::Isometry3d>& poses, std::vector<bool> fixed,
           std::vector<std::pair<int, int>> directed_pairs, const IcpOptions& options, double prior_deg = 0,
           double prior_mm = 0, const InterruptionPoint* interrupt = nullptr, std::vector<int> view_numbers = {})
      : view_numbers_(std::move(view_numbers)),
        views_(views),
        poses_(poses),
        prior_poses_(poses),
        fixed_(std::move(fixed)),
        pairs_(std::move(directed_pairs)),
        options_(options),
        prior_rad_(prior_deg / kDegPerRad),
        prior_mm_(prior_mm),
        interrupt_(interrupt) {}

  int run() {
    int iterations = 0;
    for (std::size_t stage = 0; stage < options_.gates_mm.size(); ++stage) {
      const bool last = stage + 1 == options_.gates_mm.size();
      const std::size_t sources = last || options_.early_stage_points_per_view == 0
                                      ? options_.source_points_per_view
                                      : options_.early_stage_points_per_view;
      // An early stage only has to bring the views well inside the next, narrower gate: 1 % of
      // it, and the rotation that moves a point 100 mm from the axis as much. Asking it for the
      // final tolerance lets it spend its iterations on the jitter of its wide gate.
      double tolerance_mm = options_.converged_translation_mm, tolerance_deg = options_.converged_rotation_deg;
      if (!last) {
        tolerance_mm = std::max(tolerance_mm, 0.01 * options_.gates_mm[stage + 1]);
        tolerance_deg = std::max(tolerance_deg, tolerance_mm / 100.0 * kDegPerRad);
      }
      // A stage also ends (after its sixth iteration) when the objective stops falling: a view
      // whose pose the surfaces pin
      // down only loosely (the teacup's side view: the prior holds it) otherwise jitters by a
      // few thousandths of a degree from one correspondence set to the next and spends every
      // remaining iteration there without improving the fit.
      double previous_rms = std::numeric_limits<double>::infinity();
      for (int it = 0; it < options_.max_iterations_per_stage; ++it) {
        if (interrupt_ != nullptr) interruption_point(*interrupt_);
        ++iterations;
        double rms = 0;
        if (step(options_.gates_mm[stage], sources, tolerance_deg, tolerance_mm, rms)) break;
        if (it >= 5 && rms > previous_rms * (1 - options_.converged_relative_rms)) break;
        previous_rms = rms;
      }
    }
    return iterations;
  }

  // Correspondences of one directed pair at the current poses, valid until the next call.
  // At most `max_sources` of the source's samples, evenly strided (the samples are in Morton
  // order, so a stride keeps them spread over the whole view). The storage is kept from call to
  // call: 100k correspondences are 8 MB, and fresh pages for them cost more than the search
  // (measured on a VM: ~3.6 ms per MB of first touches).
  const std::vector<Correspondence>& correspondences(int source, int target, double gate,
                                                     std::size_t max_sources = SIZE_MAX) const {
    const ViewData& s = views_[static_cast<std::size_t>(source)];
    const ViewData& t = views_[static_cast<std::size_t>(target)];
    const Eigen::Isometry3d& Ts = poses_[static_cast<std::size_t>(source)];
    const Eigen::Isometry3d& Tt = poses_[static_cast<std::size_t>(target)];
    const Eigen::Isometry3d target_from_source = Tt.inverse() * Ts;
    const Eigen::Matrix3f R = target_from_source.linear().cast<float>();
    const Eigen::Vector3f tr = target_from_source.translation().cast<float>();
    const auto cos_max = static_cast<float>(std::cos(options_.max_normal_angle_deg / kDegPerRad));
    const auto gatef = static_cast<float>(gate);
    const std::size_t stride = std::max<std::size_t>(1, (s.samples.size() + max_sources - 1) / max_sources);
    const std::size_t count = (s.samples.size() + stride - 1) / stride;
    std::vector<Correspondence>& found = found_;
    found.resize(count);
    found_ok_.assign(count, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 512), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t k = r.begin(); k < r.end(); ++k) {
        const std::uint32_t i = s.samples[k * stride];
        const Eigen::Vector3f x = R * s.cloud->points[i] + tr;
        float d2 = 0;
        const std::int64_t j = t.tree->nearest_within(x, gatef, d2);
        if (j < 0) continue;
        const Eigen::Vector3f& nq = t.cloud->normals[static_cast<std::size_t>(j)];
        if ((R * s.cloud->normals[i]).dot(nq) < cos_max) continue;
        Correspondence& c = found[k];
        c.a = Ts * s.cloud->points[i].cast<double>();
        c.b = Tt * t.cloud->points[static_cast<std::size_t>(j)].cast<double>();
        // Symmetric point-to-plane (Rusinkiewicz 2019): the sum of both normals cancels, to first
        // order, the bias a curved surface gives the one-sided residual at sparse sampling.
        c.m = (Tt.linear() * nq.cast<double>() + Ts.linear() * s.cloud->normals[i].cast<double>()).normalized();
        c.r = c.m.dot(c.a - c.b);
        found_ok_[k] = 1;
      }
    });
    std::size_t kept = 0;
    for (std::size_t k = 0; k < count; ++k)
      if (found_ok_[k]) found[kept++] = found[k];
    found.resize(kept);
    reject_outliers(found);
    return found;
  }

 private:
  std::string view_name(int position) const {
    return std::to_string(view_numbers_.empty() ? position : view_numbers_[static_cast<std::size_t>(position)]);
  }

  // Drops residuals beyond outlier_mad_factor robust sigmas of the pair's median.
  void reject_outliers(std::vector<Correspondence>& c) const {
    if (c.size() < 8) return;
    std::vector<double>& r = residuals_;
    r.resize(c.size());
    for (std::size_t i = 0; i < c.size(); ++i) r[i] = c[i].r;
    auto mid = r.begin() + static_cast<std::ptrdiff_t>(r.size() / 2);
    std::nth_element(r.begin(), mid, r.end());
    const double median = *mid;
    for (auto& x : r) x = std::abs(x - median);
    std::nth_element(r.begin(), mid, r.end());
    const double sigma = std::max(1.4826 * *mid, 1e-6);
    const double limit = options_.outlier_mad_factor * sigma;
    std::erase_if(c, [&](const Correspondence& x) { return std::abs(x.r - median) > limit; });
  }

  // One Gauss-Newton step over every pair; true when the update is below the thresholds.
  // `rms`: the objective (point-to-plane residuals and the turntable prior) at the poses this
  // step started from, per correspondence.
  bool step(double gate, std::size_t sources, double tolerance_deg, double tolerance_mm, double& rms) {
    const int n = static_cast<int>(poses_.size());
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(6 * n, 6 * n);
    Eigen::VectorXd g = Eigen::VectorXd::Zero(6 * n);
    double sum2 = 0;
    std::size_t total = 0;
    for (const auto& [s, t] : pairs_) {
      const auto& corr = correspondences(s, t, gate, sources);
      if (corr.size() < 6)
        throw std::runtime_error("ICP: views " + view_name(s) + " and " + view_name(t) + " share only " +
                                 std::to_string(corr.size()) + " correspondences within " +
                                 slproto::short_number(gate) +
                                 " mm (too little overlap or too far from the coarse pose)");
      Eigen::Matrix<double, 12, 12> h = Eigen::Matrix<double, 12, 12>::Zero();
      Eigen::Matrix<double, 12, 1> gg = Eigen::Matrix<double, 12, 1>::Zero();
      for (const auto& c : corr) {
        Eigen::Matrix<double, 12, 1> j;
        // Named cross products: GCC 12 at -O3 -mavx misreads Eigen's temporaries (-Warray-bounds).
        const Eigen::Vector3d a_cross_m = c.a.cross(c.m), b_cross_m = c.b.cross(c.m);
        j << a_cross_m, c.m, -b_cross_m, -c.m;
        h.noalias() += j * j.transpose();
        gg += j * c.r;
        sum2 += c.r * c.r;
      }
      total += corr.size();
      const int blocks[2] = {s, t};
      for (int x = 0; x < 2; ++x)
        for (int y = 0; y < 2; ++y) H.block<6, 6>(6 * blocks[x], 6 * blocks[y]) += h.block<6, 6>(6 * x, 6 * y);
      for (int x = 0; x < 2; ++x) g.segment<6>(6 * blocks[x]) += gg.segment<6>(6 * x);
    }
    if (turntable_ != nullptr) return turntable_step(H, g, sum2, total, tolerance_deg, tolerance_mm, rms);
    double prior_cost = 0;  // in the residuals' units: what the prior adds to sum2
    // Fixed poses take no part in the solve.
    for (int v = 0; v < n; ++v) {
      if (!fixed_[static_cast<std::size_t>(v)]) continue;
      H.middleRows(6 * v, 6).setZero();
      H.middleCols(6 * v, 6).setZero();
      g.segment<6>(6 * v).setZero();
    }
    // The turntable prior: the deviation e of each pose from its calibrated pose (left
    // perturbation: pose = exp(e) prior, so an update d moves e to e + d to first order) costs
    // e^2 / prior_sigma^2 in units of the residual variance, i.e. weight var_r / sigma^2.
    if (prior_rad_ > 0 && prior_mm_ > 0 && total > 0) {
      const double residual_var = std::max(sum2 / static_cast<double>(total), 1e-8);
      const double w_rot = residual_var / (prior_rad_ * prior_rad_);
      const double w_mm = residual_var / (prior_mm_ * prior_mm_);
      for (int v = 0; v < n; ++v) {
        if (fixed_[static_cast<std::size_t>(v)]) continue;
        const Eigen::Isometry3d deviation =
            poses_[static_cast<std::size_t>(v)] * prior_poses_[static_cast<std::size_t>(v)].inverse();
        const Eigen::AngleAxisd angle_axis(deviation.linear());
        const Eigen::Vector3d e_rot = angle_axis.angle() * angle_axis.axis();
        for (int k = 0; k < 3; ++k) {
          H(6 * v + k, 6 * v + k) += w_rot;
          H(6 * v + 3 + k, 6 * v + 3 + k) += w_mm;
        }
        g.segment<3>(6 * v) += w_rot * e_rot;
        g.segment<3>(6 * v + 3) += w_mm * deviation.translation();
        prior_cost += w_rot * e_rot.squaredNorm() + w_mm * deviation.translation().squaredNorm();
      }
    }
    // The objective this step minimises, as an RMS: the residuals and the prior together (on a
    // sphere only the prior changes as a view turns back toward its turntable pose).
    rms = total > 0 ? std::sqrt((sum2 + prior_cost) / static_cast<double>(total)) : 0.0;
    // Fixed poses: identity rows so their update is zero.
    for (int v = 0; v < n; ++v)
      if (fixed_[static_cast<std::size_t>(v)]) H.block<6, 6>(6 * v, 6 * v).setIdentity();
    // A whisper of damping keeps a symmetric object's free rotation from blowing up the solve.
    const double damping = 1e-12 * std::max(1.0, H.diagonal().maxCoeff());
    H.diagonal().array() += damping;
    const Eigen::VectorXd delta = H.ldlt().solve(-g);
    if (!delta.allFinite()) throw std::runtime_error("ICP: the normal equations are singular");
    bool converged = true;
    for (int v = 0; v < n; ++v) {
      if (fixed_[static_cast<std::size_t>(v)]) continue;
      const Eigen::Vector3d w = delta.segment<3>(6 * v);
      const Eigen::Vector3d t = delta.segment<3>(6 * v + 3);
      Eigen::Isometry3d update = Eigen::Isometry3d::Identity();
      if (w.norm() > 0) update.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
      update.translation() = t;
      poses_[static_cast<std::size_t>(v)] = update * poses_[static_cast<std::size_t>(v)];
      // Re-orthonormalise so many small updates don't drift off SO(3).
      Eigen::Quaterniond q(poses_[static_cast<std::size_t>(v)].linear());
      poses_[static_cast<std::size_t>(v)].linear() = q.normalized().toRotationMatrix();
      if (w.norm() * kDegPerRad > tolerance_deg || t.norm() > tolerance_mm) converged = false;
    }
    return converged;
  }

  // step() in the turntable's parameters: the poses' normal equations H, g (6 per view) taken
  // through d(pose) / d(params), the prior on each parameter (the axis' tilt and every angle
  // correction at prior_deg, its shift at prior_mm, weighed as in step()).
  bool turntable_step(const Eigen::MatrixXd& H, const Eigen::VectorXd& g, double sum2, std::size_t total,
                      double tolerance_deg, double tolerance_mm, double& rms) {
    const Eigen::MatrixXd J = turntable_->jacobian();
    Eigen::MatrixXd Hp = J.transpose() * H * J;
    Eigen::VectorXd gp = J.transpose() * g;
    double prior_cost = 0;
    if (prior_rad_ > 0 && prior_mm_ > 0 && total > 0) {
      const double residual_var = std::max(sum2 / static_cast<double>(total), 1e-8);
      const Eigen::VectorXd& p = turntable_->params();
      for (Eigen::Index k = 0; k < p.size(); ++k) {
        const bool shift = k == 2 || k == 3;
        const double w = residual_var / (shift ? prior_mm_ * prior_mm_ : prior_rad_ * prior_rad_);
        Hp(k, k) += w;
        gp[k] += w * p[k];
        prior_cost += w * p[k] * p[k];
      }
    }
    rms = total > 0 ? std::sqrt((sum2 + prior_cost) / static_cast<double>(total)) : 0.0;
    Hp.diagonal().array() += 1e-12 * std::max(1.0, Hp.diagonal().maxCoeff());
    const Eigen::VectorXd delta = Hp.ldlt().solve(-gp);
    if (!delta.allFinite()) throw std::runtime_error("ICP: the normal equations are singular");
    turntable_->update(delta);
    const std::vector<Eigen::Isometry3d> updated = turntable_->poses();
    bool converged = true;
    for (std::size_t v = 0; v < poses_.size(); ++v) {
      const Eigen::Isometry3d change = updated[v] * poses_[v].inverse();
      if (Eigen::AngleAxisd(change.linear()).angle() * kDegPerRad > tolerance_deg ||
          change.translation().norm() > tolerance_mm)
        converged = false;
      poses_[v] = updated[v];
    }
    return converged;
  }

 public:
  // Poses from the turntable's parameters instead of 6 free ones per view (`model` outlives the
  // adjustment; its poses are written into `poses` as they change).
  void use_turntable(detail::TurntablePoses* model) {
    turntable_ = model;
    poses_ = model->poses();
  }

 private:
  detail::TurntablePoses* turntable_ = nullptr;
  std::vector<int> view_numbers_;  // for messages (RegistrationOptions::view_numbers)
  std::vector<ViewData>& views_;
  std::vector<Eigen::Isometry3d>& poses_;
  std::vector<Eigen::Isometry3d> prior_poses_;  // the calibrated turntable poses
  std::vector<bool> fixed_;
  std::vector<std::pair<int, int>> pairs_;
  const IcpOptions& options_;
  double prior_rad_ = 0, prior_mm_ = 0;
  const InterruptionPoint* interrupt_ = nullptr;  // per iteration (Ctrl-C)
  // Storage kept from one correspondence search to the next.
  mutable std::vector<Correspondence> found_;
  mutable std::vector<std::uint8_t> found_ok_;
  mutable std::vector<double> residuals_;
};

// Spreads the low 21 bits of x to every third bit (for a 63-bit Morton code).
std::uint64_t spread_bits(std::uint64_t x) {
  x &= 0x1fffff;
  x = (x | x << 32) & 0x1f00000000ffffULL;
  x = (x | x << 16) & 0x1f0000ff0000ffULL;
  x = (x | x << 8) & 0x100f00f00f00f00fULL;
  x = (x | x << 4) & 0x10c30c30c30c30c3ULL;
  x = (x | x << 2) & 0x1249249249249249ULL;
  return x;
}

// `with_tree`: whether other views search this one (a pure source needs no tree).
ViewData make_view(const PointCloud& cloud, std::size_t max_samples, std::uint64_t seed, bool with_tree = true) {
  ViewData v;
  v.cloud = &cloud;
  if (with_tree) v.tree = std::make_unique<detail::NearestTree>(cloud.points);
  if (max_samples == 0) return v;  // a pure target sends no sources
  v.samples.reserve(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (cloud.normals[i].allFinite()) v.samples.push_back(static_cast<std::uint32_t>(i));
  if (v.samples.size() > max_samples) {
    std::mt19937_64 rng(seed);
    // Partial Fisher-Yates: the first max_samples entries become a uniform random subset.
    for (std::size_t i = 0; i < max_samples; ++i) {
      std::uniform_int_distribution<std::size_t> pick(i, v.samples.size() - 1);
      std::swap(v.samples[i], v.samples[pick(rng)]);
    }
    v.samples.resize(max_samples);
  }
  // Query in Morton (Z-curve) order of 0.25 mm cells: consecutive queries then walk the same
  // k-d tree leaves, whatever order the cloud came in.
  if (!v.samples.empty()) {
    Eigen::Vector3f lo = cloud.points[v.samples[0]];
    for (auto i : v.samples) lo = lo.cwiseMin(cloud.points[i]);
    std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(v.samples.size());
    for (std::size_t k = 0; k < v.samples.size(); ++k) {
      const Eigen::Vector3f c = (cloud.points[v.samples[k]] - lo) * 4.0f;
      keyed[k] = {spread_bits(static_cast<std::uint64_t>(c.x())) | spread_bits(static_cast<std::uint64_t>(c.y())) << 1 |
                      spread_bits(static_cast<std::uint64_t>(c.z())) << 2,
                  v.samples[k]};
    }
    tbb::parallel_sort(keyed.begin(), keyed.end());  // (key, index) pairs are distinct: one order
    for (std::size_t k = 0; k < keyed.size(); ++k) v.samples[k] = keyed[k].second;
  }
  return v;
}

}  // namespace

Eigen::Isometry3d to_isometry(const slproto::RigidTransform& transform) {
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c)
      out.linear()(r, c) = transform.R[3 * static_cast<std::size_t>(r) + static_cast<std::size_t>(c)];
    out.translation()[r] = transform.t[static_cast<std::size_t>(r)];
  }
  return out;
}

slproto::RigidTransform to_rigid_transform(const Eigen::Isometry3d& transform) {
  slproto::RigidTransform out;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c)
      out.R[3 * static_cast<std::size_t>(r) + static_cast<std::size_t>(c)] = transform.linear()(r, c);
    out.t[static_cast<std::size_t>(r)] = transform.translation()[r];
  }
  return out;
}

Eigen::Isometry3d coarse_table_from_view(const slproto::TurntableCalibration& turntable, double angle_deg) {
  const Eigen::Isometry3d table_from_cam = to_isometry(turntable.cam_from_table).inverse();
  return table_from_cam * to_isometry(turntable.rotation_in_camera(-angle_deg));
}

const char* refinement_mode_name(RefinementMode mode) {
  switch (mode) {
    case RefinementMode::turntable:
      return "turntable";
    case RefinementMode::joint:
      return "joint";
    case RefinementMode::sequential:
      return "sequential";
  }
  return "turntable";
}

double rotation_angle_deg(const Eigen::Isometry3d& transform) {
  return Eigen::AngleAxisd(transform.linear()).angle() * kDegPerRad;
}

double translation_mm(const Eigen::Isometry3d& transform) { return transform.translation().norm(); }

IcpResult icp_point_to_plane(const PointCloud& source, const PointCloud& target,
                             const Eigen::Isometry3d& initial_target_from_source, const IcpOptions& options) {
  check_options(options);
  check_view(source, "ICP source");
  check_view(target, "ICP target");
  std::vector<ViewData> views;
  views.push_back(make_view(target, 0, options.seed));
  views.push_back(make_view(source, options.source_points_per_view, options.seed, false));
  std::vector<Eigen::Isometry3d> poses{Eigen::Isometry3d::Identity(), initial_target_from_source};
  JointIcp icp(views, poses, {true, false}, {{1, 0}}, options);
  IcpResult result;
  result.iterations = icp.run();
  result.target_from_source = poses[1];
  const auto& corr = icp.correspondences(1, 0, options.gates_mm.back());
  double sum2 = 0;
  for (const auto& c : corr) sum2 += c.r * c.r;
  result.correspondences = corr.size();
  result.residual_rms_mm = corr.empty() ? 0.0 : std::sqrt(sum2 / static_cast<double>(corr.size()));
  return result;
}

RegistrationResult register_views(const std::vector<PointCloud>& views, const std::vector<double>& angles_deg,
                                  const slproto::TurntableCalibration& turntable, const RegistrationOptions& options,
                                  const InterruptionPoint& interrupt) {
  check_options(options.icp);
  if (views.size() != angles_deg.size())
    throw std::invalid_argument("register_views: " + std::to_string(views.size()) + " views but " +
                                std::to_string(angles_deg.size()) + " angles");
  if (views.empty()) throw std::invalid_argument("register_views: no views");
  if (!options.view_numbers.empty() && options.view_numbers.size() != views.size())
    throw std::invalid_argument("register_views: " + std::to_string(options.view_numbers.size()) +
                                " view numbers for " + std::to_string(views.size()) + " views");
  for (std::size_t i = 0; i < views.size(); ++i) {
    const std::string name =
        std::to_string(options.view_numbers.empty() ? static_cast<int>(i) : options.view_numbers[i]);
    check_view(views[i], "register_views: view " + name);
    if (!std::isfinite(angles_deg[i]))
      throw std::invalid_argument("register_views: angle of view " + name + " is not finite");
  }
  if (auto s = turntable.cam_from_table.check("turntable.cam_from_table"); !s)
    throw std::invalid_argument("register_views: " + s.error().message);

  const int n = static_cast<int>(views.size());
  RegistrationResult result;
  result.mode = options.mode;
  result.views.resize(views.size());
  std::vector<Eigen::Isometry3d> poses(views.size());
  for (std::size_t i = 0; i < views.size(); ++i) {
    poses[i] = coarse_table_from_view(turntable, angles_deg[i]);
    result.views[i].coarse_table_from_view = poses[i];
  }
  // One nearest-point tree per view (~0.1 s each at 1M points, itself on two threads): built
  // side by side, they are independent.
  std::vector<ViewData> data(views.size());
  tbb::parallel_for(std::size_t{0}, views.size(), [&](std::size_t i) {
    data[i] = make_view(views[i], options.icp.source_points_per_view, options.icp.seed + i);
  });

  std::vector<std::pair<int, int>> neighbours;
  for (int i = 0; i + 1 < n; ++i) neighbours.emplace_back(i, i + 1);
  if (options.close_loop && n > 2) neighbours.emplace_back(n - 1, 0);

  if (n > 1) {
    std::vector<std::pair<int, int>> directed;  // every neighbouring pair, both ways
    for (auto [a, b] : neighbours) {
      directed.emplace_back(a, b);
      directed.emplace_back(b, a);
    }
    if (options.mode == RefinementMode::turntable) {
      detail::TurntablePoses model(turntable, angles_deg);
      JointIcp icp(data, poses, std::vector<bool>(views.size(), false), directed, options.icp,
                   options.turntable_prior_deg, options.turntable_prior_mm, &interrupt, options.view_numbers);
      icp.use_turntable(&model);
      result.iterations = icp.run();
      result.axis_tilt_deg = model.axis_tilt_deg();
      result.axis_shift_mm = model.axis_shift_mm();
      for (std::size_t i = 0; i < views.size(); ++i)
        result.views[i].angle_correction_deg = model.angle_correction_deg(i);
    } else if (options.mode == RefinementMode::joint) {
      std::vector<bool> fixed(views.size(), false);
      fixed[0] = true;
      JointIcp icp(data, poses, fixed, directed, options.icp, options.turntable_prior_deg, options.turntable_prior_mm,
                   &interrupt, options.view_numbers);
      result.iterations = icp.run();
    } else {
      // Chain: register view i onto view i-1 (as placed so far), starting from their coarse
      // relative pose.
      for (int i = 1; i < n; ++i) {
        std::vector<Eigen::Isometry3d> pair_poses{result.views[static_cast<std::size_t>(i - 1)].coarse_table_from_view,
                                                  result.views[static_cast<std::size_t>(i)].coarse_table_from_view};
        std::vector<ViewData> pair_data;
        pair_data.push_back(make_view(views[static_cast<std::size_t>(i - 1)], options.icp.source_points_per_view,
                                      options.icp.seed + static_cast<std::uint64_t>(i) - 1));
        pair_data.push_back(make_view(views[static_cast<std::size_t>(i)], options.icp.source_points_per_view,
                                      options.icp.seed + static_cast<std::uint64_t>(i)));
        std::vector<int> pair_numbers;
        if (!options.view_numbers.empty())
          pair_numbers = {options.view_numbers[static_cast<std::size_t>(i - 1)],
                          options.view_numbers[static_cast<std::size_t>(i)]};
        JointIcp icp(pair_data, pair_poses, {true, false}, {{1, 0}, {0, 1}}, options.icp, 0, 0, &interrupt,
                     pair_numbers);
        result.iterations += icp.run();
        const Eigen::Isometry3d prev_from_this = pair_poses[0].inverse() * pair_poses[1];
        poses[static_cast<std::size_t>(i)] = poses[static_cast<std::size_t>(i - 1)] * prev_from_this;
      }
    }
  }

  // Residuals at the final poses and the last gate, per pair and per view.
  std::vector<bool> all_fixed(views.size(), true);
  const JointIcp evaluator(data, poses, all_fixed, {}, options.icp);
  std::vector<double> view_sum2(views.size(), 0.0);
  std::vector<std::size_t> view_count(views.size(), 0);
  for (auto [a, b] : neighbours) {
    double pair_sum2 = 0;
    std::size_t pair_count = 0;
    for (const auto& [s, t] : {std::pair{a, b}, std::pair{b, a}}) {
      for (const auto& c : evaluator.correspondences(s, t, options.icp.gates_mm.back())) {
        const double r2 = c.r * c.r;
        pair_sum2 += r2;
        ++pair_count;
        view_sum2[static_cast<std::size_t>(s)] += r2;
        view_sum2[static_cast<std::size_t>(t)] += r2;
        ++view_count[static_cast<std::size_t>(s)];
        ++view_count[static_cast<std::size_t>(t)];
      }
    }
    result.pairs.push_back(
        {a, b, pair_count ? std::sqrt(pair_sum2 / static_cast<double>(pair_count)) : 0.0, pair_count});
  }
  for (std::size_t i = 0; i < views.size(); ++i) {
    auto& v = result.views[i];
    v.table_from_view = poses[i];
    const Eigen::Isometry3d correction = poses[i] * v.coarse_table_from_view.inverse();
    v.correction_deg = rotation_angle_deg(correction);
    v.correction_mm = translation_mm(correction);
    v.correspondences = view_count[i];
    v.residual_rms_mm = view_count[i] ? std::sqrt(view_sum2[i] / static_cast<double>(view_count[i])) : 0.0;
  }
  return result;
}

RegistrationResult register_views_with_points(const std::vector<PointCloud>& views,
                                              const std::vector<double>& angles_deg,
                                              const slproto::TurntableCalibration& turntable,
                                              const RegistrationOptions& options, const InterruptionPoint& interrupt) {
  std::vector<std::size_t> with_points;
  for (std::size_t i = 0; i < views.size(); ++i)
    if (views[i].size() > 0) with_points.push_back(i);
  if (with_points.size() == views.size()) return register_views(views, angles_deg, turntable, options, interrupt);
  if (views.size() != angles_deg.size() ||
      (!options.view_numbers.empty() && options.view_numbers.size() != views.size()))
    throw std::invalid_argument("register_views_with_points: " + std::to_string(views.size()) + " views, " +
                                std::to_string(angles_deg.size()) + " angles and " +
                                std::to_string(options.view_numbers.size()) + " view numbers");
  if (with_points.size() < 2)
    throw std::runtime_error("only " + std::to_string(with_points.size()) + " of " + std::to_string(views.size()) +
                             " views have points: nothing to register them against");
  // A copy of the views with points: this is the rare case (a view with nothing measured).
  std::vector<PointCloud> subset;
  std::vector<double> subset_angles;
  RegistrationOptions subset_options = options;
  subset_options.view_numbers.clear();
  for (std::size_t i : with_points) {
    subset.push_back(views[i]);
    subset_angles.push_back(angles_deg[i]);
    subset_options.view_numbers.push_back(options.view_numbers.empty() ? static_cast<int>(i) : options.view_numbers[i]);
  }
  const RegistrationResult registered = register_views(subset, subset_angles, turntable, subset_options, interrupt);
  RegistrationResult result;
  result.iterations = registered.iterations;
  result.mode = registered.mode;
  result.axis_tilt_deg = registered.axis_tilt_deg;
  result.axis_shift_mm = registered.axis_shift_mm;
  result.views.resize(views.size());
  for (std::size_t i = 0; i < views.size(); ++i) {
    result.views[i].coarse_table_from_view = coarse_table_from_view(turntable, angles_deg[i]);
    result.views[i].table_from_view = result.views[i].coarse_table_from_view;
  }
  for (std::size_t k = 0; k < with_points.size(); ++k) result.views[with_points[k]] = registered.views[k];
  for (PairResidual pair : registered.pairs) {
    pair.view_a = static_cast<int>(with_points[static_cast<std::size_t>(pair.view_a)]);
    pair.view_b = static_cast<int>(with_points[static_cast<std::size_t>(pair.view_b)]);
    result.pairs.push_back(pair);
  }
  return result;
}

}  // namespace slscan::core
