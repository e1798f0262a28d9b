// Scenes of rigid bodies only (issue 21; docs/method.md "Scenes of rigid bodies only"):
// a Model without any soft node, stepped by integrator::time_step, which skips the soft
// stage (no assembly, no factorization, no linear solve: data.factorizations stays 0).
// Against closed forms (run build/tests/validation_rigid --gtest_filter='RigidOnly*'):
//  - a free box dropped onto a plane: falls exactly as implicit Euler's free fall until
//    the speculative contact catches it, lands, rests: the reaction equals the weight,
//    no penetration beyond the contact solve's tolerance;
//  - a box stacked on a box on a plane (rigid-rigid contact): each interface carries
//    the weight above it;
//  - a pendulum on a hinge alone: the small-angle period and amplitude decay of implicit
//    Euler (validation_rigid.cpp's closed form, here through the whole step).
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <support/rigid_contact.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <numbers>
#include <vector>

using namespace softdiff;

namespace rigid_only_validation {

constexpr double pi = std::numbers::pi;
constexpr double g0 = 9.81;

// A model without soft bodies (test::make_model of no body: 0 nodes, an empty pattern).
Model rigid_only(double h) {
  Model m = test::make_model(std::vector<test::BodyInput>{}, Vec3(0, 0, -g0), h);
  EXPECT_EQ(m.fem.num_nodes, 0);
  return m;
}

contact::NcpOptions tight() {
  contact::NcpOptions o = test::rigid_scenes::tight_ncp(1e-10);
  o.backend = contact::NcpBackend::dense;
  return o;
}

// Sum of the world contact forces of the last step on side `side` (a name index), as
// validation_rigid_contact.cpp's force_on_rigid.
Vec3 force_on(const Data& data, int side, int* count = nullptr) { return test::rigid_scenes::contact_force_on(data, side, count); }

// Lowest world z of body r's surface vertices.
double lowest(const Model& model, const State& s, int r) {
  const auto& b = model.rigid[static_cast<std::size_t>(r)];
  const auto& st = s.rigid[static_cast<std::size_t>(r)];
  const Mat3 R = st.orientation.toRotationMatrix();
  double z = 1e300;
  for (Eigen::Index k = 0; k < b.surface.vertices.cols(); ++k)
    z = std::min(z, (st.position + R * b.surface.vertices.col(k)).z());
  return z;
}

// A 0.1 m cube (1 kg) released at rest 0.1 m above a plane (its bottom face at z = 0.1),
// h = 1e-3 s: it lands near t = sqrt(2 d / g) = 0.143 s and rests.
TEST(RigidOnly, FreeBoxFallsOntoAPlaneAndRests) {
  const double h = 1e-3, d = 0.1, half = 0.05;
  Model model = rigid_only(h);
  rigid::RigidState s;
  s.position = Vec3(0.3, -0.2, half + d);
  test::add_rigid_body(model, "box", test::box_shape(Vec3(half, half, half)), 1000, s);
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0)}, {{"box", "floor", 0.5}}, 1e-3, tight());
  Data data(model);
  State a = model.initial, b;
  long landed = -1;
  double min_gap = 1e300;
  for (long n = 1; n <= 400; ++n) {
    const StepStatus st = integrator::time_step(model, data, a, nullptr, b, n);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    ASSERT_TRUE(data.contact.result.converged) << "step " << n;
    ASSERT_EQ(b.x.size(), 0);
    std::swap(a, b);
    // Before any contact force the fall is implicit Euler's, exact in closed form:
    // z_n = z_0 - h^2 g n (n + 1) / 2 (validation_rigid.cpp FreeFallIsExactForImplicitEuler).
    const bool pushed = data.contact.lambda.size() > 0 && data.contact.lambda.cwiseAbs().maxCoeff() > 0;
    if (landed < 0 && !pushed) {
      ASSERT_NEAR(a.rigid[0].position.z(), half + d - h * h * g0 * (n * (n + 1) / 2.0), 1e-13) << "step " << n;
    }
    if (landed < 0 && pushed) landed = n;
    min_gap = std::min(min_gap, lowest(model, a, 0));
  }
  const double weight = model.rigid[0].mass * g0;
  int count = 0;
  const Vec3 f = force_on(data, 0, &count);
  const auto& e = a.rigid[0];
  std::cout << "[rigid only] box dropped 0.1 m: lands at step " << landed << " (t " << landed * h
            << " s; sqrt(2 d / g) = " << std::sqrt(2 * d / g0) << " s), reaction " << f.transpose() << " N, weight "
            << weight << " N, " << count << " contacts, lowest vertex " << min_gap << " m, rest height "
            << e.position.z() << " m, factorizations " << data.factorizations << "\n";
  // The soft stage never ran: nothing was factorized.
  EXPECT_EQ(data.factorizations, 0);
  // Landing: the step in which the bottom face reaches the plane, within the one step
  // the speculative gap term allows (the fall is exact until then).
  EXPECT_NEAR(landed * h, std::sqrt(2 * d / g0), 2 * h);
  // At rest: reaction = weight on the four bottom corners (the NCP's tolerance 1e-10 on
  // forces of ~10 N: 1e-8 relative is ample), no sliding, no rotation.
  ASSERT_EQ(count, 4);
  EXPECT_NEAR(f.z(), weight, 1e-8 * weight);
  EXPECT_LT(f.head<2>().norm(), 1e-8 * weight);
  EXPECT_LT(e.velocity.norm(), 1e-10);
  EXPECT_LT(e.angular_velocity.norm(), 1e-10);
  // No penetration: the normal rows enforce gap + h v_n >= 0 to the NCP's tolerance 1e-10
  // (m/s, on g = H v + gap / h), so the gap after any step is >= -h 1e-10 = -1e-13 m; the
  // pose's round-off (positions ~0.3 m) is ~1e-16. 1e-12 m bounds both.
  EXPECT_GT(min_gap, -1e-12);
  EXPECT_NEAR(e.position.z(), half, 1e-12);
}

