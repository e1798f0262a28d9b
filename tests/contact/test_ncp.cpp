#include <softdiff/core/avx512_gcc12.hpp>  // first: see there
// The frictional contact NCP solvers (contact/ncp.hpp): analytic single contacts,
// random Delassus problems (full rank and rank-deficient, mu in {0, 0.3, 10}), warm
// start, failure reporting, the residual check itself, and the polish.
#include <softdiff/contact/ncp.hpp>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <cmath>
#include <gtest/gtest.h>
#include <iostream>
#include <limits>
#include <random>
#include <string>

// Allocation counter: this executable's malloc/calloc/realloc count and forward to
// glibc's (symbol interposition; sanitizer builds bring their own allocator, so the
// counter is off there and the allocation test is skipped).
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define SOFTDIFF_NCP_COUNT_MALLOC 0
#else
#define SOFTDIFF_NCP_COUNT_MALLOC 1
namespace {
long g_mallocs = 0;
}
extern "C" {
void* __libc_malloc(size_t);
void* __libc_calloc(size_t, size_t);
void* __libc_realloc(void*, size_t);
void* malloc(size_t n) {
  ++g_mallocs;
  return __libc_malloc(n);
}
void* calloc(size_t a, size_t b) {
  ++g_mallocs;
  return __libc_calloc(a, b);
}
void* realloc(void* p, size_t n) {
  ++g_mallocs;
  return __libc_realloc(p, n);
}
}
#endif

