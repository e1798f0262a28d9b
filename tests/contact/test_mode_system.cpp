// The mode-fixed system on the operator (mode_system.hpp, NcpDerivative::
// compute_operator) against the dense path (NcpDerivative::compute: Cholesky or the
// complete orthogonal decomposition) on the same problems: only sticking, only
// sliding, mixed, frictionless, and redundant (a duplicated contact: J singular, the
// minimum-norm least-squares answer, with right-hand sides that are not in J's range).
// The operator is y -> G y with the problem's G (the step's operator G_AA = h H_A A^{-1}
// H_A^T is exercised by test_step_derivatives_contact.cpp); forward and reverse mode,
// and the reverse mode against the transposed forward columns.
//
// Tolerance (derived, per comparison): CGLS stops at ||J^T s|| <= 1e-13 ||J^T r|| or
// <= 1e-14 ||J|| ||s|| (s = r - J x). With x* = J^+ r, J^T J (x - x*) = -J^T s on
// range(J^T), so ||x - x*|| <= ||J^T s|| / s_min^2 <= 1e-13 kappa^2 ||x*|| (as
// ||J^T r|| = ||J^T J x*|| <= s_max^2 ||x*||) or <= 1e-14 kappa^2 ||r|| / s_max; plus
// rounding: eps kappa for the dense decomposition and eps kappa^2 for the normal
// equations that CGLS works on. All sticking (J = G_AA), CG first: it stops at
// ||r - J x|| <= 1e-12 ||r||, so ||x - x*|| <= 1e-12 kappa ||x*||. kappa = s_max / s_min over the singular values of the
// dense J above 1e-12 s_max (the decomposition's rank decision); a factor 10 of margin.
#include <softdiff/contact/mode_system.hpp>
#include <softdiff/contact/ncp_derivatives.hpp>

#include <support/fd.hpp>

#include <gtest/gtest.h>

#include <Eigen/QR>
#include <Eigen/SVD>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>

using namespace softdiff;
using namespace softdiff::contact;

namespace test_mode_system_local {

struct Problem {
  MatX G;
  VecX mu, lambda, sigma;
  std::vector<Mode> modes;
};

// As test_ncp_derivatives.cpp: G = W W^T / n + 0.1 I (W random, n x n+3), or singular
// with contact nc-1 a copy of contact 0 (same rows of W) when duplicate; a solution with
// the given modes (strictly complementary).
Problem make_problem(const std::vector<Mode>& modes, unsigned seed, bool duplicate, double mu) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  const int nc = static_cast<int>(modes.size()), n = 3 * nc;
  Problem p;
  MatX W = MatX::Zero(n, n + 3);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n + 3; ++c) W(r, c) = u(rng);
  if (duplicate) W.bottomRows<3>() = W.topRows<3>();
  p.G = W * W.transpose() / n;
  if (!duplicate) p.G += 0.1 * MatX::Identity(n, n);
  p.mu = VecX::Constant(nc, mu);
  p.lambda = VecX::Zero(n);
  p.sigma = VecX::Zero(n);
  for (int i = 0; i < nc; ++i) {
    const double lN = 1 + 0.5 * u(rng);
    const Eigen::Vector2d dir = Eigen::Vector2d(u(rng), u(rng)).normalized();
    switch (modes[i]) {
      case Mode::breaking: p.sigma.segment<3>(3 * i) = Vec3(0.3 * u(rng), 0.3 * u(rng), 0.5 + 0.3 * u(rng)); break;
      case Mode::sticking: p.lambda.segment<3>(3 * i) = Vec3(0.2 * lN * dir[0], 0.2 * lN * dir[1], lN); break;
      case Mode::sliding:
        p.sigma.segment<2>(3 * i) = (0.3 + 0.2 * std::abs(u(rng))) * dir;
        p.lambda.segment<3>(3 * i) = Vec3(-mu * lN * dir[0], -mu * lN * dir[1], lN);
        break;
    }
  }
  if (duplicate) {
    p.sigma.tail<3>() = p.sigma.head<3>();
    p.lambda.tail<3>() = p.lambda.head<3>();
  }
  p.modes = modes;
  return p;
}

