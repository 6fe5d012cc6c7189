// The whole rig refined at once: camera, both projectors and every target pose.
#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

#include "levenberg_marquardt.hpp"
#include "pose_maths.hpp"
#include "slscan/core/calibration_solve.hpp"

namespace slscan::core {

using namespace calibration_detail;

RigBundle refine_rig_jointly(const CheckerboardTarget& target, const DeviceCalibration& camera,
                             const std::vector<TargetView>& camera_views,
                             const std::array<ProjectorObservations, 2>& projectors,
                             const LensModelOptions& camera_lens, const LensModelOptions& projector_lens) {
  target.check();
  const std::size_t n = camera_views.size();
  if (camera.from_target.size() != n)
    throw std::invalid_argument("rig refinement: " + std::to_string(n) + " camera views but " +
                                std::to_string(camera.from_target.size()) + " camera poses");
  for (std::size_t s = 0; s < 2; ++s) {
    if (projectors[s].views.size() != projectors[s].camera_view.size())
      throw std::invalid_argument("rig refinement: projector " + std::to_string(s) + " has " +
                                  std::to_string(projectors[s].views.size()) + " views but " +
                                  std::to_string(projectors[s].camera_view.size()) + " camera view indices");
    for (std::size_t v : projectors[s].camera_view)
      if (v >= n)
        throw std::invalid_argument("rig refinement: projector view refers to camera view " + std::to_string(v) +
                                    " of " + std::to_string(n));
  }
  // Layout: [camera 9 | per projector: 9 intrinsics + 6 proj_from_cam | 6 per target pose].
  const Eigen::Index projector_base = kIntrinsics;
  const Eigen::Index pose_base = kIntrinsics + 2 * (kIntrinsics + 6);
  Eigen::VectorXd x(pose_base + 6 * static_cast<Eigen::Index>(n));
  const auto put_intrinsics = [&](Eigen::Index at, const PinholeModel& m) {
    x.segment<kIntrinsics>(at) << m.fx, m.fy, m.cx, m.cy, m.distortion.k1, m.distortion.k2, m.distortion.p1,
        m.distortion.p2, m.distortion.k3;
  };
  const auto put_pose = [&](Eigen::Index at, const RigidTransform& t) {
    const Pose p = Pose::from(t);
    x.segment<3>(at) = p.w;
    x.segment<3>(at + 3) = p.t;
  };
  put_intrinsics(0, camera.model);
  for (std::size_t s = 0; s < 2; ++s) {
    const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6);
    put_intrinsics(at, projectors[s].start.intrinsics);
    put_pose(at + kIntrinsics, projectors[s].start.cam_from_proj.inverse());
  }
  for (std::size_t i = 0; i < n; ++i) put_pose(pose_base + 6 * static_cast<Eigen::Index>(i), camera.from_target[i]);
  const Eigen::VectorXd start = x;

  // Lens terms each device's options leave out stay at their start value.
  const auto free_terms = [](const LensModelOptions& lens) {
    return std::array<bool, kIntrinsics>{true,   true, true, true, true, lens.k2, lens.tangential, lens.tangential,
                                         lens.k3};
  };
  const std::array<bool, kIntrinsics> camera_free = free_terms(camera_lens);
  const std::array<bool, kIntrinsics> projector_free = free_terms(projector_lens);
  // Weights: each device's corner noise, as its separate solve measured it (floored so a
  // perfect synthetic device cannot take all the weight).
  const double camera_weight = 1.0 / std::max(camera.rms_px, 0.005);
  std::array<double, 2> projector_weight{};
  Eigen::Index residual_count = 0;
  for (const TargetView& v : camera_views) residual_count += 2 * static_cast<Eigen::Index>(v.corners.size());
  for (std::size_t s = 0; s < 2; ++s) {
    projector_weight[s] = 1.0 / std::max(projectors[s].start.reprojection_rms_px, 0.005);
    for (const TargetView& v : projectors[s].views) residual_count += 2 * static_cast<Eigen::Index>(v.corners.size());
  }

