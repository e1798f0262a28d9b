// Derivatives of the BDF2 step: see bdf2_derivatives.hpp.
#include <softdiff/integrator/bdf2_derivatives.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/integrator/rigidify_bdf2_derivatives.hpp>

namespace softdiff::integrator {

namespace {
// (1 + c) a - c b, with empty vectors standing for zero (the result empty if both are).
void combine(double c, const VecX& a, const VecX& b, VecX& out) {
  if (a.size() == 0 && (b.size() == 0 || c == 0)) {
    out.resize(0);
    return;
  }
  const Eigen::Index n = a.size() ? a.size() : b.size();
  out = VecX::Zero(n);
  if (a.size()) out += (1 + c) * a;
  if (c != 0 && b.size()) out -= c * b;
}

void demand_states(const Model& model, const State* in, const State* previous) {
  SOFTDIFF_DEMAND(in && previous && in->x.size() == 3L * model.fem.num_nodes && previous->x.size() == in->x.size(),
                  "multistep derivatives with rigidified parts: the step's states x_n and x_{n-1} are needed");
}
}  // namespace

bool multistep_jvp(StepDerivatives& derivatives, const Model& model, const Data& data, const State& out,
                   const StepTangent& d_in, const StateTangent& d_previous, StateTangent& d_out,
                   const State* in, const State* previous) {
  const double c = data.history_weight;
  if (c == 0) return derivatives.jvp(model, data, data.hat, out, d_in, d_out);
  StepTangent d_hat;
  combine(c, d_in.x, d_previous.x, d_hat.x);
  // Fixed dofs: x^ = x_n (bdf2.cpp).
  if (d_hat.x.size() && model.fem.num_fixed_dofs > 0)
    for (Eigen::Index k = 0; k < d_hat.x.size(); ++k)
      if (model.fem.fixed[static_cast<std::size_t>(k)]) d_hat.x[k] = d_in.x.size() ? d_in.x[k] : 0.0;
  combine(c, d_in.v, d_previous.v, d_hat.v);
  if (!model.rigidify.empty()) {
    // Rigidified parts: their rows of (x^, v^) are the rigid extrapolation's.
    demand_states(model, in, previous);
    const Eigen::Index n = in->x.size();
    if (d_hat.x.size() == 0) d_hat.x.setZero(n);
    if (d_hat.v.size() == 0) d_hat.v.setZero(n);
    rigidify_extrapolation_jvp(model, *in, *previous, d_in.x, d_in.v, d_previous.x, d_previous.v, d_hat.x, d_hat.v);
  }
  d_hat.lambda_a = d_in.lambda_a;
  d_hat.p = d_in.p;
  // Rigid bodies in contact: d_in.rigid is already the tangent of their extrapolated
  // states (the caller applies rigid_bdf2_derivatives.hpp's extrapolation Jacobian).
  d_hat.rigid = d_in.rigid;
  d_hat.rigid_p = d_in.rigid_p;
  return derivatives.jvp(model, data, data.hat, out, d_hat, d_out);
}

bool multistep_vjp(StepDerivatives& derivatives, const Model& model, const Data& data, const State& out,
                   const StateTangent& bar_out, StepCotangent& bar_in, StateTangent& bar_previous,
                   const State* in, const State* previous) {
  const double c = data.history_weight;
  if (!derivatives.vjp(model, data, data.hat, out, bar_out, bar_in)) return false;
  const bool parts = c != 0 && !model.rigidify.empty();
  VecX bar_hat_x, bar_hat_v;  // with parts: the cotangents of (x^, v^), before the split
  if (parts) {
    demand_states(model, in, previous);
    bar_hat_x = bar_in.x;
    bar_hat_v = bar_in.v;
  }
  bar_previous.x = -c * bar_in.x;
  bar_previous.v = -c * bar_in.v;
  if (c != 0) {
    // Fixed dofs: x^ = x_n there, so their cotangent goes to x_n whole.
    if (model.fem.num_fixed_dofs > 0)
      for (Eigen::Index k = 0; k < bar_in.x.size(); ++k)
        if (model.fem.fixed[static_cast<std::size_t>(k)]) {
          bar_previous.x[k] = 0;
          bar_in.x[k] /= 1 + c;  // undone by the scaling below
        }
    bar_in.x *= 1 + c;
    bar_in.v *= 1 + c;
  }
  // Rigidified parts: their rows through the rigid extrapolation instead of the blend.
  if (parts)
    rigidify_extrapolation_vjp(model, *in, *previous, bar_hat_x, bar_hat_v, bar_in.x, bar_in.v, bar_previous.x,
                               bar_previous.v);
  return true;
}

}  // namespace softdiff::integrator
