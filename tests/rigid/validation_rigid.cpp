// The rigid step against closed forms (docs/method.md "Rigid bodies" quotes the
// figures printed here; run build/tests/validation_rigid):
//  - free fall: exact for implicit Euler (x_n = x_0 + n h v_0 + h^2 g n (n + 1) / 2);
//  - a constant wrench, the torque along a principal axis: exact for implicit Euler too;
//  - a spinning box in free flight: linear momentum to round-off, angular momentum kept
//    by construction (reported), energy decaying at first order (reported);
//  - a pendulum on a hinge: the small-angle period within implicit Euler's error
//    (omega h)^2 / 3 (second order), the amplitude decay exp(-pi omega h) per period
//    (first order);
//  - a slider on an incline: the closed-form acceleration g sin(30 deg), stopping
//    exactly at its limit with the reaction equal to the weight;
//  - a fixed joint does not move and reacts to the loads.
#include <softdiff/rigid/rigid_body.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <numbers>
#include <vector>

using namespace softdiff;
using namespace softdiff::rigid;

namespace rigid_validation {

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

TEST(RigidValidation, FreeFallIsExactForImplicitEuler) {
  RigidBody b = box_body(Vec3(0.05, 0.05, 0.05));
  RigidState s;
  s.position = Vec3(0, 0, 1);
  s.velocity = Vec3(0.5, -0.2, 2);
  initialize(b, s);
  const Vec3 g(0, 0, -9.81);
  const double h = 1e-3;
  RigidState a = b.reference, next;
  for (int n = 1; n <= 1000; ++n) {
    step(b, a, h, g, Vec3::Zero(), Vec3::Zero(), next);
    std::swap(a, next);
    const Vec3 x = s.position + n * h * s.velocity + h * h * g * (n * (n + 1) / 2.0);
    const Vec3 v = s.velocity + n * h * g;
    ASSERT_LT((a.position - x).norm(), 1e-13) << "step " << n;  // round-off of n additions
    ASSERT_LT((a.velocity - v).norm(), 1e-13) << "step " << n;
  }
  EXPECT_EQ(a.angular_velocity, Vec3::Zero());
  EXPECT_EQ(a.orientation.coeffs(), Eigen::Quaterniond::Identity().coeffs());
}

// A constant wrench on a body at rest, the torque along a principal axis: implicit
// Euler is exact here too (I_w(q) omega stays I_k omega along the fixed axis):
// omega_n = n h tau / I_k, the angle h^2 tau / I_k n (n + 1) / 2, and the force as in
// free fall (v_n = n h f / m).
TEST(RigidValidation, ConstantWrenchIsExactForImplicitEuler) {
  RigidBody b = box_body(Vec3(0.05, 0.1, 0.2));
  RigidState s;
  const Mat3 R0 = Eigen::AngleAxisd(0.6, Vec3(1, -2, 1).normalized()).toRotationMatrix();
  s.orientation = Eigen::Quaterniond(R0);
  initialize(b, s);
  const Vec3 axis = R0.col(1);  // the body's y axis in world
  const double I_k = b.inertia(1, 1), tau = 0.02, h = 1e-3;
  const Vec3 f(0.3, -0.1, 0.2);
  RigidState a = b.reference, next;
  for (int n = 1; n <= 1000; ++n) {
    step(b, a, h, Vec3::Zero(), f, tau * axis, next);
    std::swap(a, next);
    const double omega = n * h * tau / I_k, angle = h * h * tau / I_k * (n * (n + 1) / 2.0);
    ASSERT_LT((a.angular_velocity - omega * axis).norm(), 1e-12 * (1 + omega)) << "step " << n;
    const Eigen::AngleAxisd turned(a.orientation * b.reference.orientation.conjugate());
    ASSERT_NEAR(turned.angle(), angle, 1e-12 * (1 + angle)) << "step " << n;
    ASSERT_LT((a.velocity - n * h * f / b.mass).norm(), 1e-13) << "step " << n;
  }
}

struct SpinRun {
  double momentum_drift, angular_momentum_drift, energy_change;
};

// A 0.1 x 0.2 x 0.4 m box (three distinct moments) spinning mostly about its major
// axis with an off-axis part (it nutates), moving, without gravity, for 1 s.
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
  RigidState a = b.reference, next;
  SpinRun r{0, 0, 0};
  const int steps = static_cast<int>(std::lround(1 / h));
  for (int n = 1; n <= steps; ++n) {
    step(b, a, h, Vec3::Zero(), Vec3::Zero(), Vec3::Zero(), next);
    std::swap(a, next);
    momenta(a, p, L, E);
    r.momentum_drift = std::max(r.momentum_drift, (p - p0).norm() / p0.norm());
    r.angular_momentum_drift = std::max(r.angular_momentum_drift, (L - L0).norm() / L0.norm());
  }
  const double E_rot0 = E0 - 0.5 * b.mass * b.reference.velocity.squaredNorm();
  r.energy_change = (E - E0) / E_rot0;  // relative to the rotational energy
  return r;
}

