#pragma once
// A small dense convex QP with bounds (the inverse-dynamics step of `softdiff control`):
//     min_d 1/2 d^T H d + g^T d   subject to   lo <= d <= hi,
// H symmetric positive definite (n up to a few tens), lo <= hi, +-infinity allowed.
// Solved exactly by a primal active-set method on the bounds (Nocedal & Wright,
// "Numerical Optimization", algorithm 16.3): from a feasible start (the projection of
// 0), solve the equality-constrained problem on the free variables (Cholesky of H_FF),
// step to it or to the first bound it crosses (then fix that variable), and release
// the fixed variable whose multiplier has the wrong sign; finite for strictly convex H.
// kkt_residual() measures the result: max over i of the stationarity residual of
// the free variables, the wrong-signed multipliers of the fixed ones and the bound
// violations, relative to max(1, |g|_inf).
#include <softdiff/core/types.hpp>

namespace softdiff::optim {

struct BoxQpResult {
  VecX d;
  int iterations = 0;
  bool converged = false;  // false: H not positive definite on the free set, or the iteration cap
  double kkt = 0;          // kkt_residual at d
};

BoxQpResult solve_box_qp(const MatX& H, const VecX& g, const VecX& lo, const VecX& hi, int max_iterations = 200);

double kkt_residual(const MatX& H, const VecX& g, const VecX& lo, const VecX& hi, const VecX& d);

}  // namespace softdiff::optim
