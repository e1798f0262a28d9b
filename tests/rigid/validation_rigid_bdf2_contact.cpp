// BDF2 with rigid bodies in contact (integrator/bdf2.cpp time_step_rigid_contact;
// docs/method.md "BDF2 with rigid bodies") against the closed forms of
// validation_rigid_contact.cpp's implicit Euler tests (run build/tests/validation_rigid
// --gtest_filter='RigidBdf2Contact*'), on the dense and sparse backends:
//  - a rigid block sliding down a 30 degree incline (mu 0.3): the acceleration
//    a_s = g (sin a - mu cos a) is constant, so the velocity is exact (v_n = n h a_s: the
//    Euler first step and BDF2 are exact on linear velocities) and the travel is BDF2's
//    closed form a_s t^2 / 2 + 3/4 h^2 a_s (1 - 3^-n) (as free fall, validation_rigid_bdf2);
//    no penetration, no tipping, the normal force the weight's normal part, friction mu N;
//  - a box resting flat on a plane: the reaction is the weight, on its four corners.
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <numbers>

using namespace softdiff;

namespace rigid_bdf2_contact_validation {

constexpr double pi = std::numbers::pi;
constexpr double g0 = 9.81;

class RigidBdf2Contact : public ::testing::TestWithParam<contact::NcpBackend> {};

// A soft anchor far away with every node fixed (the step needs a soft body), BDF2.
Model anchored(double h) {
  Model model = test::rigid_scenes::anchored(h, g0);
  model.step.integrator = IntegratorKind::bdf2;
  return model;
}

contact::NcpOptions tight(contact::NcpBackend backend) {
  contact::NcpOptions o = test::rigid_scenes::tight_ncp(1e-10);
  o.backend = backend;
  return o;
}

// BDF2 from model.initial (the first step implicit Euler); asserts every step ok and
// every contact solve converged, on the backend asked for.
State run(const Model& model, Data& data, long steps, bool sparse) {
  State previous, a = model.initial, b;
  for (long n = 1; n <= steps; ++n) {
    const StepStatus st = integrator::time_step(model, data, a, n == 1 ? nullptr : &previous, b, n);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    if (!st.ok()) break;
    EXPECT_TRUE(data.contact.result.converged) << "step " << n;
    if (data.contact.contacts.size() > 0) EXPECT_EQ(data.contact.result.sparse, sparse) << "step " << n;
    previous = a;
    std::swap(a, b);
  }
  return a;
}

Vec3 force_on_rigid(const Data& data, int side, int* count) { return test::rigid_scenes::contact_force_on(data, side, count); }

// Tolerances as the implicit Euler test's: the NCP tolerance 1e-10 bounds the force
// error per step to ~1e-10 of the weight, 1e-7 relative after 200 steps is far above it.
TEST_P(RigidBdf2Contact, BlockSlidesDownAnInclineAtTheClosedFormAcceleration) {
  const double a = pi / 6, mu = 0.3, h = 1e-3;
  const long steps = 200;
  const Vec3 n(std::sin(a), 0, std::cos(a)), d(std::cos(a), 0, -std::sin(a));
  Model model = anchored(h);
  const Vec3 half(0.05, 0.03, 0.02);
  rigid::RigidState s;
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(a, Vec3::UnitY()));
  s.position = half.z() * n;
  test::add_rigid_body(model, "block", test::box_shape(half), 1000, s);
  test::enable_rigid_contact(model, {test::plane(n, 0, "ramp")}, {{"block", "ramp", mu}}, 1e-3, tight(GetParam()));
  Data data(model);
  const State end = run(model, data, steps, GetParam() == contact::NcpBackend::sparse);
  const double acc = g0 * (std::sin(a) - mu * std::cos(a)), t = steps * h;
  const auto& e = end.rigid[0];
  const double v = e.velocity.dot(d), travel = (e.position - model.initial.rigid[0].position).dot(d);
  const double travel_exact = 0.5 * acc * t * t + 0.75 * h * h * acc * (1 - std::pow(3.0, -double(steps)));
  std::cout << "[rigid bdf2 contact] incline 30 deg, mu 0.3: v " << v << " (relative error " << v / (t * acc) - 1
            << "), travel " << travel << " (relative error " << travel / travel_exact - 1 << ")\n";
  EXPECT_NEAR(v, t * acc, 1e-7 * t * acc);
  EXPECT_NEAR(travel, travel_exact, 1e-7 * travel_exact);
  EXPECT_LT(std::abs(e.velocity.dot(n)), 1e-9);
  EXPECT_LT(std::abs((e.position - model.initial.rigid[0].position).dot(n)), 1e-9);
  EXPECT_LT(e.angular_velocity.norm(), 1e-8);
  int count = 0;
  const Vec3 f = force_on_rigid(data, 1, &count);
  EXPECT_EQ(count, 4);
  const double weight = model.rigid[0].mass * g0;
  EXPECT_NEAR(f.dot(n), weight * std::cos(a), 1e-7 * weight);
  EXPECT_NEAR(-f.dot(d), mu * weight * std::cos(a), 1e-7 * weight);
}

TEST_P(RigidBdf2Contact, BoxRestsFlatOnItsFourCorners) {
  Model model = anchored(1e-3);
  rigid::RigidState s;
  s.position = Vec3(0.2, -0.1, 0.02);
  test::add_rigid_body(model, "box", test::box_shape(Vec3(0.05, 0.03, 0.02)), 700, s);
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0)}, {{"box", "floor", 0.5}}, 1e-3, tight(GetParam()));
  Data data(model);
  const State end = run(model, data, 100, GetParam() == contact::NcpBackend::sparse);
  const auto& e = end.rigid[0];
  int count = 0;
  const Vec3 f = force_on_rigid(data, 1, &count);
  const double weight = model.rigid[0].mass * g0;
  std::cout << "[rigid bdf2 contact] box on a plane: reaction " << f.transpose() << " N, weight " << weight
            << " N, contacts " << count << ", height " << e.position.z() << "\n";
  ASSERT_EQ(count, 4);
  EXPECT_NEAR(f.z(), weight, 1e-8 * weight);
  EXPECT_LT(f.head<2>().norm(), 1e-8 * weight);
  for (int i = 0; i < 4; ++i) EXPECT_GT(data.contact.lambda[3 * i + 2], 0.1 * weight) << "corner " << i;
  EXPECT_LT(e.angular_velocity.norm(), 1e-10);
  EXPECT_LT(e.velocity.norm(), 1e-10);
  EXPECT_NEAR(e.position.z(), 0.02, 1e-10);
}

INSTANTIATE_TEST_SUITE_P(Backends, RigidBdf2Contact,
                         ::testing::Values(contact::NcpBackend::dense, contact::NcpBackend::sparse),
                         [](const auto& info) { return info.param == contact::NcpBackend::dense ? "dense" : "sparse"; });

}  // namespace rigid_bdf2_contact_validation
