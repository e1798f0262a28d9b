#pragma once
// The rigid bodies' part of a time step (issue 21, increment 1): each rigid body of
// the model is its own small implicit system (rigid/rigid_body.hpp: implicit Euler on
// the velocities, the exponential map on the orientation, joints and limits exact;
// BDF2: rigid/rigid_bdf2.hpp),
// stepped with the same h under the scene's gravity and no external wrench.
// integrator::time_step calls it when the model has rigid bodies (and only then: a
// scene without them pays nothing): without contact after the soft step (the two are
// independent, so the order does not matter); with contact first, as the free step of
// the one contact solve (bdf2.cpp time_step_rigid_contact, contact/rigid_contact.hpp).
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

namespace softdiff::integrator {

// Steps every rigid body from in.rigid to out.rigid (resized to match on first use;
// no allocation afterwards) over model.step.dt; records each body's StepInfo in
// data.rigid. A non-finite result is a non_finite status naming the body.
// Implicit Euler, or BDF2 (rigid/rigid_bdf2.hpp) with previous the state at t_n - dt
// (nullptr for the first step: implicit Euler); the step's start states (the
// extrapolated ones with BDF2, else in.rigid) are left in data.hat.rigid (the contact
// stage's start). The scene reader refuses static with rigid bodies.
// fell_back (BDF2 in contact with a limited joint, bdf2.cpp): when not null, set to whether
// any body's BDF2 step was redone as implicit Euler (its BDF2 end reached a limit,
// rigid_bdf2.hpp); the caller then redoes the whole step as implicit Euler.
StepStatus step_rigid_bodies(const Model& model, Data& data, const State& in, State& out, long step_index,
                             const State* previous = nullptr, bool* fell_back = nullptr);

}  // namespace softdiff::integrator
