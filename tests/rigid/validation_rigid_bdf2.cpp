// BDF2 for rigid bodies (rigid/rigid_bdf2.hpp; docs/method.md "BDF2 with rigid bodies")
// against closed forms and an independent reference (run build/tests/validation_rigid;
// docs/method.md quotes the figures printed here):
//  - free fall: the velocity exact (v_n = v_0 + n h g), the position the scheme's closed
//    form: with the implicit Euler first step (error h^2 g / 2) the BDF2 recurrence
//    e_{n+1} = 4/3 e_n - 1/3 e_{n-1} (BDF2 is exact on quadratics) gives
//    x_n = x_0 + v_0 t + g t^2 / 2 + 3/4 h^2 g (1 - 3^-n), a second-order offset;
//  - a pendulum on a hinge at 0.5 rad: the angle at t = 1 s against an RK4 reference at
//    h = 1e-5 (error ~1e-19), the error ratio ~4 when halving h (second order);
//  - a spinning box in free flight: linear and angular momentum to round-off, the energy
//    change reported;
//  - a slider on an incline reaching its limit: BDF2's closed form until the limit, then
//    exactly at the limit (the restart), at rest, the reaction the weight.
#include <softdiff/rigid/rigid_bdf2.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <numbers>

using namespace softdiff;
using namespace softdiff::rigid;

