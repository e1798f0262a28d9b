#pragma once
// Finite-difference helpers for derivative tests (STYLE.md section 5).
//
// Central differences: (f(x + h e_j) - f(x - h e_j)) / (2h). Truncation error is
// O(h^2 f'''), round-off O(eps |f| / h); with h = 1e-6 times the variable's natural
// scale (an edge length for positions, the value itself for a parameter) both are
// around 1e-10 relative for smooth functions of O(1) curvature on that scale, so a
// tolerance of 1e-6 leaves four orders of margin while still catching any wrong term.
#include <Eigen/Core>

#include <cmath>
#include <functional>
#include <random>
#include <sstream>
#include <string>

namespace softdiff::test {

using VecX = Eigen::VectorXd;
using MatX = Eigen::MatrixXd;

// A seeded vector of n entries uniform in [-scale, scale] (directions, cotangents).
inline VecX random_vector(Eigen::Index n, double scale, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  VecX v(n);
  for (Eigen::Index k = 0; k < n; ++k) v[k] = scale * u(rng);
  return v;
}

// d f / d x (m x n) of f: R^n -> R^m, step h_j = h * scale.
inline MatX fd_jacobian(const std::function<VecX(const VecX&)>& f, const VecX& x, double h) {
  VecX xp = x, xm = x;
  MatX J;
  for (int j = 0; j < x.size(); ++j) {
    xp[j] = x[j] + h;
    xm[j] = x[j] - h;
    const VecX d = (f(xp) - f(xm)) / (2 * h);
    if (j == 0) J.resize(d.size(), x.size());
    J.col(j) = d;
    xp[j] = xm[j] = x[j];
  }
  return J;
}

inline VecX fd_gradient(const std::function<double(const VecX&)>& f, const VecX& x, double h) {
  VecX g(x.size());
  VecX xp = x, xm = x;
  for (int j = 0; j < x.size(); ++j) {
    xp[j] = x[j] + h;
    xm[j] = x[j] - h;
    g[j] = (f(xp) - f(xm)) / (2 * h);
    xp[j] = xm[j] = x[j];
  }
  return g;
}

// Norm-wise relative error ||A - B|| / ||B|| and the worst entry, for messages.
struct Comparison {
  double rel_error = 0;
  Eigen::Index row = 0, col = 0;
  double analytic = 0, fd = 0;
  std::string str() const {
    std::ostringstream s;
    s.precision(6);
    s << "relative error " << rel_error << ", worst entry (" << row << ", " << col << "): analytic " << analytic
      << " vs fd " << fd;
    return s.str();
  }
};

inline Comparison compare(const MatX& analytic, const MatX& fd) {
  Comparison c;
  const double denom = fd.norm();
  c.rel_error = denom > 0 ? (analytic - fd).norm() / denom : (analytic - fd).norm();
  (analytic - fd).cwiseAbs().maxCoeff(&c.row, &c.col);
  c.analytic = analytic(c.row, c.col);
  c.fd = fd(c.row, c.col);
  return c;
}

}  // namespace softdiff::test
