// Contact-force derivatives (ncp_derivatives.hpp): dlambda from the implicit function
// theorem with the modes fixed, against central differences of the NCP solver itself,
// for problems built around a known, strictly complementary solution (only breaking,
// only sticking, only sliding, mixed), so that the modes do not switch within the
// step; the reverse mode against the forward one; a redundant problem (a duplicated
// contact) is rank-deficient, counted, and still gives finite, consistent derivatives.
//
// Step: 1e-6 relative to the perturbed quantities (g, G, mu of size ~1); the solver
// (tolerance 1e-14, polished) returns lambda to ~1e-15, so the differences carry
// ~1e-9: tolerance 1e-6.
#include <softdiff/contact/ncp.hpp>
#include <softdiff/contact/ncp_derivatives.hpp>

#include <support/fd.hpp>

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;
using namespace softdiff::contact;

namespace {

struct Problem {
  MatX G;
  VecX g, mu, lambda, sigma;
  std::vector<Mode> modes;
};

// nc contacts with the given modes, G = W W^T + 0.1 I (full rank) unless duplicate:
// then contact nc-1 repeats contact 0 (same rows of H, so G is singular).
Problem make_problem(const std::vector<Mode>& modes, unsigned seed, bool duplicate = false) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  const int nc = static_cast<int>(modes.size()), n = 3 * nc;
  Problem p;
  MatX H = MatX::Zero(n, n + 3);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n + 3; ++c) H(r, c) = u(rng);
  if (duplicate) H.bottomRows<3>() = H.topRows<3>();
  p.G = H * H.transpose() / n;
  if (!duplicate) p.G += 0.1 * MatX::Identity(n, n);
  p.mu = VecX::Constant(nc, 0.5);
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
        p.lambda.segment<3>(3 * i) = Vec3(-p.mu[i] * lN * dir[0], -p.mu[i] * lN * dir[1], lN);
        break;
    }
  }
  if (duplicate) {
    // The duplicated contact shares contact 0's state (and so its sigma).
    p.sigma.tail<3>() = p.sigma.head<3>();
    p.lambda.tail<3>() = p.lambda.head<3>();
  }
  p.g = p.sigma - p.G * p.lambda;
  p.modes = modes;
  return p;
}

NcpOptions precise() {
  NcpOptions o;
  o.tolerance = 1e-14;
  o.max_iterations = 20000;
  o.working_set = false;
  return o;
}

VecX solve(const MatX& G, const VecX& g, const VecX& mu, const VecX& warm, std::vector<Mode>& modes) {
  NcpSolver s;
  VecX lambda = warm, sigma;
  s.solve(G, g, mu, precise(), lambda, sigma, modes);
  return lambda;
}

VecX random_vector(Eigen::Index n, unsigned seed) { return test::random_vector(n, 1.0, seed); }

void check_against_differences(const std::vector<Mode>& modes, const char* name) {
  const Problem p = make_problem(modes, 5);
  const int n = static_cast<int>(p.g.size()), nc = n / 3;
  // The known solution is the solver's (modes included).
  std::vector<Mode> m0;
  const VecX l0 = solve(p.G, p.g, p.mu, p.lambda, m0);
  ASSERT_LE((l0 - p.lambda).norm(), 1e-10 * std::max(1.0, p.lambda.norm())) << name;
  ASSERT_EQ(m0, p.modes) << name;
  NcpDerivative d;
  d.compute(p.G, p.mu, p.lambda, p.sigma, p.modes);
  EXPECT_EQ(d.rank_deficiency(), 0) << name;
  // A random direction in g, G (symmetric) and mu.
  const VecX dg = random_vector(n, 6), dmu = 0.2 * random_vector(nc, 7);
  MatX dG = MatX::Zero(n, n);
  {
    const VecX a = random_vector(n * n, 8);
    dG = Eigen::Map<const MatX>(a.data(), n, n);
    dG = 0.05 * (dG + dG.transpose()).eval();
  }
  const double e = 1e-6;
  std::vector<Mode> mp, mm;
  const VecX lp = solve(p.G + e * dG, p.g + e * dg, p.mu + e * dmu, p.lambda, mp);
  const VecX lm = solve(p.G - e * dG, p.g - e * dg, p.mu - e * dmu, p.lambda, mm);
  ASSERT_EQ(mp, p.modes) << name << ": the modes switched within the step";
  ASSERT_EQ(mm, p.modes) << name;
  const VecX fd = (lp - lm) / (2 * e);
  VecX dl;
  d.jvp(dG * p.lambda + dg, dmu, dl);
  if (fd.norm() == 0) {
    EXPECT_EQ(dl.norm(), 0) << name;
  } else {
    EXPECT_LE((dl - fd).norm(), 1e-6 * fd.norm()) << name << ": analytic\n" << dl.transpose() << "\nfd\n" << fd.transpose();
  }
  // Reverse mode: <w, J d> = <J^T w, d>.
  const VecX w = random_vector(n, 9);
  VecX bar_b, bar_mu;
  d.vjp(w, bar_b, bar_mu);
  const VecX b = dG * p.lambda + dg;
  const double lhs = w.dot(dl), rhs = bar_b.dot(b) + bar_mu.dot(dmu);
  EXPECT_NEAR(lhs, rhs, 1e-12 * (w.norm() * dl.norm() + 1e-300)) << name;
}

TEST(NcpDerivatives, OnlyBreaking) {
  check_against_differences(std::vector<Mode>(5, Mode::breaking), "breaking");
}
TEST(NcpDerivatives, OnlySticking) {
  check_against_differences(std::vector<Mode>(5, Mode::sticking), "sticking");
}
TEST(NcpDerivatives, OnlySliding) {
  check_against_differences(std::vector<Mode>(5, Mode::sliding), "sliding");
}
TEST(NcpDerivatives, Mixed) {
  check_against_differences({Mode::sticking, Mode::sliding, Mode::breaking, Mode::sliding, Mode::sticking, Mode::breaking},
                            "mixed");
}

TEST(NcpDerivatives, RedundantContactsAreRankDeficientButFinite) {
  // Contact 4 duplicates contact 0 (both sticking): G is singular, J loses 3 dimensions;
  // the minimum-norm dlambda is finite and keeps the sticking contacts stuck.
  const std::vector<Mode> modes = {Mode::sticking, Mode::sliding, Mode::breaking, Mode::sticking, Mode::sticking};
  const Problem p = make_problem(modes, 11, /*duplicate=*/true);
  NcpDerivative d;
  d.compute(p.G, p.mu, p.lambda, p.sigma, p.modes);
  EXPECT_EQ(d.rank_deficiency(), 3);
  const VecX b = random_vector(p.g.size(), 12);
  VecX dl;
  d.jvp(b, {}, dl);
  ASSERT_TRUE(dl.allFinite());
  const VecX dsigma = p.G * dl + b;
  // The duplicate has the same rows: b must match for consistency, so compare the
  // sticking velocity change of contact 3 (not duplicated) only.
  EXPECT_LT(dsigma.segment<3>(9).norm(), 1e-8 * b.norm());
  // The two copies of the duplicated contact share their force change (minimum norm).
  EXPECT_LT((dl.segment<3>(0) - dl.segment<3>(12)).norm(), 1e-8 * dl.norm());
  // The reverse mode is still the transpose (the pseudo-inverse's transpose).
  const VecX w = random_vector(p.g.size(), 13);
  VecX bar_b, bar_mu;
  d.vjp(w, bar_b, bar_mu);
  EXPECT_NEAR(w.dot(dl), bar_b.dot(b), 1e-12 * w.norm() * dl.norm());
}

}  // namespace
