// Bound-constrained convex QP by a primal active-set method: see box_qp.hpp.
#include <softdiff/optim/box_qp.hpp>

#include <softdiff/core/assert.hpp>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace softdiff::optim {

double kkt_residual(const MatX& H, const VecX& g, const VecX& lo, const VecX& hi, const VecX& d) {
  const VecX grad = H * d + g;
  const double scale = std::max(1.0, g.lpNorm<Eigen::Infinity>());
  double worst = 0;
  for (Eigen::Index i = 0; i < d.size(); ++i) {
    const double tol = 1e-12 * std::max(1.0, std::abs(d[i]));
    worst = std::max({worst, lo[i] - d[i], d[i] - hi[i]});  // feasibility (absolute)
    const bool at_lo = d[i] <= lo[i] + tol, at_hi = d[i] >= hi[i] - tol;
    double r = 0;
    if (at_lo && at_hi) r = 0;             // a fixed variable (lo == hi)
    else if (at_lo) r = std::max(0.0, -grad[i]);  // at a lower bound the gradient must be >= 0
    else if (at_hi) r = std::max(0.0, grad[i]);   // at an upper bound <= 0
    else r = std::abs(grad[i]);
    worst = std::max(worst, r / scale);
  }
  return worst;
}

BoxQpResult solve_box_qp(const MatX& H, const VecX& g, const VecX& lo, const VecX& hi, int max_iterations) {
  const Eigen::Index n = g.size();
  SOFTDIFF_DEMAND(H.rows() == n && H.cols() == n && lo.size() == n && hi.size() == n, "solve_box_qp: sizes");
  for (Eigen::Index i = 0; i < n; ++i) SOFTDIFF_DEMAND(lo[i] <= hi[i], "solve_box_qp: lo > hi");
  BoxQpResult res;
  VecX d = VecX::Zero(n);
  // 0: free; -1 fixed at lo; +1 fixed at hi.
  std::vector<int> state(static_cast<std::size_t>(n), 0);
  // Start: the projection of 0; a variable moved onto a bound by it starts fixed there
  // (a variable with lo == hi stays fixed).
  for (Eigen::Index i = 0; i < n; ++i) {
    d[i] = std::clamp(0.0, lo[i], hi[i]);
    auto& s = state[static_cast<std::size_t>(i)];
    if (lo[i] == hi[i] || lo[i] > 0) s = -1;
    else if (hi[i] < 0) s = 1;
  }
  std::vector<Eigen::Index> free;
  // After a full step (no bound crossed) d minimizes the working set's subproblem: the
  // next iteration checks the multipliers instead of recomputing a step that round-off
  // alone would make nonzero (an ill-conditioned H_FF would otherwise take tiny steps
  // until the iteration cap).
  bool at_minimum = false;
  for (int it = 0; it < max_iterations; ++it) {
    res.iterations = it + 1;
    free.clear();
    for (Eigen::Index i = 0; i < n; ++i)
      if (state[static_cast<std::size_t>(i)] == 0) free.push_back(i);
    const Eigen::Index m = static_cast<Eigen::Index>(free.size());
    // The minimizer over the free variables with the fixed ones held: p = target - d_F.
    VecX step = VecX::Zero(n);
    if (m > 0 && !at_minimum) {
      MatX HF(m, m);
      VecX rhs(m);
      const VecX grad = H * d + g;
      for (Eigen::Index a = 0; a < m; ++a) {
        rhs[a] = -grad[free[static_cast<std::size_t>(a)]];
        for (Eigen::Index b = 0; b < m; ++b) HF(a, b) = H(free[static_cast<std::size_t>(a)], free[static_cast<std::size_t>(b)]);
      }
      Eigen::LLT<MatX> llt(HF);
      if (llt.info() != Eigen::Success) {
        res.d = d;
        res.kkt = kkt_residual(H, g, lo, hi, d);
        return res;
      }
      const VecX p = llt.solve(rhs);
      for (Eigen::Index a = 0; a < m; ++a) step[free[static_cast<std::size_t>(a)]] = p[a];
    }
    if (at_minimum || step.lpNorm<Eigen::Infinity>() <= 1e-15 * std::max(1.0, d.lpNorm<Eigen::Infinity>())) {
      at_minimum = false;
      // Stationary on the working set: the multipliers of the fixed variables.
      const VecX grad = H * d + g;
      Eigen::Index release = -1;
      double worst = 0;
      for (Eigen::Index i = 0; i < n; ++i) {
        const int s = state[static_cast<std::size_t>(i)];
        if (s == 0 || lo[i] == hi[i]) continue;
        const double wrong = s < 0 ? -grad[i] : grad[i];  // > 0: the bound holds the variable the wrong way
        if (wrong > worst) {
          worst = wrong;
          release = i;
        }
      }
      if (release < 0) {
        res.d = d;
        res.converged = true;
        res.kkt = kkt_residual(H, g, lo, hi, d);
        return res;
      }
      state[static_cast<std::size_t>(release)] = 0;
      continue;
    }
    // Step to the target or to the first bound crossed.
    double alpha = 1;
    Eigen::Index blocking = -1;
    int side = 0;
    for (Eigen::Index i = 0; i < n; ++i) {
      if (state[static_cast<std::size_t>(i)] != 0 || step[i] == 0) continue;
      const double bound = step[i] < 0 ? lo[i] : hi[i];
      if (!std::isfinite(bound)) continue;
      const double a = (bound - d[i]) / step[i];
      if (a < alpha) {
        alpha = std::max(a, 0.0);
        blocking = i;
        side = step[i] < 0 ? -1 : 1;
      }
    }
    d += alpha * step;
    if (blocking >= 0) {
      d[blocking] = side < 0 ? lo[blocking] : hi[blocking];
      state[static_cast<std::size_t>(blocking)] = side;
    } else {
      at_minimum = true;
    }
  }
  res.d = d;
  res.kkt = kkt_residual(H, g, lo, hi, d);
  return res;
}

}  // namespace softdiff::optim