TEST(RigidValidation, SpinningBodyInFreeFlight) {
  const SpinRun a = spin(1e-3), b = spin(5e-4);
  std::cout << "[rigid] spinning box, 1 s: h 1e-3: momentum drift " << a.momentum_drift << ", angular momentum drift "
            << a.angular_momentum_drift << ", rotational energy change " << a.energy_change << "\n"
            << "[rigid] spinning box, 1 s: h 5e-4: momentum drift " << b.momentum_drift << ", angular momentum drift "
            << b.angular_momentum_drift << ", rotational energy change " << b.energy_change << "\n";
  // Linear momentum: the velocity update adds exactly zero.
  EXPECT_EQ(a.momentum_drift, 0);
  EXPECT_EQ(b.momentum_drift, 0);
  // Angular momentum: I_w(q_{n+1}) omega_{n+1} = I_w(q_n) omega_n is the step's own
  // equation, solved to 1e-14; 1000 steps accumulate round-off.
  EXPECT_LT(a.angular_momentum_drift, 1e-11);
  EXPECT_LT(b.angular_momentum_drift, 1e-11);
  // Energy: dissipated (implicit Euler), at first order in h, bounded.
  EXPECT_LT(a.energy_change, 0);
  EXPECT_GT(a.energy_change, -0.05);
  EXPECT_NEAR(a.energy_change / b.energy_change, 2, 0.1);
}

struct PendulumRun {
  double omega0, period_error, decay_per_period;
};

// A small box bob on a massless arm of 0.5 m (the box's own inertia included), hinged
// about y at the origin, released at rest 1e-4 rad from the vertical: the finite-amplitude
// correction of the period, theta0^2/16 = 6e-10, is far below the step's error (at
// 1e-3 rad it was 6e-8, visible against (omega h)^2/3 = 1.6e-6 at h = 5e-4).
PendulumRun pendulum(double h) {
  RigidBody b = box_body(Vec3(0.02, 0.03, 0.04), Joint::Kind::hinge);
  const double l = 0.5, theta0 = 1e-4;
  RigidState s;
  s.position = Vec3(l * std::sin(theta0), 0, -l * std::cos(theta0));
  b.joint.anchor = Vec3::Zero();
  b.joint.axis = Vec3::UnitY();
  initialize(b, s);
  const double g = 9.81, I_a = b.inertia(1, 1) + b.mass * l * l;
  PendulumRun r;
  r.omega0 = std::sqrt(b.mass * g * l / I_a);
  const double T0 = 2 * pi / r.omega0;
  // Upward zero crossings of the bob's x (linear interpolation) and the positive peaks.
  std::vector<double> crossings, peaks;
  RigidState a = b.reference, next;
  double x_prev = a.position.x(), x_prev2 = x_prev;
  const long steps = std::lround(11.5 * T0 / h);
  for (long n = 1; n <= steps; ++n) {
    step(b, a, h, Vec3(0, 0, -g), Vec3::Zero(), Vec3::Zero(), next);
    std::swap(a, next);
    const double x = a.position.x();
    if (x_prev < 0 && x >= 0) crossings.push_back(h * (n - 1 + x_prev / (x_prev - x)));
    if (n >= 2 && x_prev >= x_prev2 && x_prev > x && x_prev > 0) peaks.push_back(x_prev);
    x_prev2 = x_prev;
    x_prev = x;
  }
  EXPECT_GE(crossings.size(), 11u);
  EXPECT_GE(peaks.size(), 11u);
  const double T = (crossings[10] - crossings[0]) / 10;
  r.period_error = (T - T0) / T0;
  r.decay_per_period = 1 - std::pow(peaks[10] / peaks[0], 0.1);
  return r;
}

