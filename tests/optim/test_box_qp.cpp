// The bound-constrained QP of the inverse-dynamics step (optim/box_qp.hpp): on random
// strictly convex problems (n = 1..10, bounds of every kind: two-sided, one-sided,
// infinite, equal), the solution satisfies KKT to 1e-10 relative and agrees with NLopt's
// SLSQP (an independent method: sequential quadratic programming with the same bounds,
// run to xtol_rel 1e-14) in the objective to 1e-9 relative and in d to 1e-6; and
// special cases: unconstrained (d = -H^{-1} g), all bounds active, a fixed variable.
#include <softdiff/optim/box_qp.hpp>

#include <gtest/gtest.h>
#include <nlopt.hpp>

#include <Eigen/Dense>

#include <cmath>
#include <limits>
#include <random>

using namespace softdiff;

namespace {

struct Problem {
  MatX H;
  VecX g, lo, hi;
};

double objective(const Problem& p, const VecX& d) { return 0.5 * d.dot(p.H * d) + p.g.dot(d); }

Problem random_problem(int n, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Problem p;
  MatX A(n + 2, n);
  for (int i = 0; i < A.size(); ++i) A.data()[i] = u(rng);
  p.H = A.transpose() * A + 0.05 * MatX::Identity(n, n);
  p.g = VecX(n);
  p.lo = VecX(n);
  p.hi = VecX(n);
  const double inf = std::numeric_limits<double>::infinity();
  for (int i = 0; i < n; ++i) {
    p.g[i] = 3 * u(rng);
    const int kind = static_cast<int>(rng() % 5);
    const double a = u(rng), b = a + 0.5 * (1 + u(rng));
    p.lo[i] = kind == 1 ? -inf : a;
    p.hi[i] = kind == 2 ? inf : b;
    if (kind == 3) p.lo[i] = p.hi[i] = a;  // fixed
    if (kind == 4) p.lo[i] = -inf, p.hi[i] = inf;
  }
  return p;
}

VecX slsqp(const Problem& p) {
  const int n = static_cast<int>(p.g.size());
  nlopt::opt opt(nlopt::LD_SLSQP, static_cast<unsigned>(n));
  std::vector<double> lo(p.lo.data(), p.lo.data() + n), hi(p.hi.data(), p.hi.data() + n);
  // SLSQP needs finite, distinct bounds: widen the infinite ones far beyond the solution
  // and give a fixed variable its value.
  for (int i = 0; i < n; ++i) {
    if (!std::isfinite(lo[i])) lo[i] = -1e6;
    if (!std::isfinite(hi[i])) hi[i] = 1e6;
  }
  opt.set_lower_bounds(lo);
  opt.set_upper_bounds(hi);
  auto f = [](const std::vector<double>& x, std::vector<double>& grad, void* data) {
    const Problem& q = *static_cast<const Problem*>(data);
    const Eigen::Map<const VecX> d(x.data(), static_cast<Eigen::Index>(x.size()));
    const VecX gr = q.H * d + q.g;
    if (!grad.empty()) for (std::size_t i = 0; i < grad.size(); ++i) grad[i] = gr[static_cast<Eigen::Index>(i)];
    return 0.5 * d.dot(q.H * d) + q.g.dot(d);
  };
  opt.set_min_objective(f, const_cast<Problem*>(&p));
  opt.set_xtol_rel(1e-14);
  opt.set_ftol_rel(1e-16);
  opt.set_maxeval(10000);
  std::vector<double> x(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) x[static_cast<std::size_t>(i)] = std::clamp(0.0, lo[i], hi[i]);
  double value = 0;
  try {
    opt.optimize(x, value);
  } catch (const nlopt::roundoff_limited&) {
  }
  return Eigen::Map<const VecX>(x.data(), n);
}

TEST(BoxQp, RandomProblemsSatisfyKktAndAgreeWithSlsqp) {
  std::mt19937 rng(17);
  int active_total = 0;
  for (int trial = 0; trial < 200; ++trial) {
    const int n = 1 + trial % 10;
    const Problem p = random_problem(n, rng);
    const optim::BoxQpResult r = optim::solve_box_qp(p.H, p.g, p.lo, p.hi);
    ASSERT_TRUE(r.converged) << trial;
    EXPECT_LE(r.kkt, 1e-10) << trial;
    EXPECT_LE(optim::kkt_residual(p.H, p.g, p.lo, p.hi, r.d), 1e-10) << trial;
    const VecX ref = slsqp(p);
    const double f = objective(p, r.d), f_ref = objective(p, ref);
    EXPECT_LE(f, f_ref + 1e-9 * std::max(1.0, std::abs(f_ref))) << trial;  // never worse than SLSQP
    EXPECT_NEAR(f, f_ref, 1e-9 * std::max(1.0, std::abs(f_ref))) << trial;
    EXPECT_LE((r.d - ref).lpNorm<Eigen::Infinity>(), 1e-6) << trial << "\n" << r.d.transpose() << "\n" << ref.transpose();
    for (int i = 0; i < n; ++i) active_total += r.d[i] == p.lo[i] || r.d[i] == p.hi[i];
  }
  EXPECT_GT(active_total, 100);  // the bounds mattered
}

TEST(BoxQp, IllConditionedOverActuatedProblemsConverge) {
  // Random problems shaped as the Trunk's: J^T J of a 3 x 8 Jacobian (rank 3) plus a
  // relative 1e-6 regularization, condition ~1e6-1e7 (the dumped Trunk QP below is the
  // one that reproduces the former iteration-cap failure; these random ones did not).
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int trial = 0; trial < 200; ++trial) {
    MatX J(3, 8);
    for (int i = 0; i < J.size(); ++i) J.data()[i] = 0.1 * u(rng);
    const MatX H = J.transpose() * J + 1e-6 * J.squaredNorm() / 8 * MatX::Identity(8, 8);
    VecX g(8), lo(8), hi(8);
    for (int i = 0; i < 8; ++i) {
      g[i] = 0.05 * u(rng);
      lo[i] = -0.1 * (1 + u(rng));
      hi[i] = 0.1 * (1 + u(rng));
    }
    const optim::BoxQpResult r = optim::solve_box_qp(H, g, lo, hi);
    EXPECT_TRUE(r.converged) << trial << ": " << r.iterations << " iterations";
    EXPECT_LT(r.iterations, 40) << trial;
    EXPECT_LE(r.kkt, 1e-8) << trial;
  }
}