// The derived bound of the header for x (the dense answer) and r (the right-hand side).
double bound(const MatX& J, const VecX& x, const VecX& r) {
  const Eigen::JacobiSVD<MatX> svd(J);
  const VecX s = svd.singularValues();
  double s_min = s[0];
  for (Eigen::Index k = 0; k < s.size(); ++k)
    if (s[k] > 1e-12 * s[0]) s_min = s[k];
  const double kappa = s[0] / s_min, eps = std::numeric_limits<double>::epsilon();
  return 10 * ((1e-13 + eps) * kappa * kappa * x.norm() + 1e-14 * kappa * kappa * r.norm() / s[0] +
                (1e-12 + eps) * kappa * x.norm());
}

// Preconditioned (M = (G_AA + c I)^{-1}, c = operator_shift_fraction L, formed densely):
// PCG stops as CG does (bound() covers it); CGLS on J M at ||(JM)^T s|| <= 1e-13
// ||(JM)^T r||, so with z* = M^{-1} x* the error in z is bound()'s for J M and z*, and
// ||x - x*|| <= ||M|| ||z - z*||. The sum of both bounds.
double bound_preconditioned(const MatX& J, const MatX& M, const VecX& x, const VecX& r) {
  const Eigen::JacobiSVD<MatX> svd(M);
  const double M_norm = svd.singularValues()[0];
  const VecX z = M.inverse() * x;
  return bound(J, x, r) + M_norm * bound(J * M, z, r);
}

// The reduced preconditioner of mixed sets (mode_system.hpp "Mixed sets"), formed densely
// from G: s (I + diag(s) Rot G Rot^T diag(s))^{-1} s (SparseDelassus::set_frames' operator
// on a dense G; rows with s = 0 map to 0).
struct DenseReduced {
  const MatX* G = nullptr;
  MatX M;
  bool factorize(const std::vector<Mat3>& frames, const VecX& s) {
    const Eigen::Index m = G->rows();
    MatX R = MatX::Zero(m, m);
    for (std::size_t a = 0; a < frames.size(); ++a) R.block<3, 3>(3 * a, 3 * a) = frames[a];
    const MatX K = s.asDiagonal() * R * (*G) * R.transpose() * s.asDiagonal();
    M = s.asDiagonal() * (MatX::Identity(m, m) + K).inverse() * s.asDiagonal();
    return true;
  }
};

// The operator path with the reduced preconditioner, G_AA and the preconditioner dense.
void compute_reduced(NcpDerivative& op, const MatX& G_AA, double L, const Problem& p, DenseReduced& reduced) {
  op.compute_operator(
      [&](const VecX& y, VecX& out) {
        out = G_AA * y;
        return true;
      },
      L, p.mu, p.lambda, p.sigma, p.modes, {},
      [&](const std::vector<Mat3>& frames, const VecX& s) { return reduced.factorize(frames, s); },
      [&](VecX& v) {
        v = reduced.M * v;
        return true;
      });
}

// GMRES with the reduced preconditioner stops at ||Dl Rot (r - J x)|| <= 1e-12 ||Dl Rot r||
// (forward; Rot orthogonal, Dl = diag(1, 1 / (L w)) with L w = L mu lambda_N / |sigma_T|
// on the sliding rows p), so ||r - J x|| <= kappa(Dl) 1e-12 ||r|| and ||x - x*|| <=
// ||r - J x|| / s_min(J); the adjoint's J'^T y' = Rot r gives ||r - J^T y|| <= 1e-12 ||r||
// (kappa(Dl) bounds both). Plus rounding: eps kappa(J) ||x*|| for the dense
// decomposition, eps kappa(Dl) ||r|| / s_min for GMRES's recomputed residual; a factor
// 10 of margin. Redundant (J singular, r outside its range): GMRES does not reach its
// tolerance and the CGLS follows: bound() (the sum of both is taken).
double bound_reduced(const MatX& J, const Problem& p, const std::vector<int>& act, double L, const VecX& x,
                     const VecX& r) {
  const Eigen::JacobiSVD<MatX> svd(J);
  const VecX sv = svd.singularValues();
  double s_min = sv[0];
  for (Eigen::Index k = 0; k < sv.size(); ++k)
    if (sv[k] > 1e-12 * sv[0]) s_min = sv[k];
  double dmax = 1, dmin = 1;
  for (int i : act)
    if (p.modes[i] == Mode::sliding && p.mu[i] > 0) {
      const double Lw = L * p.mu[i] * p.lambda[3 * i + 2] / p.sigma.segment<2>(3 * i).norm();
      dmax = std::max(dmax, 1 / Lw);
      dmin = std::min(dmin, 1 / Lw);
    }
  const double eps = std::numeric_limits<double>::epsilon(), kD = dmax / dmin;
  return bound(J, x, r) + 10 * ((1e-12 + eps) * kD * r.norm() / s_min + eps * sv[0] / s_min * x.norm());
}

