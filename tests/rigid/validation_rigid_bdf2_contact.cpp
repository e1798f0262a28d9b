// BDF2 with rigid bodies in contact (integrator/bdf2.cpp time_step_rigid_contact;
// docs/method.md "BDF2 with rigid bodies") against the closed forms of
// validation_rigid_contact.cpp's implicit Euler tests (run build/tests/validation_rigid
// --gtest_filter='RigidBdf2Contact*'), on the dense and sparse backends:
//  - a rigid block sliding down a 30 degree incline (mu 0.3): the acceleration
//    a_s = g (sin a - mu cos a) is constant, so the velocity is exact (v_n = n h a_s: the
//    Euler first step and BDF2 are exact on linear velocities) and the travel is BDF2's
//    closed form a_s t^2 / 2 + 3/4 h^2 a_s (1 - 3^-n) (as free fall, validation_rigid_bdf2);
//    no penetration, no tipping, the normal force the weight's normal part, friction mu N;
//  - a box resting flat on a plane: the reaction is the weight, on its four corners;
//  - a box dropped 1 mm onto a plane: it lands without bouncing (the impact restart);
//  - a rigid cube dropped 1 mm onto a soft slab: it lands without bouncing (the restart of
//    soft-rigid impacts) and rests with the slab's reaction equal to its weight.
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
    if (data.contact.contacts.size() > 0) {
      EXPECT_EQ(data.contact.result.sparse, sparse) << "step " << n;
    }
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

// An impact (2026-12-04, rbimp; docs/method.md "BDF2", *Impacts: BDF2 restarts*): a box
// (0.1 x 0.06 x 0.04 m, 700 kg/m^3) dropped from 1 mm onto a plane, h = 2 ms: it lands
// at 0.137 m/s during step 8. The exact motion stops there (an inelastic contact: the
// NCP has no restitution) and rests at z = 0.02 m with the weight on its corners.
// Before the restart BDF2 bounced here (v_z +0.057 m/s the step after the landing, a
// rise of 0.47 mm above the rest height with the rigid stack's middle box): the history
// (x^, v^) carried the pre-impact velocity. Now the landing step and the one after are
// implicit Euler steps and BDF2 resumes at the next one. Checked after the first step
// whose contacts carry a force, for BDF2 and (unchanged) implicit Euler:
//  - no bounce: v_z <= 1e-9 m/s and z <= 0.02 + 1e-9 m at every later step (the NCP's
//    tolerance 1e-10 relative bounds the contact velocity's error to ~1e-10 of the
//    velocity scale 0.14 m/s; 1e-9 is ten times that, far below the 57 mm/s and
//    0.47 mm of the bounce), no sinking (z >= 0.02 - 1e-9), the normal force > 0 at
//    every step;
//  - at rest after 40 steps: the reaction the weight (1e-8 relative, as the resting box
//    above), velocity below 1e-10;
//  - BDF2: exactly two restarted steps (history_weight 0 after the first step), after
//    which every step is BDF2 again (history_weight 1/3).
struct Landing {
  int landed = 0;          // the first step whose contacts carry a force
  int restarted = 0;       // steps after the first with history_weight 0
  int bdf2_after = 0;      // BDF2 steps after the restarted ones
  double max_vz = -1e300;  // after the landing
  double max_rise = -1e300, max_sink = -1e300;
  double min_force = 1e300;
  State end;
};

