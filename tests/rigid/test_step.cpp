// The rigid step (lib/softdiff/rigid/rigid_body.cpp): initialize()'s checks and
// projection, the joint coordinate, the rotational Newton's Jacobian against central
// differences, the step matrix against the step, and exact joint limits.
#include <softdiff/core/error.hpp>
#include <softdiff/rigid/joint_equation.hpp>
#include <softdiff/rigid/rigid_body.hpp>
#include <softdiff/rigid/rotation.hpp>
#include <support/fd.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <stdexcept>

using namespace softdiff;
using namespace softdiff::rigid;

namespace rigid_step_test {

constexpr double pi = std::numbers::pi;

// A 0.2 x 0.1 x 0.05 m box of density 1000 (1 kg), surface tessellated.
RigidBody box_body(Joint::Kind kind = Joint::Kind::free) {
  RigidBody b;
  b.name = "block";
  b.shape.kind = Shape::Kind::box;
  b.shape.half_extents = Vec3(0.1, 0.05, 0.025);
  const MassProperties p = mass_properties(b.shape, 1000);
  b.mass = p.mass;
  b.inertia = p.inertia;
  b.surface = tessellate(b.shape, p.centre, 0.01);
  b.joint.kind = kind;
  return b;
}

RigidState tilted_state() {
  RigidState s;
  s.position = Vec3(0.1, 0.2, 0.3);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Vec3(1, 2, 3).normalized()));
  s.velocity = Vec3(0.3, -0.2, 0.1);
  s.angular_velocity = Vec3(1, -2, 0.5);
  return s;
}

void expect_invalid(RigidBody b, const RigidState& s, const std::string& fragment) {
  try {
    initialize(b, s);
    ADD_FAILURE() << "no exception; expected one containing \"" << fragment << "\"";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'block'"), std::string::npos) << e.what();
  }
}

TEST(RigidInitialize, Errors) {
  const RigidState s = tilted_state();
  RigidBody b = box_body();
  b.mass = 0;
  expect_invalid(b, s, "mass must be positive");
  b = box_body();
  b.inertia(2, 2) = -1;
  expect_invalid(b, s, "positive definite");
  b = box_body();
  b.inertia(0, 1) = 1;
  expect_invalid(b, s, "symmetric");
  b = box_body();
  RigidState bad = s;
  bad.orientation.coeffs() *= 1.001;
  expect_invalid(b, bad, "unit");
  bad = s;
  bad.velocity.x() = std::nan("");
  expect_invalid(b, bad, "not finite");
  b.joint.limits = std::make_pair(-1.0, 1.0);
  expect_invalid(b, s, "free joint takes no limits");
  b = box_body(Joint::Kind::hinge);
  b.joint.axis = Vec3(0, 0, 1.01);
  expect_invalid(b, s, "axis must be a unit vector");
  b = box_body(Joint::Kind::hinge);
  b.joint.limits = std::make_pair(0.1, 0.5);
  expect_invalid(b, s, "outside the joint limits");
  b.joint.limits = std::make_pair(0.5, -0.5);
  expect_invalid(b, s, "lower <= upper");
  b.joint.limits = std::make_pair(-4.0, 4.0);
  expect_invalid(b, s, "span less than 2 pi");
  b = box_body(Joint::Kind::slider);
  b.joint.limits = std::make_pair(-0.3, -0.1);
  expect_invalid(b, s, "outside the joint limits");
  b = box_body(Joint::Kind::fixed);
  b.joint.limits = std::make_pair(-0.3, 0.1);
  expect_invalid(b, s, "fixed joint takes no limits");
}