// Two boxes stacked on a plane, the upper one off-centre (still over the lower one's
// face): rigid-rigid contact with no soft dof. The floor carries both weights, the
// interface the upper box's; neither moves.
TEST(RigidOnly, StackedBoxesCarryTheWeightAbove) {
  const double h = 2e-3;
  Model model = rigid_only(h);
  rigid::RigidState s;
  s.position = Vec3(0, 0, 0.05);
  test::add_rigid_body(model, "base", test::box_shape(Vec3(0.1, 0.1, 0.05)), 500, s, 0.2);
  s.position = Vec3(0.02, -0.01, 0.1 + 0.03 + 1e-4);  // released 0.1 mm above the base
  test::add_rigid_body(model, "top", test::box_shape(Vec3(0.04, 0.04, 0.03)), 500, s, 0.2);
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0)}, {{"base", "floor", 0.5}, {"base", "top", 0.5}},
                             1e-3, tight());
  Data data(model);
  State a = model.initial, b;
  for (long n = 1; n <= 250; ++n) {
    const StepStatus st = integrator::time_step(model, data, a, nullptr, b, n);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    ASSERT_TRUE(data.contact.result.converged) << "step " << n;
    std::swap(a, b);
  }
  const double w_base = model.rigid[0].mass * g0, w_top = model.rigid[1].mass * g0;
  // Names: base 0, top 1, floor 2. The force on the top box (from the base) and the
  // force on the pair base + top from the floor (the base's total less what the top
  // box pushes on it).
  const Vec3 on_top = force_on(data, 1);
  const Vec3 on_base = force_on(data, 0);
  std::cout << "[rigid only] stack: force on top " << on_top.transpose() << " N (weight " << w_top
            << "), net contact force on base " << on_base.transpose() << " N (weight " << w_base << "), top at "
            << a.rigid[1].position.transpose() << "\n";
  EXPECT_EQ(data.factorizations, 0);
  EXPECT_NEAR(on_top.z(), w_top, 1e-8 * w_top);
  EXPECT_LT(on_top.head<2>().norm(), 1e-8 * w_top);
  // The base: floor (w_base + w_top) less the top's push (w_top) = its own weight.
  EXPECT_NEAR(on_base.z(), w_base, 1e-8 * (w_base + w_top));
  for (int r = 0; r < 2; ++r) {
    EXPECT_LT(a.rigid[static_cast<std::size_t>(r)].velocity.norm(), 1e-9) << r;
    EXPECT_LT(a.rigid[static_cast<std::size_t>(r)].angular_velocity.norm(), 1e-9) << r;
  }
  EXPECT_NEAR(a.rigid[1].position.z(), 0.13, 1e-11);
  EXPECT_NEAR(a.rigid[0].position.z(), 0.05, 1e-11);
}

