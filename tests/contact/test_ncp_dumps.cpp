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

}  // namespace
}  // namespace softdiff::contact
