#pragma once
// Derivatives of the BDF2 step (sibling of bdf2.hpp; docs/method.md "BDF2",
// "Derivatives of the BDF2 step").
//
// The step is (x_f, v_f) = Phi_h'(x^, v^, lambda_a, p), the implicit Euler step of size
// h' = data.h from x^ = (1 + c) x_n - c x_{n-1}, v^ = (1 + c) v_n - c v_{n-1},
// c = data.history_weight (1/3; 0 and h' = dt for the first step and for implicit
// Euler). So its tangent is implicit Euler's (StepDerivatives, at the record's hat
// state and h') applied to
//     dx^ = (1 + c) dx_n - c dx_{n-1},   dv^ = (1 + c) dv_n - c dv_{n-1},
// and its cotangent splits implicit Euler's bar_x^, bar_v^ into
//     bar_x_n = (1 + c) bar_x^,  bar_x_{n-1} = -c bar_x^   (and the same for v).
// On fixed dofs x^ = x_n exactly (bdf2.cpp), so there dx^ = dx_n, bar_x_n = bar_x^.
// Everything else (lambda_a, parameters, contact through the NCP of the step) is
// implicit Euler's at (x^, v^, h'). Rigid bodies in contact (StepTangent::rigid,
// StepCotangent::rigid): the tangent passed in and the cotangent returned are those of
// their EXTRAPOLATED states (data.hat.rigid); the caller (diff/trajectory.cpp) maps them
// from and to (s_n, s_{n-1}) by rigid_bdf2_derivatives.hpp. These functions serve both integrators: with
// c = 0 they are StepDerivatives::jvp / vjp.
// Rigidified parts (model.rigidify): the parts' rows of (x^, v^) are not the linear blend
// but rigidify_extrapolated_state's rigid pose and field; their tangent and cotangent are
// rigidify_bdf2_derivatives.hpp's, which need the step's states x_n (in) and x_{n-1}
// (previous): demanded when c != 0 and the model has parts.
#include <softdiff/integrator/implicit_euler_derivatives.hpp>

namespace softdiff::integrator {

// d_in: tangents of x_n, v_n, lambda_a, p; d_previous: of x_{n-1}, v_{n-1} (empty:
// zero). data: the record of the step (implicit_euler_step, bdf2_step or time_step)
// that produced out.
bool multistep_jvp(StepDerivatives& derivatives, const Model& model, const Data& data, const State& out,
                   const StepTangent& d_in, const StateTangent& d_previous, StateTangent& d_out,
                   const State* in = nullptr, const State* previous = nullptr);

// bar_in: cotangents of x_n, v_n, lambda_a, p; bar_previous: of x_{n-1}, v_{n-1}
// (zero vectors for an implicit Euler step).
bool multistep_vjp(StepDerivatives& derivatives, const Model& model, const Data& data, const State& out,
                   const StateTangent& bar_out, StepCotangent& bar_in, StateTangent& bar_previous,
                   const State* in = nullptr, const State* previous = nullptr);

}  // namespace softdiff::integrator