namespace softdiff::contact {
namespace {

struct Problem {
  MatX G;
  VecX g, mu;
};

struct Solved {
  NcpResult result;
  VecX lambda, sigma;
  std::vector<Mode> modes;
};

const char* name(NcpSolverKind kind) { return kind == NcpSolverKind::admm ? "admm" : "pgs"; }

// The solvers themselves (ADMM, PGS, polish) on the whole problem: the working set is
// off here (its tests below turn it on), so that iteration counts are the solver's.
Solved solve(const Problem& p, NcpSolverKind kind, double tolerance, bool polish, int max_iterations = 20000,
             const VecX* warm = nullptr, bool working_set = false) {
  NcpOptions o;
  o.working_set = working_set;
  o.solver = kind;
  o.tolerance = tolerance;
  o.polish = polish;
  o.max_iterations = max_iterations;
  Solved s;
  s.lambda = warm ? *warm : VecX::Zero(p.g.size());
  NcpSolver solver;
  s.result = solver.solve(p.G, p.g, p.mu, o, s.lambda, s.sigma, s.modes);
  return s;
}

// The NCP conditions checked directly (not through ncp_residuals): per contact,
// lambda in K (lambda_N >= 0, ||lambda_T|| <= mu lambda_N), sigma + Gamma in K*
// (equivalent to sigma_N >= 0), complementarity lambda . (sigma + Gamma) = 0
// (= lambda_N sigma_N + (lambda_T . sigma_T + mu lambda_N ||sigma_T||): both terms are
// >= 0 for a feasible pair, so both vanish separately at a solution), with the scales
// of ncp.hpp. The residual bounds dist(sigma + Gamma, K*) = -sigma_N / sqrt(1 + mu^2)
// (distance to the cone's boundary plane), hence the factor sqrt(1 + mu^2) on sigma_N
// and, through it, on the split products. Also sigma is G lambda + g.
void expect_ncp_solution(const Problem& p, const Solved& s, double tol, const std::string& where) {
  const int nc = static_cast<int>(p.mu.size());
  ASSERT_EQ(s.lambda.size(), 3 * nc) << where;
  ASSERT_TRUE(s.lambda.allFinite()) << where;
  const VecX sigma = p.G * s.lambda + p.g;
  const double ls = std::max(s.lambda.cwiseAbs().maxCoeff(), 1e-300);
  const double vs = std::max(p.g.cwiseAbs().maxCoeff(), 1e-300);
  EXPECT_LE((sigma - s.sigma).cwiseAbs().maxCoeff(), 1e-12 * vs) << where << ": sigma is not G lambda + g";
  for (int i = 0; i < nc; ++i) {
    const Vec3 l = s.lambda.segment<3>(3 * i), v = sigma.segment<3>(3 * i);
    const double mu = p.mu[i];
    const double f = std::sqrt(1 + mu * mu);
    EXPECT_GE(l[2], -tol * ls) << where << " contact " << i;
    EXPECT_LE(l.head<2>().norm(), mu * l[2] + tol * ls) << where << " contact " << i;
    EXPECT_GE(v[2], -f * tol * vs) << where << " contact " << i;
    EXPECT_LE(std::abs(l[2] * v[2]), 2 * f * tol * ls * vs) << where << " contact " << i;
    EXPECT_LE(std::abs(l.head<2>().dot(v.head<2>()) + mu * l[2] * v.head<2>().norm()), 2 * f * tol * ls * vs)
        << where << " contact " << i;
  }
}

// ---------------------------------------------------------------------------
// One contact, analytic solutions.

// A diagonally dominant SPD block (a point mass near a stiff coupling).
MatX block_G() {
  MatX G(3, 3);
  G << 2.0, 0.3, -0.2,  //
      0.3, 1.5, 0.25,   //
      -0.2, 0.25, 1.8;
  return G;
}

Problem single(const MatX& G, const Vec3& g, double mu) { return {G, g, VecX::Constant(1, mu)}; }

class SingleContact : public ::testing::TestWithParam<NcpSolverKind> {};

TEST_P(SingleContact, FreeIsBreaking) {
  const Problem p = single(block_G(), Vec3(0.1, -0.2, 0.5), 0.5);
  const Solved s = solve(p, GetParam(), 1e-12, true);
  EXPECT_TRUE(s.result.converged);
  EXPECT_LE(s.result.residuals.max(), 1e-12);
  EXPECT_EQ(s.lambda, VecX::Zero(3));
  EXPECT_EQ(s.modes[0], Mode::breaking);
  EXPECT_EQ(s.result.breaking, 1);
  EXPECT_LE((s.sigma - p.g).norm(), 1e-15);
}

TEST_P(SingleContact, FrictionlessImpact) {
  const Problem p = single(block_G(), Vec3(0.3, 0.1, -1.0), 0.0);
  const Solved s = solve(p, GetParam(), 1e-12, true);
  EXPECT_TRUE(s.result.converged);
  EXPECT_LE(s.result.residuals.max(), 1e-12);
  const Vec3 expected(0, 0, 1.0 / 1.8);  // lambda_N = -g_N / G_NN, lambda_T = 0 (mu = 0)
  EXPECT_LE((s.lambda - expected).norm(), 1e-10) << s.lambda.transpose();
  EXPECT_NEAR(s.sigma[2], 0, 1e-12);
  EXPECT_EQ(s.modes[0], Mode::sliding);  // mu = 0: the tangential velocity is free
  std::cout << name(GetParam()) << " impact: " << s.result.iterations << " iterations, residual "
            << s.result.residuals.max() << (s.result.polished ? " (polished)" : "") << "\n";
}

TEST_P(SingleContact, Sticking) {
  const MatX G = block_G();
  const Vec3 g(0.05, -0.04, -1.0);
  const double mu = 0.5;
  const Vec3 expected = -Mat3(G).llt().solve(g);  // sigma = 0
  ASSERT_GT(expected[2], 0);
  ASSERT_LT(expected.head<2>().norm(), 0.5 * mu * expected[2]);  // strictly inside: sticking is the solution
  const Problem p = single(G, g, mu);
  const Solved s = solve(p, GetParam(), 1e-12, true);
  EXPECT_TRUE(s.result.converged);
  EXPECT_LE(s.result.residuals.max(), 1e-12);
  EXPECT_LE((s.lambda - expected).norm(), 1e-10) << s.lambda.transpose();
  EXPECT_LE(s.sigma.norm(), 1e-12);
  EXPECT_EQ(s.modes[0], Mode::sticking);
  std::cout << name(GetParam()) << " sticking: " << s.result.iterations << " iterations, residual "
            << s.result.residuals.max() << (s.result.polished ? " (polished)" : "") << "\n";
}

TEST_P(SingleContact, Sliding) {
  // G = I / m: lambda_N = -m g_N, lambda_T = -mu lambda_N g_T / |g_T| (the tangential
  // velocity keeps its direction: sigma_T = g_T (1 - mu |g_N| / |g_T|)), sigma_N = 0.
  const double m = 2.0, mu = 0.3;
  const Vec3 g(1.0, 0.5, -1.0);
  const Problem p = single(MatX::Identity(3, 3) / m, g, mu);
  Vec3 expected;
  expected[2] = -m * g[2];
  expected.head<2>() = -mu * expected[2] * g.head<2>() / g.head<2>().norm();
  const Solved s = solve(p, GetParam(), 1e-12, true);
  EXPECT_TRUE(s.result.converged);
  EXPECT_LE(s.result.residuals.max(), 1e-12);
  EXPECT_LE((s.lambda - expected).norm(), 1e-10) << s.lambda.transpose();
  EXPECT_NEAR(s.sigma[2], 0, 1e-12);
  EXPECT_GT(s.sigma.head<2>().dot(g.head<2>()), 0);
  EXPECT_EQ(s.modes[0], Mode::sliding);
  std::cout << name(GetParam()) << " sliding: " << s.result.iterations << " iterations, residual "
            << s.result.residuals.max() << (s.result.polished ? " (polished)" : "") << "\n";
}

INSTANTIATE_TEST_SUITE_P(Solvers, SingleContact, ::testing::Values(NcpSolverKind::admm, NcpSolverKind::pgs),
                         [](const auto& tp) { return std::string(name(tp.param)); });

// ---------------------------------------------------------------------------
// Random Delassus problems G = J M^-1 J^T: J (3 nc x ndof) random, M diagonal with
// masses in [0.5, 2]; g = J v + (0, 0, phi_i) with v random and gaps phi_i in
// [-0.5, 0.2] (a physical free velocity plus penetration: most contacts active, some
// separating). rank(G) = min(3 nc, ndof). mu_value < 0 draws each mu from {0, 0.3, 10}.
// G = J M^{-1} J^T, g = J v with the normal rows shifted by a gap in [-0.5, 0.2], and mu
// = mu_value, or (mu_value < 0) drawn from {0, 0.3, 10}: the common end of the generators.
Problem delassus_problem(const MatX& J, const VecX& Minv, const VecX& v, double mu_value, std::mt19937& rng) {
  std::uniform_real_distribution<double> gap(-0.5, 0.2);
  std::uniform_int_distribution<int> pick(0, 2);
  const int nc = static_cast<int>(J.rows() / 3);
  Problem p;
  p.G = J * Minv.asDiagonal() * J.transpose();
  p.G = 0.5 * (p.G + p.G.transpose()).eval();
  p.g = J * v;
  p.mu.resize(nc);
  const double choices[3] = {0.0, 0.3, 10.0};
  for (int i = 0; i < nc; ++i) {
    p.g[3 * i + 2] += gap(rng);
    p.mu[i] = mu_value >= 0 ? mu_value : choices[pick(rng)];
  }
  return p;
}

Problem random_problem(unsigned seed, int nc, int ndof, double mu_value) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1), mass(0.5, 2);
  MatX J(3 * nc, ndof);
  for (Eigen::Index k = 0; k < J.size(); ++k) J.data()[k] = u(rng);
  VecX Minv(ndof), v(ndof);
  for (int k = 0; k < ndof; ++k) Minv[k] = 1 / mass(rng);
  for (int k = 0; k < ndof; ++k) v[k] = u(rng);
  return delassus_problem(J, Minv, v, mu_value, rng);
}

