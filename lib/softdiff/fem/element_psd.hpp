#pragma once
// psd_projection at a fraction of its cost (method.md "Elements and materials").
//
// The projection is unchanged: K~_e = (K_e)+, the nearest PSD matrix to the element
// Hessian (material::clamp_negative_eigenvalues). Two facts make it cheap:
//
// 1. The skip. K_e = sum_q V_q B_q^T C_q B_q with C_q = dP/dF at point q (9 x 9). If
//    every C_q is PSD, K_e is PSD (a sum of congruences of PSD matrices) and the
//    projection leaves it alone. For the linear tetrahedron the converse holds too:
//    B (9 x 12) has rank 9 (its kernel is the 3 translations), so every vec(dF) is
//    some B u and u^T K_e u = V vec(dF)^T C vec(dF): K_e is PSD exactly when C is. The
//    test is a Cholesky factorization (LLT, ~120 multiply-adds) of C + s I with
//    s = 1e-12 sum_i |C_ii|: an element whose C has no eigenvalue below -s is kept as
//    assembled. Without the shift, the exact zero eigenvalues of C (the corotational
//    and Neo-Hookean twist modes at rest) would fail it on round-off. The old code
//    clamped eigenvalues of K_e in [-1e-12, 0) relative too; the difference is a change
//    of K_e below 1e-12 of its size.
// 2. The reduction (linear tetrahedra). With Q (4 x 3) an orthonormal basis of the
//    vectors of R^4 whose entries sum to 0 (tet4_deformation_basis) and G (3 x 4) the
//    shape gradients (G 1 = 0, so G = G Q Q^T), B = B_H (Q (x) I3)^T where B_H is the
//    "B" of the 3 x 3 gradients H = G Q. So
//        K_e = Q_b C^ Q_b^T,   C^ = V B_H^T C B_H (9 x 9),   Q_b = Q (x) I3 (12 x 9),
//    Q_b has orthonormal columns, and the projection commutes with it:
//        (K_e)+ = Q_b (C^)+ Q_b^T.
//    A 9 x 9 eigendecomposition replaces the 12 x 12 one; the result is the same
//    matrix (to round-off: tests/fem/test_element_psd.cpp). The 3 eigenvalues of K_e
//    that C^ lacks are the translations' zeros, which the projection keeps.
//    The derivative (Daleckii-Krein, material::PsdProjectionDerivative) reduces the
//    same way: for a direction dK = V B^T dC B, Q_b^T dK Q_b = V B_H^T dC B_H and
//    D(dK) = Q_b D^(Q_b^T dK Q_b) Q_b^T with D^ the 9 x 9 derivative at C^; in the
//    reverse mode only B D(Y) B^T is used, and the blocks of D(Y) outside Q_b's range
//    vanish under B, so B D(Y) B^T = B_H D^(Q_b^T Y Q_b) B_H^T. The tie rule (equal
//    eigenvalues to 1e-12 of the spectral radius) is the 12 x 12 one: the zeros C^
//    lacks do not change the spectral radius.
// The 10-node element keeps the 30 x 30 projection (its kernel is the same 3
// translations: 27 of 30 would be saved) after the skip.
#include <softdiff/fem/assembly.hpp>
#include <softdiff/material/psd.hpp>

#include <Eigen/Cholesky>
#include <cmath>