TEST(RigidInitialize, ProjectsTheVelocityOntoTheJoint) {
  const RigidState s = tilted_state();
  {
    RigidBody b = box_body(Joint::Kind::hinge);
    b.joint.anchor = Vec3(0.2, 0.1, 0.3);
    b.joint.axis = Vec3(0, 1, 1).normalized();
    initialize(b, s);
    const Vec3 n = b.joint.axis, t = n.cross(s.position - b.joint.anchor);
    const double rate = n.dot(b.reference.angular_velocity);
    EXPECT_LT((b.reference.angular_velocity - rate * n).norm(), 1e-15);
    EXPECT_LT((b.reference.velocity - rate * t).norm(), 1e-15);
    // The kinetic-energy projection keeps the momentum along the allowed motion.
    const Mat3 R = s.orientation.toRotationMatrix(), Iw = R * b.inertia * R.transpose();
    EXPECT_NEAR(b.mass * t.dot(b.reference.velocity) + n.dot(Iw * b.reference.angular_velocity),
                b.mass * t.dot(s.velocity) + n.dot(Iw * s.angular_velocity), 1e-15);
    // The joint's data in body axes.
    EXPECT_LT((s.position + R * b.anchor_body - b.joint.anchor).norm(), 1e-15);
    EXPECT_LT((R * b.axis_body - n).norm(), 1e-15);
  }
  {
    RigidBody b = box_body(Joint::Kind::slider);
    b.joint.axis = Vec3(1, 0, 0);
    initialize(b, s);
    EXPECT_EQ(b.reference.velocity, Vec3(0.3, 0, 0));
    EXPECT_EQ(b.reference.angular_velocity, Vec3::Zero());
  }
  {
    RigidBody b = box_body(Joint::Kind::fixed);
    initialize(b, s);
    EXPECT_EQ(b.reference.velocity, Vec3::Zero());
    EXPECT_EQ(b.reference.angular_velocity, Vec3::Zero());
  }
  {
    RigidBody b = box_body();
    initialize(b, s);
    EXPECT_EQ(b.reference.velocity, s.velocity);
    EXPECT_EQ(b.reference.angular_velocity, s.angular_velocity);
  }
}

TEST(RigidJoint, Coordinate) {
  const RigidState s = tilted_state();
  RigidBody b = box_body(Joint::Kind::hinge);
  b.joint.anchor = Vec3(0, 0, 0.5);
  b.joint.axis = Vec3(1, 1, 0).normalized();
  b.joint.limits = std::make_pair(-0.5, 4.0);
  initialize(b, s);
  EXPECT_EQ(joint_coordinate(b, b.reference), 0);
  for (double angle : {-0.5, 0.3, 3.5, 4.0}) {
    RigidState r = b.reference;
    const Eigen::AngleAxisd rot(angle, b.joint.axis);
    r.orientation = rot * r.orientation;
    r.position = b.joint.anchor + rot * (r.position - b.joint.anchor);
    // In the window of the limits (centre 1.75, +-pi): 3.5 and 4.0 are not wrapped.
    EXPECT_NEAR(joint_coordinate(b, r), angle, 1e-14) << angle;
  }
  b.joint.limits.reset();
  RigidState r = b.reference;
  r.orientation = Eigen::AngleAxisd(3.5, b.joint.axis) * r.orientation;
  EXPECT_NEAR(joint_coordinate(b, r), 3.5 - 2 * pi, 1e-14);  // (-pi, pi] without limits

  RigidBody sl = box_body(Joint::Kind::slider);
  sl.joint.axis = Vec3(0, 0.6, 0.8);
  initialize(sl, s);
  r = sl.reference;
  r.position += 0.25 * sl.joint.axis;
  EXPECT_NEAR(joint_coordinate(sl, r), 0.25, 1e-15);
}