namespace rigid_bdf2_validation {

constexpr double pi = std::numbers::pi;

RigidBody box_body(const Vec3& half_extents, Joint::Kind kind = Joint::Kind::free) {
  RigidBody b;
  b.name = "box";
  b.shape.kind = Shape::Kind::box;
  b.shape.half_extents = half_extents;
  const MassProperties p = mass_properties(b.shape, 1000);
  b.mass = p.mass;
  b.inertia = p.inertia;
  b.surface = tessellate(b.shape, p.centre, 1);
  b.joint.kind = kind;
  return b;
}

// Steps a trajectory by BDF2 (the first step implicit Euler), restarting after a limit
// as the integrator does (integrator/rigid_bodies.cpp).
struct Stepper {
  Stepper(const RigidBody& b, const RigidState& start) : body(b), previous(start), current(start) {}
  const RigidBody& body;
  RigidState previous, current, hat, next;
  bool first = true;
  StepInfo info;
  StepInfo operator()(double h, const Vec3& g, const Vec3& force = Vec3::Zero(), const Vec3& torque = Vec3::Zero()) {
    info = bdf2_step(body, current, first ? nullptr : &previous, h, g, force, torque, hat, next, true, info.at_limit);
    previous = current;
    current = next;
    first = false;
    return info;
  }
};

TEST(RigidBdf2Validation, FreeFallIsTheSchemesClosedForm) {
  RigidBody b = box_body(Vec3(0.05, 0.05, 0.05));
  RigidState s;
  s.position = Vec3(0, 0, 1);
  s.velocity = Vec3(0.5, -0.2, 2);
  initialize(b, s);
  const Vec3 g(0, 0, -9.81);
  const double h = 1e-3;
  Stepper st(b, b.reference);
  double worst = 0;
  for (int n = 1; n <= 1000; ++n) {
    st(h, g);
    const double t = n * h;
    const Vec3 x = s.position + t * s.velocity + 0.5 * t * t * g + 0.75 * h * h * (1 - std::pow(3.0, -n)) * g;
    const Vec3 v = s.velocity + t * g;
    worst = std::max(worst, (st.current.position - x).norm());
    // Round-off: each step adds ~eps |x| (|x| < 3 m) and the recurrence's modes 1 and
    // 1/3 keep it (no growth): after 1000 steps ~ 1000 x 2.2e-16 x 3 = 7e-13.
    ASSERT_LT((st.current.position - x).norm(), 1e-12) << "step " << n;
    ASSERT_LT((st.current.velocity - v).norm(), 1e-12) << "step " << n;
  }
  std::cout << "[rigid bdf2] free fall, 1000 steps of 1 ms: largest distance to the closed form " << worst << " m\n";
  EXPECT_EQ(st.current.angular_velocity, Vec3::Zero());
  EXPECT_EQ(st.current.orientation.coeffs(), Eigen::Quaterniond::Identity().coeffs());
}

// theta'' = -k sin theta by RK4 (an independent reference).
double pendulum_reference(double k, double theta0, double T) {
  const double h = 1e-5;
  const long steps = std::lround(T / h);
  double th = theta0, w = 0;
  for (long i = 0; i < steps; ++i) {
    const double k1t = w, k1w = -k * std::sin(th);
    const double k2t = w + 0.5 * h * k1w, k2w = -k * std::sin(th + 0.5 * h * k1t);
    const double k3t = w + 0.5 * h * k2w, k3w = -k * std::sin(th + 0.5 * h * k2t);
    const double k4t = w + h * k3w, k4w = -k * std::sin(th + h * k3t);
    th += h / 6 * (k1t + 2 * k2t + 2 * k3t + k4t);
    w += h / 6 * (k1w + 2 * k2w + 2 * k3w + k4w);
  }
  return th;
}

TEST(RigidBdf2Validation, PendulumOnAHingeIsSecondOrder) {
  const double l = 0.5, theta0 = 0.5, g = 9.81, T = 1.0;
  double k = 0, errors[3] = {0, 0, 0};
  const double hs[3] = {4e-3, 2e-3, 1e-3};
  for (int i = 0; i < 3; ++i) {
    RigidBody b = box_body(Vec3(0.02, 0.03, 0.04), Joint::Kind::hinge);
    RigidState s;
    // The angle theta from the downward vertical, positive towards +x: the bob at
    // (l sin theta, 0, -l cos theta); the hinge about y at the origin.
    s.position = Vec3(l * std::sin(theta0), 0, -l * std::cos(theta0));
    b.joint.anchor = Vec3::Zero();
    b.joint.axis = Vec3::UnitY();
    initialize(b, s);
    k = b.mass * g * l / (b.inertia(1, 1) + b.mass * l * l);
    Stepper st(b, b.reference);
    const long steps = std::lround(T / hs[i]);
    for (long n = 0; n < steps; ++n) st(hs[i], Vec3(0, 0, -g));
    const double theta = std::atan2(st.current.position.x(), -st.current.position.z());
    ASSERT_NEAR((st.current.position - b.joint.anchor).norm(), l, 1e-12);  // on its joint
    errors[i] = theta;
  }
  const double ref = pendulum_reference(k, theta0, T);
  for (double& e : errors) e = std::abs(e - ref);
  std::cout << "[rigid bdf2] pendulum 0.5 rad, angle at 1 s vs RK4 (" << ref << " rad): errors " << errors[0] << ", "
            << errors[1] << ", " << errors[2] << " rad at h 4e-3, 2e-3, 1e-3; ratios " << errors[0] / errors[1] << ", "
            << errors[1] / errors[2] << "\n";
  // Second order: ratio 4 up to the next term of the error's expansion, O(h) relative
  // (at omega h <= 0.018 a few percent); implicit Euler would give 2.
  EXPECT_NEAR(errors[0] / errors[1], 4, 0.4);
  EXPECT_NEAR(errors[1] / errors[2], 4, 0.4);
}

struct SpinRun {
  double momentum_drift, angular_momentum_drift, energy_change;
};

// The box of validation_rigid's spin test (three distinct moments, nutating), 1 s.
SpinRun spin(double h) {
  RigidBody b = box_body(Vec3(0.05, 0.1, 0.2));
  RigidState s;
  s.position = Vec3(0.1, 0.2, 0.3);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Vec3(1, 1, 0).normalized()));
  s.velocity = Vec3(0.4, -0.3, 0.2);
  s.angular_velocity = s.orientation * Vec3(1, 2, 10);
  initialize(b, s);
  const auto momenta = [&](const RigidState& x, Vec3& p, Vec3& L, double& E) {
    const Mat3 R = x.orientation.toRotationMatrix(), Iw = R * b.inertia * R.transpose();
    p = b.mass * x.velocity;
    L = Iw * x.angular_velocity + x.position.cross(p);  // about the world origin
    E = 0.5 * b.mass * x.velocity.squaredNorm() + 0.5 * x.angular_velocity.dot(Iw * x.angular_velocity);
  };
  Vec3 p0, L0, p, L;
  double E0, E;
  momenta(b.reference, p0, L0, E0);
  Stepper st(b, b.reference);
  SpinRun r{0, 0, 0};
  const int steps = static_cast<int>(std::lround(1 / h));
  for (int n = 1; n <= steps; ++n) {
    st(h, Vec3::Zero());
    momenta(st.current, p, L, E);
    r.momentum_drift = std::max(r.momentum_drift, (p - p0).norm() / p0.norm());
    r.angular_momentum_drift = std::max(r.angular_momentum_drift, (L - L0).norm() / L0.norm());
  }
  const double E_rot0 = E0 - 0.5 * b.mass * b.reference.velocity.squaredNorm();
  r.energy_change = (E - E0) / E_rot0;
  return r;
}

TEST(RigidBdf2Validation, SpinningBodyInFreeFlight) {
  const SpinRun a = spin(1e-3), b = spin(5e-4);
  std::cout << "[rigid bdf2] spinning box, 1 s: h 1e-3: momentum drift " << a.momentum_drift
            << ", angular momentum drift " << a.angular_momentum_drift << ", rotational energy change "
            << a.energy_change << "\n"
            << "[rigid bdf2] spinning box, 1 s: h 5e-4: momentum drift " << b.momentum_drift
            << ", angular momentum drift " << b.angular_momentum_drift << ", rotational energy change "
            << b.energy_change << "\n";
  // Linear momentum: 4/3 v - 1/3 v of equal velocities is v to round-off (1 ulp per step,
  // not exactly as implicit Euler's + 0).
  EXPECT_LT(a.momentum_drift, 1e-13);
  EXPECT_LT(b.momentum_drift, 1e-13);
  // Angular momentum about the origin: L^ = 4/3 L_n - 1/3 L_{n-1} is the step's own
  // equation, solved to 1e-14 relative; the orbital part p x x follows the exact p.
  EXPECT_LT(a.angular_momentum_drift, 1e-11);
  EXPECT_LT(b.angular_momentum_drift, 1e-11);
  // Energy: dissipated at second order (ratio 4 when halving h, up to the O(h) next
  // term: 10%), 1e-5 of the rotational energy at h = 1e-3 where implicit Euler loses
  // ~1e-2 at first order (validation_rigid).
  EXPECT_LT(a.energy_change, 0);
  EXPECT_NEAR(a.energy_change / b.energy_change, 4, 0.4);
}