  const auto unpack = [&](const Eigen::VectorXd& params) {
    Eigen::VectorXd full = params;
    for (int j = 0; j < kIntrinsics; ++j) {
      if (!camera_free[static_cast<std::size_t>(j)]) full(j) = start(j);
      for (std::size_t s = 0; s < 2; ++s) {
        const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6) + j;
        if (!projector_free[static_cast<std::size_t>(j)]) full(at) = start(at);
      }
    }
    return full;
  };
  auto residuals = [&](const Eigen::VectorXd& params) {
    const Eigen::VectorXd full = unpack(params);
    const PinholeModel cam = intrinsics_from(full.head<kIntrinsics>(), camera.model.width, camera.model.height);
    std::array<PinholeModel, 2> proj;
    std::array<Pose, 2> proj_from_cam;
    std::array<Eigen::Matrix3d, 2> rpc;
    for (std::size_t s = 0; s < 2; ++s) {
      const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6);
      proj[s] = intrinsics_from(full.segment<kIntrinsics>(at), projectors[s].start.intrinsics.width,
                                projectors[s].start.intrinsics.height);
      proj_from_cam[s] = pose_at(full, at + kIntrinsics);
      rpc[s] = proj_from_cam[s].R();
    }
    std::vector<Pose> poses(n);
    std::vector<Eigen::Matrix3d> rotations(n);
    for (std::size_t i = 0; i < n; ++i) {
      poses[i] = pose_at(full, pose_base + 6 * static_cast<Eigen::Index>(i));
      rotations[i] = poses[i].R();
    }
    Eigen::VectorXd out(residual_count);
    Eigen::Index k = 0;
    for (std::size_t i = 0; i < n; ++i)
      for (const CornerObservation& c : camera_views[i].corners) {
        const Eigen::Vector3d pc = rotations[i] * target.corner(c.id) + poses[i].t;
        out.segment<2>(k) = camera_weight * (project(cam, pc) - c.pixel);
        k += 2;
      }
    for (std::size_t s = 0; s < 2; ++s)
      for (std::size_t v = 0; v < projectors[s].views.size(); ++v) {
        const std::size_t i = projectors[s].camera_view[v];
        for (const CornerObservation& c : projectors[s].views[v].corners) {
          const Eigen::Vector3d pc = rotations[i] * target.corner(c.id) + poses[i].t;
          out.segment<2>(k) = projector_weight[s] * (project(proj[s], rpc[s] * pc + proj_from_cam[s].t) - c.pixel);
          k += 2;
        }
      }
    return out;
  };
  Eigen::VectorXd step = Eigen::VectorXd::Constant(x.size(), 1e-6);
  step.head<4>().setConstant(1e-3);
  for (std::size_t s = 0; s < 2; ++s) {
    const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6);
    step.segment<4>(at).setConstant(1e-3);
    step.segment<3>(at + kIntrinsics + 3).setConstant(1e-5);
  }
  for (Eigen::Index i = pose_base + 3; i < x.size(); i += 6) step.segment<3>(i).setConstant(1e-5);
  levenberg_marquardt(residuals, x, step, 50);
  x = unpack(x);

  RigBundle out;
  out.camera.model = intrinsics_from(x.head<kIntrinsics>(), camera.model.width, camera.model.height);
  if (auto status = out.camera.model.check("rig refinement (camera)"); !status)
    throw std::runtime_error(status.error().message + " (are the views varied enough?)");
  double sum = 0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < n; ++i) {
    out.camera.from_target.push_back(pose_at(x, pose_base + 6 * static_cast<Eigen::Index>(i)).transform());
    const double rms = view_reprojection_rms(target, out.camera.model, out.camera.from_target[i], camera_views[i]);
    out.camera.view_rms_px.push_back(rms);
    sum += rms * rms * static_cast<double>(camera_views[i].corners.size());
    count += camera_views[i].corners.size();
  }
  out.camera.rms_px = std::sqrt(sum / static_cast<double>(count));
  for (std::size_t s = 0; s < 2; ++s) {
    const Eigen::Index at = projector_base + static_cast<Eigen::Index>(s) * (kIntrinsics + 6);
    slproto::ProjectorCalibration& p = out.projectors[s];
    p.intrinsics = intrinsics_from(x.segment<kIntrinsics>(at), projectors[s].start.intrinsics.width,
                                   projectors[s].start.intrinsics.height);
    if (auto status = p.intrinsics.check("rig refinement (projector)"); !status)
      throw std::runtime_error(status.error().message + " (are the views varied enough?)");
    const RigidTransform proj_from_cam = pose_at(x, at + kIntrinsics).transform();
    p.cam_from_proj = proj_from_cam.inverse();
    double psum = 0;
    std::size_t pcount = 0;
    for (std::size_t v = 0; v < projectors[s].views.size(); ++v) {
      const double rms = view_reprojection_rms(target, p.intrinsics,
                                               proj_from_cam * out.camera.from_target[projectors[s].camera_view[v]],
                                               projectors[s].views[v]);
      out.projector_view_rms_px[s].push_back(rms);
      psum += rms * rms * static_cast<double>(projectors[s].views[v].corners.size());
      pcount += projectors[s].views[v].corners.size();
    }
    p.reprojection_rms_px = std::sqrt(psum / static_cast<double>(std::max<std::size_t>(pcount, 1)));
  }
  return out;
}

}  // namespace slscan::core