// Physically structured: each contact on 1-3 of nn nodes (barycentric weights), with
// an orthonormal frame whose normal is within max_angle of +z; nodal masses in
// [0.5, 2]. J^T's block of a contact is sum_k w_k C^T on its nodes, as in
// contact_jacobian_transpose. rank(G) <= 3 nn: more contacts than nodes make G
// singular (shared nodes). A solution exists when some velocity puts every contact
// strictly inside the dual cone (mu ||u_T|| < u_N); a uniform +z velocity does if
// mu tan(max_angle) < 1, so max_angle = 0.09 covers mu = 10 even on singular G.
// (Dense random J with mu = 10 and many contacts per dof has no such guarantee.)
Problem physical_problem(unsigned seed, int nc, int nn, double mu_value, double max_angle = 0.09) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1), u01(0, 1), mass(0.5, 2);
  std::uniform_int_distribution<int> node(0, nn - 1), count(1, 3);
  const double two_pi = 6.283185307179586;
  MatX J = MatX::Zero(3 * nc, 3 * nn);
  for (int i = 0; i < nc; ++i) {
    const double th = max_angle * u01(rng), ph = two_pi * u01(rng), rot = two_pi * u01(rng);
    const Vec3 n(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
    const Vec3 a = std::abs(n[0]) < 0.9 ? Vec3::UnitX() : Vec3::UnitY();
    const Vec3 t1 = n.cross(a).normalized(), t2 = n.cross(t1);
    const Vec3 s1 = std::cos(rot) * t1 + std::sin(rot) * t2;
    Mat3 C;
    C << s1, n.cross(s1), n;
    const int k = count(rng);
    double w[3], sum = 0;
    for (int q = 0; q < k; ++q) sum += (w[q] = 0.1 + u01(rng));
    for (int q = 0; q < k; ++q) J.block<3, 3>(3 * i, 3 * node(rng)) += (w[q] / sum) * C.transpose();
  }
  VecX Minv(3 * nn), v(3 * nn);
  for (int b = 0; b < nn; ++b) Minv.segment<3>(3 * b).setConstant(1 / mass(rng));
  for (int k = 0; k < 3 * nn; ++k) v[k] = u(rng);
  return delassus_problem(J, Minv, v, mu_value, rng);
}

struct RandomCase {
  int nc, ndof;
  double mu;
  unsigned seed;
  bool physical;  // physical_problem (ndof = 3 nn) instead of a dense random J
};

Problem make(const RandomCase& c) {
  return c.physical ? physical_problem(c.seed, c.nc, c.ndof / 3, c.mu) : random_problem(c.seed, c.nc, c.ndof, c.mu);
}

class RandomProblems : public ::testing::TestWithParam<RandomCase> {};

// Both solvers converge to tolerance 1e-10 without polish (the iteration itself, not
// the polish, must converge) and the solution satisfies the NCP conditions checked
// independently. Then with the polish on, still a solution.
TEST_P(RandomProblems, BothSolversConverge) {
  const RandomCase c = GetParam();
  const Problem p = make(c);
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    const std::string where = std::string(name(kind)) + (c.physical ? " physical" : " dense") + " nc " + std::to_string(c.nc) + " ndof " +
                              std::to_string(c.ndof) + " mu " + std::to_string(c.mu);
    const Solved s = solve(p, kind, 1e-10, false);
    EXPECT_TRUE(s.result.converged) << where << ": residual " << s.result.residuals.max() << " after "
                                    << s.result.iterations;
    expect_ncp_solution(p, s, 1e-10, where);
    const Solved sp = solve(p, kind, 1e-10, true);
    EXPECT_TRUE(sp.result.converged) << where << " polished";
    expect_ncp_solution(p, sp, 1e-10, where + " polished");
    EXPECT_EQ(sp.result.sticking + sp.result.sliding + sp.result.breaking, c.nc);
    std::cout << where << ": " << s.result.iterations << " iterations (rho updates " << s.result.rho_updates
              << "), residual " << s.result.residuals.max() << "; with polish " << sp.result.residuals.max()
              << (sp.result.polished ? " (polished)" : " (not kept)") << "; modes stick/slide/break "
              << sp.result.sticking << "/" << sp.result.sliding << "/" << sp.result.breaking << "\n";
  }
}

INSTANTIATE_TEST_SUITE_P(
    Delassus, RandomProblems,
    ::testing::Values(
        // dense random J, mu in {0, 0.3}: full rank (60 rows, 90 dofs) and rank 30 < 60
        RandomCase{20, 90, 0.0, 1, false}, RandomCase{20, 90, 0.3, 2, false},  //
        RandomCase{20, 30, 0.0, 5, false}, RandomCase{20, 30, 0.3, 6, false},
        // physical J, all mu: full rank (30 nodes) and rank <= 30 < 60 (10 nodes)
        RandomCase{20, 90, 0.3, 2, true}, RandomCase{20, 90, 10.0, 3, true}, RandomCase{20, 90, -1, 4, true},
        RandomCase{20, 30, 0.0, 5, true}, RandomCase{20, 30, 10.0, 7, true}, RandomCase{20, 30, -1, 8, true},
        RandomCase{40, 30, 10.0, 31, true}),
    [](const auto& tp) {
      const RandomCase& c = tp.param;
      return std::string(c.physical ? "physical" : "dense") + "_nc" + std::to_string(c.nc) + "_ndof" +
             std::to_string(c.ndof) + "_" +
             (c.mu < 0 ? std::string("mixed") : "mu" + std::to_string(static_cast<int>(10 * c.mu)));
    });