// validation_rigid.cpp's pendulum (a small box bob on a massless 0.5 m arm, hinged about
// y, released 1e-4 rad from the vertical), stepped by integrator::time_step in a model
// that has nothing else: the period error and the amplitude decay of implicit Euler.
TEST(RigidOnly, PendulumAloneMatchesTheSmallAnglePeriod) {
  for (double h : {1e-3, 5e-4}) {
    Model model = rigid_only(h);
    const double l = 0.5, theta0 = 1e-4;
    rigid::RigidState s;
    s.position = Vec3(l * std::sin(theta0), 0, -l * std::cos(theta0));
    test::add_rigid_body(model, "bob", test::box_shape(Vec3(0.02, 0.03, 0.04)), 1000, s, 1,
                         rigid::Joint::Kind::hinge);
    auto& body = model.rigid[0];
    body.joint.anchor = Vec3::Zero();
    body.joint.axis = Vec3::UnitY();
    rigid::initialize(body, s);
    model.initial.rigid[0] = body.reference;
    const double I_a = body.inertia(1, 1) + body.mass * l * l;
    const double omega0 = std::sqrt(body.mass * g0 * l / I_a), T0 = 2 * pi / omega0;
    Data data(model);
    State a = model.initial, b;
    std::vector<double> crossings, peaks;
    double x_prev = a.rigid[0].position.x(), x_prev2 = x_prev;
    const long steps = std::lround(11.5 * T0 / h);
    for (long n = 1; n <= steps; ++n) {
      const StepStatus st = integrator::time_step(model, data, a, nullptr, b, n);
      ASSERT_TRUE(st.ok()) << describe(model, st);
      std::swap(a, b);
      const double x = a.rigid[0].position.x();
      if (x_prev < 0 && x >= 0) crossings.push_back(h * (n - 1 + x_prev / (x_prev - x)));
      if (n >= 2 && x_prev >= x_prev2 && x_prev > x && x_prev > 0) peaks.push_back(x_prev);
      x_prev2 = x_prev;
      x_prev = x;
    }
    ASSERT_GE(crossings.size(), 11u);
    ASSERT_GE(peaks.size(), 11u);
    const double T = (crossings[10] - crossings[0]) / 10;
    const double period_error = (T - T0) / T0, decay = 1 - std::pow(peaks[10] / peaks[0], 0.1);
    // Implicit Euler on theta'' = -omega^2 theta (validation_rigid.cpp PendulumOnAHinge):
    // the period 2 pi h / atan(omega h), the amplitude factor (1 + (omega h)^2)^(-1/2) per step.
    const double wh = omega0 * h;
    const double period_expected = wh / std::atan(wh) - 1;
    const double decay_expected = 1 - std::pow(1 + wh * wh, -pi / std::atan(wh));
    std::cout << "[rigid only] pendulum (omega " << omega0 << " rad/s), h " << h << ": period error " << period_error
              << " (implicit Euler's " << period_expected << "), decay per period " << decay << " (expected "
              << decay_expected << "), factorizations " << data.factorizations << "\n";
    EXPECT_EQ(data.factorizations, 0);
    // As validation_rigid.cpp: the measurement (interpolated crossings, sampled peaks) is
    // accurate to ~(omega h)^2 / 8 of the amplitude and ~1e-8 of the period: 3% of the error.
    EXPECT_NEAR(period_error, period_expected, 0.03 * period_expected) << "h " << h;
    EXPECT_NEAR(decay, decay_expected, 0.03 * decay_expected) << "h " << h;
  }
}

}  // namespace rigid_only_validation