// precondition: 0 none, 1 M = (G_AA + c I)^{-1}, 2 the reduced preconditioner (mixed sets).
void check(const std::vector<Mode>& modes, bool duplicate, double mu, const char* name, int precondition = 0) {
  const Problem p = make_problem(modes, 5, duplicate, mu);
  const int n = static_cast<int>(p.G.rows()), nc = n / 3;
  NcpDerivative dense, op;
  dense.compute(p.G, p.mu, p.lambda, p.sigma, p.modes);
  if (duplicate) {
    EXPECT_GT(dense.rank_deficiency(), 0) << name;
  }
  // G_AA of the active contacts as an operator.
  const std::vector<int> act = dense.active_contacts();
  const int na = static_cast<int>(act.size());
  MatX G_AA(3 * na, 3 * na);
  double L = 1e-300;
  for (int a = 0; a < na; ++a)
    for (int b = 0; b < na; ++b) G_AA.block<3, 3>(3 * a, 3 * b) = p.G.block<3, 3>(3 * act[a], 3 * act[b]);
  for (int a = 0; a < na; ++a) L = std::max(L, G_AA.block<3, 3>(3 * a, 3 * a).diagonal().maxCoeff());
  op.compute_operator(
      [&](const VecX& y, VecX& out) {
        out = G_AA * y;
        return true;
      },
      L, p.mu, p.lambda, p.sigma, p.modes);
  const MatX M = (G_AA + operator_shift_fraction * L * MatX::Identity(3 * na, 3 * na)).inverse();
  if (precondition) {
    op.compute_operator(
        [&](const VecX& y, VecX& out) {
          out = G_AA * y;
          return true;
        },
        L, p.mu, p.lambda, p.sigma, p.modes, [&](VecX& v) {
          v = M * v;
          return true;
        });
    ASSERT_TRUE(op.operator_system().preconditioned()) << name;
  }
  DenseReduced reduced{&G_AA, MatX()};
  if (precondition == 2) {
    compute_reduced(op, G_AA, L, p, reduced);
    ASSERT_FALSE(op.operator_system().preconditioned()) << name;
  }
  ASSERT_TRUE(op.on_operator()) << name;
  ASSERT_EQ(op.active_contacts(), act) << name;
  EXPECT_EQ(op.degenerate(), dense.degenerate()) << name;
  const MatX& J = dense.jacobian();
  ASSERT_EQ(J.rows(), 3 * na) << name;
  // Forward: random b and dmu (not in J's range when J is singular).
  for (unsigned seed = 10; seed < 13; ++seed) {
    const VecX b = test::random_vector(n, 1.0, seed), dmu = 0.2 * test::random_vector(nc, 1.0, seed + 100);
    VecX dl_dense, dl_op, r;
    dense.jvp(b, dmu, dl_dense);
    op.jvp(b, dmu, dl_op);
    dense.right_hand_side(b, dmu, r);
    ASSERT_GT(dl_dense.norm(), 0) << name;
    const double tol = precondition == 2   ? bound_reduced(J, p, act, L, dl_dense, r)
                       : precondition == 1 ? bound_preconditioned(J, M, dl_dense, r)
                                           : bound(J, dl_dense, r);
    std::printf("%s jvp: difference %.2e, bound %.2e (|dlambda| %.2e)\n", name, (dl_op - dl_dense).norm(), tol,
                dl_dense.norm());
    EXPECT_LE((dl_op - dl_dense).norm(), tol) << name << " jvp, seed " << seed << ": CGLS iterations "
                                              << op.operator_system().last_iterations();
    if (precondition == 2 && !duplicate) {
      EXPECT_TRUE(op.operator_system().reduced_used()) << name << ": GMRES with the reduced preconditioner";
      std::printf("%s jvp: %d GMRES iterations\n", name, op.operator_system().last_iterations());
    }
    // Reverse.
    VecX bb_dense, bm_dense, bb_op, bm_op;
    dense.vjp(b, bb_dense, bm_dense);
    op.vjp(b, bb_op, bm_op);
    VecX la(3 * na);
    for (int a = 0; a < na; ++a) la.segment<3>(3 * a) = b.segment<3>(3 * act[a]);
    // (bar_b, bar_mu) = (R^T y, D^T y): the bound on y times |(R, D)| <= max over the
    // blocks of 1 + |L P| + |D_i| (sliding: |L P| = L mu lambda_N / |sigma_T|,
    // |D_i| = L lambda_N).
    const VecX y_dense = J.transpose().completeOrthogonalDecomposition().solve(la);
    double RD = 1;
    for (int a = 0; a < na; ++a)
      if (p.modes[act[a]] == Mode::sliding && p.mu[act[a]] > 0) {
        const double lN = p.lambda[3 * act[a] + 2];
        RD = std::max(RD, 1 + L * p.mu[act[a]] * lN / p.sigma.segment<2>(3 * act[a]).norm() + L * lN);
      }
    const double tol_r =
        RD * (precondition == 2   ? bound_reduced(J.transpose(), p, act, L, y_dense, la)
              : precondition == 1 ? bound_preconditioned(J.transpose(), M, y_dense, la)
                                  : bound(J.transpose(), y_dense, la));
    std::printf("%s vjp: difference %.2e, bound %.2e (|bar_b| %.2e)\n", name,
                (bb_op - bb_dense).norm() + (bm_op - bm_dense).norm(), tol_r, bb_dense.norm());
    EXPECT_LE((bb_op - bb_dense).norm() + (bm_op - bm_dense).norm(), tol_r) << name << " vjp, seed " << seed;
  }
  // The reverse mode is the transpose of the forward one, column by column: e_k^T
  // (d dlambda / d b) from jvp equals bar_b's entry k of the vjp of e_j.
  MatX Jf(n, n), Jr(n, n);
  for (int k = 0; k < n; ++k) {
    VecX col, bb, bm;
    op.jvp(VecX::Unit(n, k), VecX(), col);
    Jf.col(k) = col;
    op.vjp(VecX::Unit(n, k), bb, bm);
    Jr.row(k) = bb.transpose();
  }
  const auto cmp = test::compare(Jr, Jf);
  EXPECT_LT(cmp.rel_error, 1e-9) << name << " vjp rows against jvp columns: " << cmp.str();
}

}  // namespace test_mode_system_local