// Frictionless (mu = 0): the NCP is the KKT system of the convex QP
// min 1/2 l^T G l + g^T l over l_N >= 0, l_T = 0. Two minimizers l1, l2 of a convex
// quadratic give the same value along their segment, so (l1 - l2)^T G (l1 - l2) = 0,
// i.e. G l1 = G l2 (G PSD): sigma is unique even when G is singular and lambda is
// not. Both solvers must therefore give the same sigma, to the accuracy the
// residuals allow.
TEST(NcpSolvers, FrictionlessSigmaIsUniqueOnSingularG) {
  const Problem p = random_problem(11, 20, 30, 0.0);
  const Solved a = solve(p, NcpSolverKind::admm, 1e-12, true);
  const Solved b = solve(p, NcpSolverKind::pgs, 1e-12, true);
  ASSERT_TRUE(a.result.converged && b.result.converged);
  EXPECT_LE((a.sigma - b.sigma).cwiseAbs().maxCoeff(), 1e-8 * p.g.cwiseAbs().maxCoeff());
}

// With friction the NCP may have several solutions in general; uniqueness holds when
// mu is small relative to the anisotropy of a well-conditioned, full-rank G (the
// fixed-point map is then a contraction). Here: few contacts on many dofs (cond(G) of
// order 10) and mu = 0.3, so both solvers must find the same point.
TEST(NcpSolvers, AdmmAndPgsAgreeOnFullRankFriction) {
  const Problem p = random_problem(12, 10, 200, 0.3);
  Eigen::SelfAdjointEigenSolver<MatX> eig(p.G);
  ASSERT_LT(eig.eigenvalues().maxCoeff() / eig.eigenvalues().minCoeff(), 50);
  const Solved a = solve(p, NcpSolverKind::admm, 1e-12, true);
  const Solved b = solve(p, NcpSolverKind::pgs, 1e-12, true);
  ASSERT_TRUE(a.result.converged && b.result.converged);
  EXPECT_LE((a.lambda - b.lambda).cwiseAbs().maxCoeff(), 1e-8 * a.lambda.cwiseAbs().maxCoeff());
  EXPECT_LE((a.sigma - b.sigma).cwiseAbs().maxCoeff(), 1e-8 * p.g.cwiseAbs().maxCoeff());
  EXPECT_EQ(a.modes, b.modes);
}

// The iteration counts of the two solvers on 100-contact problems, mixed mu (reported):
// 200 nodes (G 300 x 300 of full rank) and 50 nodes (rank <= 150).
TEST(NcpSolvers, HundredContacts) {
  for (const int nn : {200, 50}) {
    const Problem p = physical_problem(13, 100, nn, -1);
    for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
      const Solved s = solve(p, kind, 1e-10, false);
      EXPECT_TRUE(s.result.converged) << name(kind) << " residual " << s.result.residuals.max();
      expect_ncp_solution(p, s, 1e-10, name(kind));
      std::cout << name(kind) << " 100 contacts on " << nn << " nodes: " << s.result.iterations
                << " iterations, rho updates " << s.result.rho_updates << ", residual " << s.result.residuals.max()
                << "\n";
    }
  }
}

// Self-contact-like: many vertex-triangle contacts (each on 4 of nn nodes: the vertex
// with weight 1, the triangle's 3 with -barycentric weights), 3 nc = 600 rows on
// 3 nn = 60 dofs (G of rank <= 60), mu = 0.2, most contacts separating (gap in
// [0.05, 1]) and 5% penetrating (gap in [-0.2, 0]): most end up breaking, as in a
// folding soft body. This is where plain ADMM needs thousands of iterations (the
// small non-zero eigenvalues of G); ADMM now hands over to PGS when it stalls.
Problem self_contact_problem(unsigned seed, int nc, int nn) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1), u01(0, 1), mass(0.5, 2), sep(0.05, 1), pen(-0.2, 0);
  std::uniform_int_distribution<int> node(0, nn - 1);
  const double two_pi = 6.283185307179586;
  MatX J = MatX::Zero(3 * nc, 3 * nn);
  for (int i = 0; i < nc; ++i) {
    const double th = 3.14159 * u01(rng), ph = two_pi * u01(rng);
    const Vec3 n(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
    const Vec3 a = std::abs(n[0]) < 0.9 ? Vec3::UnitX() : Vec3::UnitY();
    const Vec3 t1 = n.cross(a).normalized(), t2 = n.cross(t1);
    Mat3 C;
    C << t1, t2, n;
    double b[3], sum = 0;
    for (double& bk : b) sum += (bk = 0.1 + u01(rng));
    int nodes[4];
    for (int q = 0; q < 4; ++q) {
      bool fresh;
      do {
        nodes[q] = node(rng);
        fresh = true;
        for (int r = 0; r < q; ++r) fresh = fresh && nodes[r] != nodes[q];
      } while (!fresh);
    }
    J.block<3, 3>(3 * i, 3 * nodes[0]) += C.transpose();
    for (int q = 0; q < 3; ++q) J.block<3, 3>(3 * i, 3 * nodes[q + 1]) -= (b[q] / sum) * C.transpose();
  }
  VecX Minv(3 * nn), v(3 * nn);
  for (int k = 0; k < nn; ++k) Minv.segment<3>(3 * k).setConstant(1 / mass(rng));
  for (int k = 0; k < 3 * nn; ++k) v[k] = 0.05 * u(rng);
  Problem p;
  p.G = J * Minv.asDiagonal() * J.transpose();
  p.G = 0.5 * (p.G + p.G.transpose()).eval();
  p.g = J * v;
  p.mu = VecX::Constant(nc, 0.2);
  for (int i = 0; i < nc; ++i) p.g[3 * i + 2] += u01(rng) < 0.05 ? pen(rng) : sep(rng);
  return p;
}

