// Derivatives of the rigid step (lib/softdiff/rigid/rigid_derivatives.cpp) against
// central finite differences of rigid::step itself: the state Jacobian (12 x 12) and the
// parameter Jacobian (mass, inertia) of a free spinning body with its gyroscopic term, a
// hinge pendulum, a slider, both at a limit, a fixed body; and the dot-product test of
// the JVP against the VJP.
#include <softdiff/rigid/rigid_derivatives.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>

using namespace softdiff;
using namespace softdiff::rigid;

namespace rigid_derivatives_test {

struct Case {
  RigidBody body;
  RigidState in;
  double h = 0.01;
  Vec3 g = Vec3(0, 0, -9.81), f = Vec3::Zero(), tau = Vec3::Zero();
};

using test::rigid_scenes::generic_state;
using test::rigid_scenes::rigid_block;

RigidState step_of(const Case& c, const RigidBody& body, const RigidState& in, StepInfo* info = nullptr) {
  RigidState out;
  const StepInfo i = step(body, in, c.h, c.g, c.f, c.tau, out);
  if (info) *info = i;
  return out;
}

// Runs `warmup` steps from c.in first (a generic state on the joint, mid-motion).
void advance(Case& c, int warmup) {
  for (int k = 0; k < warmup; ++k) c.in = step_of(c, c.body, c.in);
}

// Central differences, column by column: states moved along the unit tangent e_j by
// +-eps (rigid::retract: the rotation vector in world axes), outputs compared in the
// tangent space of the unperturbed output (tangent_between). eps = 1e-6 on states of
// size ~1: the truncation error (eps^2 times the third derivative, ~1e-12) is below the
// round-off of the differences (1e-16 / 1e-6 = 1e-10) and of the rotational Newton
// (converged to 1e-14 of the momentum: 1e-14 / 1e-6 = 1e-8 relative). The tolerance
// 1e-6 per column, relative to max(|column|, 1), is 100 times that.
// Parameters: eps times the value (mass), times the inertia's trace / 3 (its components).
// want_limit: whether the step must end on a limit (every perturbed run checked too).
void check(const Case& c, bool want_limit) {
  StepInfo info;
  const RigidState out = step_of(c, c.body, c.in, &info);
  ASSERT_EQ(info.at_limit, want_limit);
  StepJacobian J;
  step_jacobian(c.body, c.in, out, info, c.h, c.g, c.f, J);
  ASSERT_TRUE(J.state.allFinite() && J.params.allFinite());
  const double eps = 1e-6, tol = 1e-6;
  for (int j = 0; j < 12; ++j) {
    StepInfo ip, im;
    const RigidState sp = step_of(c, c.body, retract(c.in, Vec12::Unit(j), eps), &ip);
    const RigidState sm = step_of(c, c.body, retract(c.in, Vec12::Unit(j), -eps), &im);
    ASSERT_EQ(ip.at_limit, want_limit);
    ASSERT_EQ(im.at_limit, want_limit);
    const Vec12 fd = (tangent_between(out, sp) - tangent_between(out, sm)) / (2 * eps);
    EXPECT_LE((J.state.col(j) - fd).norm(), tol * std::max(fd.norm(), 1.0))
        << "state column " << j << "\nanalytic " << J.state.col(j).transpose() << "\nfd       " << fd.transpose();
  }
  const double trace = c.body.inertia.trace() / 3;
  for (int k = 0; k < kRigidParameters; ++k) {
    const double value = get_parameter(c.body, k);
    const double e = eps * (k == 0 ? value : trace);
    RigidBody bp = c.body, bm = c.body;
    set_parameter(bp, k, value + e);
    set_parameter(bm, k, value - e);
    const Vec12 fd = (tangent_between(out, step_of(c, bp, c.in)) - tangent_between(out, step_of(c, bm, c.in))) / (2 * e);
    // Per unit of the parameter: scaled to the parameter's size for the comparison.
    const double scale = k == 0 ? value : trace;
    EXPECT_LE(scale * (J.params.col(k) - fd).norm(), tol * std::max(scale * fd.norm(), 1.0))
        << rigid_parameter_name(k) << "\nanalytic " << J.params.col(k).transpose() << "\nfd       " << fd.transpose();
  }
}

TEST(RigidStepDerivatives, FreeSpinningBodyWithGyroscopicTerm) {
  Case c;
  c.body = rigid_block(Joint::Kind::free);
  c.in = generic_state();
  initialize(c.body, c.in);
  c.f = Vec3(0.5, -0.2, 1.0);    // an external force: the mass column is not zero
  c.tau = Vec3(0.01, 0.02, -0.03);
  c.h = 0.02;                    // h |omega| = 0.2: the exponential map and E A far from I
  check(c, false);
  // The gyroscopic coupling is in the Jacobian: d omega'/d omega is not the identity.
  StepInfo info;
  const RigidState out = step_of(c, c.body, c.in, &info);
  StepJacobian J;
  step_jacobian(c.body, c.in, out, info, c.h, c.g, c.f, J);
  EXPECT_GT((J.state.block<3, 3>(9, 9) - Mat3::Identity()).norm(), 1e-2);
}

TEST(RigidStepDerivatives, FreeBodySlowSpin) {
  // |h omega| < 1e-3: the Taylor branches of the exponential map and right Jacobian.
  Case c;
  c.body = rigid_block(Joint::Kind::free);
  c.in = generic_state();
  c.in.angular_velocity = Vec3(0.01, -0.02, 0.03);
  initialize(c.body, c.in);
  c.tau = Vec3(1e-3, 0, 2e-3);
  check(c, false);
}

Case hinge_case() {
  Case c;
  c.body = rigid_block(Joint::Kind::hinge);
  c.body.joint.anchor = Vec3(0.1, 0.2, 0.5);
  c.body.joint.axis = Vec3(1, 0.3, 0.2).normalized();
  c.in = generic_state();
  initialize(c.body, c.in);  // projects the velocity onto the hinge
  c.in = c.body.reference;
  return c;
}

TEST(RigidStepDerivatives, HingePendulum) {
  Case c = hinge_case();
  advance(c, 7);  // mid-swing, away from t = 0
  check(c, false);
}

TEST(RigidStepDerivatives, HingeAtLimit) {
  Case c = hinge_case();
  c.body.joint.limits = std::make_pair(-0.05, 0.05);
  c.in.angular_velocity *= 0;  // released at rest, the lever arm mostly horizontal
  c.in.velocity *= 0;
  c.in.position = c.body.joint.anchor + Vec3(0, 0.2, -0.05);
  initialize(c.body, c.in);
  c.in = c.body.reference;
  // Swing onto the limit gravity pushes it to, then rest there.
  int k = 0;
  for (StepInfo info; k < 400; ++k) {
    c.in = step_of(c, c.body, c.in, &info);
    if (info.at_limit) break;
  }
  ASSERT_LT(k, 400) << "the pendulum never reached its limit";
  advance(c, 3);
  check(c, true);
}

Case slider_case() {
  Case c;
  c.body = rigid_block(Joint::Kind::slider);
  c.body.joint.anchor = Vec3(0.1, 0.2, 0.3);
  c.body.joint.axis = Vec3(0.2, 0.5, -1).normalized();  // downhill
  c.in = generic_state();
  initialize(c.body, c.in);
  c.in = c.body.reference;
  c.f = Vec3(0.3, 0, 0.1);
  return c;
}

TEST(RigidStepDerivatives, Slider) {
  Case c = slider_case();
  advance(c, 3);
  check(c, false);
}

TEST(RigidStepDerivatives, SliderAtLimit) {
  Case c = slider_case();
  c.body.joint.limits = std::make_pair(-0.01, 0.01);
  advance(c, 20);  // slides down onto 0.01 and rests
  check(c, true);
}

TEST(RigidStepDerivatives, Fixed) {
  Case c;
  c.body = rigid_block(Joint::Kind::fixed);
  c.in = generic_state();
  initialize(c.body, c.in);
  c.in = c.body.reference;
  check(c, false);
  StepInfo info;
  const RigidState out = step_of(c, c.body, c.in, &info);
  StepJacobian J;
  step_jacobian(c.body, c.in, out, info, c.h, c.g, c.f, J);
  EXPECT_EQ(J.params.norm(), 0.0);
  EXPECT_EQ(J.state.bottomRows<6>().norm(), 0.0);
}

// <bar, J d> = <J^T bar, d> for the JVP and VJP (the state and parameter parts), on
// random directions: both are products with the same blocks, so to round-off (1e-14).
TEST(RigidStepDerivatives, JvpVjpDotProduct) {
  std::mt19937 rng(21);
  std::normal_distribution<double> nd;
  auto rnd = [&](auto v) {
    for (Eigen::Index i = 0; i < v.size(); ++i) v[i] = nd(rng);
    return v;
  };
  // <bar, J d> = <J^T bar, d> for random directions, to round-off.
  auto expect_dot_product = [&](const Case& c, const std::string& what) {
    StepInfo info;
    const RigidState out = step_of(c, c.body, c.in, &info);
    StepJacobian J;
    step_jacobian(c.body, c.in, out, info, c.h, c.g, c.f, J);
    const Vec12 d = rnd(Vec12()), bar = rnd(Vec12());
    const Vec7 dp = rnd(Vec7());
    Vec12 bar_in;
    Vec7 bar_p;
    step_vjp(J, bar, bar_in, bar_p);
    const double lhs = bar.dot(step_jvp(J, d, dp)), rhs = bar_in.dot(d) + bar_p.dot(dp);
    EXPECT_NEAR(lhs, rhs, 1e-13 * (std::abs(lhs) + 1)) << what;
  };
  for (Case c : {hinge_case(), slider_case()}) {
    advance(c, 5);
    expect_dot_product(c, "joint");
  }
  Case c;
  c.body = rigid_block(Joint::Kind::free);
  c.in = generic_state();
  initialize(c.body, c.in);
  expect_dot_product(c, "free");
}

TEST(RigidStepDerivatives, ParameterErrors) {
  RigidBody b = rigid_block(Joint::Kind::free);
  EXPECT_THROW(set_parameter(b, 0, -1.0), std::invalid_argument);
  EXPECT_THROW(set_parameter(b, 4, 1.0), std::invalid_argument);  // xy = 1: not positive definite
  EXPECT_NO_THROW(set_parameter(b, 1, 0.03));
  EXPECT_EQ(get_parameter(b, 1), 0.03);
  EXPECT_EQ(rigid_parameter_name(6), "inertia.yz");
}

}  // namespace rigid_derivatives_test
