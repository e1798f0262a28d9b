#pragma once
// Derivatives of the static equilibrium (sibling of static_solver.hpp): the implicit
// function theorem on the converged residual of the last load step,
//     R(x; theta) = Pi (f_int(x) + P + H_a(x)^T lambda_a) = 0,
// dx*/dtheta = J^{-1} Pi dR/dtheta with J = -dR/dx = K(x*) - d(H_a^T lambda_a)/dx, which is
// the static solver's tangent K + sum_cables lambda d^2L/dx^2 exactly when every actuator
// is a cable or a translation servo (method.md "Static equilibrium"); J is then
// symmetric, and positive definite at a stable equilibrium. Columns (the theta layout
// of diff/trajectory.hpp): young (f_int / E), poisson (f_int at the Lame derivative),
// density (P / rho), an actuator's offset (H_a^T: the offset adds to its final value),
// and zero for the Rayleigh factors, x0 and v0 (the equilibrium does not depend on them).
// One factorization of J per call (the solver's last one is an iterate earlier).
// Not covered (SOFTDIFF_DEMAND): pressure cavities and rotation servos (J would not be
// symmetric, or not the solver's tangent), psd_projection (K(x*) unprojected is not in
// the record), contact.
#include <softdiff/core/parameters.hpp>
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <vector>

namespace softdiff::integrator {

struct StaticTheta {
  std::vector<ParameterId> parameters;
  bool actuation = false;  // one column per actuator
};

// dx*/dtheta (3n x (parameters + actuators)) at the equilibrium `equilibrium` of
// solve_static (its last load step). Uses data's workspace (evaluates and factorizes
// at x*). Returns false if an element is inverted at x* or J is not positive definite.
bool static_sensitivities(const Model& model, Data& data, const State& equilibrium, const StaticTheta& theta,
                          MatX& dx_dtheta);

}  // namespace softdiff::integrator
