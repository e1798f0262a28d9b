#pragma once
// Corotational elasticity (method.md, "Internal forces and stiffness"):
//
//   psi(F) = mu ||F - R||_F^2 + lambda/2 tr^2(R^T F - I),   F = R S (polar decomposition)
//   P      = 2 mu (F - R) + lambda tr(S - I) R
//   dP/dF  = 2 mu I_9 + lambda r r^T + c dR/dF,   r = vec(R),  c = lambda tr(S - I) - 2 mu
//
// P: d psi = 2 mu (F - R):(dF - dR) + lambda tr(S - I) d tr(S). With dR = R W (W skew),
// (F - R):R W = tr((S - I) W) = 0 (S - I symmetric, W skew), and
// d tr(S) = d tr(R^T F) = tr(W^T S) + R:dF = R:dF. Hence P above.
// dP = 2 mu dF + lambda (R:dF) R + c dR, which is the dP/dF above.
//
// Rotation gradient. Differentiating R^T F = S (symmetric) gives
//   W S + S W = R^T dF - dF^T R =: A (skew).
// With W = [w]_x, A = [a]_x and the identity S [w]_x + [w]_x S = [(tr(S) I - S) w]_x
// (S symmetric), w = B a with B = (tr(S) I - S)^{-1}. The axial vector of A is
// a = N^T vec(dF), where N (9x3) has columns n_m = vec(R [e_m]_x); and vec(dR) =
// vec(R [w]_x) = N w. So
//   dR/dF = N B N^T   (symmetric, 9x9, rank 3).
// In the SVD frame F = U diag(sigma) V^T, B = V diag(1/(sigma_2 + sigma_3),
// 1/(sigma_1 + sigma_3), 1/(sigma_1 + sigma_2)) V^T and N V has columns
// q_m = vec(U [e_m]_x V^T), so dR/dF = sum_m q_m q_m^T / (sigma_a + sigma_b),
// {a, b} = {1, 2, 3} \ {m}: the three "twist" modes of McAdams et al. 2011
// ("Efficient elasticity for character skinning with contact and collisions") and
// Kim & Eberle, "Dynamic Deformables: Implementation and Production Practicalities"
// (SIGGRAPH course notes, the rotation gradient and its twist eigenmatrices). This form
// is used for dP/dF: it does not depend on which singular vectors the SVD picked when
// singular values repeat (equal sigmas give equal weights), so it is well defined and
// exact at F = I and wherever singular values coincide.
//
// Polar decomposition and inversion. R comes from a signed ("rotation-variant") SVD:
// Eigen::JacobiSVD gives sigma_1 >= sigma_2 >= sigma_3 >= 0 and orthogonal U, V; if
// det U < 0 (resp. det V < 0) we negate U's (resp. V's) last column and sigma_3. Then U,
// V are proper rotations, R = U V^T is a rotation, S = V diag(sigma) V^T is symmetric
// (indefinite when det F < 0) and F = R S holds for every F, including inverted ones
// (Irving, Teran & Fedkiw 2004). sigma_3 is then the signed smallest singular value.
//
// When sigma_a + sigma_b -> 0. After the sign fix sigma_1 >= sigma_2 >= |sigma_3|, so
// every sigma_a + sigma_b >= 0, and only sigma_2 + sigma_3 can vanish: an inverted
// element whose two smallest stretches are equal in magnitude (e.g. F = diag(1, s, -s)),
// or F of rank <= 1. There the rotation of the polar decomposition is not unique (any
// half-turn in the (v_2, v_3) plane works), R(F) is discontinuous, and the exact
// dR/dF grows like 1/(sigma_2 + sigma_3). We clamp each denominator at
// kMinTwistDenominator (F is dimensionless, so an absolute floor): dP/dF stays finite
// and symmetric, psi and P are unaffected, and dP/dF is exact wherever no clamp is
// active (always in the FD tests). A clamped dP/dF is large and typically indefinite
// (c < 0 once tr(S) < 3 + 2 mu / lambda), which is what `psd_projection` is for.
//
// Allocation-free: fixed-size Eigen types only (JacobiSVD<Matrix3d> holds no heap data).
#include <softdiff/material/kernel_util.hpp>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>

