// BDF2: see bdf2.hpp.
#include <softdiff/integrator/bdf2.hpp>

#include <softdiff/contact/contact_step.hpp>
#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/core/timer.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/rigid_bodies.hpp>
#include <softdiff/integrator/rigidify.hpp>

#include <string>

namespace softdiff::integrator {

StepStatus bdf2_step(const Model& model, Data& data, const State& in, const State* previous, State& out,
                     long step_index, const VecX* lambda_a) {
  if (!previous) return implicit_euler_step(model, data, in, out, step_index, lambda_a);
  SOFTDIFF_DEMAND(previous->x.size() == in.x.size() && previous->v.size() == in.v.size(),
                  "bdf2_step: the previous state has " + std::to_string(previous->x.size()) + " coordinates, expected " +
                      std::to_string(in.x.size()));
  const auto t0 = Clock::now();
  const double h = model.step.dt, c = 1.0 / 3.0;
  data.h = 2.0 * h / 3.0;
  data.history_weight = c;
  data.hat.t = in.t;
  data.hat.x = (1 + c) * in.x - c * previous->x;
  data.hat.v = (1 + c) * in.v - c * previous->v;
  // Fixed dofs do not move: x^ = x_n there exactly (4/3 x - 1/3 x would drift by
  // round-off step after step).
  if (model.fem.num_fixed_dofs > 0)
    for (Eigen::Index k = 0; k < in.x.size(); ++k)
      if (model.fem.fixed[static_cast<std::size_t>(k)]) data.hat.x[k] = in.x[k];
  // Rigidified parts: their extrapolated state made rigid (integrator/rigidify.hpp).
  if (!model.rigidify.empty()) rigidify_extrapolated_state(model, in, *previous, data.hat);
  const double extrapolation = seconds_since(t0);
  const StepStatus status = backward_euler_stage(model, data, data.hat, out, step_index, lambda_a, data.h, in.t + h);
  data.timings.other += extrapolation;  // the stage resets the timings; the extrapolation counts as "other"
  return status;
}

namespace {
// Rigid bodies in contact (docs/method.md "Rigid bodies in contact"): the rigid free
// step (rigid::step without contact; BDF2: rigid::bdf2_step, implicit Euler of size
// h' = 2 h / 3 from the extrapolated states), then the soft step whose contact stage
// solves the one NCP on the soft and rigid velocities (with the stage's h: h' for
// BDF2, as the soft bodies), then the rigid poses integrated with the corrected
// velocities from the step's start states (the extrapolated ones for BDF2: the BDF2
// pose update p_{n+1} = p^ + h' v_{n+1}). With Newton iterations too (implicit Euler, and
// BDF2's stage from the extrapolated states): the rigid free step and W_r are fixed for
// the step (the rigid step is linear in the contact impulse), every iteration's NCP takes
// the same rigid rows (docs/method.md "Newton with rigid contact").
// crossed (BDF2 with a limited joint, time_step_rigid_contact_limits below): when not
// null, the step stops after the rigid free step if a body's BDF2 free end reached a limit
// (*crossed set): the caller redoes it as implicit Euler.
StepStatus time_step_rigid_contact(const Model& model, Data& data, const State& in, const State* previous, State& out,
                                   long step_index, const VecX* lambda_a, bool* crossed = nullptr) {
  const bool bdf2 = model.step.integrator == IntegratorKind::bdf2;
  SOFTDIFF_DEMAND(bdf2 || model.step.integrator == IntegratorKind::implicit_euler,
                  "time_step: rigid bodies in contact need implicit_euler or bdf2 (Newton too)");
  const auto t0 = Clock::now();
  const StepStatus free = step_rigid_bodies(model, data, in, out, step_index, bdf2 ? previous : nullptr, crossed);
  if (!free.ok() || (crossed && *crossed)) return free;
  // data.hat.rigid: the rigid start states of the stage (the soft bdf2_step leaves them).
  contact::begin_rigid_contact(model, data, data.hat.rigid, out.rigid);
  const double rigid_seconds = seconds_since(t0);
  const StepStatus soft = bdf2 ? bdf2_step(model, data, in, previous, out, step_index, lambda_a)
                               : implicit_euler_step(model, data, in, out, step_index, lambda_a);  // resets the timings
  data.timings.other += rigid_seconds;
  if (!(soft.ok() || soft.code == StepStatus::Code::not_converged)) return soft;
  const StepStatus rigid = contact::end_rigid_contact(model, data, out.rigid, data.h, step_index);
  return rigid.ok() ? soft : rigid;
}
}  // namespace

namespace {
// A scene of rigid bodies only (no soft node): the soft stage is skipped, no matrix is
// assembled or factorized (the linear solver is never called). Without contact the
// rigid bodies' own step; with contact the rigid free step, then the one NCP on the
// rigid velocities alone (contact/contact_step.cpp: G = h sum_r H_r W_r H_r^T, no soft
// block, the dense backend), then the poses integrated with the corrected velocities,
// exactly as time_step_rigid_contact without the soft step. The soft state stays empty
// (x, v of size 0); the record (data.h, history_weight, hat) is the rigid step's.
StepStatus time_step_rigid_only(const Model& model, Data& data, const State& in, const State* previous, State& out,
                                long step_index, bool* crossed = nullptr) {
  const bool bdf2 = model.step.integrator == IntegratorKind::bdf2 && previous;
  const double h = model.step.dt;
  data.timings = {};
  data.h = bdf2 ? 2.0 * h / 3.0 : h;
  data.history_weight = bdf2 ? 1.0 / 3.0 : 0.0;
  data.hat.t = in.t;
  data.hat.x.resize(0);
  data.hat.v.resize(0);
  data.newton_iterations_used = 1;
  data.newton_residual = 0;
  out.x.resize(0);
  out.v.resize(0);
  out.t = in.t + h;
  const StepStatus free = step_rigid_bodies(model, data, in, out, step_index, bdf2 ? previous : nullptr, crossed);
  if (!free.ok() || !model.contact.with_rigid() || (crossed && *crossed)) return free;
  const auto t0 = Clock::now();
  contact::begin_rigid_contact(model, data, data.hat.rigid, out.rigid);
  data.timings.other += seconds_since(t0);
  const StepStatus contact = contact::resolve_contacts(model, data, data.hat, out.v, step_index, data.h);
  if (!contact.ok()) return contact;
  return contact::end_rigid_contact(model, data, out.rigid, data.h, step_index);
}

// BDF2 in contact with a limited hinge or slider (docs/method.md "BDF2 with rigid bodies",
// *Limits in contact*): a limit is an inelastic impact, after which BDF2 restarts, as
// without contact (rigid/rigid_bdf2.hpp), but for the whole step: the one NCP has one h
// (the soft and rigid bodies, the contacts and the limit rows share h' = 2h/3 or h). So
//   - the step after a step that ended at a limit (a limited body's data.rigid at_limit,
//     set below) is the implicit Euler contact step of size h from s_n;
//   - otherwise the BDF2 contact step runs; if a body's BDF2 free end reaches a limit
//     (the free step stops there: nothing else is computed), or the contact solve's
//     result has an active limit row (its force > 0), the step is redone as the implicit
//     Euler contact step of size h from s_n (the redo warm-starts from the BDF2 attempt's
//     forces).
// The branch taken is the step's record: data.history_weight (1/3 BDF2, 0 implicit Euler)
// and data.h (h', h); the derivatives read it there (diff/trajectory.cpp), nothing is
// decided again. After the step each limited body's data.rigid at_limit says whether it
// ended at a limit: an active limit row (contacts detected), else the free step's clamp
// (no contact: the free step is the result, rigid::step's exact limit).
// Whether a limited body's limit row of the last contact solve is active (force > 0),
// or, without contacts, the free step stopped at a limit; recorded in data.rigid[r].at_limit.
bool mark_limits(const Model& model, Data& data) {
  const bool solved = data.contact.contacts.size() > 0;
  const auto& ll = data.contact.rigid.limit_lambda;
  bool any = false;
  int slot = 0;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& b = model.rigid[r];
    if (!(b.joint.limits && (b.joint.kind == rigid::Joint::Kind::hinge || b.joint.kind == rigid::Joint::Kind::slider))) {
      data.rigid[r].at_limit = false;
      continue;
    }
    if (solved) {
      SOFTDIFF_DEMAND(ll.size() >= slot + 2, "bdf2: the contact solve left no limit forces");
      data.rigid[r].at_limit = ll[slot] > 0 || ll[slot + 1] > 0;
    }
    any = any || data.rigid[r].at_limit;
    slot += 2;
  }
  return any;
}

// The normal velocity n . sum_k w_k v_k of contact c at state s: soft nodes from s.v,
// a rigid body's pseudo-node k from its body's twist, v_r + omega_r x (R_r X_k)
// (positive: separating, as the contact's gap).
double normal_velocity(const Model& model, const collision::Contact& c, const State& s) {
  const int n = model.fem.num_nodes;
  Vec3 u = Vec3::Zero();
  for (int k = 0; k < c.count; ++k) {
    const int node = c.nodes[static_cast<std::size_t>(k)];
    const double w = c.weights[static_cast<std::size_t>(k)];
    if (node < 0 || w == 0) continue;
    if (node < n) {
      if (s.v.size() >= 3 * static_cast<Eigen::Index>(node) + 3) u += w * s.v.segment<3>(3 * static_cast<Eigen::Index>(node));
      continue;
    }
    const int r = model.contact.rigid_node_body[static_cast<std::size_t>(node - n)];
    const auto& body = model.rigid[static_cast<std::size_t>(r)];
    const auto& b = s.rigid[static_cast<std::size_t>(r)];
    const int j = node - model.contact.rigid_node_begin[static_cast<std::size_t>(r)];
    const Vec3 rho = b.orientation * body.surface.vertices.col(j);
    u += w * (b.velocity + b.angular_velocity.cross(rho));
  }
  return c.frame.col(2).dot(u);
}

// The closing speed above which a contact counts as an impact: one that would cover a
// hundredth of the detection margin in one step (margin 1 mm, dt 2 ms: 5 mm/s). A
// resting or slowly pressed contact (round-off, creep) stays
// below it; the spurious lift a closing speed V leaves under BDF2 is about 1.7 V dt
// (measured: 0.47 mm at V = 0.137 m/s, dt = 2 ms), so an impact below the threshold lifts
// the body by at most ~2% of the margin.
double impact_closing_speed(const Model& model) { return 0.01 * model.contact.detection.margin / model.step.dt; }

// Which contacts the impact test looks at (docs/method.md "BDF2", *Impacts: BDF2
// restarts*): every contact of the attempt: a rigid body's against an obstacle or another
// rigid body (every node a pseudo-node; 2026-12-04 rbimp), a soft body's against an
// obstacle or another soft body (every node soft; 2026-12-04 rsoft), and a soft-rigid
// contact (soft nodes and pseudo-nodes in one contact; 2026-12-04 rsrb: a rigid cube
// landing on a soft slab, a soft finger hitting a free block). The soft-rigid contacts
// were left out while the derivatives through such a restart did not check (test_rigid
// RigidBdf2ContactTrajectory.CubeOnASoftSlab): the redo detects its contacts at s_n,
// where the contacts the previous step closed have round-off gaps (1e-12-1e-10 m), and the
// narrow phase took their normal as d / |d|, noise at such gaps (1e-6 to 3e-6 rad measured,
// varying non-smoothly with the state); the BDF2 attempt detects at the extrapolated
// x^, a third of a step inside, where d / |d| is accurate. rnrm's normals at tiny gaps
// (collision/detection.cpp, docs/method.md *Contact normals at tiny gaps*) take the face
// normal there and removed the cause (measured: docs/method.md *Soft-rigid impacts
// restart*).
//
// The impact test (docs/method.md "BDF2", *Impacts: BDF2 restarts*, 2026-12-04 rbimp,
// extended to soft contacts 2026-12-04 rsoft, to soft-rigid ones 2026-12-04 rsrb), on
// the BDF2 attempt's contacts, with N(s)
// a contact's normal velocity at state s (soft nodes: H v from the nodal velocities;
// pseudo-nodes: the body's twist) and V the closing speed above:
//  (a) the step closes the contact: it carries a normal force (lambda_N > 0) and
//      N(s_n) < -V (it was closing at the step's start);
//  (b) the step follows an impact at the contact: N(s_{n-1}) < -V and
//      N(s_n) - N(s_{n-1}) > V (the last step stopped it: an impulse acted there). The
//      history (x^, v^) still holds the pre-impact velocity, and the BDF2 attempt may
//      leave the contact with no force at all (it separates: the bounce), so (a) alone
//      misses this step.
// Stateless: a function of s_n, s_{n-1} and the attempt, so the derivatives' recomputed
// step (diff/trajectory.cpp, check-grad) takes the same branch from the same states.
bool impact(const Model& model, const Data& data, const State& in, const State& previous, double closing_speed) {
  const auto& list = data.contact.contacts.contacts;
  const auto& lambda = data.contact.lambda;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const auto& c = list[i];
    const double now = normal_velocity(model, c, in), before = normal_velocity(model, c, previous);
    const Eigen::Index row = 3 * static_cast<Eigen::Index>(i) + 2;
    const bool pressed = lambda.size() > row && lambda[row] > 0;
    if ((pressed && now < -closing_speed) || (before < -closing_speed && now - before > closing_speed)) return true;
  }
  return false;
}

