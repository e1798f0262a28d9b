// The rigid bodies' part of a time step: see rigid_bodies.hpp.
#include <softdiff/integrator/rigid_bodies.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/timer.hpp>

#include <string>

namespace softdiff::integrator {

StepStatus step_rigid_bodies(const Model& model, Data& data, const State& in, State& out, long step_index) {
  const std::size_t n = model.rigid.size();
  SOFTDIFF_DEMAND(in.rigid.size() == n, "step_rigid_bodies: the state has " + std::to_string(in.rigid.size()) +
                                            " rigid bodies, the model " + std::to_string(n));
  SOFTDIFF_DEMAND(model.step.integrator == IntegratorKind::implicit_euler,
                  "step_rigid_bodies: rigid bodies are stepped by implicit Euler only");
  const auto t0 = Clock::now();
  if (out.rigid.size() != n) out.rigid.resize(n);
  if (data.rigid.size() != n) data.rigid.resize(n);
  const Vec3 zero = Vec3::Zero();  // no external wrench yet (contact: a later increment)
  StepStatus status;
  for (std::size_t r = 0; r < n; ++r) {
    data.rigid[r] = rigid::step(model.rigid[r], in.rigid[r], model.step.dt, model.step.gravity, zero, zero, out.rigid[r]);
    if (!rigid::finite(out.rigid[r])) {
      status.code = StepStatus::Code::non_finite;
      status.step = step_index;
      status.detail = "rigid body '" + model.rigid[r].name + "' has a non-finite pose or velocity after the step";
      break;
    }
  }
  data.timings.other += seconds_since(t0);
  return status;
}

}  // namespace softdiff::integrator
