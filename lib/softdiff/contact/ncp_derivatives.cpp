// Derivatives of the contact forces: see ncp_derivatives.hpp.
#include <softdiff/contact/ncp_derivatives.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>

#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

namespace softdiff::contact {

void NcpDerivative::compute(const MatX& G, const VecX& mu, const VecX& lambda, const VecX& sigma,
                            const std::vector<Mode>& modes) {
  const int nc = static_cast<int>(mu.size());
  SOFTDIFF_DEMAND(G.rows() == 3 * nc && G.cols() == 3 * nc,
                  "NcpDerivative::compute: G does not match " + std::to_string(nc) + " contacts");
  set_active(mu, lambda, sigma, modes);
  const double L = std::max(G.diagonal().maxCoeff(), 1e-300);
  scale_ = L;
  assemble(mu, lambda, sigma, modes, L, [&](int a, int b) { return G.block<3, 3>(3 * active_[a], 3 * active_[b]); });
}

void NcpDerivative::compute_active(const MatX& G_AA, const VecX& mu, const VecX& lambda, const VecX& sigma,
                                   const std::vector<Mode>& modes) {
  set_active(mu, lambda, sigma, modes);
  const Eigen::Index m = 3 * static_cast<Eigen::Index>(active_.size());
  SOFTDIFF_DEMAND(G_AA.rows() == m && G_AA.cols() == m,
                  "NcpDerivative::compute_active: G_AA is not 3 na x 3 na for " + std::to_string(active_.size()) +
                      " active contacts");
  const double L = m > 0 ? std::max(G_AA.diagonal().maxCoeff(), 1e-300) : 1.0;
  scale_ = L;
  assemble(mu, lambda, sigma, modes, L, [&](int a, int b) { return G_AA.block<3, 3>(3 * a, 3 * b); });
}

void NcpDerivative::set_active(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes) {
  nc_ = static_cast<int>(mu.size());
  SOFTDIFF_DEMAND(lambda.size() == 3 * nc_ && sigma.size() == 3 * nc_ && static_cast<int>(modes.size()) == nc_,
                  "NcpDerivative::compute: sizes do not match " + std::to_string(nc_) + " contacts");
  active_.clear();
  for (int i = 0; i < nc_; ++i)
    if (modes[i] != Mode::breaking) active_.push_back(i);
}

void NcpDerivative::compute_operator(OperatorModeSystem::Apply G_AA, double L, const VecX& mu, const VecX& lambda,
                                     const VecX& sigma, const std::vector<Mode>& modes,
                                     OperatorModeSystem::Precondition M,
                                     OperatorModeSystem::FactorizeReduced reduce,
                                     OperatorModeSystem::Precondition reduce_apply) {
  set_active(mu, lambda, sigma, modes);
  SOFTDIFF_DEMAND(L > 0 && std::isfinite(L), "NcpDerivative::compute_operator: the scale L must be positive");
  const int na = static_cast<int>(active_.size());
  scale_ = L;
  degenerate_ = 0;
  rank_deficiency_ = 0;
  cholesky_ = false;
  operator_ = true;
  J_.resize(0, 0);
  R_.assign(static_cast<std::size_t>(na), Mat3::Zero());
  D_.assign(static_cast<std::size_t>(na), Vec3::Zero());
  std::vector<Mat3> T(static_cast<std::size_t>(na));
  for (int a = 0; a < na; ++a)
    if (mode_blocks(mu, lambda, sigma, modes, L, a, T[a])) ++degenerate_;
  op_.set(std::move(G_AA), R_, std::move(T));  // S = R
  op_.set_preconditioner(std::move(M));
  if (reduce && reduce_apply) op_.set_reduced_preconditioner(std::move(reduce), std::move(reduce_apply));
}

bool NcpDerivative::mode_blocks(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes,
                                double L, int a, Mat3& T) {
  const int i = active_[a];
  R_[a].setIdentity();
  D_[a].setZero();
  T.setZero();
  if (modes[i] == Mode::sticking) return false;
  // Sliding: the normal row stays; the tangential rows are those of
  // L (lambda_T + mu lambda_N t(sigma_T)).
  const double mui = mu[i], lN = lambda[3 * i + 2];
  const Eigen::Vector2d sT = sigma.segment<2>(3 * i);
  const double sn = sT.norm();
  R_[a].topRows<2>().setZero();
  T.topLeftCorner<2, 2>() = L * Eigen::Matrix2d::Identity();
  if (mui > 0 && sn > 0) {
    const Eigen::Vector2d t = sT / sn;
    const Eigen::Matrix2d P = (mui * lN / sn) * (Eigen::Matrix2d::Identity() - t * t.transpose());
    R_[a].topLeftCorner<2, 2>() = L * P;
    T.block<2, 1>(0, 2) = L * mui * t;
    D_[a].head<2>() = L * lN * t;
    return false;
  }
  return mui > 0;  // no sliding direction: lambda_T held
}

template <typename Block>
void NcpDerivative::assemble(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes,
                             double L, const Block& G_ab) {
  const int na = static_cast<int>(active_.size()), m = 3 * na;
  degenerate_ = 0;
  rank_deficiency_ = 0;
  cholesky_ = false;
  operator_ = false;
  R_.assign(static_cast<std::size_t>(na), Mat3::Zero());
  D_.assign(static_cast<std::size_t>(na), Vec3::Zero());
  if (na == 0) return;
  MatX& J = J_;
  J.resize(m, m);
  bool all_sticking = true;
  Mat3 T;
  for (int a = 0; a < na; ++a) {
    const int i = active_[a];
    if (mode_blocks(mu, lambda, sigma, modes, L, a, T)) ++degenerate_;
    for (int b = 0; b < na; ++b) J.block<3, 3>(3 * a, 3 * b) = G_ab(a, b);
    if (modes[i] == Mode::sticking) continue;
    all_sticking = false;
    // Sliding: J's rows are R_a G_A + T_a; R_a's top rows are L P (or zero without a
    // sliding direction), its normal row e_N.
    J.middleRows<2>(3 * a).setZero();
    if (!R_[a].topLeftCorner<2, 2>().isZero(0)) {
      const Eigen::Matrix2d LP = R_[a].topLeftCorner<2, 2>();
      for (int b = 0; b < na; ++b) J.block<2, 3>(3 * a, 3 * b) += LP * G_ab(a, b).template topRows<2>();
    }
    J.block<2, 3>(3 * a, 3 * a) += T.topRows<2>();
  }
  if (all_sticking) {
    // J = G_AA: symmetric positive semi-definite. Cholesky when it is definite to a
    // margin (the smallest pivot above 1e-12 of the largest: the same rank decision
    // as the decomposition below), else the least-squares path.
    llt_.compute(J);
    if (llt_.info() == Eigen::Success) {
      const VecX d = llt_.matrixLLT().diagonal().cwiseAbs2();  // the squared pivots of L
      cholesky_ = d.minCoeff() > 1e-12 * d.maxCoeff();
    }
  }
  if (cholesky_) return;
  cod_.setThreshold(1e-12);
  cod_.compute(J);
  rank_deficiency_ = m - static_cast<int>(cod_.rank());
}

void NcpDerivative::right_hand_side(const VecX& b, const VecX& dmu, VecX& rhs) const {
  SOFTDIFF_DEMAND(b.size() == 3 * nc_ && (dmu.size() == 0 || dmu.size() == nc_), "NcpDerivative: sizes");
  const int na = static_cast<int>(active_.size());
  rhs.resize(3 * na);
  for (int a = 0; a < na; ++a) {
    const int i = active_[a];
    rhs.segment<3>(3 * a) = R_[a] * b.segment<3>(3 * i);
    if (dmu.size()) rhs.segment<3>(3 * a) += D_[a] * dmu[i];
  }
}

void NcpDerivative::jvp(const VecX& b, const VecX& dmu, VecX& dlambda) const {
  SOFTDIFF_DEMAND(b.size() == 3 * nc_ && (dmu.size() == 0 || dmu.size() == nc_), "NcpDerivative::jvp: sizes");
  dlambda = VecX::Zero(3 * nc_);
  if (active_.empty()) return;
  const int na = static_cast<int>(active_.size());
  VecX rhs;
  right_hand_side(b, dmu, rhs);
  VecX d;
  if (operator_) {
    if (!op_.solve(rhs, d))
      throw ComputationError("the contact derivative's mode-fixed system on the operator did not converge (" +
                             std::to_string(op_.last_iterations()) + " iterations, " + std::to_string(na) +
                             " active contacts)");
    d = -d;
  } else {
    d = cholesky_ ? VecX(-llt_.solve(rhs)) : VecX(-cod_.solve(rhs));
  }
  for (int a = 0; a < na; ++a) dlambda.segment<3>(3 * active_[a]) = d.segment<3>(3 * a);
}

void NcpDerivative::vjp(const VecX& bar_lambda, VecX& bar_b, VecX& bar_mu) const {
  SOFTDIFF_DEMAND(bar_lambda.size() == 3 * nc_, "NcpDerivative::vjp: sizes");
  bar_b = VecX::Zero(3 * nc_);
  bar_mu = VecX::Zero(nc_);
  if (active_.empty()) return;
  const int na = static_cast<int>(active_.size());
  VecX la(3 * na);
  for (int a = 0; a < na; ++a) la.segment<3>(3 * a) = bar_lambda.segment<3>(3 * active_[a]);
  VecX y;
  if (operator_) {
    // (J^T)^+ la = (J^+)^T la: CGLS on J^T.
    if (!op_.solve(la, y, true))
      throw ComputationError("the contact derivative's transposed mode-fixed system on the operator did not converge (" +
                             std::to_string(op_.last_iterations()) + " iterations, " + std::to_string(na) +
                             " active contacts)");
    y = -y;
  } else if (cholesky_) {
    y = -llt_.solve(la);  // J symmetric
  } else {
    // (J^+)^T la from the same decomposition: Eigen 3.4 implements the transposed solve
    // of a complete orthogonal decomposition (_solve_impl_transposed, public, used by
    // its own transpose().solve() machinery, which 3.4 does not wire for this class).
    y.resize(la.size());
    cod_.template _solve_impl_transposed<false>(la, y);
    y = -y;
  }
  for (int a = 0; a < na; ++a) {
    const int i = active_[a];
    bar_b.segment<3>(3 * i) = R_[a].transpose() * y.segment<3>(3 * a);
    bar_mu[i] = D_[a].dot(y.segment<3>(3 * a));
  }
}

}  // namespace softdiff::contact
