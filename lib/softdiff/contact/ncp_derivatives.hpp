#pragma once
// Derivatives of the contact forces (method.md "Derivatives"; sibling of ncp.hpp): the
// implicit function theorem on the NCP with the contact modes held fixed (Le Lidec et
// al. 2024). At a solution lambda (sigma = G lambda + g, modes from the solver), a
// perturbation that moves sigma by b at fixed lambda (b = dG lambda + dg) and the
// friction coefficients by dmu changes lambda by dlambda with, per contact i:
//   breaking  dlambda_i = 0
//   sticking  dsigma_i = G_i dlambda + b_i = 0                              (3 rows)
//   sliding   dsigma_N,i = 0,
//             d(lambda_T + mu lambda_N t) = 0,  t = sigma_T / |sigma_T|,
//             dt = (I - t t^T) dsigma_T / |sigma_T|                           (2 rows)
// i.e. J dlambda_A = -(R b + D dmu) over the active (non-breaking) contacts A, with J
// the Jacobian of the mode equations (the polish's), R their derivative with respect
// to sigma at fixed lambda and D with respect to mu. The force rows are scaled by
// L = max diag G as in the polish (all rows velocities). J is square but singular when
// contacts are redundant (rank-deficient G) or degenerate: the minimum-norm least-
// squares solution is taken (complete orthogonal decomposition, rank decided at
// 1e-12 relative; Cholesky when every active contact sticks and G_AA is definite),
// which for a consistent system is the smallest force change, and
// rank_deficiency() counts the dimensions lost. A sliding contact with sigma_T = 0 has
// no sliding direction (a mode boundary): its tangential rows are lambda_T-fixed and
// it is counted in degenerate().
#include <softdiff/contact/ncp.hpp>

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <vector>

namespace softdiff::contact {

class NcpDerivative {
 public:
  // At the solution (lambda, sigma, modes) of NCP(G, g, mu).
  void compute(const MatX& G, const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes);
  // The same from G_AA alone (3 na x 3 na, the active contacts in increasing order):
  // the sparse backend, which never forms G (the scale L is then max diag G_AA).
  void compute_active(const MatX& G_AA, const VecX& mu, const VecX& lambda, const VecX& sigma,
                      const std::vector<Mode>& modes);
  // The active (non-breaking) contacts of (modes), as compute() selects them.
  const std::vector<int>& active_contacts() const { return active_; }

  // dlambda (3 nc) for b (3 nc) and dmu (nc; empty: zero).
  void jvp(const VecX& b, const VecX& dmu, VecX& dlambda) const;
  // The transpose: bar_b (3 nc) and bar_mu (nc) for bar_lambda (3 nc).
  void vjp(const VecX& bar_lambda, VecX& bar_b, VecX& bar_mu) const;

  int rank_deficiency() const { return rank_deficiency_; }
  int degenerate() const { return degenerate_; }
  int active() const { return static_cast<int>(active_.size()); }

 private:
  void set_active(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes);
  template <typename Block>
  void assemble(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes, double L,
                const Block& G_ab);

  int nc_ = 0;
  std::vector<int> active_;  // active contact ids
  // J's factorization: Cholesky when every active contact sticks (J = G_AA, symmetric)
  // and it is positive definite; otherwise the complete orthogonal decomposition of J
  // (minimum-norm least squares; its transposed solve gives (J^+)^T for the reverse mode).
  bool cholesky_ = false;
  Eigen::LLT<MatX> llt_;
  Eigen::CompleteOrthogonalDecomposition<MatX> cod_;
  MatX J_;                   // (3 na x 3 na) the mode system
  MatX R_;                   // (3 na x 3 nc) d(mode equations)/d sigma at fixed lambda
  MatX D_;                   // (3 na x nc) d(mode equations)/d mu
  int rank_deficiency_ = 0, degenerate_ = 0;
};

}  // namespace softdiff::contact