TEST(RigidValidation, PendulumOnAHinge) {
  for (double h : {1e-3, 5e-4}) {
    const PendulumRun r = pendulum(h);
    const double wh = r.omega0 * h;
    // Implicit Euler on theta'' = -omega^2 theta: per step, the rotation atan(omega h)
    // and the factor (1 + (omega h)^2)^(-1/2). So the period is 2 pi h / atan(omega h),
    // relative error (omega h)^2 / 3 - (omega h)^4 / 5..., and the amplitude decays by
    // (1 + (omega h)^2)^(-N/2) per period of N = 2 pi / atan(omega h) steps.
    const double period_expected = wh / std::atan(wh) - 1;
    const double decay_expected = 1 - std::pow(1 + wh * wh, -pi / std::atan(wh));
    std::cout << "[rigid] pendulum (omega " << r.omega0 << " rad/s), h " << h << ": period error " << r.period_error
              << " (implicit Euler's " << period_expected << ", (omega h)^2/3 = " << wh * wh / 3
              << "), amplitude decay per period " << r.decay_per_period << " (expected " << decay_expected << ")\n";
    // The measurement (interpolated crossings, sampled peaks) is accurate to about
    // (omega h)^2/8 of the amplitude and ~1e-8 of the period: 3% of the error is ample.
    EXPECT_NEAR(r.period_error, period_expected, 0.03 * period_expected) << "h " << h;
    EXPECT_NEAR(r.decay_per_period, decay_expected, 0.03 * decay_expected) << "h " << h;
  }
}

// A 1 kg block sliding down a 30 degree incline axis from rest, limits [-0.01, 0.1] m:
// s_n = h^2 a n (n + 1) / 2 with a = g sin(30 deg) exactly until the limit, where it stops
// exactly and the reaction (rail and limit) carries the weight.
TEST(RigidValidation, SliderOnAnInclineStopsAtItsLimit) {
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
  RigidState a = b.reference, next;
  int arrival = -1;
  StepInfo info;
  for (int n = 1; n <= 500; ++n) {
    info = step(b, a, h, g, Vec3::Zero(), Vec3::Zero(), next);
    std::swap(a, next);
    const double c = joint_coordinate(b, a), free_travel = h * h * a_exact * n * (n + 1) / 2.0;
    ASSERT_LE(c, 0.1 + 1e-15) << "step " << n;
    ASSERT_EQ(a.orientation.coeffs(), b.reference.orientation.coeffs());
    ASSERT_LT((a.position - s.position - c * axis).norm(), 1e-15) << "off its axis at step " << n;
    if (free_travel <= 0.1) {
      ASSERT_FALSE(info.at_limit);
      ASSERT_NEAR(c, free_travel, 1e-14) << "step " << n;
      ASSERT_NEAR(axis.dot(a.velocity), n * h * a_exact, 1e-12) << "step " << n;
      // The rail's reaction is the weight's normal part: m (g - a axis).
      ASSERT_LT((info.constraint_force - b.mass * (a_exact * axis - g)).norm(), 1e-9) << "step " << n;
    } else {
      if (arrival < 0) arrival = n;
      ASSERT_TRUE(info.at_limit);
      ASSERT_NEAR(c, 0.1, 1e-15) << "step " << n;  // round-off of n . (x - x_0), |x| ~ 0.5 m
    }
  }
  // Arrival: the first n with h^2 a n (n + 1) / 2 > 0.1.
  const int expected = static_cast<int>(std::ceil((-1 + std::sqrt(1 + 8 * 0.1 / (h * h * a_exact))) / 2));
  EXPECT_EQ(arrival, expected);
  // At rest to round-off: the coordinate's round-off (~1e-16 m) over h is the velocity,
  // over h^2 (times 1 kg) the reaction's.
  EXPECT_LT(a.velocity.norm(), 1e-12);
  EXPECT_LT((info.constraint_force + b.mass * g).norm(), 1e-9);
  EXPECT_EQ(info.constraint_torque, Vec3::Zero());
  std::cout << "[rigid] slider: at its limit 0.1 m after " << arrival << " steps of 1 ms (closed form " << expected
            << "), reaction at rest " << info.constraint_force.transpose() << " N\n";
}

TEST(RigidValidation, FixedJointDoesNotMove) {
  RigidBody b = box_body(Vec3(0.05, 0.1, 0.02), Joint::Kind::fixed);
  RigidState s;
  s.position = Vec3(1, 2, 3);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Vec3(1, 2, 2).normalized()));
  s.velocity = Vec3(1, 0, 0);
  s.angular_velocity = Vec3(0, 3, 0);
  initialize(b, s);
  const Vec3 g(0, 0, -9.81), f(1, -2, 0.5), tau(0.1, 0.2, -0.3);
  RigidState a = b.reference, next;
  StepInfo info;
  for (int n = 1; n <= 100; ++n) {
    info = step(b, a, 1e-3, g, f, tau, next);
    std::swap(a, next);
  }
  EXPECT_EQ(a.position, s.position);
  EXPECT_EQ(a.orientation.coeffs(), s.orientation.coeffs());
  EXPECT_EQ(a.velocity, Vec3::Zero());
  EXPECT_EQ(a.angular_velocity, Vec3::Zero());
  EXPECT_LT((info.constraint_force + b.mass * g + f).norm(), 1e-12);
  EXPECT_LT((info.constraint_torque + tau).norm(), 1e-15);
}

}  // namespace rigid_validation