TEST(BoxQp, TheTrunkQpThatOnceHitTheIterationCap) {
  // A QP of the Trunk demo (control_trunk_demo, step 1 from rest: 8 cables, condition
  // ~4e6 from the relative 1e-6 regularization of a rank-3 J^T J), dumped as it was.
  // Recomputing the step at the working set's minimizer gave round-off steps above the
  // stationarity threshold, and the iteration took them until its cap of 200; now it
  // converges in a few iterations.
  const int n = 8;
  const double h[] = {4.4934881704600773e-06, 2.4153655001109588e-07, -3.6726413893798755e-06, 1.2585201358966665e-07, 9.433229758887986e-07, 3.1014627832668698e-08, -4.5261509156725719e-07, 1.3894367428452017e-08, 2.4153655001109588e-07, 4.751493560353159e-06, 3.6990787939078637e-07, -4.385365837700531e-06, 6.2655264133780667e-08, 1.0650611209298448e-06, 3.5519002705189685e-07, -8.8940779141512905e-07, -3.6726413893798755e-06, 3.6990787939078637e-07, 4.3092700548565345e-06, 1.7537282336031631e-07, -7.9131641804658723e-07, 1.0590444141538404e-07, 1.1524136126025642e-06, 1.5771908208073443e-07, 1.2585201358966665e-07, -4.385365837700531e-06, 1.7537282336031631e-07, 4.5961838661336456e-06, 1.2393364648441551e-09, -9.8223870970075884e-07, 1.1363992943541293e-07, 1.0042795970094222e-06, 9.433229758887986e-07, 6.2655264133780667e-08, -7.9131641804658723e-07, 1.2393364648441551e-09, 1.9844694552641487e-07, 9.1234475942113723e-09, -1.0699009939971692e-07, -4.1632804273420952e-09, 3.1014627832668698e-08, 1.0650611209298448e-06, 1.0590444141538404e-07, -9.8223870970075884e-07, 9.1234475942113723e-09, 2.3887094966876493e-07, 8.4387247201055985e-08, -1.9879284875871566e-07, -4.5261509156725719e-07, 3.5519002705189685e-07, 1.1524136126025642e-06, 1.1363992943541293e-07, -1.0699009939971692e-07, 8.4387247201055985e-08, 5.1421959445189654e-07, 9.1201529424634395e-08, 1.3894367428452017e-08, -8.8940779141512905e-07, 1.5771908208073443e-07, 1.0042795970094222e-06, -4.1632804273420952e-09, -1.9879284875871566e-07, 9.1201529424634395e-08, 2.2856203390838264e-07};
  const double gv[] = {2.925166764395202e-07, -2.2110065606014909e-08, 2.2751053662214302e-07, 3.4886125738491577e-07, 5.304861501239687e-08, -4.974878474566064e-09, 2.476249096958317e-07, 1.1277501514645092e-07}, lov[] = {0, -0.17015751028178075, 0, 0, 0, 0, 0, 0}, hiv[] = {0.25, 0.079842489718219251, 0.25, 0.25, 0.45000000000000001, 0.45000000000000001, 0.45000000000000001, 0.45000000000000001};
  const MatX H = Eigen::Map<const MatX>(h, n, n);
  const VecX g = Eigen::Map<const VecX>(gv, n), lo = Eigen::Map<const VecX>(lov, n), hi = Eigen::Map<const VecX>(hiv, n);
  const optim::BoxQpResult r = optim::solve_box_qp(H, g, lo, hi);
  EXPECT_TRUE(r.converged);
  EXPECT_LT(r.iterations, 40);
  EXPECT_LE(r.kkt, 1e-12);
}

TEST(BoxQp, SpecialCases) {
  MatX H(2, 2);
  H << 2, 0.5, 0.5, 1;
  const VecX g = (VecX(2) << -1, 2).finished();
  const double inf = std::numeric_limits<double>::infinity();
  const VecX free_lo = VecX::Constant(2, -inf), free_hi = VecX::Constant(2, inf);
  auto r = optim::solve_box_qp(H, g, free_lo, free_hi);
  EXPECT_LE((r.d - H.ldlt().solve(-g)).norm(), 1e-14);
  // Both at bounds: the unconstrained minimizer (1, -2.5)/1.75 ... lies outside [0, 0.1]^2.
  r = optim::solve_box_qp(H, g, VecX::Zero(2), VecX::Constant(2, 0.1));
  EXPECT_TRUE(r.converged);
  EXPECT_EQ(r.d[0], 0.1);
  EXPECT_EQ(r.d[1], 0.0);
  EXPECT_LE(r.kkt, 1e-14);
  // A fixed variable (lo == hi) stays at its value.
  r = optim::solve_box_qp(H, g, (VecX(2) << 0.3, -inf).finished(), (VecX(2) << 0.3, inf).finished());
  EXPECT_EQ(r.d[0], 0.3);
  EXPECT_NEAR(r.d[1], -(g[1] + 0.5 * 0.3) / 1.0, 1e-14);
}

}  // namespace