Landing drop_box(IntegratorKind integrator, contact::NcpBackend backend) {
  const double h = 2e-3, z_rest = 0.02;
  Model model = anchored(h);
  model.step.integrator = integrator;
  rigid::RigidState s;
  s.position = Vec3(0.2, -0.1, z_rest + 1e-3);
  test::add_rigid_body(model, "box", test::box_shape(Vec3(0.05, 0.03, 0.02)), 700, s);
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0)}, {{"box", "floor", 0.5}}, 1e-3, tight(backend));
  Data data(model);
  Landing r;
  State previous, a = model.initial, b;
  for (long n = 1; n <= 40; ++n) {
    const StepStatus st = integrator::time_step(model, data, a, n == 1 ? nullptr : &previous, b, n);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    if (!st.ok()) break;
    EXPECT_TRUE(data.contact.result.converged) << "step " << n;
    previous = a;
    std::swap(a, b);
    const double fz = force_on_rigid(data, 1, nullptr).z();
    if (!r.landed && fz > 0) r.landed = static_cast<int>(n);
    if (n > 1 && data.history_weight == 0) ++r.restarted;
    if (n > 1 && data.history_weight != 0 && r.restarted) ++r.bdf2_after;
    if (!r.landed) continue;
    const auto& e = a.rigid[0];
    r.max_vz = std::max(r.max_vz, e.velocity.z());
    r.max_rise = std::max(r.max_rise, e.position.z() - z_rest);
    r.max_sink = std::max(r.max_sink, z_rest - e.position.z());
    r.min_force = std::min(r.min_force, fz);
  }
  r.end = a;
  const double weight = model.rigid[0].mass * g0;
  const Vec3 f = force_on_rigid(data, 1, nullptr);
  std::cout << "[rigid bdf2 contact] box dropped 1 mm (" << (integrator == IntegratorKind::bdf2 ? "bdf2" : "implicit Euler")
            << "): landed at step " << r.landed << ", restarted steps " << r.restarted << ", max v_z after " << r.max_vz
            << " m/s, max rise " << r.max_rise << " m, max sink " << r.max_sink << " m, end reaction " << f.z()
            << " N (weight " << weight << ")\n";
  EXPECT_NEAR(f.z(), weight, 1e-8 * weight);
  EXPECT_LT(f.head<2>().norm(), 1e-8 * weight);
  EXPECT_LT(a.rigid[0].velocity.norm(), 1e-10);
  EXPECT_LT(a.rigid[0].angular_velocity.norm(), 1e-10);
  return r;
}

void expect_no_bounce(const Landing& r) {
  ASSERT_GT(r.landed, 1);
  EXPECT_LE(r.max_vz, 1e-9);
  EXPECT_LE(r.max_rise, 1e-9);
  EXPECT_LE(r.max_sink, 1e-9);
  EXPECT_GT(r.min_force, 0);
}

TEST_P(RigidBdf2Contact, BoxDroppedOneMillimetreLandsWithoutBouncing) {
  const Landing r = drop_box(IntegratorKind::bdf2, GetParam());
  expect_no_bounce(r);
  EXPECT_EQ(r.restarted, 2);
  EXPECT_EQ(r.bdf2_after, 40 - 1 - 2 - (r.landed - 1 - 1));  // every step after the two restarts is BDF2
}

TEST_P(RigidBdf2Contact, BoxDroppedOneMillimetreLandsWithoutBouncingUnderImplicitEuler) {
  expect_no_bounce(drop_box(IntegratorKind::implicit_euler, GetParam()));
}

INSTANTIATE_TEST_SUITE_P(Backends, RigidBdf2Contact,
                         ::testing::Values(contact::NcpBackend::dense, contact::NcpBackend::sparse),
                         [](const auto& param_info) { return param_info.param == contact::NcpBackend::dense ? "dense" : "sparse"; });

}  // namespace rigid_bdf2_contact_validation