TEST(NcpSolvers, RankDeficientManyBreaking) {
  const Problem p = self_contact_problem(91, 200, 20);
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    const Solved s = solve(p, kind, 1e-10, false, 20000);
    EXPECT_TRUE(s.result.converged) << name(kind) << " residual " << s.result.residuals.max();
    // Measured: ADMM 327, PGS 75 iterations; 1000 (the default budget) leaves a 3x margin.
    EXPECT_LE(s.result.iterations, 1000) << name(kind);
    expect_ncp_solution(p, s, 1e-10, std::string(name(kind)) + " self-contact");
    std::cout << name(kind) << " self-contact 200 contacts on 20 nodes: " << s.result.iterations
              << " iterations (PGS fallback " << s.result.fallback_iterations << "), rho updates "
              << s.result.rho_updates << ", residual " << s.result.residuals.max() << ", |lambda| "
              << s.lambda.cwiseAbs().maxCoeff() << "\n";
    const Solved sp = solve(p, kind, 1e-10, true, 20000);
    EXPECT_TRUE(sp.result.converged) << name(kind) << " polished";
    expect_ncp_solution(p, sp, 1e-10, std::string(name(kind)) + " self-contact polished");
    std::cout << "  modes stick/slide/break " << sp.result.sticking << "/" << sp.result.sliding << "/"
              << sp.result.breaking << "\n";
  }
}

// ---------------------------------------------------------------------------
// The per-contact penalty (options.admm_scaling) on a mass ratio: 40 decoupled
// contacts, every other one on a body 1e6 times lighter (its 3x3 block of G 1e6 times
// larger), random SPD blocks, random g (some pushing, some sliding). One rho cannot
// suit both scales; rho_i = rho d_i (d_i = tr(G_ii) / 3) makes the scaled problem's
// blocks O(1). Pure ADMM (no PGS fallback, no polish, no working set), tolerance
// 1e-10: the scaled iteration converges and gives the NCP's (unique: G has full rank)
// solution; the unscaled one needs at least 3x its iterations (measured below, printed).
TEST(NcpSolvers, ScaledAdmmOnAMassRatio) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  const int nc = 40;
  Problem p{MatX::Zero(3 * nc, 3 * nc), VecX(3 * nc), VecX::Constant(nc, 0.3)};
  for (int i = 0; i < nc; ++i) {
    MatX B(3, 3);
    for (int k = 0; k < 9; ++k) B(k / 3, k % 3) = u(rng);
    B = B * B.transpose() + 0.5 * MatX::Identity(3, 3);
    p.G.block<3, 3>(3 * i, 3 * i) = (i % 2 ? 1e6 : 1.0) * B;
    p.g.segment<3>(3 * i) = Vec3(u(rng), u(rng), u(rng) - 0.5);
  }
  Solved s[2];
  for (const bool scaled : {false, true}) {
    NcpOptions o;
    o.working_set = false;
    o.polish = false;
    o.admm_fallback = false;
    o.admm_scaling = scaled;
    o.tolerance = 1e-10;
    o.max_iterations = 5000;
    Solved& r = s[scaled];
    r.lambda = VecX::Zero(3 * nc);
    NcpSolver solver;
    r.result = solver.solve(p.G, p.g, p.mu, o, r.lambda, r.sigma, r.modes);
    std::cout << (scaled ? "scaled" : "unscaled") << " ADMM, mass ratio 1e6: " << r.result.iterations
              << " iterations, residual " << r.result.residuals.max() << "\n";
  }
  ASSERT_TRUE(s[1].result.converged) << s[1].result.residuals.max();
  expect_ncp_solution(p, s[1], 1e-10, "scaled ADMM");
  EXPECT_GE(s[0].result.iterations, 3 * s[1].result.iterations);
  if (s[0].result.converged) {
    // Two solutions to 1e-10 of the same full-rank problem: the same forces up to the
    // conditioning of G (1e6 here) times the tolerance.
    EXPECT_LE((s[0].lambda - s[1].lambda).norm(), 1e-3 * s[1].lambda.norm());
  }
}

// The polish's cost where its Newton matrix is well conditioned and the mode equations
// are linear: 60 decoupled contacts (G block diagonal, each block B B^T + 0.5 I), g
// chosen so that lambda_i = (0.1 a, 0.1 b, 1) (|a|, |b| <= 1, inside the cone mu = 1)
// with sigma_i = 0: every contact sticks. The Newton matrix is G (LU's condition
// estimate ~0.1), so one step solves the equations to rounding, and a further step
// (if any: here the first step already lands below the rounding test) reuses that
// factorization (a chord step, O(m^2)): exactly one O(m^3) factorization. A guard on
// the count that docs/performance.md's 400-contact slab depends on (there, without
// the chord steps, the step at the rounding floor factorized again); the solution is
// checked independently.
TEST(NcpSolvers, PolishFactorizesOnceWhenTheModeEquationsAreLinear) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  const int nc = 60;
  Problem p{MatX::Zero(3 * nc, 3 * nc), VecX(3 * nc), VecX::Constant(nc, 1.0)};
  for (int i = 0; i < nc; ++i) {
    MatX B(3, 3);
    for (int k = 0; k < 9; ++k) B(k / 3, k % 3) = u(rng);
    const MatX Gi = B * B.transpose() + 0.5 * MatX::Identity(3, 3);
    p.G.block<3, 3>(3 * i, 3 * i) = Gi;
    p.g.segment<3>(3 * i) = -Gi * Vec3(0.1 * u(rng), 0.1 * u(rng), 1.0);
  }
  const Solved s = solve(p, NcpSolverKind::admm, 1e-8, true);
  ASSERT_TRUE(s.result.converged) << s.result.residuals.max();
  ASSERT_EQ(s.result.sticking, nc);  // the premise: linear mode equations
  EXPECT_TRUE(s.result.polished);
  EXPECT_EQ(s.result.polish_factorizations, 1);
  expect_ncp_solution(p, s, 1e-12, "polished");
}

