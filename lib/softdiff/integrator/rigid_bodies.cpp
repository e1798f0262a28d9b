// The rigid bodies' part of a time step: see rigid_bodies.hpp.
#include <softdiff/integrator/rigid_bodies.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/timer.hpp>
#include <softdiff/rigid/rigid_bdf2.hpp>

#include <string>

namespace softdiff::integrator {

StepStatus step_rigid_bodies(const Model& model, Data& data, const State& in, State& out, long step_index,
                             const State* previous, bool* fell_back) {
  const std::size_t n = model.rigid.size();
  SOFTDIFF_DEMAND(in.rigid.size() == n, "step_rigid_bodies: the state has " + std::to_string(in.rigid.size()) +
                                            " rigid bodies, the model " + std::to_string(n));
  const bool bdf2 = model.step.integrator == IntegratorKind::bdf2;
  SOFTDIFF_DEMAND(bdf2 || model.step.integrator == IntegratorKind::implicit_euler,
                  "step_rigid_bodies: rigid bodies are stepped by implicit Euler or BDF2 only");
  if (bdf2 && previous)
    SOFTDIFF_DEMAND(previous->rigid.size() == n, "step_rigid_bodies: the previous state has " +
                                                     std::to_string(previous->rigid.size()) + " rigid bodies, the model " +
                                                     std::to_string(n));
  const auto t0 = Clock::now();
  if (out.rigid.size() != n) out.rigid.resize(n);
  if (data.rigid.size() != n) data.rigid.resize(n);
  if (data.hat.rigid.size() != n) data.hat.rigid.resize(n);
  const Vec3 zero = Vec3::Zero();  // no external wrench yet (contact: a later increment)
  StepStatus status;
  if (fell_back) *fell_back = false;
  for (std::size_t r = 0; r < n; ++r) {
    // BDF2 restarts after a step that ended at a joint limit (rigid_bdf2.hpp): data.rigid
    // holds the last step's info (the first step, previous == nullptr, is Euler anyway).
    const bool restart = data.rigid[r].at_limit;
    const bool multistep = bdf2 && previous;
    data.rigid[r] = rigid::bdf2_step(model.rigid[r], in.rigid[r], multistep ? &previous->rigid[r] : nullptr,
                                     model.step.dt, model.step.gravity, zero, zero, data.hat.rigid[r], out.rigid[r],
                                     true, restart);
    if (fell_back && multistep && !data.rigid[r].bdf2) *fell_back = true;  // the branch the step recorded
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
