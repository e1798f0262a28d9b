#pragma once
// Saint Venant-Kirchhoff (method.md, "Internal forces and stiffness"):
//
//   psi(F) = mu E:E + lambda/2 tr^2(E),   E = (F^T F - I) / 2
//   P      = F S,   S = 2 mu E + lambda tr(E) I   (second Piola-Kirchhoff stress)
//   dP     = dF S + F dS,   dS = 2 mu dE + lambda tr(dE) I,   dE = sym(F^T dF)
//
// In indices (a = 3 j + i, b = 3 l + k; vec column-major):
//   dP_ij/dF_kl = delta_ik S_lj + mu (F_il F_kj + (F F^T)_ik delta_jl) + lambda F_kl F_ij,
// i.e. block (j, l) of dP/dF (rows 3j.., columns 3l..) is
//   S_lj I + mu (delta_jl F F^T + f_l f_j^T) + lambda f_j f_l^T,   f_j = column j of F.
// Defined for every F (no inversion barrier; the energy grows as F -> 0 collapses).
// E is formed from D = F - I as (D + D^T + D^T D) / 2, which keeps psi accurate to
// relative round-off near the rest state (F^T F - I would cancel).
#include <softdiff/material/kernel_util.hpp>

namespace softdiff::material::stvk {

template <class T>
T psi(const Eigen::Matrix<T, 3, 3>& F, double mu, double lambda) {
  using M = Eigen::Matrix<T, 3, 3>;
  const M D = F - M::Identity();
  const M E = (D + D.transpose() + D.transpose() * D) * T(0.5);
  const T t = E.trace();
  return T(mu) * E.cwiseProduct(E).sum() + T(0.5 * lambda) * t * t;
}

inline void stress(const Mat3& F, double mu, double lambda, Mat3& P, Mat9* dP_dF) {
  const Mat3 D = F - Mat3::Identity();
  Mat3 E = D + D.transpose();
  E.noalias() += D.transpose() * D;
  E *= 0.5;
  Mat3 S = (2.0 * mu) * E;
  S.diagonal().array() += lambda * E.trace();
  P.noalias() = F * S;
  if (dP_dF == nullptr) return;
  Mat3 FFt;
  FFt.noalias() = F * F.transpose();
  for (int l = 0; l < 3; ++l)
    for (int j = 0; j < 3; ++j) {
      auto blk = dP_dF->block<3, 3>(3 * j, 3 * l);
      blk.noalias() = mu * F.col(l) * F.col(j).transpose();
      blk.noalias() += lambda * F.col(j) * F.col(l).transpose();
      if (j == l) blk += mu * FFt;
      blk.diagonal().array() += S(l, j);
    }
}

// d(dP/dF)[dF]: differentiate each block in the direction dF (constant in F: the
// energy is a quartic polynomial, so this is exact everywhere):
//   dS_lj I + mu (delta_jl (dF F^T + F dF^T) + dF_l f_j^T + f_l dF_j^T)
//           + lambda (dF_j f_l^T + f_j dF_l^T),   dF_j = column j of dF.
inline void stress_hessian_directional(const Mat3& F, double mu, double lambda, const Mat3& dF, Mat9& out) {
  Mat3 dE;
  dE.noalias() = F.transpose() * dF;
  dE = 0.5 * (dE + dE.transpose()).eval();
  Mat3 dS = (2.0 * mu) * dE;
  dS.diagonal().array() += lambda * dE.trace();
  Mat3 sym2;
  sym2.noalias() = dF * F.transpose();
  sym2 += sym2.transpose().eval();
  for (int l = 0; l < 3; ++l)
    for (int j = 0; j < 3; ++j) {
      auto blk = out.block<3, 3>(3 * j, 3 * l);
      blk.noalias() = mu * dF.col(l) * F.col(j).transpose();
      blk.noalias() += mu * F.col(l) * dF.col(j).transpose();
      blk.noalias() += lambda * dF.col(j) * F.col(l).transpose();
      blk.noalias() += lambda * F.col(j) * dF.col(l).transpose();
      if (j == l) blk += mu * sym2;
      blk.diagonal().array() += dS(l, j);
    }
}

}  // namespace softdiff::material::stvk