using test_mode_system_local::check;

TEST(OperatorModeSystem, OnlySticking) { check(std::vector<Mode>(5, Mode::sticking), false, 0.5, "sticking"); }
TEST(OperatorModeSystem, OnlySliding) { check(std::vector<Mode>(5, Mode::sliding), false, 0.5, "sliding"); }
TEST(OperatorModeSystem, Mixed) {
  check({Mode::sticking, Mode::sliding, Mode::breaking, Mode::sliding, Mode::sticking, Mode::breaking}, false, 0.5,
        "mixed");
}
TEST(OperatorModeSystem, Frictionless) {
  check({Mode::sliding, Mode::sliding, Mode::breaking, Mode::sliding}, false, 0.0, "frictionless");
}
TEST(OperatorModeSystem, RedundantSticking) {
  check({Mode::sticking, Mode::sticking, Mode::breaking, Mode::sticking, Mode::sticking}, true, 0.5,
        "redundant sticking");
}
TEST(OperatorModeSystem, RedundantMixed) {
  check({Mode::sticking, Mode::sliding, Mode::breaking, Mode::sticking, Mode::sticking}, true, 0.5, "redundant mixed");
}
TEST(OperatorModeSystem, RedundantSliding) {
  check({Mode::sliding, Mode::sliding, Mode::sticking, Mode::sliding}, true, 0.5, "redundant sliding");
}
// Preconditioned by (G_AA + c I)^{-1} (mode_system.hpp): every contact sticking, PCG (and,
// redundant with right-hand sides outside the range, CGLS on G M: still G^+ r, M being a
// function of G); and the mixed (invertible) system by CGLS on J M: J^{-1} r.
TEST(OperatorModeSystem, PreconditionedSticking) {
  check(std::vector<Mode>(5, Mode::sticking), false, 0.5, "preconditioned sticking", 1);
}
TEST(OperatorModeSystem, PreconditionedRedundantSticking) {
  check({Mode::sticking, Mode::sticking, Mode::breaking, Mode::sticking, Mode::sticking}, true, 0.5,
        "preconditioned redundant sticking", 1);
}
TEST(OperatorModeSystem, PreconditionedMixed) {
  check({Mode::sticking, Mode::sliding, Mode::breaking, Mode::sliding, Mode::sticking, Mode::breaking}, false, 0.5,
        "preconditioned mixed", 1);
}
// The reduced preconditioner of mixed sets (mode_system.hpp "Mixed sets"): GMRES on the
// rotated, row-scaled system, right-preconditioned by the Delassus of the reduced
// directions plus C; the local rows exact. Mixed, all sliding, frictionless (every
// tangential row local) and a mixed set of 36 active contacts (of 40, 14 sliding); the
// step's operator on more than 64 is test_step_derivatives_contact.cpp's.
TEST(OperatorModeSystem, ReducedMixed) {
  check({Mode::sticking, Mode::sliding, Mode::breaking, Mode::sliding, Mode::sticking, Mode::breaking}, false, 0.5,
        "reduced mixed", 2);
}
TEST(OperatorModeSystem, ReducedSliding) {
  check(std::vector<Mode>(5, Mode::sliding), false, 0.5, "reduced sliding", 2);
}
TEST(OperatorModeSystem, ReducedFrictionless) {
  check({Mode::sliding, Mode::sliding, Mode::breaking, Mode::sticking}, false, 0.0, "reduced frictionless", 2);
}
TEST(OperatorModeSystem, ReducedLargeMixed) {
  std::vector<Mode> modes(40, Mode::sticking);
  for (int i = 0; i < 40; i += 3) modes[i] = Mode::sliding;
  for (int i = 1; i < 40; i += 10) modes[i] = Mode::breaking;
  check(modes, false, 0.5, "reduced large mixed", 2);
}
// Redundant (contact 4 a copy of contact 0: J singular). Right-hand sides outside J's
// range: GMRES does not reach its tolerance, the CGLS follows (J^+ r, as the dense
// path; checked by check()). A consistent right-hand side r = J x0: GMRES converges to a
// solution x of J x = r, which may differ from J^+ r by an element of null(J): its
// residual and its component in range(J^T) are checked against the dense answer.
TEST(OperatorModeSystem, ReducedRedundantMixed) {
  const std::vector<Mode> modes = {Mode::sticking, Mode::sliding, Mode::breaking, Mode::sticking, Mode::sticking};
  check(modes, true, 0.5, "reduced redundant mixed", 2);
  using namespace test_mode_system_local;
  const Problem p = make_problem(modes, 5, true, 0.5);
  NcpDerivative dense, op;
  dense.compute(p.G, p.mu, p.lambda, p.sigma, p.modes);
  const std::vector<int> act = dense.active_contacts();
  const int na = static_cast<int>(act.size());
  MatX G_AA(3 * na, 3 * na);
  for (int a = 0; a < na; ++a)
    for (int b = 0; b < na; ++b) G_AA.block<3, 3>(3 * a, 3 * b) = p.G.block<3, 3>(3 * act[a], 3 * act[b]);
  const double L = p.G.diagonal().maxCoeff();  // the dense path's scale: the same J
  DenseReduced reduced{&G_AA, MatX()};
  compute_reduced(op, G_AA, L, p, reduced);
  const MatX& J = dense.jacobian();
  const Eigen::CompleteOrthogonalDecomposition<MatX> cod(J);
  ASSERT_LT(cod.rank(), J.rows());
  for (int transposed = 0; transposed < 2; ++transposed) {
    const MatX Jt = transposed ? MatX(J.transpose()) : J;
    const VecX r = Jt * test::random_vector(3 * na, 1.0, 40 + transposed);  // in range(Jt)
    VecX x;
    ASSERT_TRUE(op.operator_system().solve(r, x, transposed)) << transposed;
    EXPECT_TRUE(op.operator_system().reduced_used()) << transposed;
    const VecX x_min = Jt.completeOrthogonalDecomposition().solve(r);  // Jt^+ r
    // The component of x in range(Jt^T) is Jt^+ Jt x = Jt^+ (r - s), s = r - Jt x.
    const VecX x_range = Jt.completeOrthogonalDecomposition().solve(VecX(Jt * x));
    const double residual = (Jt * x - r).norm();
    const double tol = bound_reduced(Jt, p, act, L, x_min, r);
    std::printf("reduced redundant mixed, consistent (%s): |J x - r| %.2e, |P(x) - J^+ r| %.2e, "
                "|x - J^+ r| %.2e, bound %.2e, %d GMRES iterations\n",
                transposed ? "transposed" : "forward", residual, (x_range - x_min).norm(), (x - x_min).norm(), tol,
                op.operator_system().last_iterations());
    EXPECT_LE((x_range - x_min).norm(), tol) << transposed;
    EXPECT_LE(residual, tol * Jt.norm()) << transposed;
  }
}

