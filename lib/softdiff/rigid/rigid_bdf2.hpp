#pragma once
// BDF2 for a rigid body (issue 21; docs/method.md "BDF2 with rigid bodies"), built as
// the soft BDF2 is (integrator/bdf2.hpp): the BDF2 step of size h from (s_{n-1}, s_n)
// is the implicit Euler step of size h' = 2 h / 3 (rigid::step) from an extrapolated
// state s^. Its parts:
//   - translation (free body): p^ = 4/3 p_n - 1/3 p_{n-1}, v^ = 4/3 v_n - 1/3 v_{n-1},
//     then v_{n+1} = v^ + h' F / m, p_{n+1} = p^ + h' v_{n+1}: exactly the BDF2 formulas
//     on (p, v);
//   - rotation (free body), in the rotation vector phi relative to q_n (q = exp([phi]) q_n,
//     world axes, phi_n = 0, phi_{n-1} = log(q_{n-1} q_n^{-1})): q^ = exp(-1/3 phi_{n-1}) q_n,
//     and the angular momentum L = I_w(q) omega (world) by BDF2:
//     L^ = 4/3 L_n - 1/3 L_{n-1}, omega^ = I_w(q^)^{-1} L^. rigid::step from s^ solves
//     I_w(q_{n+1}) omega_{n+1} = L^ + h' tau with q_{n+1} = exp(h' [omega_{n+1}]) q^
//     (the gyroscopic term implicit: Newton on omega). So the momentum equation is BDF2
//     exactly (a free body keeps L to round-off), and the orientation is
//     phi_{n+1} = -1/3 phi_{n-1} + h' omega_{n+1} + O(h^3): BDF2 on phi' = omega, where
//     the exact phi' = J_l(phi)^{-1} omega differs from omega by phi x omega / 2 + O(phi^2),
//     and phi_{n+1} x omega_{n+1} = O(h^2) (phi_{n+1} ~ h omega_n, omega_{n+1} - omega_n =
//     O(h)); the composition exp(h' omega) exp(-phi_{n-1}/3) differs from
//     exp(h' omega - phi_{n-1}/3) by a commutator O(h^3) as well. Local error O(h^3):
//     second order (validation_rigid_bdf2 measures the ratio 4 when halving h).
//   - hinge, slider: scalar BDF2 in the joint coordinate c (angle, travel) relative to c_n:
//     c^ = c_n + 1/3 (c_n - c_{n-1}) (a hinge's difference wrapped into (-pi, pi]),
//     cdot^ = 4/3 cdot_n - 1/3 cdot_{n-1}, s^ the body moved along its joint to c^
//     (rigid::move_along_joint) with the joint rate cdot^; rigid::step from s^ with h'
//     solves the joint's equation and clamps to the limits exactly (the limit holds at
//     c_{n+1}; the reaction is m (v_{n+1} - v^) / h' - F, the BDF2 momentum balance).
//   - fixed: does not move.
// The first step (no previous state) is implicit Euler of size h, as the soft BDF2.
// Limits (without contact): a limit is an inelastic impact, a discontinuity of the
// velocity that BDF2's history would carry on (clamping c_{n+1} = c^ + h' cdot_{n+1} at
// the limit leaves the BDF2 velocity (limit - c^) / h', which points away from the limit
// when the body arrives early in the step (alpha < 1/3 of it), and the next step bounces it off).
// So BDF2 restarts there, as after any discontinuity: a step whose BDF2 end crosses a
// limit is redone as implicit Euler of size h from s_n, and so is every step after a step
// that ended at a limit (`restart`: the caller passes the last step's at_limit). A body
// resting on its limit is thus stepped by implicit Euler (at rest both agree: the
// reaction is the load), and BDF2 resumes from the first step ending off the limit.
#include <softdiff/rigid/rigid_body.hpp>

namespace softdiff::rigid {

// The extrapolated state s^ from previous (t_{n-1}) and in (t_n). hat must not alias
// in or previous. Throws ComputationError naming the body for a non-finite result.
void bdf2_extrapolate(const RigidBody& body, const RigidState& in, const RigidState& previous, RigidState& hat);

// One BDF2 step of length h: bdf2_extrapolate, then rigid::step from the extrapolated
// state (left in hat, the contact stage's start state) with h' = 2 h / 3; *h_used is set
// to the step length used from hat (h' or h). previous == nullptr or restart, or a
// limit reached at the end of the BDF2 step: implicit Euler of size h (hat = in).
// Arguments and errors as rigid::step.
StepInfo bdf2_step(const RigidBody& body, const RigidState& in, const RigidState* previous, double h,
                   const Vec3& gravity, const Vec3& force, const Vec3& torque, RigidState& hat, RigidState& out,
                   bool enforce_limits = true, bool restart = false, double* h_used = nullptr);

}  // namespace softdiff::rigid