StepStatus time_step_rigid_contact_limits(const Model& model, Data& data, const State& in, const State* previous,
                                          State& out, long step_index, const VecX* lambda_a) {
  const bool rigid_only = model.fem.num_nodes == 0;
  auto attempt = [&](const State* prev, bool* crossed) {
    return rigid_only ? time_step_rigid_only(model, data, in, prev, out, step_index, crossed)
                      : time_step_rigid_contact(model, data, in, prev, out, step_index, lambda_a, crossed);
  };
  // The restart: a limited body ended the last step at a limit (none before the first step).
  bool restart = !previous;
  for (std::size_t r = 0; r < data.rigid.size() && r < model.rigid.size(); ++r) restart = restart || data.rigid[r].at_limit;
  auto usable = [](const StepStatus& st) { return st.ok() || st.code == StepStatus::Code::not_converged; };
  StepStatus status;
  double attempt_residual = -1;  // the BDF2 attempt's NCP residual when it did not converge
  if (!restart) {
    bool crossed = false;
    status = attempt(previous, &crossed);
    if (!usable(status)) return status;
    if (!crossed && data.contact.contacts.size() > 0 && !data.contact.result.converged)
      attempt_residual = data.contact.result.residuals.max();
    if (!crossed) {
      if (!mark_limits(model, data) && !impact(model, data, in, *previous, impact_closing_speed(model)))
        return status;  // the BDF2 branch
    }
  }
  // The implicit Euler branch: of size h from s_n (previous null: every part implicit Euler).
  for (auto& info : data.rigid) info.at_limit = false;
  status = attempt(nullptr, nullptr);
  // The redo warm-starts from the BDF2 attempt's forces. When the attempt's NCP did not
  // converge and the redo's ended further from a solution than the attempt's (or the
  // redo failed), the redo runs again from zero forces (docs/method.md "BDF2",
  // *gripper_lift under bdf2*, 2026-12-04 glift): configs/gripper_lift.yaml under bdf2,
  // step 123: the attempt stopped at residual 9.7e-3 with |lambda| up to 3.5, the redo
  // from those forces diverged (residual 2.5e9, |lambda| 1.8e11) and the step with it;
  // from zero it reaches 1e-5 and the run finishes. A converged redo is kept as it is
  // (the attempt's forces are the better start there: the cube on the soft slab's step 8
  // converges from them, not from zero). A function of the step's inputs and warm start,
  // so the derivatives' recomputed step (diff/trajectory.cpp) takes the same branch.
  if (attempt_residual >= 0 && data.contact.contacts.size() > 0 &&
      (!usable(status) || (!data.contact.result.converged && !(data.contact.result.residuals.max() <= attempt_residual)))) {
    for (auto& info : data.rigid) info.at_limit = false;
    data.contact.previous_keys.clear();  // no key matches: the NCP starts from zero forces
    status = attempt(nullptr, nullptr);
  }
  if (!usable(status)) return status;
  mark_limits(model, data);
  return status;
}
}  // namespace

