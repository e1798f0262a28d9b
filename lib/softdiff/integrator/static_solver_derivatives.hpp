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
// friction (a pair rule's coefficient: through the contact modes only), and zero for the
// Rayleigh factors, x0 and v0 (the equilibrium does not depend on them).
//
// With contact (docs/method.md "Derivatives", "Static equilibrium with contact"): the
// derivative of the last load step's converged equilibrium x* with the contacts and
// forces of the solver's last NCP held fixed, and the modes of equilibrium_modes()
// (below): a sticking contact's point stays where it is (its tangential position and
// its closed gap), a sliding one keeps its normal gap and its force on the cone against
// its slip over the last load step, a breaking one carries no force. With H_c the
// contacts' Jacobian:
//     (J - dH_c^T lambda) dx - H_c^T dlambda = Pi dR/dtheta,   mode rows on dsigma = H_c dx,
// the dynamic step's contact derivative with h = 1 (contact/contact_step_derivatives.hpp:
// the NCP derivative on G_AA = H_A J^{-1} H_A^T, the geometry terms dH^T lambda). A body
// held by contact alone has J singular on its rigid motions: when every active contact
// is a vertex on an obstacle, J + rho H_E^T H_E (the equality rows H_E; the same system,
// exact) is factorized; otherwise J + tau E (E its free dofs, tau as the static solver's
// proximal term) with a refinement that removes tau (the system is nonsingular when the
// active contacts hold the body). Exact (to the solves' round-off) where every contact
// sticks against an obstacle; where contacts slide, or stick on another body's faces,
// it approximates the solver's path-dependent answer (measured in docs/method.md).
// One factorization per call (the solver's last one is an iterate earlier).
// Not covered (SOFTDIFF_DEMAND): pressure cavities and rotation servos (J would not be
// symmetric, or not the solver's tangent), psd_projection (K(x*) unprojected is not in
// the record).
#include <softdiff/core/parameters.hpp>
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <utility>
#include <vector>

namespace softdiff::integrator {

struct StaticTheta {
  std::vector<ParameterId> parameters;
  bool actuation = false;  // one column per actuator
  // Rigid bodies' parameters (body, k), after the actuators: k = 0 the mass (the weight
  // m g on the body), k = 1..6 the inertia (no effect on the equilibrium: zero columns).
  std::vector<std::pair<int, int>> rigid_parameters;
  // Measurement only (2026-12-04, branch ffric): computes the derivative of a free rigid
  // body in frictional contact beside soft bodies under static.friction load_step, which
  // is otherwise refused as not validated (docs/method.md *Load-step-anchored friction*,
  // the free body: it agrees with differences on the cube on the slab, not yet with
  // friction on the soft corner's walls). For the tests that measure it; the CLI, the
  // Python module and calibration never set it.
  bool measure_free_body_friction = false;
};

// With rigid bodies (docs/method.md "Static equilibrium with rigid bodies", derivatives;
// 2026-12-03, issue 21): the unknowns are the soft dx and each rigid body's pose tangent
// (dp, dtheta) (world axes, exp(dtheta) q; T dc on a joint), the equations the soft
// ones above and T^T (w_r + H_r^T lambda) = 0 per body, linearized with the contact
// forces' geometry terms (on the pseudo-nodes too), the lever arms' rotation
// (sum_k [F_k]x [rho_k]x dtheta) and a hinge basis' change ((n x dp).f on the axis).
// The rigid equations have no stiffness: they take the proximal block tau_r diag(m I,
// I_w) (tau_r m = 1e-4 max K_ii; 1e-6 before ffric) and the refinement removes it as it removes a held
// body's tau. G is then formed dense over all contacts (H_s K^{-1} H_s^T + sum_r H_r W_r
// H_r^T). Rows 3n + 6R (the soft dofs, then (dp, dtheta) per body: the check-grad rows).
// Since rstfree (docs/method.md "Static derivatives: sliders, joint limits, rigid bodies
// only"): sliders; an active joint limit holds its body (W_r = 0); scenes of rigid bodies
// only (no soft system; free bodies there too). Rigidified parts (free and
// translation-servo; rstat, 2026-12-04): the reduced equilibrium P^T R = 0 on the parts'
// Schur complement less the arms' rotation term Q (docs/method.md "Static equilibrium with
// rigidified parts", *Derivatives*); since rstp also beside rigid bodies, with a cable
// through a part and on a body held by contact alone. Not covered (SOFTDIFF_DEMAND, issue
// 21): a free body beside soft bodies.
//
// dx*/dtheta (3n (+ 6R) x (parameters + actuators + rigid parameters)) at the equilibrium `equilibrium` of
// solve_static (its last load step; data holds that solve's record, data.contact its
// last NCP). Uses data's workspace (evaluates and factorizes at x*). Returns false if an
// element is inverted at x*, J (+ tau E) is not positive definite, or the refinement
// does not converge (the contacts do not hold a body held by contact alone).
bool static_sensitivities(const Model& model, Data& data, const State& equilibrium, const StaticTheta& theta,
                          MatX& dx_dtheta);

// The contact modes the derivative holds at the equilibrium x, from the last NCP's forces
// (its sigma is the last increment, ~0 at convergence, so its own classification is
// decided by round-off where a force is on the cone): breaking where lambda_N <= tol,
// sliding where mu lambda_N - |lambda_T| <= tol (mu = 0: sliding, frictionless), sticking
// otherwise; tol = 10 * contact tolerance * max |lambda|. sigma (3 nc): for a sliding
// contact its tangential slip over the last load step, s_T = H_T (x - x_start) (x_start:
// Data::static_load_step_start), the slip whose direction the force opposes at the end
// of a straight slip path; where that slip is below 1e-9 of the scene's size, the
// direction -lambda_T / |lambda_T| with an unbounded length (the direction held).
void equilibrium_modes(const Model& model, const ContactData& cd, const VecX& x, const VecX& x_start,
                       std::vector<contact::Mode>& modes, VecX& sigma);

// The reverse mode: bar_theta = (dx*/dtheta)^T bar_x (parameters + actuators) with one
// transposed solve, whatever the number of parameters. Same record and failures.
bool static_vjp(const Model& model, Data& data, const State& equilibrium, const StaticTheta& theta, const VecX& bar_x,
                VecX& bar_theta);

}  // namespace softdiff::integrator