// The rotational Newton's Jacobian dr/domega = E A - h E [A omega] J_r(h omega) against
// central differences. Step 1e-6 |omega| (fd.hpp): r is smooth with derivatives of order
// |A| (1 + h |omega|)^k, so truncation (h_fd^2 r''') and round-off (eps |r| / h_fd) are both
// near 1e-10 relative; 1e-7 leaves three orders of margin and would catch any wrong term
// (the gyroscopic term alone is h |A omega| / |A| ~ 1e-2 .. 1 of the Jacobian here).
// Three rotation sizes: h |omega| = 5e-4 (the Taylor branch of J_r), 0.09 and 1.3.
TEST(RigidStep, RotationalJacobianMatchesCentralDifferences) {
  const RigidBody b = box_body();
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(1, -1, 2).normalized()).toRotationMatrix();
  const Mat3 A = R * b.inertia * R.transpose();
  const Vec3 L(0.01, -0.02, 0.005);
  const double h = 0.01;
  for (double size : {0.05, 9.0, 130.0}) {
    const Vec3 omega = size * Vec3(0.3, -0.5, 0.8).normalized();
    const double step = 1e-6 * omega.norm();
    const test::MatX fd = test::fd_jacobian(
        [&](const test::VecX& w) { return test::VecX(angular_residual(A, L, h, Vec3(w))); }, omega, step);
    const test::MatX analytic = angular_residual_jacobian(A, h, omega);
    const test::Comparison c = test::compare(analytic, fd);
    EXPECT_LT(c.rel_error, 1e-7) << "h |omega| = " << h * omega.norm() << ": " << c.str();
    // The gyroscopic part is not negligible in the larger cases (the test sees it).
    if (size > 1) {
      EXPECT_GT((analytic - quaternion_exp(h * omega).toRotationMatrix() * A).norm(), 1e-3 * analytic.norm());
    }
  }
  // The residual is zero at the step's solution, and the momentum is I_w(q_{n+1}) omega_{n+1}.
  RigidBody free = box_body();
  initialize(free, tilted_state());
  RigidState out;
  step(free, free.reference, 0.01, Vec3::Zero(), Vec3::Zero(), Vec3::Zero(), out);
  const Mat3 Rn = free.reference.orientation.toRotationMatrix(), Rp = out.orientation.toRotationMatrix();
  const Vec3 Ln = Rn * free.inertia * Rn.transpose() * free.reference.angular_velocity;
  EXPECT_LT((Rp * free.inertia * Rp.transpose() * out.angular_velocity - Ln).norm(), 1e-14 * Ln.norm());
}

// The step matrix against the step: a change dp = (h df, h dtau) of the applied impulse
// changes the end velocities by A^{-1} dp (A = step_matrix). Central differences on the
// force and torque with step 1e-6 of their scale (0.1 N, 0.01 N m): the step is smooth in
// them (one Newton solve), so the fd error is ~1e-10 relative; tolerance 1e-7.
TEST(RigidStep, StepMatrixMatchesTheStep) {
  RigidBody b = box_body();
  initialize(b, tilted_state());
  const double h = 0.01;
  const Vec3 g(0, 0, -9.81), f0(0.1, 0.2, -0.1), tau0(0.01, -0.02, 0.03);
  const auto end_velocities = [&](const test::VecX& load) {
    RigidState out;
    step(b, b.reference, h, g, load.head<3>(), load.tail<3>(), out);
    test::VecX v(6);
    v << out.velocity, out.angular_velocity;
    return v;
  };
  test::VecX load(6);
  load << f0, tau0;
  const test::MatX fd = test::fd_jacobian(end_velocities, load, 1e-6 * 0.05);
  RigidState out;
  step(b, b.reference, h, g, f0, tau0, out);
  const test::MatX analytic = h * step_matrix(b, b.reference, out, h).inverse();
  const test::Comparison c = test::compare(analytic, fd);
  EXPECT_LT(c.rel_error, 1e-7) << c.str();
}

