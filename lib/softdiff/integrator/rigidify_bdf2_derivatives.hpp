#pragma once
// Derivatives of the BDF2 extrapolation of rigidified parts (issue 21; docs/method.md
// "Rigidified parts", *BDF2*, *Derivatives*): the tangent and the cotangent of
// rigidify_extrapolated_state (rigidify.hpp), the parts' rows of the stage's start state
// (x^, v^) as functions of (x_n, v_n, x_{n-1}, v_{n-1}). Used by multistep_jvp /
// multistep_vjp (bdf2_derivatives.hpp), which chain it with the implicit Euler stage's.
//
// Per part (m_i the lumped masses, c the centroids, a_i = x_{n,i} - c_n,
// b_i = x_{n-1,i} - c_{n-1}):
//   K = sum m a b^T = R S (R the polar factor, S symmetric): dR = R [w]x with
//       (tr S I - S) w = sum m [b_i x R^T dx_{n,i} - (R^T a_i) x dx_{n-1,i}]
//       (the skew part of R^T dK; sum m b_i = sum m a_i = 0 drops the centroids' terms);
//   phi = log R: dphi = J_r(phi)^{-1} w;  E = exp(phi / 3): dE = E [theta]x,
//       theta = J_r(phi / 3) dphi / 3;
//   x^_i = c^ + r_i, r_i = E a_i, c^ = 4/3 c_n - 1/3 c_{n-1}: dr_i = E (theta x a_i + da_i);
//   v_p^ = (4/3 sum m v_n - 1/3 sum m v_{n-1}) / m;
//   L = sum m (4/3 a x v_n - 1/3 b x v_{n-1});  I^ = sum m (|r|^2 I - r r^T);
//   omega^ = I^{-1} L: domega^ = I^{-1} (dL - dI^ omega^);
//   v^_i = v_p^ + omega^ x r_i.
// The reverse mode transposes each piece. No allocation (fixed-size per part).
#include <softdiff/core/types.hpp>

namespace softdiff {
struct Model;
struct State;
}  // namespace softdiff

namespace softdiff::integrator {

// Overwrites the parts' rows of dx_hat, dv_hat (sized 3n) with the tangent of the
// extrapolated part state along (dx_n, dv_n, dx_prev, dv_prev) (empty: zero); in and
// previous are the states x_n and x_{n-1} of the step. The other rows are left as given.
void rigidify_extrapolation_jvp(const Model& model, const State& in, const State& previous, const VecX& dx_n,
                                const VecX& dv_n, const VecX& dx_prev, const VecX& dv_prev, VecX& dx_hat,
                                VecX& dv_hat);

// Sets the parts' rows of bar_x_n, bar_v_n, bar_x_prev, bar_v_prev (sized 3n) to the
// cotangents, through the parts' extrapolation, of the parts' rows of bar_x_hat,
// bar_v_hat. The other rows are left as given.
void rigidify_extrapolation_vjp(const Model& model, const State& in, const State& previous, const VecX& bar_x_hat,
                                const VecX& bar_v_hat, VecX& bar_x_n, VecX& bar_v_n, VecX& bar_x_prev,
                                VecX& bar_v_prev);

}  // namespace softdiff::integrator
