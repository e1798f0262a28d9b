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
// J = S G_AA + T with S, T block-diagonal (one 3x3 block per active contact) and R = S
// (on the contact's own columns): compute_operator() never forms G_AA or J and solves
// by CGLS on the operator (mode_system.hpp), whose minimum-norm least-squares answer is
// the decomposition's (docs/method.md "The mode-fixed system at scale").
#include <softdiff/contact/mode_system.hpp>
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
  // The same on the operator y -> G_AA y (3 na, the active contacts in increasing
  // order): never forms G_AA; L is the scale of the force rows (any positive value of
  // G_AA's size: the rows are scaled, the solution of an invertible J is not; the
  // operator path passes the power iteration's lambda_max(G_AA), docs/method.md "The
  // derivative's scale").
  // M (optional): the preconditioner (G_AA + c I)^{-1} of mode_system.hpp;
  // reduce, reduce_apply (optional): the mixed sets' reduced preconditioner there.
  void compute_operator(OperatorModeSystem::Apply G_AA, double L, const VecX& mu, const VecX& lambda,
                        const VecX& sigma, const std::vector<Mode>& modes, OperatorModeSystem::Precondition M = {},
                        OperatorModeSystem::FactorizeReduced reduce = {},
                        OperatorModeSystem::Precondition reduce_apply = {});
  bool on_operator() const { return operator_; }
  const OperatorModeSystem& operator_system() const { return op_; }
  // The active (non-breaking) contacts of (modes), as compute() selects them.
  const std::vector<int>& active_contacts() const { return active_; }

  // dlambda (3 nc) for b (3 nc) and dmu (nc; empty: zero).
  void jvp(const VecX& b, const VecX& dmu, VecX& dlambda) const;
  // The right-hand side r = R b + D dmu (3 na) of the mode-fixed system J dlambda_A = -r.
  void right_hand_side(const VecX& b, const VecX& dmu, VecX& r) const;
  // J (3 na x 3 na) on the dense paths (empty on the operator path), for reports and tests.
  const MatX& jacobian() const { return J_; }
  // The transpose: bar_b (3 nc) and bar_mu (nc) for bar_lambda (3 nc).
  void vjp(const VecX& bar_lambda, VecX& bar_b, VecX& bar_mu) const;

  // The dense paths' rank deficiency of J (the operator path makes no rank decision: 0).
  int rank_deficiency() const { return rank_deficiency_; }
  int degenerate() const { return degenerate_; }
  int active() const { return static_cast<int>(active_.size()); }
  // The scale L of the force rows (and of the operator path's preconditioner shift):
  // max diag G_AA on the dense paths, the caller's on the operator path (there the power
  // iteration's estimate of lambda_max(G_AA), contact_step_derivatives.cpp).
  double scale() const { return scale_; }

 private:
  void set_active(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes);
  template <typename Block>
  void assemble(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes, double L,
                const Block& G_ab);
  // R's and D's blocks (and S = R, T) of active contact a (contact i); returns whether
  // the contact is a degenerate sliding one.
  bool mode_blocks(const VecX& mu, const VecX& lambda, const VecX& sigma, const std::vector<Mode>& modes, double L,
                   int a, Mat3& T);

  int nc_ = 0;
  std::vector<int> active_;  // active contact ids
  // J's factorization: Cholesky when every active contact sticks (J = G_AA, symmetric)
  // and it is positive definite; otherwise the complete orthogonal decomposition of J
  // (minimum-norm least squares; its transposed solve gives (J^+)^T for the reverse mode).
  bool cholesky_ = false;
  Eigen::LLT<MatX> llt_;
  Eigen::CompleteOrthogonalDecomposition<MatX> cod_;
  MatX J_;                   // (3 na x 3 na) the mode system
  // d(mode equations)/d sigma at fixed lambda (3 na x 3 nc) and d/d mu (3 na x nc):
  // block-diagonal, one block per active contact on its own columns.
  std::vector<Mat3> R_;      // (na) 3x3
  std::vector<Vec3> D_;      // (na) 3x1
  bool operator_ = false;    // compute_operator(): solves by op_, no J_
  OperatorModeSystem op_;
  int rank_deficiency_ = 0, degenerate_ = 0;
  double scale_ = 1;
};

}  // namespace softdiff::contact