TEST(RigidStep, JointVelocitiesLieInTheMotionBasis) {
  for (Joint::Kind kind : {Joint::Kind::hinge, Joint::Kind::slider, Joint::Kind::fixed}) {
    RigidBody b = box_body(kind);
    b.joint.anchor = Vec3(0, 0, 0.5);
    b.joint.axis = Vec3(0.6, 0, 0.8);
    initialize(b, tilted_state());
    RigidState out;
    step(b, b.reference, 0.01, Vec3(0, 0, -9.81), Vec3(1, 2, 3), Vec3(0.1, 0.2, 0.3), out);
    const Eigen::Matrix<double, 6, Eigen::Dynamic> T = joint_motion_basis(b, out);
    Eigen::Matrix<double, 6, 1> v;
    v << out.velocity, out.angular_velocity;
    EXPECT_EQ(T.cols(), kind == Joint::Kind::fixed ? 0 : 1);
    if (T.cols() == 1) {
      const double rate = T.col(0).dot(v) / T.col(0).squaredNorm();
      EXPECT_LT((v - rate * T.col(0)).norm(), 1e-14 * (1 + v.norm()));
    } else {
      EXPECT_EQ(v.norm(), 0);
    }
  }
  EXPECT_EQ(joint_motion_basis(box_body(), tilted_state()), Mat6::Identity());
}

TEST(RigidStep, WorldVertices) {
  RigidBody b = box_body();
  const RigidState s = tilted_state();
  const Mat3X w = world_vertices(b, s);
  const Mat3 R = s.orientation.toRotationMatrix();
  for (Eigen::Index k = 0; k < w.cols(); ++k)
    EXPECT_LT((w.col(k) - (R * b.surface.vertices.col(k) + s.position)).norm(), 1e-15);
}

TEST(RigidStep, BadCallsThrow) {
  RigidBody b = box_body();
  initialize(b, tilted_state());
  RigidState out;
  EXPECT_THROW(step(b, b.reference, 0, Vec3::Zero(), Vec3::Zero(), Vec3::Zero(), out), std::invalid_argument);
  RigidState same = b.reference;
  EXPECT_THROW(step(b, same, 0.01, Vec3::Zero(), Vec3::Zero(), Vec3::Zero(), same), std::invalid_argument);
  EXPECT_THROW(step(b, b.reference, 0.01, Vec3(0, 0, std::nan("")), Vec3::Zero(), Vec3::Zero(), out),
               ComputationError);
}

// A 0.2 m bar on a hinge at its end (axis y), limits [-0.3, 0.3] rad: gravity swings it
// onto the upper limit, where it stops exactly (no penetration, no bounce, no spring),
// rests with the reaction balancing its weight, and leaves the limit under a torque
// that pulls it back. Every step's free_rate is the rate of the same step without limits.
TEST(RigidStep, HingeLimitStopsExactly) {
  RigidBody b = box_body(Joint::Kind::hinge);
  RigidState s;
  s.position = Vec3(0.1, 0, 0);
  b.joint.anchor = Vec3::Zero();
  b.joint.axis = Vec3::UnitY();
  b.joint.limits = std::make_pair(-0.3, 0.3);
  initialize(b, s);
  const Vec3 g(0, 0, -9.81);
  const double h = 1e-3;
  RigidState a = b.reference, next;
  int arrival = -1;
  StepInfo info;
  for (int k = 1; k <= 1000; ++k) {
    info = step(b, a, h, g, Vec3::Zero(), Vec3::Zero(), next);
    std::swap(a, next);
    const double c = joint_coordinate(b, a);
    ASSERT_LE(c, 0.3 + 1e-14) << "step " << k;
    if (info.at_limit && arrival < 0) arrival = k;
    // free_rate (the contact stage's free rate of a limited joint): the rate of the same
    // step without its limits, exactly (the same root before the clamp).
    {
      RigidState unclamped;  // from the step's start (in `next` after the swap)
      const StepInfo free_info = step(b, next, h, g, Vec3::Zero(), Vec3::Zero(), unclamped, false);
      EXPECT_EQ(info.free_rate, b.joint.axis.dot(unclamped.angular_velocity)) << "step " << k;
      EXPECT_EQ(free_info.free_rate, info.free_rate) << "step " << k;
      EXPECT_FALSE(free_info.at_limit);
    }
    if (arrival > 0) {
      EXPECT_TRUE(info.at_limit) << "step " << k;
      EXPECT_NEAR(c, 0.3, 1e-14) << "step " << k;
    }
    // The joint holds exactly: anchor and axis where they were.
    const Mat3 R = a.orientation.toRotationMatrix();
    ASSERT_LT((a.position + R * b.anchor_body - b.joint.anchor).norm(), 1e-14) << "step " << k;
    ASSERT_LT((R * b.axis_body - b.joint.axis).norm(), 1e-14) << "step " << k;
  }
  ASSERT_GT(arrival, 0);
  // Free swing to the limit: about sqrt(2 * 0.3 / alpha) with alpha = m g d / I_a.
  const double I_a = b.inertia(1, 1) + b.mass * 0.01, alpha = b.mass * 9.81 * 0.1 / I_a;
  EXPECT_NEAR(arrival * h, std::sqrt(2 * 0.3 / alpha), 0.02);
  // At rest on the limit: no velocity; the reaction's resultant balances the weight and
  // its moment about the centre of mass is zero.
  EXPECT_LT(a.angular_velocity.norm(), 1e-10);
  EXPECT_LT(a.velocity.norm(), 1e-11);
  EXPECT_LT((info.constraint_force + b.mass * g).norm(), 1e-7 * b.mass * 9.81);
  EXPECT_LT(info.constraint_torque.norm(), 1e-7 * b.mass * 9.81 * 0.1);
  // Pulled back by a torque twice the weight's moment: it leaves the limit.
  const Vec3 pull(0, -2 * b.mass * 9.81 * 0.1, 0);
  info = step(b, a, h, g, Vec3::Zero(), pull, next);
  EXPECT_FALSE(info.at_limit);
  EXPECT_LT(joint_coordinate(b, next), 0.3 - 1e-8);
}