// validation_rigid's slider on a 30 degree incline, limits [-0.01, 0.1] m, by BDF2:
// from rest under the constant a = g sin 30, the first (Euler) step is s_1 = h^2 a and
// then BDF2 is exact on the quadratic offset as in free fall:
// s_n = a t^2 / 2 + 3/4 h^2 a (1 - 3^-n). At the limit: exactly there, at rest, the
// reaction the weight.
TEST(RigidBdf2Validation, SliderOnAnInclineStopsAtItsLimit) {
  RigidBody b = box_body(Vec3(0.05, 0.05, 0.05), Joint::Kind::slider);
  b.mass = 1;
  const Vec3 axis(std::cos(pi / 6), 0, -std::sin(pi / 6));
  b.joint.axis = axis;
  b.joint.limits = std::make_pair(-0.01, 0.1);
  RigidState s;
  s.position = Vec3(0.2, 0.3, 0.4);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Vec3::UnitZ()));
  initialize(b, s);
  const Vec3 g(0, 0, -9.81);
  const double h = 1e-3, a_exact = 9.81 * 0.5;
  Stepper st(b, b.reference);
  int arrival = -1;
  for (int n = 1; n <= 500; ++n) {
    const StepInfo info = st(h, g);
    const double c = joint_coordinate(b, st.current), t = n * h;
    const double free_travel = 0.5 * a_exact * t * t + 0.75 * h * h * a_exact * (1 - std::pow(3.0, -n));
    ASSERT_LE(c, 0.1 + 1e-15) << "step " << n;
    ASSERT_EQ(st.current.orientation.coeffs(), b.reference.orientation.coeffs());
    // Off the axis by round-off only: two vector additions per step (the extrapolation
    // and the step; one for implicit Euler, whose test bounds it by 1e-15), each rounding
    // a component (|x| < 0.5 m) by at most 2^-54 = 5.6e-17: at most 2 x 500 x 5.6e-17 x
    // sqrt(3) = 1e-13 after 500 steps (a random walk gives ~1e-15: measured 1.0e-15).
    ASSERT_LT((st.current.position - s.position - c * axis).norm(), 1e-13) << "off its axis at step " << n;
    if (free_travel <= 0.1) {
      ASSERT_FALSE(info.at_limit);
      ASSERT_NEAR(c, free_travel, 1e-13) << "step " << n;
      ASSERT_NEAR(axis.dot(st.current.velocity), t * a_exact, 1e-11) << "step " << n;
      ASSERT_LT((info.constraint_force - b.mass * (a_exact * axis - g)).norm(), 1e-8) << "step " << n;
    } else {
      if (arrival < 0) arrival = n;
      ASSERT_TRUE(info.at_limit) << "step " << n;  // no bounce: it stays on the limit
      ASSERT_NEAR(c, 0.1, 1e-15) << "step " << n;
    }
  }
  EXPECT_GT(arrival, 0);
  EXPECT_LT(st.current.velocity.norm(), 1e-12);
  EXPECT_LT((st.info.constraint_force + b.mass * g).norm(), 1e-9);
  std::cout << "[rigid bdf2] slider: at its limit 0.1 m after " << arrival << " steps of 1 ms, reaction at rest "
            << st.info.constraint_force.transpose() << " N\n";
}

// A hinge's BDF2 extrapolation wraps the angle difference: a fast wheel crossing the
// window's edge (no limits: window (-pi, pi]) keeps its rate.
TEST(RigidBdf2Validation, HingeCrossingPiKeepsItsRate) {
  RigidBody b = box_body(Vec3(0.05, 0.05, 0.01), Joint::Kind::hinge);
  RigidState s;
  s.angular_velocity = Vec3(0, 0, 20);  // about its own centre: no gravity torque
  b.joint.anchor = Vec3::Zero();
  b.joint.axis = Vec3::UnitZ();
  initialize(b, s);
  Stepper st(b, b.reference);
  for (int n = 0; n < 400; ++n) {  // 8 rad: crosses pi
    st(1e-3, Vec3(0, 0, -9.81));
    ASSERT_NEAR(st.current.angular_velocity.z(), 20, 1e-11) << "step " << n;
  }
}

}  // namespace rigid_bdf2_validation
