#pragma once
// Static equilibrium (`integrator: static`): f_int(x) + P + H_a(x)^T lambda_a = 0
// (method.md), with fixed dofs projected. Load step s of L applies s/L of gravity
// and the actuators' values at pseudo-time s/L (a constant value v gives v s/L). Newton's method with a backtracking line
// search on the total potential energy Pi(x) = E(x) - P.x, and load steps: the
// external load is ramped as s / load_steps, s = 1..load_steps, each solved to
// ||Pi (f_int + s P / L)|| <= tolerance * max(||Pi s P / L||, ||f_int||) (relative
// residual force norm; ||f_int|| includes the reactions at fixed dofs, the force scale
// of displacement-driven problems). With actuators: the line search is on the
// residual norm, and the tangent is K + sum_cables lambda d^2L/dx^2 (exact for
// cables; cavities' and rotation servos' derivatives are left out). The model's
// pattern must hold the cables' stiffness cliques (io::build_model does this; a
// hand-built model passes model.actuation.stiffness_cliques() to build_fem_model):
// SOFTDIFF_DEMAND otherwise. Where the tangent is not positive definite (compression
// on the way to a stable equilibrium), the step uses A + tau I on the free dofs with
// the smallest tenfold-grown tau that factorizes (Data::static_shifted_iterations counts
// those iterations); the exact tangent is used wherever it factorizes (docs/method.md
// "Indefinite tangent").
// Contact (model.contact.enabled): each Newton iteration runs the contact stage of the
// step on the linearized problem (contact::resolve_contacts with h = 1: G = H_c A^{-1}
// H_c^T, g = H_c dx_free + phi, dx = dx_free + A^{-1} H_c^T lambda, friction on the
// iteration's increment), takes the full step (no potential: halved only where an
// element inverts), and converges on f_int + P + H_a^T lambda_a + H_c^T lambda and the
// NCP's tolerance; data.contact holds the last NCP of the last load step. A body
// without fixed dofs (held by contact) gets a proximal term on its dofs (docs/method.md
// "Static equilibrium", "Contact").
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <functional>

namespace softdiff::integrator {

// Called after each converged load step with the load factor s / L and the state
// (v = 0, t = load factor).
using LoadStepCallback = std::function<void(long load_step, const State& state)>;

StepStatus solve_static(const Model& model, Data& data, const State& in, State& out,
                        const LoadStepCallback& on_load_step = {});

}  // namespace softdiff::integrator