namespace softdiff::fem {

// True when C (9 x 9, symmetric) has no eigenvalue below -1e-12 sum_i |C_ii| (see 1.).
inline bool tangent_is_psd(const Mat9& C) {
  Mat9 A = C;
  A.diagonal().array() += 1e-12 * C.diagonal().cwiseAbs().sum();
  const Eigen::LLT<Mat9, Eigen::Lower> llt(A);
  return llt.info() == Eigen::Success;
}

// Q (4 x 3): orthonormal columns, each summing to 0 (Helmert's basis).
inline const Eigen::Matrix<double, 4, 3>& tet4_deformation_basis() {
  static const Eigen::Matrix<double, 4, 3> Q = [] {
    Eigen::Matrix<double, 4, 3> q;
    q << 1, 1, 1,  //
        -1, 1, 1,  //
        0, -2, 1,  //
        0, 0, -3;
    q.col(0) /= std::sqrt(2.0);
    q.col(1) /= std::sqrt(6.0);
    q.col(2) /= std::sqrt(12.0);
    return q;
  }();
  return Q;
}

// Q_b = Q (x) I3 (12 x 9): Q_b(3a+i, 3l+k) = Q(a, l) delta_ik.
inline const Eigen::Matrix<double, 12, 9>& tet4_deformation_basis_3d() {
  static const Eigen::Matrix<double, 12, 9> Qb = [] {
    Eigen::Matrix<double, 12, 9> q = Eigen::Matrix<double, 12, 9>::Zero();
    for (int a = 0; a < 4; ++a)
      for (int l = 0; l < 3; ++l)
        for (int i = 0; i < 3; ++i) q(3 * a + i, 3 * l + i) = tet4_deformation_basis()(a, l);
    return q;
  }();
  return Qb;
}

// C^ = V B_H^T C B_H for H = G Q.
inline Mat9 tet4_reduced_stiffness(const Mat9& C, const Mat3& H, double volume) {
  Mat9 C_hat = Mat9::Zero();
  add_stiffness_from_tangent<3>(C, H, volume, C_hat);
  return C_hat;
}

// K_e = V B^T C B of a linear tetrahedron (G = shape gradients, 3 x 4), projected when
// `project` (psd_projection): kept as assembled when C passes tangent_is_psd or C^ has
// no negative eigenvalue, else Q_b (C^)+ Q_b^T.
inline void tet4_stiffness(const Mat9& C, const Eigen::Matrix<double, 3, 4>& G, double volume, bool project,
                           Mat12& K_e) {
  if (project && !tangent_is_psd(C)) {
    const Mat3 H = G * tet4_deformation_basis();
    const Mat9 C_hat = tet4_reduced_stiffness(C, H, volume);
    const Eigen::SelfAdjointEigenSolver<Mat9> eig(C_hat, Eigen::ComputeEigenvectors);
    if (eig.eigenvalues()(0) < 0.0) {
      const Mat9 Qc = eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).asDiagonal();
      const Mat9 C_plus = Qc * eig.eigenvectors().transpose();
      const auto& Qb = tet4_deformation_basis_3d();
      const Eigen::Matrix<double, 12, 9> T = Qb * C_plus;
      K_e.noalias() = T * Qb.transpose();
      return;
    }
  }
  element_stiffness_from_tangent(C, G, volume, K_e);
}

// The derivative of tet4_stiffness's projection at (C, G, V) (see 2.).
struct Tet4PsdDerivative {
  material::PsdProjectionDerivative<9> reduced;
  Mat3 H;
  bool identity = true;  // K_e kept as assembled: D = identity

  void compute(const Mat9& C, const Eigen::Matrix<double, 3, 4>& G, double volume) {
    identity = true;
    if (tangent_is_psd(C)) return;
    H = G * tet4_deformation_basis();
    reduced.compute(tet4_reduced_stiffness(C, H, volume));
    identity = reduced.identity;
  }
  // D(V B^T dC B) w_e (12), for a tangent direction dC (9 x 9, symmetric). Not identity.
  Vec12 apply_tangent(const Mat9& dC, double volume, const Vec12& w_e) const {
    const auto& Qb = tet4_deformation_basis_3d();
    const Mat9 D = reduced.apply(tet4_reduced_stiffness(dC, H, volume));
    const Eigen::Matrix<double, 9, 1> w_hat = Qb.transpose() * w_e;
    return Qb * (D * w_hat);
  }
  // B D(sym(y_e w_e^T)) B^T (9 x 9): the reverse mode's S^. Not identity.
  Mat9 reverse(const Vec12& y_e, const Vec12& w_e) const {
    const auto& Qb = tet4_deformation_basis_3d();
    const Eigen::Matrix<double, 9, 1> y_hat = Qb.transpose() * y_e, w_hat = Qb.transpose() * w_e;
    const Mat9 Y = 0.5 * (y_hat * w_hat.transpose() + w_hat * y_hat.transpose());
    const Mat9 S = reduced.apply(Y);
    // B_H S B_H^T with B_H(3j+i, 3l+i) = H(j, l): entry (3j+i, 3m+k) =
    // sum_{l,n} H(j,l) S(3l+i, 3n+k) H(m,n).
    Mat9 out;
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k) {
        Mat3 s;  // s(l, n) = S(3l+i, 3n+k)
        for (int l = 0; l < 3; ++l)
          for (int n = 0; n < 3; ++n) s(l, n) = S(3 * l + i, 3 * n + k);
        const Mat3 t = H * s * H.transpose();
        for (int j = 0; j < 3; ++j)
          for (int m = 0; m < 3; ++m) out(3 * j + i, 3 * m + k) = t(j, m);
      }
    return out;
  }
};

}  // namespace softdiff::fem