// The scale's power iteration (mode_system.hpp power_iteration; docs/method.md "The
// derivative's scale") against the closed form: G = Q diag(d) Q^T with Q a random
// orthogonal matrix and d_k = 2^-k (k = 0..29), so lambda_max = 1 and the gap ratio
// rho = lambda_2 / lambda_1 = 1/2. The estimates are Rayleigh quotients of the iterates:
// lower bounds of lambda_max (to rounding, 1e-14), increasing. Asymptotically the error
// e_k ~ C rho^(2k) and the change between successive estimates e_{k-1} - e_k ~ e_k
// (rho^-2 - 1), so at the stopping rule (change <= tol) e <= tol rho^2 / (1 - rho^2) =
// tol / 3; a factor 2 of margin for the pre-asymptotic iterations. Also: a cap of one
// product cannot converge (two estimates are needed), and a failing product is reported.
TEST(OperatorModeSystem, PowerIterationScale) {
  const int n = 30;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  MatX X(n, n);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) X(r, c) = u(rng);
  const MatX Q = Eigen::HouseholderQR<MatX>(X).householderQ();
  VecX d(n);
  for (int k = 0; k < n; ++k) d[k] = std::pow(0.5, k);
  const MatX G = Q * d.asDiagonal() * Q.transpose();
  const OperatorModeSystem::Apply apply = [&](const VecX& y, VecX& o) {
    o = G * y;
    return true;
  };
  for (const double tol : {1e-2, 1e-3, 1e-6}) {
    VecX y = VecX::Ones(n), Gy;
    const PowerIteration p = power_iteration(apply, y, Gy, tol, 200);
    const double error = (1 - p.value) / 1.0;
    std::printf("tolerance %.0e: %d products, estimate %.15f, relative error %.2e (bound %.2e)\n", tol, p.iterations,
                p.value, error, 2 * tol / 3);
    EXPECT_TRUE(p.converged);
    EXPECT_FALSE(p.failed);
    EXPECT_GE(error, -1e-14);  // a lower bound
    EXPECT_LE(error, 2 * tol / 3);
  }
  {
    VecX y = VecX::Ones(n), Gy;
    const PowerIteration p = power_iteration(apply, y, Gy, 1e-3, 1);
    EXPECT_FALSE(p.converged);
    EXPECT_FALSE(p.failed);
    EXPECT_EQ(p.iterations, 1);
  }
  {
    VecX y = VecX::Ones(n), Gy;
    const PowerIteration p = power_iteration([](const VecX&, VecX&) { return false; }, y, Gy, 1e-3, 50);
    EXPECT_TRUE(p.failed);
    EXPECT_FALSE(p.converged);
  }
}

