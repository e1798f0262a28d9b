#include <softdiff/core/avx512_gcc12.hpp>  // first: see there
// The contact NCP of real scenes where ADMM, PGS and the polish missed the tolerance
// (docs/method.md "The NCP on the grip: a semismooth Newton stage"), dumped once from
// the dense fallback's solve (ncp.cpp's solve_core on the dense G_CC of the contacts
// that may carry force) and solved here without the scene. Each file (text, one number
// a line, 17 significant digits): nc, mu (nc), g (3 nc), the warm start the scene's
// solve started from (3 nc), then G's upper triangle row by row (G is symmetric).
#include <softdiff/contact/ncp.hpp>

#include <fstream>
#include <iostream>
#include <gtest/gtest.h>
#include <string>

namespace softdiff::contact {
namespace {

struct Dump {
  MatX G;
  VecX g, mu, warm;
};

Dump load_dump(const std::string& name) {
  const std::string path = std::string(SOFTDIFF_SOURCE_DIR) + "/tests/contact/data/" + name;
  std::ifstream in(path);
  Dump d;
  int nc = 0;
  in >> nc;
  if (!in || nc <= 0) {
    ADD_FAILURE() << "cannot read " << path;
    return d;
  }
  const int n = 3 * nc;
  d.mu.resize(nc);
  d.g.resize(n);
  d.warm.resize(n);
  d.G.resize(n, n);
  for (int i = 0; i < nc; ++i) in >> d.mu[i];
  for (int i = 0; i < n; ++i) in >> d.g[i];
  for (int i = 0; i < n; ++i) in >> d.warm[i];
  for (int i = 0; i < n; ++i)
    for (int j = i; j < n; ++j) {
      in >> d.G(i, j);
      d.G(j, i) = d.G(i, j);
    }
  EXPECT_TRUE(static_cast<bool>(in)) << path << " is truncated";
  return d;
}

// A late step of the grip (configs/gripper_free.yaml, `softdiff simulate
// configs/gripper_free.yaml --steps 90 --threads 1`, step 85; dumped once, 2026-12-03):
// the dense fallback's 62 contacts of the fingers and the cylinder, where ADMM stalled,
// PGS from there and the mode polish stopped at 1.2e-6 (tolerance 1e-8) and the
// semismooth Newton stage (ncp.cpp, newton_alart_curnier) reached 5e-10. Solved as the
// fallback solves it (ADMM from the warm start, PGS when it stalls, the polish, the
// Newton stage); the solution is checked independently of the solver's residuals.
TEST(NcpDumps, GripLateStepReachesTheTolerance) {
  const Dump d = load_dump("ncp_grip_slow_sliding.txt");
  ASSERT_EQ(d.mu.size(), 62);
  NcpOptions o;
  o.working_set = false;  // the fallback's inner solve
  NcpSolver solver;
  VecX lambda = d.warm, sigma;
  std::vector<Mode> modes;
  const NcpResult r = solver.solve(d.G, d.g, d.mu, o, lambda, sigma, modes);
  const NcpResiduals check = ncp_residuals(d.G, d.g, d.mu, lambda);
  std::cout << "residual " << check.max() << " (solver " << r.residuals.max() << "), " << r.iterations
            << " iterations, sticking " << r.sticking << ", sliding " << r.sliding << "\n";
  EXPECT_TRUE(r.converged);
  EXPECT_LE(check.max(), o.tolerance);
  EXPECT_LE((sigma - (d.G * lambda + d.g)).cwiseAbs().maxCoeff(), 1e-12 * d.g.cwiseAbs().maxCoeff());
  // Without the polish (and so without the Newton stage) the solvers stop above the
  // tolerance on this problem: it is one the stage is for.
  o.polish = false;
  VecX lambda0 = d.warm, sigma0;
  const NcpResult r0 = NcpSolver().solve(d.G, d.g, d.mu, o, lambda0, sigma0, modes);
  EXPECT_GT(r0.residuals.max(), o.tolerance);
}

// Step 81 of the grip (the same run as above; dumped 2026-12-04, branch rgrip): the
// operator's stall fallback's 38 contacts (37 of them active, whose 111 x 111 block of G
// has 75 singular values below 1e-10 of the largest: redundant soft-rigid contacts of the
// fingers on the cylinder and the cylinder's rim on the pedestal). ADMM stalls after 100
// iterations at 1.7e-7, and PGS from its (polished) iterate ends above it, at 5.2e-7
// after 900 sweeps (PGS is not monotone in the NCP residual); neither the polish nor the
// Newton stage reaches the tolerance. Before 2026-12-04 (rgrip) the solve returned PGS's
// 5.2e-7. solve_core now keeps ADMM's iterate when it is at least twice lower: the
// returned residual is at most that of ADMM alone run for the same iterations
// (deterministic: the same iterate as the stalled ADMM's, before its polish). The solve
// is reported as not converged, with the residuals of what it returns.
TEST(NcpDumps, GripStallKeepsTheBetterOfAdmmAndPgs) {
  const Dump d = load_dump("ncp_grip_pgs_above_admm.txt");
  ASSERT_EQ(d.mu.size(), 38);
  NcpOptions o;
  o.working_set = false;  // the fallback's inner solve
  VecX lambda = d.warm, sigma;
  std::vector<Mode> modes;
  const NcpResult r = NcpSolver().solve(d.G, d.g, d.mu, o, lambda, sigma, modes);
  const double returned = ncp_residuals(d.G, d.g, d.mu, lambda).max();
  const int admm_iterations = r.iterations - r.fallback_iterations;
  ASSERT_GT(r.fallback_iterations, 0) << "ADMM did not stall: the problem no longer exercises the PGS fallback";
  // ADMM alone for the iterations it ran before the stall (no stall test, no polish).
  NcpOptions a = o;
  a.admm_fallback = false;
  a.polish = false;
  a.max_iterations = admm_iterations;
  VecX la = d.warm, sa;
  const NcpResult ra = NcpSolver().solve(d.G, d.g, d.mu, a, la, sa, modes);
  ASSERT_EQ(ra.iterations, admm_iterations);
  const double admm = ncp_residuals(d.G, d.g, d.mu, la).max();
  // PGS alone from ADMM's iterate with the rest of the budget, as solve_core runs it.
  NcpOptions q = o;
  q.solver = NcpSolverKind::pgs;
  q.polish = false;
  q.max_iterations = r.fallback_iterations;
  VecX lp = la, sp;
  NcpSolver().solve(d.G, d.g, d.mu, q, lp, sp, modes);
  const double pgs = ncp_residuals(d.G, d.g, d.mu, lp).max();
  std::cout << "returned " << returned << " (solver " << r.residuals.max() << "), ADMM alone (" << admm_iterations
            << " iterations) " << admm << ", PGS from there (" << r.fallback_iterations << " sweeps) " << pgs << "\n";
  EXPECT_GT(pgs, 2 * admm) << "PGS no longer ends well above ADMM here: the case this test is about is gone";
  EXPECT_LE(returned, admm);
  EXPECT_NEAR(r.residuals.max(), returned, 1e-6 * returned);  // the residuals reported are the returned iterate's
  EXPECT_EQ(r.converged, returned <= o.tolerance);  // not converged here (1.7e-7): reported as such
  EXPECT_LE((sigma - (d.G * lambda + d.g)).cwiseAbs().maxCoeff(), 1e-12 * d.g.cwiseAbs().maxCoeff());
}

}  // namespace
}  // namespace softdiff::contact