// A hinge spinning fast (200 rad/s, 32 turns) with its centre of mass 1e-15 m off the axis
// under gravity: the joint equation's bracket (h^2 Q_max / I_a ~ 1e-18 rad) is below the
// round-off of h cdot (the pad of solve_joint; without it the step threw), the angle
// passes +-pi many times, and the joint still holds.
TEST(RigidStep, FastHingeManyTurns) {
  RigidBody b = box_body(Joint::Kind::hinge);
  RigidState s;
  s.position = Vec3(1e-15, 0, 0);
  s.angular_velocity = Vec3(0, 0, 200);
  b.joint.axis = Vec3::UnitZ();
  b.joint.anchor = Vec3::Zero();
  initialize(b, s);
  RigidState a = b.reference, next;
  for (int k = 1; k <= 1000; ++k) {
    step(b, a, 1e-3, Vec3(0, -9.81, 0), Vec3::Zero(), Vec3::Zero(), next);
    std::swap(a, next);
    const Mat3 R = a.orientation.toRotationMatrix();
    ASSERT_LT((a.position + R * b.anchor_body - b.joint.anchor).norm(), 1e-15) << "step " << k;
    ASSERT_LT((R * b.axis_body - b.joint.axis).norm(), 1e-12) << "step " << k;
    ASSERT_NEAR(a.angular_velocity.z(), 200, 1e-9) << "step " << k;
  }
}

// The hinge equation's derivative dg/ddelta (its safeguarded Newton) against central
// differences with step 1e-6 (delta is an angle of order 0.1-1 rad): g is smooth with
// derivatives of order I_a / h and h |c|, so the fd error is ~1e-10 relative; 1e-7.
TEST(RigidStep, JointEquationDerivativeMatchesCentralDifferences) {
  JointEquation e;
  e.I_a = 0.02;
  e.cdot = 3;
  e.Q0 = 0.1;
  e.c1 = 4;
  e.c2 = -7;
  e.h = 0.05;  // large, so that the load term is a sizeable part of dg
  for (double d : {-0.8, 0.0, 0.15, 1.3}) {
    const double fd = (e.g(d + 1e-6) - e.g(d - 1e-6)) / 2e-6;
    EXPECT_NEAR(e.dg(d), fd, 1e-7 * std::abs(fd)) << "delta " << d;
    EXPECT_GT(std::abs(e.dg(d) - e.I_a / e.h), 1e-3 * std::abs(fd)) << "delta " << d;
  }
}

}  // namespace rigid_step_test