StepStatus time_step(const Model& model, Data& data, const State& in, const State* previous, State& out,
                     long step_index, const VecX* lambda_a) {
  if (model.step.integrator == IntegratorKind::bdf2 && model.contact.with_rigid())
    return time_step_rigid_contact_limits(model, data, in, previous, out, step_index, lambda_a);
  if (model.fem.num_nodes == 0) return time_step_rigid_only(model, data, in, previous, out, step_index);
  if (model.contact.with_rigid()) return time_step_rigid_contact(model, data, in, previous, out, step_index, lambda_a);
  const bool bdf2 = model.step.integrator == IntegratorKind::bdf2 && previous;
  StepStatus soft = bdf2 ? bdf2_step(model, data, in, previous, out, step_index, lambda_a)
                         : implicit_euler_step(model, data, in, out, step_index, lambda_a);
  auto usable = [](const StepStatus& st) { return st.ok() || st.code == StepStatus::Code::not_converged; };
  if (!usable(soft)) return soft;
  // A soft impact (docs/method.md "BDF2", *Impacts: BDF2 restarts*, 2026-12-04 rsoft):
  // the BDF2 attempt is redone as the implicit Euler step of size h from s_n, whose
  // record (history_weight 0, h, hat = s_n) the derivatives read; the rigid bodies (not
  // in contact) take that step's branch too: implicit Euler, so the step has one record.
  bool restarted = false;
  if (bdf2 && model.contact.enabled && impact(model, data, in, *previous, impact_closing_speed(model))) {
    soft = implicit_euler_step(model, data, in, out, step_index, lambda_a);
    if (!usable(soft)) return soft;
    restarted = true;
  }
  if (model.rigid.empty()) return soft;
  // The rigid bodies: independent of the soft ones while there is no contact.
  const StepStatus rigid = step_rigid_bodies(model, data, in, out, step_index, bdf2 && !restarted ? previous : nullptr);
  return rigid.ok() ? soft : rigid;
}

}  // namespace softdiff::integrator
