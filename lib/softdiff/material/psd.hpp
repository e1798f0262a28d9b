#pragma once
// Projection of a symmetric matrix onto the positive semi-definite cone (the nearest
// PSD matrix in the Frobenius norm): eigen-decompose, clamp negative eigenvalues to
// zero, reconstruct. Fixed size, no heap allocation (SelfAdjointEigenSolver on a
// fixed-size matrix keeps its workspace on the stack).
#include <Eigen/Core>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>

namespace softdiff::material {

// Only the lower triangle of K is read. If K is already PSD (smallest computed
// eigenvalue >= 0) it is left untouched, bit for bit; otherwise it is replaced by
// Q max(Lambda, 0) Q^T, which is exactly symmetric up to round-off.
template <int N>
inline void clamp_negative_eigenvalues(Eigen::Matrix<double, N, N>& K) {
  using Mat = Eigen::Matrix<double, N, N>;
  using Vec = Eigen::Matrix<double, N, 1>;
  const Eigen::SelfAdjointEigenSolver<Mat> eig(K, Eigen::ComputeEigenvectors);
  if (eig.eigenvalues()(0) >= 0.0) return;  // ascending order
  const Vec clamped = eig.eigenvalues().cwiseMax(0.0);
  const Mat Qc = eig.eigenvectors() * clamped.asDiagonal();
  K.noalias() = Qc * eig.eigenvectors().transpose();
}

// The derivative of clamp_negative_eigenvalues at K in a symmetric direction dK
// (Daleckii-Krein): with K = Q Lambda Q^T and f = max(., 0),
//     d(K+) = Q (Gamma o (Q^T dK Q)) Q^T,   Gamma_ij = (f(l_i) - f(l_j)) / (l_i - l_j),
// and Gamma_ij = (f'(l_i) + f'(l_j)) / 2 when l_i = l_j to rounding (1e-12 of the
// spectral radius; f' = 1 for l > 0, 0 below, so a pair straddling 0 gets 1/2, the
// limit of the quotient). Where clamp_negative_eigenvalues leaves K untouched (smallest
// eigenvalue >= 0) the projection is the identity near K (for the PSD matrices around
// it) and so is its derivative: d(K+) = dK. The map dK -> d(K+) is self-adjoint in the
// Frobenius inner product (Gamma is symmetric), which the reverse mode uses. Not
// differentiable where an eigenvalue crosses 0 (a set of measure zero).
template <int N>
struct PsdProjectionDerivative {
  using Mat = Eigen::Matrix<double, N, N>;
  Mat Q, Gamma;
  bool identity = true;

  void compute(const Mat& K) {
    const Eigen::SelfAdjointEigenSolver<Mat> eig(K, Eigen::ComputeEigenvectors);
    const auto& l = eig.eigenvalues();
    identity = l(0) >= 0.0;
    if (identity) return;
    Q = eig.eigenvectors();
    const double tie = 1e-12 * std::max(std::abs(l(0)), std::abs(l(N - 1)));
    for (int j = 0; j < N; ++j)
      for (int i = 0; i < N; ++i) {
        const double li = l(i), lj = l(j);
        if (std::abs(li - lj) <= tie)
          Gamma(i, j) = 0.5 * ((li > 0 ? 1.0 : 0.0) + (lj > 0 ? 1.0 : 0.0));
        else
          Gamma(i, j) = (std::max(li, 0.0) - std::max(lj, 0.0)) / (li - lj);
      }
  }
  // d(K+) for the direction dK (symmetric).
  Mat apply(const Mat& dK) const {
    if (identity) return dK;
    const Mat T = (Q.transpose() * dK * Q).cwiseProduct(Gamma);
    return Q * T * Q.transpose();
  }
};

}  // namespace softdiff::material
