#pragma once
// Derivatives of the rigid BDF2 step (issue 21; docs/method.md "BDF2 with rigid bodies",
// "Derivatives"). The step of rigid_bdf2.hpp is rigid::step of size h' = 2 h / 3 from the
// extrapolated state s^ = E(s_n, s_{n-1}) (or implicit Euler of size h from s_n: the
// first step, a restart after a limit, a BDF2 end that reaches a limit). So its Jacobian
// is the implicit Euler step's (rigid_derivatives.hpp, at s^ and h') times E's:
//     d s_{n+1} = J_step (E_n d s_n + E_{n-1} d s_{n-1} + E_p d params) + J_p d params.
// E's parts (tangents as rigid_derivatives.hpp: dp, dtheta in world axes, dv, domega):
//   free body: dp^ = 4/3 dp_n - 1/3 dp_{n-1} (and v); the orientation q^ = exp(-c phi) q_n,
//     c = 1/3, phi = log(q_{n-1} q_n^-1): with q_n -> exp(a) q_n, q_{n-1} -> exp(b) q_{n-1},
//     d phi = J_l(phi)^-1 b - J_r(phi)^-1 a and
//     dtheta^ = R(-c phi) a - c J_l(-c phi) d phi   (J_l(x) = J_r(-x));
//     omega^ = A^-1 L^, A = I_w(q^), L^ = (1 + c) A_n omega_n - c A_{n-1} omega_{n-1}:
//     d omega^ = A^-1 (dL^ - (A [omega^] - [A omega^]) dtheta^), where
//     dL^ = (1 + c) (A_n d omega_n + (A_n [omega_n] - [A_n omega_n]) a) - c (same at n-1, b),
//     and the inertia component k: d omega^ = A^-1 ((1 + c) dA_n omega_n - c dA_{n-1} omega_{n-1}
//     - dA^ omega^), dA = R S_k R^T (the mass does not enter).
//   hinge, slider: e = c (c_n - c_{n-1}), d c = n.dtheta (hinge) or n.dp (slider); s^ is
//     s_n moved by e along the joint (p^ = a + R_e (p_n - a), q^ = exp(e n) q_n) with the
//     rate (1 + c) n.omega_n - c n.omega_{n-1} (n.v for a slider).
//   fixed: s^ = s_n.
// Which branch the step took is the step's record, StepInfo::bdf2 (set by bdf2_step: the
// BDF2 branch unless previous is null or restart, or the BDF2 end reached a limit): it
// is read, never decided again (2026-12-03, rbranch).
#include <softdiff/rigid/rigid_derivatives.hpp>

namespace softdiff::rigid {

// d s^ / d s_n, d s^ / d s_{n-1}, d s^ / d params of bdf2_extrapolate(body, in, previous, hat).
struct ExtrapolationJacobian {
  Mat12 in = Mat12::Zero(), previous = Mat12::Zero();
  Mat12x7 params = Mat12x7::Zero();
};
void extrapolation_jacobian(const RigidBody& body, const RigidState& in, const RigidState& previous,
                            const RigidState& hat, ExtrapolationJacobian& E);

// The Jacobian of one rigid BDF2 step (bdf2_step) that went from in (and previous) to out
// with `info`, hat the extrapolated start state it left. state: d out / d in; previous:
// d out / d previous (zero on the implicit Euler branch); params: d out / d params.
// bdf2 is set to the branch the step recorded (info.bdf2), h_used to its step length.
// previous may be null on the implicit Euler branch only (std::invalid_argument otherwise).
struct Bdf2StepJacobian {
  bool bdf2 = false;
  double h_used = 0;
  StepJacobian step;  // of rigid::step from hat with h_used
  ExtrapolationJacobian extrapolation;  // identity on `in` for the implicit Euler branch
  Mat12 state = Mat12::Zero(), previous = Mat12::Zero();
  Mat12x7 params = Mat12x7::Zero();
};
void bdf2_step_jacobian(const RigidBody& body, const RigidState& in, const RigidState* previous,
                        const RigidState& hat, const RigidState& out, const StepInfo& info, double h,
                        const Vec3& gravity, Bdf2StepJacobian& J);

}  // namespace softdiff::rigid
