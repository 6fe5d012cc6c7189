// The Levenberg-Marquardt every calibration refinement runs. Private to slscan_core.
#pragma once

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

namespace slscan::core::calibration_detail {

// Minimises |residuals(x)|^2 with Levenberg-Marquardt on a central-difference Jacobian.
// The problems here have tens of parameters and a few thousand residuals, so a dense
// Jacobian is cheap next to the image work that produced the corners.
template <class Residuals>
void levenberg_marquardt(Residuals&& residuals, Eigen::VectorXd& x, const Eigen::VectorXd& step, int max_iterations) {
  Eigen::VectorXd r = residuals(x);
  double cost = r.squaredNorm();
  double lambda = 1e-3;
  Eigen::MatrixXd jacobian(r.size(), x.size());
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    for (Eigen::Index j = 0; j < x.size(); ++j) {
      Eigen::VectorXd xp = x, xm = x;
      xp(j) += step(j);
      xm(j) -= step(j);
      jacobian.col(j) = (residuals(xp) - residuals(xm)) / (2.0 * step(j));
    }
    const Eigen::MatrixXd jtj = jacobian.transpose() * jacobian;
    const Eigen::VectorXd jtr = jacobian.transpose() * r;
    bool improved = false;
    for (int attempt = 0; attempt < 12 && !improved; ++attempt) {
      Eigen::MatrixXd a = jtj;
      // A parameter the residuals ignore (a lens term held fixed) gets a unit diagonal, so its
      // step is exactly zero instead of a division by nothing.
      for (Eigen::Index j = 0; j < a.rows(); ++j) a(j, j) = jtj(j, j) > 0 ? jtj(j, j) * (1.0 + lambda) : 1.0;
      const Eigen::VectorXd dx = a.ldlt().solve(-jtr);
      const Eigen::VectorXd candidate = x + dx;
      const Eigen::VectorXd rc = residuals(candidate);
      const double candidate_cost = rc.squaredNorm();
      if (std::isfinite(candidate_cost) && candidate_cost < cost) {
        const double gain = (cost - candidate_cost) / std::max(cost, 1e-300);
        x = candidate;
        r = rc;
        cost = candidate_cost;
        lambda = std::max(lambda * 0.3, 1e-12);
        improved = true;
        if (gain < 1e-12 || dx.cwiseAbs().cwiseQuotient(step).maxCoeff() < 1e-6) return;
      } else {
        lambda *= 10;
      }
    }
    if (!improved) return;
  }
}

}  // namespace slscan::core::calibration_detail
