#pragma once
// Compressible Neo-Hookean, SOFA's and Bonet & Wood's form (method.md, "Internal forces
// and stiffness"):
//
//   psi(F) = mu/2 (tr(F^T F) - 3) - mu ln J + lambda/2 (ln J)^2,   J = det F
//   P      = mu (F - F^{-T}) + lambda ln J F^{-T}
//   dP     = mu dF + (mu - lambda ln J) F^{-T} dF^T F^{-T} + lambda (F^{-T}:dF) F^{-T}
//
// using d F^{-T} = -F^{-T} dF^T F^{-T} and d ln J = F^{-T}:dF. With G = F^{-T}
// (= cof(F) / J) and c = mu - lambda ln J, in indices (a = 3 j + i, b = 3 l + k):
//   dP_ij/dF_kl = mu delta_ik delta_jl + c G_il G_kj + lambda G_kl G_ij,
// i.e. block (j, l) of dP/dF is  mu delta_jl I + c g_l g_j^T + lambda g_j g_l^T.
// Undefined for J <= 0: psi is +infinity, stress() returns false (also for a
// non-finite J). psi is evaluated through D = F - I (tr(F^T F) - 3 = ||D||^2 + 2 tr D,
// and for J > 1/2, ln J = log1p(I1(D) + I2(D) + I3(D))) so that it keeps full relative
// accuracy near the rest state, where its terms would otherwise cancel.
#include <softdiff/material/kernel_util.hpp>

#include <cmath>
#include <limits>
#include <type_traits>

namespace softdiff::material::neo_hookean {

template <class T>
T psi(const Eigen::Matrix<T, 3, 3>& F, double mu, double lambda) {
  using M = Eigen::Matrix<T, 3, 3>;
  // J exactly as stress() computes it, so that both agree on where the law is defined.
  const T J = detail::det_from_cofactor(F, detail::cofactor(F));
  if (!(detail::value_of(J) > 0.0)) return T(std::numeric_limits<double>::infinity());
  const M D = F - M::Identity();
  const T i1 = D.trace();
  T ln_J;
  if (detail::value_of(J) > 0.5) {
    // ln J = log1p(J - 1), J - 1 = I1(D) + I2(D) + I3(D) without the cancellation of J - 1.
    const T i3 = detail::det_from_cofactor(D, detail::cofactor(D));
    const T i2 = T(0.5) * (i1 * i1 - D.cwiseProduct(D.transpose()).sum());
    const T J_minus_1 = i1 + i2 + i3;
    if constexpr (std::is_floating_point_v<T>) {
      ln_J = std::log1p(J_minus_1);
    } else {
      using std::log;
      ln_J = log(T(1.0) + J_minus_1);
    }
  } else {
    using std::log;
    ln_J = log(J);
  }
  return T(0.5 * mu) * (D.cwiseProduct(D).sum() + T(2.0) * i1) - T(mu) * ln_J + T(0.5 * lambda) * ln_J * ln_J;
}

// F^{-T} and ln J; false if J <= 0 or J is not finite.
inline bool inverse_transpose_and_log_det(const Mat3& F, Mat3& G, double& ln_J) {
  G = detail::cofactor(F);
  const double J = detail::det_from_cofactor(F, G);
  if (!(J > 0.0) || !std::isfinite(J)) return false;
  G /= J;
  ln_J = std::log(J);
  return true;
}

inline bool stress(const Mat3& F, double mu, double lambda, Mat3& P, Mat9* dP_dF) {
  Mat3 G;
  double ln_J;
  if (!inverse_transpose_and_log_det(F, G, ln_J)) return false;
  P = mu * F + (lambda * ln_J - mu) * G;
  if (dP_dF == nullptr) return true;
  const double c = mu - lambda * ln_J;
  for (int l = 0; l < 3; ++l)
    for (int j = 0; j < 3; ++j) {
      auto blk = dP_dF->block<3, 3>(3 * j, 3 * l);
      blk.noalias() = c * G.col(l) * G.col(j).transpose();
      blk.noalias() += lambda * G.col(j) * G.col(l).transpose();
      if (j == l) blk.diagonal().array() += mu;
    }
  return true;
}

// d(dP/dF)[dF]: with dG = -G dF^T G and dc = -lambda G:dF, block (j, l) is
//   dc g_l g_j^T + c (dg_l g_j^T + g_l dg_j^T) + lambda (dg_j g_l^T + g_j dg_l^T).
inline bool stress_hessian_directional(const Mat3& F, double mu, double lambda, const Mat3& dF, Mat9& out) {
  Mat3 G;
  double ln_J;
  if (!inverse_transpose_and_log_det(F, G, ln_J)) return false;
  const double c = mu - lambda * ln_J;
  const double dc = -lambda * G.cwiseProduct(dF).sum();
  Mat3 dG;
  dG.noalias() = -G * dF.transpose() * G;
  for (int l = 0; l < 3; ++l)
    for (int j = 0; j < 3; ++j) {
      auto blk = out.block<3, 3>(3 * j, 3 * l);
      blk.noalias() = dc * G.col(l) * G.col(j).transpose();
      blk.noalias() += c * dG.col(l) * G.col(j).transpose();
      blk.noalias() += c * G.col(l) * dG.col(j).transpose();
      blk.noalias() += lambda * dG.col(j) * G.col(l).transpose();
      blk.noalias() += lambda * G.col(j) * dG.col(l).transpose();
    }
  return true;
}

}  // namespace softdiff::material::neo_hookean
