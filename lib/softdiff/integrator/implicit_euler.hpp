#pragma once
// Implicit Euler with Rayleigh damping (method.md, "The step").
//
// newton_iterations == 1 is the paper's linearized step:
//     A  = M + h D + h^2 K(x_i),   D = alpha M + beta K(x_i)
//     b  = h (P + f_int(x_i) - D v_i) - h^2 K(x_i) v_i
//     A dv = b,  v_f = v_i + dv,  x_f = x_i + h v_f
// newton_iterations > 1 solves the nonlinear implicit Euler equations
//     R(v) = M (v - v_i) - h (P + f_int(x_i + h v)) + h D v = 0,  D = alpha M + beta K(x_i)
// by Newton's method started at v = 0 (x = x_i), whose first iterate is exactly the
// linearized step; it stops when ||R|| <= newton_tolerance * ||R(0)|| or after
// newton_iterations solves. The damping matrix is frozen at x_i (linear Rayleigh
// damping of the step), so the residual is a function of v alone.
// Contact: the first iteration's contact stage (contact/contact_step.hpp) detects the
// contacts at x_i; every further iteration solves the NCP of its linearization on
// them (G_k = h H_c A_k^{-1} H_c^T), and the residual and the line search's merit
// include the contact forces h H_c^T lambda (docs/method.md "Newton iterations with
// contact").
// Fixed dofs are projected (method.md): A <- Pi A Pi + (I - Pi), b <- Pi b.
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

namespace softdiff::integrator {

// One time step from `in` to `out` (out may not alias in). `step_index` (1-based)
// is recorded in the status. Fills data's record (F, K, factor, timings).
// lambda_a: the actuation values of this step (n_a), or nullptr for the model's
// schedules at t_i + h (a controller or an optimizer sets them step by step).
StepStatus implicit_euler_step(const Model& model, Data& data, const State& in, State& out, long step_index,
                               const VecX* lambda_a = nullptr);

// The implicit Euler stage every one-step and multistep step runs (integrator/bdf2.hpp):
// the step above of size h from `in`, reaching t_next, with actuation at t_next.
// implicit_euler_step is this with h = dt, t_next = in.t + dt after recording data.h,
// data.history_weight = 0 and data.hat = in.
StepStatus backward_euler_stage(const Model& model, Data& data, const State& in, State& out, long step_index,
                                const VecX* lambda_a, double h, double t_next);

// Assembles data.A = (1 + h alpha) M + h beta K_damping + h^2 K, projected, per body.
void assemble_system_matrix(const Model& model, double h, const VecX& K_damping, const VecX& K, Data& data);
// The same into any matrix A with the model's pattern.
void assemble_system_matrix(const Model& model, double h, const VecX& K_damping, const VecX& K, SparseMatrix& A);

// b <- Pi b: zero the fixed dofs.
void project(const Model& model, VecX& b);

// Symbolic analysis on first use, then numeric factorization of data.A.
StepStatus factorize(const Model& model, Data& data, long step_index);

// Post-step checks: finite values, inverted elements, divergence.
StepStatus check_state(const Model& model, const State& state, long step_index);

}  // namespace softdiff::integrator