namespace softdiff::material::corotational {

// Floor on sigma_a + sigma_b in dR/dF (see above).
inline constexpr double kMinTwistDenominator = 1e-8;

// Signed SVD F = U diag(sigma) V^T with U, V proper rotations, and R = U V^T.
struct Polar {
  Mat3 U;
  Mat3 V;
  Vec3 sigma;  // sigma_1 >= sigma_2 >= |sigma_3|; sigma_3 < 0 iff det F < 0
  Mat3 R;      // rotation of F = R S
  // S = V diag(sigma) V^T, the symmetric stretch.
  Mat3 stretch() const { return V * sigma.asDiagonal() * V.transpose(); }
};

// A non-finite F (JacobiSVD then reports InvalidInput) gives NaN everywhere, so that
// psi, P and dP/dF are NaN rather than uninitialized.
inline void polar_svd(const Mat3& F, Polar& p) {
  const Eigen::JacobiSVD<Mat3, Eigen::NoQRPreconditioner> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
  if (svd.info() != Eigen::Success) {
    constexpr double nan = std::numeric_limits<double>::quiet_NaN();
    p.U.setConstant(nan);
    p.V.setConstant(nan);
    p.sigma.setConstant(nan);
    p.R.setConstant(nan);
    return;
  }
  p.U = svd.matrixU();
  p.V = svd.matrixV();
  p.sigma = svd.singularValues();
  if (p.U.determinant() < 0.0) {
    p.U.col(2) *= -1.0;
    p.sigma(2) *= -1.0;
  }
  if (p.V.determinant() < 0.0) {
    p.V.col(2) *= -1.0;
    p.sigma(2) *= -1.0;
  }
  p.R.noalias() = p.U * p.V.transpose();
}

// psi from the SVD: ||F - R||^2 = ||diag(sigma) - I||^2, tr(R^T F - I) = sum(sigma) - 3.
inline double psi_from_polar(const Polar& p, double mu, double lambda) {
  const Vec3 e = p.sigma - Vec3::Ones();
  const double t = e.sum();
  return mu * e.squaredNorm() + 0.5 * lambda * t * t;
}

// Weights 1 / max(sigma_a + sigma_b, kMinTwistDenominator), {a, b} = {0, 1, 2} \ {m}
// (the sum is formed directly, not as tr - sigma_m, to keep its relative accuracy).
inline Vec3 twist_weights(const Vec3& sigma) {
  Vec3 w;
  for (int m = 0; m < 3; ++m)
    w(m) = 1.0 / std::max(sigma((m + 1) % 3) + sigma((m + 2) % 3), kMinTwistDenominator);
  return w;
}

// Twist modes q_m = vec(U [e_m]_x V^T) (columns of Q) and their weights w:
// dR/dF = Q diag(w) Q^T.
// U [e_m]_x V^T = u_a v_b^T - u_b v_a^T with a = m+2, b = m+1 (mod 3).
inline void twist_modes(const Polar& p, Eigen::Matrix<double, 9, 3>& Q, Vec3& w) {
  w = twist_weights(p.sigma);
  for (int m = 0; m < 3; ++m) {
    const int a = (m + 2) % 3, b = (m + 1) % 3;
    Eigen::Map<Mat3> q(Q.col(m).data());
    q.noalias() = p.U.col(a) * p.V.col(b).transpose();
    q.noalias() -= p.U.col(b) * p.V.col(a).transpose();
  }
}

// dP/dF = 2 mu I + lambda r r^T + c Q diag(w) Q^T.
inline void stress_derivative(const Polar& p, double mu, double lambda, Mat9& dP_dF) {
  const double c = lambda * (p.sigma.sum() - 3.0) - 2.0 * mu;
  Eigen::Matrix<double, 9, 3> Q;
  Vec3 w;
  twist_modes(p, Q, w);
  const Eigen::Map<const Vec9> r(p.R.data());
  dP_dF.setZero();
  dP_dF.diagonal().setConstant(2.0 * mu);
  dP_dF.noalias() += lambda * r * r.transpose();
  const Eigen::Matrix<double, 9, 3> Qw = Q * (c * w).asDiagonal();
  dP_dF.noalias() += Qw * Q.transpose();
}

// P (and dP/dF if requested) given the polar decomposition of F.
inline void stress(const Mat3& F, const Polar& p, double mu, double lambda, Mat3& P, Mat9* dP_dF) {
  const double tr_e = p.sigma.sum() - 3.0;
  P = 2.0 * mu * (F - p.R) + (lambda * tr_e) * p.R;
  if (dP_dF != nullptr) stress_derivative(p, mu, lambda, *dP_dF);
}

inline void stress(const Mat3& F, double mu, double lambda, Mat3& P, Mat9* dP_dF) {
  Polar p;
  polar_svd(F, p);
  stress(F, p, mu, lambda, P, dP_dF);
}

// d(dP/dF)[dF], the derivative of dP/dF in the direction dF (the third derivative of psi
// contracted with vec(dF); symmetric 9x9). With H = 2 mu I + lambda r r^T + c D,
// D = dR/dF = N B N^T (see the header comment), and in direction E = dF:
//   w_E = B N^T vec(E), dR = R [w_E]_x, r_E = vec(dR),   dc = lambda R:E,
//   dN has columns vec(dR [e_m]_x),
//   dS = R^T E - [w_E]_x S (symmetric), dB = -B (tr(dS) I - dS) B, tr(dS) = R:E,
//   dD = dN B N^T + N B dN^T + N dB N^T,
//   dH = lambda (r_E r^T + r r_E^T) + dc D + c dD.
// Exact wherever no twist denominator is clamped (B uses the same clamp as dP/dF).
inline void stress_hessian_directional(const Polar& p, double mu, double lambda, const Mat3& dF, Mat9& out) {
  const Mat3& R = p.R;
  const double c = lambda * (p.sigma.sum() - 3.0) - 2.0 * mu;
  const Mat3 B = p.V * twist_weights(p.sigma).asDiagonal() * p.V.transpose();
  const Mat3 S = p.stretch();

  Eigen::Matrix<double, 9, 3> N;
  for (int m = 0; m < 3; ++m) Eigen::Map<Mat3>(N.col(m).data()).noalias() = R * detail::skew(Vec3::Unit(m));
  const auto e = detail::vec(dF);
  const Vec3 w_E = B * (N.transpose() * e);
  const Mat3 W_E = detail::skew(w_E);
  const Mat3 dR = R * W_E;
  const auto r = detail::vec(R);
  const auto r_E = detail::vec(dR);
  const double R_dot_E = r.dot(e);

  Eigen::Matrix<double, 9, 3> dN;
  for (int m = 0; m < 3; ++m) Eigen::Map<Mat3>(dN.col(m).data()).noalias() = dR * detail::skew(Vec3::Unit(m));
  Mat3 dS = R.transpose() * dF - W_E * S;
  dS = 0.5 * (dS + dS.transpose()).eval();
  const Mat3 X = R_dot_E * Mat3::Identity() - dS;
  const Mat3 dB = -B * X * B;

  const Eigen::Matrix<double, 9, 3> G = N * B;  // D = G N^T
  // The (9x3)(3x9) products are evaluated coefficient by coefficient (lazyProduct):
  // 9 + 9 + 3 is above Eigen's threshold for small products, and its general GEMM path
  // (blocking, packing, an OpenMP query per product) cost 12% of a calibration's time
  // (perf, tests/bench BM_CalibrationIteration/3; docs/performance.md "Calibration").
  out.noalias() = lambda * r_E * r.transpose();
  out.noalias() += lambda * r * r_E.transpose();
  out.noalias() += (lambda * R_dot_E) * G.lazyProduct(N.transpose());
  out.noalias() += c * dN.lazyProduct(G.transpose());
  out.noalias() += c * G.lazyProduct(dN.transpose());
  const Eigen::Matrix<double, 9, 3> NdB = N * dB;
  out.noalias() += c * NdB.lazyProduct(N.transpose());
}

// d^2P[E, W] = d(dP/dF)[E] vec(W) as a 3x3 matrix, from the polar decomposition of the
// step (R, V, sigma: PointCache, FemData::R / polar_V / polar_sigma), without the SVD and
// without forming the 9x9 d(dP/dF)[E]: the forward sensitivities need only this product
// (fem::add_stiffness_jvp with a record, docs/method.md "Derivatives"). It is the product
// of stress_hessian_directional above with vec(W), term by term, with
// N^T vec(X) = vee(R^T X), vee(Y) = (Y_21 - Y_12, Y_02 - Y_20, Y_10 - Y_01) (the columns
// of N are vec(R [e_m]_x)), N a = vec(R [a]_x), dN^T vec(X) = vee(dR^T X),
// dN a = vec(dR [a]_x), G^T vec(W) = B N^T vec(W) = B a_W:
//   d^2P[E, W] = lambda (R:W) dR + lambda (dR:W) R + c dR [B a_W]_x + R [z]_x,
//   z = lambda (R:E) B a_W + c B vee(dR^T W) + c dB a_W.
// About 400 flops against the SVD and the 9x9 products of the directional derivative.
// Exact wherever stress_hessian_directional is (the same clamped twist weights).
inline void stress_second_derivative(const Mat3& R, const Mat3& V, const Vec3& sigma, double mu, double lambda,
                                     const Mat3& E, const Mat3& W, Mat3& out) {
  const auto vee = [](const Mat3& Y) { return Vec3(Y(2, 1) - Y(1, 2), Y(0, 2) - Y(2, 0), Y(1, 0) - Y(0, 1)); };
  const double c = lambda * (sigma.sum() - 3.0) - 2.0 * mu;
  Mat3 B, S;
  B.noalias() = V * twist_weights(sigma).asDiagonal() * V.transpose();
  S.noalias() = V * sigma.asDiagonal() * V.transpose();
  Mat3 RtE;
  RtE.noalias() = R.transpose() * E;
  const Vec3 w_E = B * vee(RtE);
  const Mat3 W_E = detail::skew(w_E);
  Mat3 dR;
  dR.noalias() = R * W_E;
  const double R_dot_E = RtE.trace();  // R:E = tr(R^T E)
  Mat3 dS = RtE;
  dS.noalias() -= W_E * S;
  dS = 0.5 * (dS + dS.transpose()).eval();
  Mat3 X = -dS;
  X.diagonal().array() += R_dot_E;
  Mat3 RtW, dRtW;
  RtW.noalias() = R.transpose() * W;
  dRtW.noalias() = dR.transpose() * W;
  const Vec3 a_W = vee(RtW);
  const Vec3 b_W = B * a_W;
  // dB a_W = -B X B a_W = -B X b_W.
  const Vec3 z = (lambda * R_dot_E) * b_W + c * (B * vee(dRtW)) - c * (B * (X * b_W));
  const double R_dot_W = RtW.trace(), dR_dot_W = dRtW.trace();
  out.noalias() = (lambda * R_dot_W) * dR;
  out.noalias() += (lambda * dR_dot_W) * R;
  out.noalias() += c * (dR * detail::skew(b_W));
  out.noalias() += R * detail::skew(z);
}

inline void stress_hessian_directional(const Mat3& F, double mu, double lambda, const Mat3& dF, Mat9& out) {
  Polar p;
  polar_svd(F, p);
  stress_hessian_directional(p, mu, lambda, dF, out);
}

// Rotation of the polar decomposition by Higham's scaled Newton iteration
// X <- (g X + X^{-T} / g) / 2, g = sqrt(||X^{-1}||_F / ||X||_F) (N. Higham, "Computing
// the polar decomposition - with applications", 1986). Works for AutoDiff scalars (the
// derivatives of the iterates converge to dR: every iterate is R(F) times a symmetric
// factor that tends to I, and g only enters as a constant); meant for tests. Converges
// to the orthogonal polar factor, which is a rotation only for det F > 0.
template <class T>
Eigen::Matrix<T, 3, 3> polar_rotation_newton(const Eigen::Matrix<T, 3, 3>& F) {
  using M = Eigen::Matrix<T, 3, 3>;
  M X = F;
  int extra = -1;  // iterations still to run after the values converged
  for (int it = 0; it < 100 && extra != 0; ++it) {
    const M C = detail::cofactor(X);
    const M X_inv_T = C / detail::det_from_cofactor(X, C);
    const Mat3 Xv = detail::value_of_matrix(X), Yv = detail::value_of_matrix(X_inv_T);
    const double g = std::sqrt(Yv.norm() / Xv.norm());
    const M X_next = X * T(0.5 * g) + X_inv_T * T(0.5 / g);
    const double change = (detail::value_of_matrix(X_next) - Xv).norm();
    X = X_next;
    if (extra > 0) --extra;
    if (extra < 0 && change < 1e-14) extra = 2;  // two more so the derivatives settle too
  }
  return X;
}

// psi(F) for any scalar: SVD for double (defined for every F, inverted included);
// scaled Newton for other scalars (AutoDiff in tests; requires det F > 0).
template <class T>
T psi(const Eigen::Matrix<T, 3, 3>& F, double mu, double lambda) {
  if constexpr (std::is_same_v<T, double>) {
    Polar p;
    polar_svd(F, p);
    return psi_from_polar(p, mu, lambda);
  } else {
    const Eigen::Matrix<T, 3, 3> R = polar_rotation_newton(F);
    const Eigen::Matrix<T, 3, 3> D = F - R;
    const T t = R.cwiseProduct(F).sum() - T(3.0);  // tr(R^T F) - 3
    return T(mu) * D.cwiseProduct(D).sum() + T(0.5 * lambda) * t * t;
  }
}

}  // namespace softdiff::material::corotational