namespace rigid_bdf2_contact_validation {

// A soft-rigid impact (2026-12-04, rsrb; docs/method.md "BDF2", *Soft-rigid impacts
// restart*): the 40 mm rigid cube of rigid_scenes.hpp slab_and_cube (500 kg/m^3, 32 g)
// dropped from 1 mm above the damped soft slab (0.12 x 0.12 x 0.01 m, E 50 kPa, Rayleigh
// 20 1/s and 0.01 s, bottom fixed), h = 2 ms, mu 0.5, under bdf2: it lands at
// sqrt(2 g 1 mm) = 0.14 m/s. The NCP's impact is inelastic (the contact's normal velocity
// set to zero); the cube then rests on the slab at its static compression (measured 12 um
// below the contact height). The slab's stiffness damping makes the cube on the slab
// overdamped (k = m g / 12 um ~ 2.6e4 N/m, omega = sqrt(k / m) ~ 900 rad/s, damping ratio
// (20 / omega + 0.01 omega) / 2 ~ 4.5): the cube has no rebound of its own, only
// the slab's damped response to the inelastic stop moves it (measured with the restart:
// up to 1.0e-4 m/s upwards, 0.6 um above its height at the landing; without it the cube
// left the slab at +0.095 m/s and rose 0.81 mm). Checked after the first step whose
// contacts carry a force on the cube (the landing), for 300 steps (0.6 s, ~60 of the slow
// time constant):
//  - no bounce: v_z of the cube <= V = 0.01 margin / dt = 5 mm/s at every later step (the
//    impact rule's own threshold: a contact closing slower than V does not restart, and
//    the lift it leaves is under 2% of the margin; docs/method.md *Impacts: BDF2
//    restarts*), and the cube never rises above its height at the end of the landing step
//    by more than 1.7 V dt = 17 um (the lift a closing speed V leaves under BDF2, the same
//    rule), the normal force on the cube > 0 at every step after the landing (no
//    separation). Without the restart of soft-rigid contacts this test fails (v_z, rise,
//    force and restart count, measured 2026-12-04);
//  - at rest after 300 steps: the slab's reaction on the cube equals its weight to 1e-6
//    relative (the NCP tolerance 1e-10 per step; the residual acceleration of the
//    overdamped mode after 60 time constants is far below), horizontal force below 1e-6 of
//    the weight, the cube's velocity below 1e-6 m/s.
TEST(RigidBdf2SoftRigidContact, CubeDroppedOneMillimetreOntoASoftSlabLandsWithoutBouncing) {
  const double h = 2e-3;
  const long steps = 300;
  Model model = test::rigid_scenes::slab_and_cube(h);
  model.step.integrator = IntegratorKind::bdf2;
  model.contact.ncp = test::rigid_scenes::tight_ncp(1e-10);
  model.initial.rigid[0].position.z() += 1e-3;
  const double V = 0.01 * model.contact.detection.margin / h, weight = model.rigid[0].mass * g0;
  Data data(model);
  State previous, a = model.initial, b;
  int landed = 0, restarted = 0;
  double z_landed = 0, max_vz = -1e300, max_rise = -1e300, min_force = 1e300;
  for (long n = 1; n <= steps; ++n) {
    const StepStatus st = integrator::time_step(model, data, a, n == 1 ? nullptr : &previous, b, n);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    EXPECT_TRUE(data.contact.result.converged) << "step " << n;
    previous = a;
    std::swap(a, b);
    if (n > 1 && data.history_weight == 0) ++restarted;
    const double fz = force_on_rigid(data, 1, nullptr).z();
    const auto& e = a.rigid[0];
    if (!landed) {
      if (fz > 0) landed = static_cast<int>(n), z_landed = e.position.z();
      continue;
    }
    max_vz = std::max(max_vz, e.velocity.z());
    max_rise = std::max(max_rise, e.position.z() - z_landed);
    min_force = std::min(min_force, fz);
  }
  const Vec3 f = force_on_rigid(data, 1, nullptr);
  const auto& e = a.rigid[0];
  std::cout << "[rigid bdf2 contact] cube dropped 1 mm onto the soft slab: landed at step " << landed
            << ", restarted steps " << restarted << ", max v_z after " << max_vz << " m/s (V = " << V
            << "), max rise above the landing height " << max_rise << " m, min normal force " << min_force
            << " N, rest height " << e.position.z() << " (landing " << z_landed << "), end reaction " << f.transpose()
            << " N (weight " << weight << ", relative error " << f.z() / weight - 1 << "), |v| " << e.velocity.norm()
            << "\n";
  ASSERT_GT(landed, 1);
  EXPECT_GT(restarted, 0);
  EXPECT_LE(max_vz, V);
  EXPECT_LE(max_rise, 1.7 * V * h);
  EXPECT_GT(min_force, 0);
  EXPECT_NEAR(f.z(), weight, 1e-6 * weight);
  EXPECT_LT(f.head<2>().norm(), 1e-6 * weight);
  EXPECT_LT(e.velocity.norm(), 1e-6);
}

}  // namespace rigid_bdf2_contact_validation
