#pragma once
// An independent check of the contact solution of a step (GoogleTest assertions).
#include <softdiff/contact/ncp.hpp>
#include <softdiff/data.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <string>

namespace softdiff::test {

// sigma = G lambda + g of the last step's contact solution, computed independently
// of the solver: from the dense G (dense backend), else as h H A^{-1} H^T lambda + g
// with the step's factorization and the step's h (sparse backend, which never forms
// G): data.h (dt, or 2 dt / 3 for BDF2) unless given (the static solver: 1).
inline VecX contact_sigma(const Data& data, double h = 0) {
  if (h == 0) h = data.h;
  const auto& cd = data.contact;
  if (cd.G.rows() == cd.g.size()) return cd.G * cd.lambda + cd.g;
  const VecX f = cd.Ht * cd.lambda;
  VecX dv;
  EXPECT_TRUE(data.solver->solve(f, dv));
  return h * (cd.Ht.transpose() * dv) + cd.g;
}

// The contact solution of the last step, checked independently of the solver's own
// report: residuals recomputed from (sigma, g, mu, lambda) (ncp_residuals_at, sigma
// from contact_sigma), lambda in each cone to `tolerance` relative, sigma + Gamma in
// the dual cone, and the modes consistent with lambda and sigma.
inline void expect_valid_contact_solution(const Data& data, double tolerance, const std::string& where,
                                          double h = 0) {
  const auto& cd = data.contact;
  const int nc = cd.contacts.size();
  if (nc == 0) return;
  const VecX sigma = contact_sigma(data, h);
  const contact::NcpResiduals r = contact::ncp_residuals_at(sigma, cd.g, cd.mu, cd.lambda);
  EXPECT_LE(r.primal, tolerance) << where;
  EXPECT_LE(r.dual, tolerance) << where;
  EXPECT_LE(r.complementarity, tolerance) << where;
  const double lscale = std::max(cd.lambda.cwiseAbs().maxCoeff(), 1e-300);
  const double vscale = std::max(cd.g.cwiseAbs().maxCoeff(), 1e-300);
  for (int i = 0; i < nc; ++i) {
    const Vec3 l = cd.lambda.segment<3>(3 * i), s = sigma.segment<3>(3 * i);
    const double mu = cd.mu[i];
    EXPECT_GE(l[2], -tolerance * lscale) << where << " contact " << i;
    EXPECT_LE(l.head<2>().norm(), mu * l[2] + tolerance * lscale) << where << " contact " << i;
    // sigma + Gamma in the dual cone {||s_T|| mu <= s_N + mu ||s_T||}: s_N >= 0.
    EXPECT_GE(s[2], -tolerance * vscale) << where << " contact " << i;
  }
}

}  // namespace softdiff::test
