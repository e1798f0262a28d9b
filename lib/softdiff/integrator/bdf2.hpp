#pragma once
// BDF2 beside implicit Euler (docs/method.md "BDF2"; scene.md `integrator: bdf2`).
//
// The second-order backward differentiation formula on x' = v, M v' = F(x, v):
//     x_{n+1} - 4/3 x_n + 1/3 x_{n-1} = 2/3 h v_{n+1}
//     M (v_{n+1} - 4/3 v_n + 1/3 v_{n-1}) = 2/3 h F(x_{n+1}, v_{n+1})
// With h' = 2 h / 3 and the extrapolated state
//     x^ = 4/3 x_n - 1/3 x_{n-1},   v^ = 4/3 v_n - 1/3 v_{n-1},
// this is exactly the implicit Euler step of size h' from (x^, v^):
//     x_{n+1} = x^ + h' v_{n+1},   M (v_{n+1} - v^) = h' F(x_{n+1}, v_{n+1}),
// so the step runs the implicit Euler stage (implicit_euler.hpp) from (x^, v^) with h':
// (on fixed dofs x^ = x_n exactly), linearized at x^ (newton_iterations = 1: A = M + h' D + h'^2 K(x^)), or Newton on
// its residual; the same laws, actuators (at t_{n+1}), fixed nodes, Rayleigh damping
// (D = alpha M + beta K(x^)), psd_projection, and contact (the NCP of the step's
// effective mass A / h' with the gap term phi(x^) / h', contact/contact_step.hpp).
// The first step (no previous state) is implicit Euler of size h.
// One factorization per step, as implicit Euler; with a constant system matrix (linear
// law) two: the first step's (h) and the BDF2 steps' (h').
//
// The record (data.h = h', data.history_weight = 1/3, data.hat = (x^, v^)) is what the
// derivatives use (bdf2_derivatives.hpp): the step is the implicit Euler step of size
// h' composed with the linear map (x_n, v_n, x_{n-1}, v_{n-1}) -> (x^, v^).
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

namespace softdiff::integrator {

// One BDF2 step from `in` (t_n) to `out` (t_n + dt). previous: the state at t_n - dt,
// or nullptr for the first step (then implicit Euler). Otherwise as implicit_euler_step.
StepStatus bdf2_step(const Model& model, Data& data, const State& in, const State* previous, State& out,
                     long step_index, const VecX* lambda_a = nullptr);

// The model's integrator (implicit_euler or bdf2): previous is ignored by implicit
// Euler; BDF2 takes it (nullptr for the first step).
StepStatus time_step(const Model& model, Data& data, const State& in, const State* previous, State& out,
                     long step_index, const VecX* lambda_a = nullptr);

}  // namespace softdiff::integrator
