#pragma once
// Linear (small-strain) elasticity, a softdiff extension (SOFA's method="small"):
//
//   psi(F) = mu eps:eps + lambda/2 tr^2(eps),   eps = (F + F^T)/2 - I
//   P      = 2 mu eps + lambda tr(eps) I
//   dP_ij/dF_kl = mu (delta_ik delta_jl + delta_il delta_jk) + lambda delta_ij delta_kl
//
// Not rotation invariant (valid for small rotations only), but its stiffness is
// constant: a scene whose bodies are all `linear` has a constant system matrix,
// factorized once per run. It equals every other law's linearization at F = I.
#include <softdiff/material/kernel_util.hpp>

namespace softdiff::material::linear {

template <class T>
T psi(const Eigen::Matrix<T, 3, 3>& F, double mu, double lambda) {
  using M = Eigen::Matrix<T, 3, 3>;
  const M eps = (F + F.transpose()) * T(0.5) - M::Identity();
  const T t = eps.trace();
  return T(mu) * eps.cwiseProduct(eps).sum() + T(0.5 * lambda) * t * t;
}

inline void stress(const Mat3& F, double mu, double lambda, Mat3& P, Mat9* dP_dF) {
  Mat3 eps = 0.5 * (F + F.transpose());
  eps.diagonal().array() -= 1.0;
  P = (2.0 * mu) * eps;
  P.diagonal().array() += lambda * eps.trace();
  if (dP_dF == nullptr) return;
  dP_dF->setZero();
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 3; ++i) {
      (*dP_dF)(3 * j + i, 3 * j + i) += mu;  // delta_ik delta_jl
      (*dP_dF)(3 * j + i, 3 * i + j) += mu;  // delta_il delta_jk
      if (i == j)
        for (int k = 0; k < 3; ++k) (*dP_dF)(3 * j + i, 3 * k + k) += lambda;
    }
}

}  // namespace softdiff::material::linear
