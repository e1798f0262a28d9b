// Derivatives of the contact forces: see ncp_derivatives.hpp.
#include <softdiff/contact/ncp_derivatives.hpp>

#include <softdiff/core/assert.hpp>

#include <Eigen/QR>
#include <algorithm>
#include <string>

namespace softdiff::contact {

void NcpDerivative::compute(const MatX& G, const VecX& mu, const VecX& lambda, const VecX& sigma,
                            const std::vector<Mode>& modes) {
  const int nc = static_cast<int>(mu.size());
  SOFTDIFF_DEMAND(G.rows() == 3 * nc && G.cols() == 3 * nc,
                  "NcpDerivative::compute: G does not match " + std::to_string(nc) + " contacts");
  set_active(mu, lambda, sigma, modes);
  const double L = std::max(G.diagonal().maxCoeff(), 1e-300);
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

template <typename Block>
void NcpDerivative::assemble(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes,
                             double L, const Block& G_ab) {
  const int na = static_cast<int>(active_.size()), m = 3 * na;
  degenerate_ = 0;
  rank_deficiency_ = 0;
  cholesky_ = false;
  R_ = MatX::Zero(m, 3 * nc_);
  D_ = MatX::Zero(m, nc_);
  if (na == 0) return;
  MatX& J = J_;
  J.resize(m, m);
  bool all_sticking = true;
  for (int a = 0; a < na; ++a) {
    const int i = active_[a];
    for (int b = 0; b < na; ++b) J.block<3, 3>(3 * a, 3 * b) = G_ab(a, b);
    R_.block<3, 3>(3 * a, 3 * i).setIdentity();
    if (modes[i] == Mode::sticking) continue;
    all_sticking = false;
    // Sliding: the normal row stays; the tangential rows are those of
    // L (lambda_T + mu lambda_N t(sigma_T)).
    const double mui = mu[i], lN = lambda[3 * i + 2];
    const Eigen::Vector2d sT = sigma.segment<2>(3 * i);
    const double sn = sT.norm();
    R_.block<2, 3>(3 * a, 3 * i).setZero();
    J.middleRows<2>(3 * a).setZero();
    J.block<2, 2>(3 * a, 3 * a) = L * Eigen::Matrix2d::Identity();
    if (mui > 0 && sn > 0) {
      const Eigen::Vector2d t = sT / sn;
      const Eigen::Matrix2d P = (mui * lN / sn) * (Eigen::Matrix2d::Identity() - t * t.transpose());
      for (int b = 0; b < na; ++b) J.block<2, 3>(3 * a, 3 * b) += L * P * G_ab(a, b).template topRows<2>();
      J.block<2, 1>(3 * a, 3 * a + 2) += L * mui * t;
      R_.block<2, 2>(3 * a, 3 * i) = L * P;
      D_.block<2, 1>(3 * a, i) = L * lN * t;
    } else if (mui > 0) {
      ++degenerate_;  // no sliding direction: lambda_T held
    }
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

void NcpDerivative::jvp(const VecX& b, const VecX& dmu, VecX& dlambda) const {
  SOFTDIFF_DEMAND(b.size() == 3 * nc_ && (dmu.size() == 0 || dmu.size() == nc_), "NcpDerivative::jvp: sizes");
  dlambda = VecX::Zero(3 * nc_);
  if (active_.empty()) return;
  VecX rhs = R_ * b;
  if (dmu.size()) rhs += D_ * dmu;
  const VecX d = cholesky_ ? VecX(-llt_.solve(rhs)) : VecX(-cod_.solve(rhs));
  for (std::size_t a = 0; a < active_.size(); ++a) dlambda.segment<3>(3 * active_[a]) = d.segment<3>(3 * a);
}

void NcpDerivative::vjp(const VecX& bar_lambda, VecX& bar_b, VecX& bar_mu) const {
  SOFTDIFF_DEMAND(bar_lambda.size() == 3 * nc_, "NcpDerivative::vjp: sizes");
  bar_b = VecX::Zero(3 * nc_);
  bar_mu = VecX::Zero(nc_);
  if (active_.empty()) return;
  VecX la(3 * active_.size());
  for (std::size_t a = 0; a < active_.size(); ++a) la.segment<3>(3 * a) = bar_lambda.segment<3>(3 * active_[a]);
  VecX y;
  if (cholesky_) {
    y = -llt_.solve(la);  // J symmetric
  } else {
    // (J^+)^T la from the same decomposition: Eigen 3.4 implements the transposed solve
    // of a complete orthogonal decomposition (_solve_impl_transposed, public, used by
    // its own transpose().solve() machinery, which 3.4 does not wire for this class).
    y.resize(la.size());
    cod_.template _solve_impl_transposed<false>(la, y);
    y = -y;
  }
  bar_b = R_.transpose() * y;
  bar_mu = D_.transpose() * y;
}

}  // namespace softdiff::contact