// The polish on redundant contacts: every contact of a physical problem (120 contacts
// on 40 nodes, mu = 1) twice, so G = [G0 G0; G0 G0] and every Newton matrix of the
// polish is singular (each active contact's rows twice: the complete orthogonal
// decomposition's minimum-norm step). After the first such matrix the solve's later
// Newton steps go to the decomposition directly: one LU tried in all (before, one per
// Newton step, each thrown away: a third of a decomposition's time at m = 300 to 400).
// The premise (two Newton steps, so one decomposition without an LU before it) and the
// solution (to the solve's tolerance) are checked.
TEST(NcpSolvers, PolishTriesLuOnceOnRedundantContacts) {
  const Problem q = physical_problem(7, 120, 40, 1.0);
  Problem p{MatX(2 * 360, 2 * 360), VecX(2 * 360), VecX(2 * 120)};
  p.G << q.G, q.G, q.G, q.G;
  p.g << q.g, q.g;
  p.mu << q.mu, q.mu;
  const Solved s = solve(p, NcpSolverKind::admm, 1e-10, true);
  ASSERT_TRUE(s.result.converged) << s.result.residuals.max();
  ASSERT_TRUE(s.result.polished);
  ASSERT_GE(s.result.polish_factorizations, 2);  // the premise
  EXPECT_EQ(s.result.polish_lu_factorizations, 1);
  expect_ncp_solution(p, s, 1e-10, "redundant polish");
}

// ---------------------------------------------------------------------------
// Warm start: from the solution, no (or one) iteration.
TEST(NcpSolvers, WarmStartFromTheSolution) {
  const Problem p = physical_problem(21, 20, 10, -1);
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    const Solved s = solve(p, kind, 1e-10, true);
    ASSERT_TRUE(s.result.converged) << name(kind);
    const Solved w = solve(p, kind, 1e-10, true, 20000, &s.lambda);
    EXPECT_TRUE(w.result.converged) << name(kind);
    EXPECT_LE(w.result.iterations, 1) << name(kind);
    EXPECT_LE((w.lambda - s.lambda).cwiseAbs().maxCoeff(), 1e-9 * s.lambda.cwiseAbs().maxCoeff()) << name(kind);
  }
}

// Failure is reported: two iterations on a hard problem (rank-deficient, mu = 10,
// polish off so that it cannot rescue the iterate) do not converge; the residuals are
// those of the returned, finite lambda. The budget is per solve: the restart of the
// stalled solve (NcpOptions::restarts, 1 by default) runs its two iterations too.
TEST(NcpSolvers, NotConvergedIsReported) {
  const Problem p = random_problem(31, 40, 30, 10.0);
  const int restarts = NcpOptions().restarts;
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    const Solved s = solve(p, kind, 1e-10, false, 2);
    EXPECT_FALSE(s.result.converged) << name(kind);
    EXPECT_EQ(s.result.iterations, 2 * (1 + restarts)) << name(kind);
    EXPECT_EQ(s.result.restarts, restarts) << name(kind);
    EXPECT_TRUE(s.lambda.allFinite()) << name(kind);
    EXPECT_GT(s.result.residuals.max(), 1e-10) << name(kind);
    const NcpResiduals r = ncp_residuals(p.G, p.g, p.mu, s.lambda);
    EXPECT_NEAR(r.max(), s.result.residuals.max(), 1e-12 * r.max()) << name(kind);
  }
}

TEST(NcpSolvers, NonFiniteInput) {
  const Problem ok = random_problem(41, 5, 30, 0.3);
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
  for (int which = 0; which < 3; ++which)
    for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
      Problem p = ok;
      if (which == 0) p.G(3, 4) = nan;
      if (which == 1) p.g[2] = inf;
      if (which == 2) p.mu[1] = nan;
      const Solved s = solve(p, kind, 1e-10, true);
      EXPECT_FALSE(s.result.converged) << name(kind) << " case " << which;
      EXPECT_TRUE(s.lambda.allFinite() && s.sigma.allFinite()) << name(kind) << " case " << which;
      EXPECT_EQ(s.lambda, VecX::Zero(15));
      EXPECT_EQ(s.modes.size(), 5u);
    }
  // A non-finite warm start is dropped, not propagated.
  VecX warm = VecX::Zero(15);
  warm[5] = nan;
  const Solved s = solve(ok, NcpSolverKind::admm, 1e-10, true, 20000, &warm);
  EXPECT_TRUE(s.result.converged);
  EXPECT_TRUE(s.lambda.allFinite());
}

