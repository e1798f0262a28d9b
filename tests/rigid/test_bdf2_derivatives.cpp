// Derivatives of the rigid BDF2 step (lib/softdiff/rigid/rigid_bdf2_derivatives.cpp)
// against central finite differences of rigid::bdf2_step itself: d out / d s_n (12 x 12),
// d out / d s_{n-1} (BDF2's history, 12 x 12) and d out / d (mass, inertia) (12 x 7), for
// a free body spinning about a non-principal axis (the extrapolated orientation
// exp(-phi/3) q_n and angular momentum: the rotation terms), a slow spin (the Taylor
// branches), a hinge pendulum, a slider, a fixed body, and the implicit Euler branches:
// a restart after a limit and a BDF2 end that reaches a limit (the history's columns zero).
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/rigid/rigid_bdf2.hpp>
#include <softdiff/rigid/rigid_bdf2_derivatives.hpp>
#include <support/rigid_contact.hpp>

#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <string>

using namespace softdiff;
using namespace softdiff::rigid;

namespace rigid_bdf2_derivatives_test {

struct Case {
  RigidBody body;
  RigidState previous, in;
  bool restart = false;
  double h = 0.01;
  Vec3 g = Vec3(0, 0, -9.81);
};

using test::rigid_scenes::generic_state;
using test::rigid_scenes::rigid_block;

RigidState bdf2_of(const Case& c, const RigidBody& body, const RigidState& in, const RigidState& previous,
                   StepInfo* info = nullptr, RigidState* hat_out = nullptr) {
  RigidState hat, out;
  const Vec3 zero = Vec3::Zero();
  const StepInfo i = bdf2_step(body, in, &previous, c.h, c.g, zero, zero, hat, out, true, c.restart);
  if (info) *info = i;
  if (hat_out) *hat_out = hat;
  return out;
}

// From the body's reference state: one implicit Euler step, then `steps` BDF2 steps (a
// history of the integrator's own), restarting after a step that ended at a limit as
// integrator/rigid_bodies.cpp does. Leaves (previous, in) and the restart flag.
void run(Case& c, int steps) {
  const Vec3 zero = Vec3::Zero();
  RigidState hat, out;
  c.in = c.body.reference;
  StepInfo info = bdf2_step(c.body, c.in, nullptr, c.h, c.g, zero, zero, hat, out);
  c.previous = c.in;
  c.in = out;
  for (int k = 0; k < steps; ++k) {
    info = bdf2_step(c.body, c.in, &c.previous, c.h, c.g, zero, zero, hat, out, true, info.at_limit);
    c.previous = c.in;
    c.in = out;
  }
  c.restart = info.at_limit;
}

// Central differences column by column (states moved by rigid::retract along the unit
// tangent, outputs compared in the tangent space of the unperturbed output). eps = 1e-6
// on states of size ~1: truncation eps^2 times the third derivative (~1e-12) is below
// the round-off (1e-16 / 1e-6 = 1e-10, and the rotational Newton's 1e-14 of the momentum:
// 1e-8 relative); tolerance 1e-6 per column relative to max(|column|, 1), 100 times that.
// Parameters: eps times the mass, times the inertia's trace / 3 (its components).
void check(const Case& c, bool want_bdf2) {
  StepInfo info;
  RigidState hat;
  const RigidState out = bdf2_of(c, c.body, c.in, c.previous, &info, &hat);
  Bdf2StepJacobian J;
  bdf2_step_jacobian(c.body, c.in, &c.previous, hat, out, info, c.h, c.g, J);
  ASSERT_EQ(J.bdf2, want_bdf2);
  ASSERT_TRUE(J.state.allFinite() && J.previous.allFinite() && J.params.allFinite());
  if (!want_bdf2) {
    EXPECT_EQ(J.previous.norm(), 0.0);
  }
  const double eps = 1e-6, tol = 1e-6;
  for (int side = 0; side < 2; ++side)
    for (int j = 0; j < 12; ++j) {
      const RigidState& base = side == 0 ? c.in : c.previous;
      const RigidState bp = retract(base, Vec12::Unit(j), eps), bm = retract(base, Vec12::Unit(j), -eps);
      StepInfo ip, im;
      const RigidState sp = side == 0 ? bdf2_of(c, c.body, bp, c.previous, &ip) : bdf2_of(c, c.body, c.in, bp, &ip);
      const RigidState sm = side == 0 ? bdf2_of(c, c.body, bm, c.previous, &im) : bdf2_of(c, c.body, c.in, bm, &im);
      ASSERT_EQ(ip.at_limit, info.at_limit);
      ASSERT_EQ(im.at_limit, info.at_limit);
      const Vec12 fd = (tangent_between(out, sp) - tangent_between(out, sm)) / (2 * eps);
      const Vec12 an = side == 0 ? Vec12(J.state.col(j)) : Vec12(J.previous.col(j));
      EXPECT_LE((an - fd).norm(), tol * std::max(fd.norm(), 1.0))
          << (side == 0 ? "s_n" : "s_{n-1}") << " column " << j << "\nanalytic " << an.transpose() << "\nfd       "
          << fd.transpose();
    }
  const double trace = c.body.inertia.trace() / 3;
  for (int k = 0; k < kRigidParameters; ++k) {
    const double value = get_parameter(c.body, k);
    const double e = eps * (k == 0 ? value : trace);
    RigidBody bp = c.body, bm = c.body;
    set_parameter(bp, k, value + e);
    set_parameter(bm, k, value - e);
    const Vec12 fd = (tangent_between(out, bdf2_of(c, bp, c.in, c.previous)) -
                      tangent_between(out, bdf2_of(c, bm, c.in, c.previous))) / (2 * e);
    const double scale = k == 0 ? value : trace;
    EXPECT_LE(scale * (J.params.col(k) - fd).norm(), tol * std::max(scale * fd.norm(), 1.0))
        << rigid_parameter_name(k) << "\nanalytic " << J.params.col(k).transpose() << "\nfd       " << fd.transpose();
  }
}

TEST(RigidBdf2StepDerivatives, FreeSpinningBodyWithHistory) {
  Case c;
  c.body = rigid_block(Joint::Kind::free);
  initialize(c.body, generic_state());
  c.h = 0.02;  // h |omega| = 0.2: the rotation between s_{n-1} and s_n far from I
  run(c, 4);
  check(c, true);
  // The history matters: the previous state's rotation block is not zero.
  StepInfo info;
  RigidState hat;
  const RigidState out = bdf2_of(c, c.body, c.in, c.previous, &info, &hat);
  Bdf2StepJacobian J;
  bdf2_step_jacobian(c.body, c.in, &c.previous, hat, out, info, c.h, c.g, J);
  EXPECT_GT((J.previous.block<3, 3>(3, 3).norm()), 0.1);
  EXPECT_GT((J.previous.block<3, 3>(9, 9).norm()), 0.1);
}

TEST(RigidBdf2StepDerivatives, FreeBodySlowSpin) {
  // |h omega| < 1e-3: the Taylor branches of the exponential map, logarithm and Jacobians.
  Case c;
  c.body = rigid_block(Joint::Kind::free);
  RigidState s = generic_state();
  s.angular_velocity = Vec3(0.01, -0.02, 0.03);
  initialize(c.body, s);
  run(c, 3);
  check(c, true);
}

Case hinge_case() {
  Case c;
  c.body = rigid_block(Joint::Kind::hinge);
  c.body.joint.anchor = Vec3(0.1, 0.2, 0.5);
  c.body.joint.axis = Vec3(1, 0.3, 0.2).normalized();
  initialize(c.body, generic_state());  // projects the velocity onto the hinge
  return c;
}

TEST(RigidBdf2StepDerivatives, HingePendulum) {
  Case c = hinge_case();
  run(c, 7);  // mid-swing
  check(c, true);
}

TEST(RigidBdf2StepDerivatives, Slider) {
  Case c;
  c.body = rigid_block(Joint::Kind::slider);
  c.body.joint.anchor = Vec3(0.1, 0.2, 0.3);
  c.body.joint.axis = Vec3(0.2, 0.5, -1).normalized();  // downhill
  initialize(c.body, generic_state());
  run(c, 3);
  check(c, true);
}

TEST(RigidBdf2StepDerivatives, Fixed) {
  Case c;
  c.body = rigid_block(Joint::Kind::fixed);
  initialize(c.body, generic_state());
  run(c, 2);
  check(c, true);
  StepInfo info;
  RigidState hat;
  const RigidState out = bdf2_of(c, c.body, c.in, c.previous, &info, &hat);
  Bdf2StepJacobian J;
  bdf2_step_jacobian(c.body, c.in, &c.previous, hat, out, info, c.h, c.g, J);
  EXPECT_EQ(J.params.norm(), 0.0);
  EXPECT_EQ(J.previous.norm(), 0.0);
}

// A hinge pendulum released at rest swings onto the limit gravity pushes it to: the step
// whose BDF2 end reaches the limit is redone as implicit Euler (rigid_bdf2.hpp), and every
// step after one ending at the limit too (restart): both differentiated as implicit Euler
// of size h from s_n, the history's columns zero.
Case limited_hinge() {
  Case c = hinge_case();
  c.body.joint.limits = std::make_pair(-0.05, 0.05);
  RigidState s = c.body.reference;
  s.angular_velocity.setZero();
  s.velocity.setZero();
  s.position = c.body.joint.anchor + Vec3(0, 0.2, -0.05);
  initialize(c.body, s);
  return c;
}

TEST(RigidBdf2StepDerivatives, HingeReachingItsLimit) {
  Case c = limited_hinge();
  // The first BDF2 step (no restart pending) that reaches the limit.
  int k = 1;
  for (; k < 400; ++k) {
    run(c, k);
    if (c.restart) break;
  }
  ASSERT_LT(k, 400) << "the pendulum never reached its limit";
  run(c, k - 1);  // the step before: (previous, in) of the step that reaches it
  ASSERT_FALSE(c.restart);
  check(c, false);
}

TEST(RigidBdf2StepDerivatives, HingeRestingOnItsLimit) {
  Case c = limited_hinge();
  int k = 1;
  for (; k < 400 && !c.restart; ++k) run(c, k);
  run(c, k + 3);  // resting on it: each step restarts
  ASSERT_TRUE(c.restart);
  check(c, false);
}

// The branch decided again from (s_n, s_{n-1}, restart) by redoing the BDF2 step from s^:
// what the derivatives did before the step recorded its branch (rigid::bdf2_branch_taken,
// removed 2026-12-03, rbranch), kept here as the independent reference of the record.
bool branch_by_redoing(const RigidBody& body, const RigidState& in, const RigidState* previous, bool restart, double h,
                       const Vec3& gravity) {
  if (!previous || restart) return false;
  if (!body.joint.limits) return true;
  RigidState hat_state, out;
  bdf2_extrapolate(body, in, *previous, hat_state);
  const Vec3 zero = Vec3::Zero();
  return !step(body, hat_state, 2.0 * h / 3.0, gravity, zero, zero, out, true).at_limit;
}

// The step records the branch each body's BDF2 step took (rigid::StepInfo::bdf2, in
// data.rigid), which the derivatives read: it must be the branch the step took, here
// compared with branch_by_redoing above (the removed bdf2_branch_taken, verbatim). Three bodies through integrator::time_step under BDF2
// (h = 1 ms, 150 steps), in a scene of rigid bodies only and beside a soft anchor (the
// rigid step after the soft one): a bob on a 0.2 m horizontal arm hinged about y, falling
// onto its limit 0.05 rad (about 45 steps), a block on a vertical slider falling onto its
// limit 0.02 m below (about 64 steps), a free box falling (BDF2 after its first step).
// Each limited body must take all three branches: BDF2, the landing (a BDF2 end reaching
// the limit, redone as implicit Euler), and the restarts while it rests on its limit.
TEST(RigidBdf2StepDerivatives, TheStepRecordsTheBranchItTook) {
  const double h = 1e-3;
  for (const bool rigid_only : {true, false}) {
    Model model = rigid_only ? test::rigid_scenes::rigid_only_model(h) : test::rigid_scenes::anchored(h);
    model.step.integrator = IntegratorKind::bdf2;
    RigidState s;
    s.position = Vec3(0.2, 0, 0);
    test::add_rigid_body(model, "bob", test::box_shape(Vec3(0.02, 0.02, 0.02)), 1000, s, 1, Joint::Kind::hinge);
    s.position = Vec3(1, 0, 0);
    test::add_rigid_body(model, "block", test::box_shape(Vec3(0.02, 0.03, 0.01)), 500, s, 1, Joint::Kind::slider);
    s.position = Vec3(2, 0, 0);
    s.angular_velocity = Vec3(1, 2, 5);
    test::add_rigid_body(model, "box", test::box_shape(Vec3(0.02, 0.03, 0.04)), 800, s, 1, Joint::Kind::free);
    RigidBody& bob = model.rigid[0];
    bob.joint.anchor = Vec3::Zero();
    bob.joint.axis = Vec3::UnitY();  // gravity turns the arm towards +angle
    bob.joint.limits = std::make_pair(-0.05, 0.05);
    RigidBody& block = model.rigid[1];
    block.joint.anchor = Vec3(1, 0, 0);
    block.joint.axis = Vec3::UnitZ();
    block.joint.limits = std::make_pair(-0.02, 0.02);
    for (int r = 0; r < 2; ++r) {
      initialize(model.rigid[static_cast<std::size_t>(r)], model.initial.rigid[static_cast<std::size_t>(r)]);
      model.initial.rigid[static_cast<std::size_t>(r)] = model.rigid[static_cast<std::size_t>(r)].reference;
    }
    Data data(model);
    State a = model.initial, b, previous;
    int bdf2[3] = {0, 0, 0}, landing[3] = {0, 0, 0}, restarted[3] = {0, 0, 0};
    for (long n = 1; n <= 150; ++n) {
      std::vector<bool> restart(model.rigid.size(), false);
      for (std::size_t r = 0; r < data.rigid.size(); ++r) restart[r] = data.rigid[r].at_limit;
      const StepStatus st = integrator::time_step(model, data, a, n > 1 ? &previous : nullptr, b, n);
      ASSERT_TRUE(st.ok()) << describe(model, st);
      ASSERT_EQ(data.rigid.size(), model.rigid.size());
      for (std::size_t r = 0; r < model.rigid.size(); ++r) {
        const bool taken = branch_by_redoing(model.rigid[r], a.rigid[r], n > 1 ? &previous.rigid[r] : nullptr,
                                             restart[r], h, model.step.gravity);
        ASSERT_EQ(data.rigid[r].bdf2, taken) << model.rigid[r].name << ", step " << n;
        bdf2[r] += taken ? 1 : 0;
        landing[r] += n > 1 && !restart[r] && !taken ? 1 : 0;
        restarted[r] += restart[r] ? 1 : 0;
      }
      previous = a;
      std::swap(a, b);
    }
    for (int r = 0; r < 2; ++r) {
      EXPECT_GT(bdf2[r], 30) << model.rigid[static_cast<std::size_t>(r)].name;
      EXPECT_EQ(landing[r], 1) << model.rigid[static_cast<std::size_t>(r)].name;
      EXPECT_GT(restarted[r], 50) << model.rigid[static_cast<std::size_t>(r)].name;
      EXPECT_TRUE(a.rigid[static_cast<std::size_t>(r)].angular_velocity.norm() + a.rigid[static_cast<std::size_t>(r)].velocity.norm() < 1e-9);
    }
    EXPECT_EQ(bdf2[2], 149);  // the free box: BDF2 after its first step
    EXPECT_EQ(landing[2] + restarted[2], 0);
  }
}

}  // namespace rigid_bdf2_derivatives_test
