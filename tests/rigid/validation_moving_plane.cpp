// A plane obstacle moving along its normal (scene.md obstacles, `offset: [[t, offset], ...]`;
// docs/method.md "Moving planes") against closed forms. The contact stage takes the
// plane at the step's end time t_{n+1}: the gap constraint n . x_{n+1} >= offset(t_{n+1})
// is then exact for implicit Euler (x_{n+1} = x_n + h v_{n+1}), so:
//  - a rigid box resting on a plane that rises at constant speed U moves with it: after
//    the first step its velocity is U and its bottom at offset(t_n), to the NCP tolerance;
//  - a plane dropping faster than g t lets a box fall freely: implicit Euler's free fall
//    z_n = z_0 - g h^2 n (n + 1) / 2, v_n = -n g h, no contact force;
//  - a soft cube resting on a plane that rises 10 mm over 0.1 s and stops: its bottom
//    nodes move with the plane while it rises, and it comes to rest on the plane's final
//    position with the reaction equal to the weight.
// Figures printed here are quoted in docs/method.md "Moving planes" (run
// build/tests/validation_rigid --gtest_filter='MovingPlane*').
#include <softdiff/collision/obstacle.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <support/contact.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>
#include <support/rigid_contact.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <string>

using namespace softdiff;

namespace moving_plane_validation {

constexpr double g0 = 9.81;

// A soft anchor far away with every node fixed (build_model's rule: a scene needs a soft
// body); it takes part in no contact pair.
Model anchored(double h) { return test::rigid_scenes::anchored(h, g0); }

collision::Obstacle moving_plane(std::vector<std::array<double, 2>> schedule) {
  collision::Obstacle o;
  o.name = "floor";
  o.kind = collision::ShapeKind::plane;
  o.normal = Vec3::UnitZ();
  o.offset = schedule.front()[1];
  o.offset_schedule = std::move(schedule);
  collision::prepare(o);
  return o;
}

contact::NcpOptions tight() { return test::rigid_scenes::tight_ncp(1e-10); }

// The schedule: piecewise linear, held outside, scaled with a non-unit normal.
TEST(MovingPlane, OffsetScheduleIsPiecewiseLinearAndHeldOutside) {
  collision::Obstacle o = moving_plane({{0.1, 0.0}, {0.3, 0.02}, {0.5, 0.02}});
  EXPECT_EQ(collision::plane_offset_at(o, 0.0), 0.0);
  EXPECT_EQ(collision::plane_offset_at(o, 0.1), 0.0);
  EXPECT_NEAR(collision::plane_offset_at(o, 0.2), 0.01, 1e-15);
  EXPECT_EQ(collision::plane_offset_at(o, 0.4), 0.02);
  EXPECT_EQ(collision::plane_offset_at(o, 9.0), 0.02);
  collision::Obstacle s;
  s.kind = collision::ShapeKind::plane;
  s.normal = Vec3(0, 0, 2);
  s.offset_schedule = {{0, 0.0}, {1, 0.04}};
  collision::prepare(s);  // unit normal: the offsets halve
  EXPECT_NEAR(collision::plane_offset_at(s, 0.5), 0.01, 1e-15);
  collision::Obstacle bad = s;
  bad.normal = Vec3::UnitZ();
  bad.offset_schedule = {{0, 0.0}, {0, 0.01}};
  EXPECT_THROW(collision::prepare(bad), InputError);
  collision::Obstacle sphere;
  sphere.kind = collision::ShapeKind::sphere;
  sphere.radius = 0.1;
  sphere.offset_schedule = {{0, 0.0}, {1, 0.01}};
  EXPECT_THROW(collision::prepare(sphere), InputError);
}

// A rigid box (0.1 x 0.06 x 0.04 m, 700 kg/m^3, mu 0.5) resting on z = 0; the plane rises
// at U = 0.05 m/s from t = 0 to 0.2 s. Step 1: the constraint z_1 - 0.02 >= U h with
// gravity pressing down gives v_1 = U exactly (an impulse m (U + g h)); after that the
// contact carries the weight and v_n = U. Tolerances: the NCP's 1e-10 (scaled residuals)
// bounds the normal velocity error to ~1e-10 of the step's velocity scale; 1e-9 m/s and
// 1e-11 m over 150 steps are far above that and far below any physical effect.
TEST(MovingPlane, RigidBoxRidesARisingPlaneAtItsSpeed) {
  const double h = 1e-3, U = 0.05;
  Model model = anchored(h);
  rigid::RigidState s;
  s.position = Vec3(0.2, -0.1, 0.02);
  test::add_rigid_body(model, "box", test::box_shape(Vec3(0.05, 0.03, 0.02)), 700, s);
  test::enable_rigid_contact(model, {moving_plane({{0, 0.0}, {0.2, 0.2 * U}})}, {{"box", "floor", 0.5}}, 1e-3, tight());
  Data data(model);
  State a = model.initial, b;
  const double m = model.rigid[0].mass;
  double worst_v = 0, worst_z = 0, worst_f = 0;
  for (long n = 1; n <= 150; ++n) {
    ASSERT_TRUE(integrator::time_step(model, data, a, nullptr, b, n).ok()) << "step " << n;
    ASSERT_TRUE(data.contact.result.converged) << "step " << n;
    std::swap(a, b);
    const auto& e = a.rigid[0];
    // The contacts' side a is the box's pseudo-nodes: the force on the box is + C lambda.
    Vec3 f = Vec3::Zero();
    for (int i = 0; i < data.contact.contacts.size(); ++i)
      f += data.contact.contacts.contacts[static_cast<std::size_t>(i)].frame * data.contact.lambda.segment<3>(3 * i);
    if (n == 1) {
      EXPECT_NEAR(f.z(), m * (U / h + g0), 1e-8 * m * (U / h + g0));
    } else {
      worst_f = std::max(worst_f, std::abs(f.z() - m * g0) / (m * g0));
    }
    worst_v = std::max(worst_v, (e.velocity - Vec3(0, 0, U)).norm());
    worst_z = std::max(worst_z, std::abs(e.position.z() - 0.02 - U * n * h));
    EXPECT_LT(e.angular_velocity.norm(), 1e-9) << "step " << n;
  }
  std::cout << "rising plane (U = " << U << " m/s): max |v - U| " << worst_v << " m/s, max |z - offset - 0.02| "
            << worst_z << " m, max |reaction - m g| / m g after step 1 " << worst_f << "\n";
  EXPECT_LT(worst_v, 1e-9);
  EXPECT_LT(worst_z, 1e-11);
  EXPECT_LT(worst_f, 1e-7);
}

// The plane drops at c = 1.5 m/s from t = 0 while the box falls from rest on it: the box's
// bottom, z_0 - g t^2 / 2 (and implicit Euler's, a little above), stays above -c t for
// t < 2 c / g = 0.31 s, so over 0.2 s no contact force acts: implicit Euler's free fall
// exactly (v_n = -n g h, z_n = z_0 - g h^2 n (n + 1) / 2; rounding only: 1e-12).
TEST(MovingPlane, PlaneDroppingFasterThanGravityLetsTheBoxFallFreely) {
  const double h = 1e-3, c = 1.5;
  Model model = anchored(h);
  rigid::RigidState s;
  s.position = Vec3(0.2, -0.1, 0.02);
  test::add_rigid_body(model, "box", test::box_shape(Vec3(0.05, 0.03, 0.02)), 700, s);
  test::enable_rigid_contact(model, {moving_plane({{0, 0.0}, {1, -c}})}, {{"box", "floor", 0.5}}, 1e-3, tight());
  Data data(model);
  State a = model.initial, b;
  double worst_z = 0, worst_v = 0, largest_force = 0;
  for (long n = 1; n <= 200; ++n) {
    ASSERT_TRUE(integrator::time_step(model, data, a, nullptr, b, n).ok()) << "step " << n;
    std::swap(a, b);
    const auto& e = a.rigid[0];
    const double z = 0.02 - g0 * h * h * static_cast<double>(n * (n + 1)) / 2;
    worst_z = std::max(worst_z, std::abs(e.position.z() - z));
    worst_v = std::max(worst_v, std::abs(e.velocity.z() + static_cast<double>(n) * g0 * h));
    if (data.contact.lambda.size() > 0) largest_force = std::max(largest_force, data.contact.lambda.cwiseAbs().maxCoeff());
  }
  const double t = 0.2;
  std::cout << "dropping plane (c = " << c << " m/s): max |z - z_n| " << worst_z << " m, max |v - v_n| " << worst_v
            << " m/s, largest contact force " << largest_force << " N; z(0.2) " << a.rigid[0].position.z()
            << " m against the continuous " << 0.02 - g0 * t * t / 2 << " m\n";
  EXPECT_LT(worst_z, 1e-12);
  EXPECT_LT(worst_v, 1e-12);
  EXPECT_EQ(largest_force, 0.0);
  // Implicit Euler against the continuous free fall: z_n = z_0 - g t^2 / 2 - g h t / 2.
  EXPECT_NEAR(a.rigid[0].position.z() - (0.02 - g0 * t * t / 2), -g0 * h * t / 2, 1e-12);
}

// A soft cube (20 mm, E = 50 kPa, damped) resting on z = 0; the plane rises 10 mm over
// 0.1 s (U = 0.1 m/s) and stops. While it rises, no node goes below the plane (gap >=
// -1e-9 m: the NCP's tolerance times the step's velocity scale, with margin) and a bottom
// node pressed on it (lambda_n > 0) moves at U (its constraint is active); at the end the
// cube rests on z = 0.01: the bottom nodes at the plane (gap >= -h tol), the reaction
// equal to the weight (at rest to 1e-7 m/s: m |dv| / h, 1e-5 of the weight), speed ~ 0.
TEST(MovingPlane, SoftCubeRestsOnAPlaneThatRisesAndStops) {
  test::BodySpec spec;
  spec.young = 5e4;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 30;
  spec.rayleigh_stiffness = 0.005;
  const double h = 2e-3, U = 0.1, L = 0.02;
  Model model = test::make_model(test::box_mesh(2, 2, 2, L, L, L), spec, Vec3(0, 0, -g0), h);
  test::ContactSpec cs;
  cs.mu = 0.5;
  cs.ncp = tight();
  test::enable_contact(model, {moving_plane({{0, 0.0}, {0.1, 0.1 * U}})}, cs);
  Data data(model);
  const int nn = model.fem.num_nodes;
  std::vector<int> bottom;
  for (int i = 0; i < nn; ++i)
    if (model.fem.X(2, i) < 1e-12) bottom.push_back(i);
  ASSERT_EQ(bottom.size(), 9u);
  State a = model.initial, b;
  double worst_rise = 0, lowest = 1;
  int pressed = 0;
  const long steps = 600;
  for (long n = 1; n <= steps; ++n) {
    ASSERT_TRUE(integrator::time_step(model, data, a, nullptr, b, n).ok()) << "step " << n;
    ASSERT_TRUE(data.contact.result.converged) << "step " << n;
    std::swap(a, b);
    const double offset = std::min(U * static_cast<double>(n) * h, 0.1 * U);
    for (int i : bottom) lowest = std::min(lowest, a.x[3 * i + 2] - offset);
    if (static_cast<double>(n) * h > 0.1 - 1e-12) continue;
    for (int i = 0; i < data.contact.contacts.size(); ++i)
      if (data.contact.lambda[3 * i + 2] > 1e-12) {
        const int node = data.contact.contacts.contacts[static_cast<std::size_t>(i)].nodes[0];
        worst_rise = std::max(worst_rise, std::abs(a.v[3 * node + 2] - U));
        ++pressed;
      }
  }
  double weight = 0;
  for (int k = 2; k < model.fem.gravity_force.size(); k += 3) weight -= model.fem.gravity_force[k];
  double reaction = 0, worst_gap = 0, speed = 0;
  for (int i = 0; i < data.contact.contacts.size(); ++i) reaction += data.contact.lambda[3 * i + 2];
  for (int i : bottom) worst_gap = std::max(worst_gap, std::abs(a.x[3 * i + 2] - 0.01));
  for (int i = 0; i < nn; ++i) speed = std::max(speed, a.v.segment<3>(3 * i).norm());
  std::cout << "soft cube on a plane rising 10 mm and stopping: max |v_n - U| of the pressed nodes while rising "
            << worst_rise << " m/s (" << pressed << " node-steps), lowest gap " << lowest << " m; at 1.2 s: reaction " << reaction << " N, weight " << weight
            << " N, max |z_bottom - 0.01| " << worst_gap << " m, speed " << speed << " m/s\n";
  EXPECT_GT(pressed, 9 * 40);  // pressed on most steps of the rise (50 steps)
  EXPECT_LT(worst_rise, 1e-8);
  EXPECT_GT(lowest, -1e-9);
  EXPECT_LT(speed, 1e-7);
  EXPECT_NEAR(reaction, weight, 1e-5 * weight);
  EXPECT_LT(worst_gap, 1e-8);
}

}  // namespace moving_plane_validation