// ncp_residuals can fail: perturbing a solution raises each residual.
TEST(NcpResidualsCheck, DetectsWrongSolutions) {
  const Problem p = random_problem(51, 20, 90, 0.3);
  const Solved s = solve(p, NcpSolverKind::admm, 1e-12, true);
  ASSERT_TRUE(s.result.converged);
  const NcpResiduals r0 = ncp_residuals(p.G, p.g, p.mu, s.lambda);
  EXPECT_LE(r0.max(), 1e-12);
  // Find an active and a breaking contact.
  int active = -1, breaking = -1;
  for (int i = 0; i < 20; ++i) {
    if (s.modes[i] != Mode::breaking && active < 0) active = i;
    if (s.modes[i] == Mode::breaking && breaking < 0) breaking = i;
  }
  ASSERT_GE(active, 0);
  ASSERT_GE(breaking, 0);
  const double ls = s.lambda.cwiseAbs().maxCoeff();
  {  // out of the cone: primal
    VecX l = s.lambda;
    l[3 * active + 2] = -0.01 * ls;
    const NcpResiduals r = ncp_residuals(p.G, p.g, p.mu, l);
    EXPECT_GT(r.primal, 1e-4);
  }
  {  // too little normal force: the contact penetrates, dual
    VecX l = s.lambda;
    l.segment<3>(3 * active) *= 0.9;
    const NcpResiduals r = ncp_residuals(p.G, p.g, p.mu, l);
    EXPECT_GT(r.max(), 1e-4);
  }
  {  // a force on a separating contact: complementarity
    VecX l = s.lambda;
    l[3 * breaking + 2] += 0.01 * ls;
    const NcpResiduals r = ncp_residuals(p.G, p.g, p.mu, l);
    EXPECT_GT(r.complementarity, 1e-5);
  }
  {  // the dual-cone distance: mu = 0, a single contact with sigma_N = -1 is at distance 1
    const NcpResiduals r = ncp_residuals(MatX::Zero(3, 3), Vec3(0.5, 0, -1), VecX::Zero(1), VecX::Zero(3));
    EXPECT_DOUBLE_EQ(r.dual, 1.0);
    EXPECT_EQ(r.primal, 0.0);
  }
}

// The polish brings a loosely converged mixed sticking / sliding / breaking solution
// to machine precision.
TEST(NcpSolvers, PolishReachesMachinePrecision) {
  const Problem p = physical_problem(61, 30, 50, -1);
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    const Solved rough = solve(p, kind, 1e-7, false);
    const Solved fine = solve(p, kind, 1e-7, true);
    ASSERT_TRUE(rough.result.converged && fine.result.converged) << name(kind);
    EXPECT_GT(fine.result.sticking, 0) << name(kind);
    EXPECT_GT(fine.result.sliding, 0) << name(kind);
    EXPECT_GT(fine.result.breaking, 0) << name(kind);
    EXPECT_TRUE(fine.result.polished) << name(kind);
    EXPECT_LE(fine.result.residuals.max(), 1e-13) << name(kind);
    EXPECT_LT(fine.result.residuals.max(), rough.result.residuals.max()) << name(kind);
    expect_ncp_solution(p, fine, 1e-13, std::string(name(kind)) + " polished");
    std::cout << name(kind) << " polish: " << rough.result.residuals.max() << " -> " << fine.result.residuals.max()
              << " (stick/slide/break " << fine.result.sticking << "/" << fine.result.sliding << "/"
              << fine.result.breaking << ")\n";
  }
}

// The solver object is reusable: a second solve of another problem of the same size
// gives the result a fresh solver gives (the workspace carries no state but buffers).
TEST(NcpSolvers, ReusedWorkspace) {
  const Problem a = random_problem(71, 20, 90, -1), b = random_problem(72, 20, 90, -1);
  NcpSolver solver;
  NcpOptions o;
  o.tolerance = 1e-10;
  o.working_set = false;
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    o.solver = kind;
    VecX la = VecX::Zero(60), lb = VecX::Zero(60), sa, sb;
    std::vector<Mode> ma, mb;
    solver.solve(a.G, a.g, a.mu, o, la, sa, ma);
    const NcpResult rb = solver.solve(b.G, b.g, b.mu, o, lb, sb, mb);
    const Solved fresh = solve(b, kind, 1e-10, true);
    EXPECT_EQ(rb.iterations, fresh.result.iterations);
    EXPECT_EQ(lb, fresh.lambda);
  }
}

// The iterations allocate nothing: after a first solve sized the workspace, solves of
// the same size make no heap allocation, whatever their number of iterations (the
// polish is off: its dense system is sized by the number of active contacts).
TEST(NcpSolvers, NoAllocationAfterFirstSolve) {
#if SOFTDIFF_NCP_COUNT_MALLOC
  const Problem p = physical_problem(81, 20, 10, -1);
  NcpSolver solver;
  VecX lambda, sigma;
  std::vector<Mode> modes;
  NcpOptions o;
  o.polish = false;
  o.working_set = false;  // the solver's own iterations (the working set sizes its reduced problem per set)
  o.tolerance = 1e-30;  // never met: run all iterations
  bool first = true;  // the first solve sizes the workspace (and sigma, modes)
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    o.solver = kind;
    for (const int iterations : {5, 5, 50, 500}) {
      o.max_iterations = iterations;
      lambda.setZero(p.g.size());
      const long before = g_mallocs;
      const NcpResult r = solver.solve(p.G, p.g, p.mu, o, lambda, sigma, modes);
      const long count = g_mallocs - before;
      EXPECT_EQ(r.iterations, iterations * (1 + o.restarts)) << name(kind);  // the restart of the stalled solve too
      if (!first) {
        EXPECT_EQ(count, 0) << name(kind) << " " << iterations << " iterations";
      }
      first = false;
    }
  }
#else
  GTEST_SKIP() << "allocation counter off under sanitizers";
#endif
}

// ---------------------------------------------------------------------------
// The working set (ncp.cpp): contacts are screened exactly, so with it on the
// solution is a solution of the whole NCP (checked independently), with the same
// tolerance. Many contacts far from touching (g_N > 0 by 1 to 2 units, most of them
// breaking) and a few pressed ones: the reduced problem is much smaller than the
// whole, it is solved in a few rounds, and the breaking contacts are outside it.
Problem mostly_breaking_problem(unsigned seed) {
  Problem p = physical_problem(seed, 120, 40, 0.3);
  std::mt19937 rng(seed + 1);
  std::uniform_real_distribution<double> far(1.0, 2.0);
  for (int i = 10; i < 120; ++i) p.g[3 * i + 2] = far(rng) + std::abs(p.g[3 * i + 2]);
  return p;
}

