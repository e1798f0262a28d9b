#pragma once
// Projection of a symmetric matrix onto the positive semi-definite cone (the nearest
// PSD matrix in the Frobenius norm): eigen-decompose, clamp negative eigenvalues to
// zero, reconstruct. Fixed size, no heap allocation (SelfAdjointEigenSolver on a
// fixed-size matrix keeps its workspace on the stack).
#include <Eigen/Core>
#include <Eigen/Eigenvalues>

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

}  // namespace softdiff::material