// Contacts just apart (g_N = +0.05) coupled with pressed ones (g_N = -1) through a
// dense random J (couplings of both signs): pushing the pressed contacts closes some
// of the others, so the set has to grow (round 2 and later).
Problem growing_problem(unsigned seed) {
  Problem p = random_problem(seed, 60, 90, 0.3);
  for (int i = 0; i < 60; ++i) p.g[3 * i + 2] = i < 6 ? -1.0 : 0.05;
  return p;
}

TEST(NcpWorkingSet, SolvesTheWholeProblemOnAFewContacts) {
  const Problem p = mostly_breaking_problem(101);
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    const Solved direct = solve(p, kind, 1e-10, true, 20000, nullptr, false);
    const Solved ws = solve(p, kind, 1e-10, true, 20000, nullptr, true);
    ASSERT_TRUE(direct.result.converged) << name(kind);
    EXPECT_TRUE(ws.result.converged) << name(kind);
    EXPECT_FALSE(ws.result.working_set_fallback) << name(kind);
    EXPECT_GE(ws.result.working_set_rounds, 1) << name(kind);
    EXPECT_LT(ws.result.working_set_size, 60) << name(kind);  // of 120
    expect_ncp_solution(p, ws, 1e-10, std::string(name(kind)) + " working set");
    // sigma is unique where G is definite on the active contacts; compare the velocities.
    EXPECT_LE((ws.sigma - direct.sigma).cwiseAbs().maxCoeff(), 1e-7 * p.g.cwiseAbs().maxCoeff()) << name(kind);
    std::cout << name(kind) << " working set: " << ws.result.working_set_rounds << " rounds, "
              << ws.result.working_set_size << " of 120 contacts, " << ws.result.iterations
              << " iterations (whole problem: " << direct.result.iterations << ")\n";
  }
}

TEST(NcpWorkingSet, GrowsUntilNoContactOutsideIsViolated) {
  const Problem p = growing_problem(103);
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    const Solved ws = solve(p, kind, 1e-10, true, 20000, nullptr, true);
    EXPECT_TRUE(ws.result.converged) << name(kind);
    EXPECT_FALSE(ws.result.working_set_fallback) << name(kind);
    EXPECT_GE(ws.result.working_set_rounds, 2) << name(kind);
    expect_ncp_solution(p, ws, 1e-10, std::string(name(kind)) + " growing working set");
    std::cout << name(kind) << " growing working set: " << ws.result.working_set_rounds << " rounds, "
              << ws.result.working_set_size << " of 60 contacts\n";
  }
}

// Nothing pushes in (every g_N > 0, cold start): the set is empty, lambda = 0 solves
// the whole problem, no iteration.
TEST(NcpWorkingSet, EmptySetWhenNothingTouches) {
  Problem p = mostly_breaking_problem(104);
  for (int i = 0; i < 10; ++i) p.g[3 * i + 2] = 1.0 + std::abs(p.g[3 * i + 2]);
  const Solved s = solve(p, NcpSolverKind::admm, 1e-10, true, 20000, nullptr, true);
  EXPECT_TRUE(s.result.converged);
  EXPECT_EQ(s.result.working_set_rounds, 1);
  EXPECT_EQ(s.result.working_set_size, 0);
  EXPECT_EQ(s.result.iterations, 0);
  EXPECT_EQ(s.lambda, VecX::Zero(p.g.size()));
  EXPECT_EQ(s.result.breaking, 120);
}

// Warm-started from the solution, the set is the contacts that carry force: one round.
TEST(NcpWorkingSet, WarmStartFromTheSolutionIsOneRound) {
  const Problem p = mostly_breaking_problem(102);
  const Solved s = solve(p, NcpSolverKind::admm, 1e-10, true);
  ASSERT_TRUE(s.result.converged);
  const Solved w = solve(p, NcpSolverKind::admm, 1e-10, true, 20000, &s.lambda, true);
  EXPECT_TRUE(w.result.converged);
  EXPECT_EQ(w.result.working_set_rounds, 1);
  EXPECT_LE(w.result.iterations, 1);
}

// A working set that does not converge hands over to the whole problem (from its
// lambda, with a budget of its own: the iterations add up), and the failure of both is
// reported with the residuals of the returned lambda.
TEST(NcpWorkingSet, FailureFallsBackToTheWholeProblem) {
  const Problem p = random_problem(31, 40, 30, 10.0);
  for (const NcpSolverKind kind : {NcpSolverKind::admm, NcpSolverKind::pgs}) {
    const Solved s = solve(p, kind, 1e-10, false, 2, nullptr, true);
    EXPECT_FALSE(s.result.converged) << name(kind);
    EXPECT_TRUE(s.result.working_set_fallback) << name(kind);
    EXPECT_GT(s.result.iterations, 2) << name(kind);
    // two per solve (the working set's and the whole problem's), and again for the restart
    EXPECT_LE(s.result.iterations, 4 * (1 + NcpOptions().restarts)) << name(kind);
    EXPECT_TRUE(s.lambda.allFinite()) << name(kind);
    const NcpResiduals r = ncp_residuals(p.G, p.g, p.mu, s.lambda);
    EXPECT_NEAR(r.max(), s.result.residuals.max(), 1e-12 * r.max()) << name(kind);
  }
}

}  // namespace
}  // namespace softdiff::contact
