// BDF2 with frictional contact (docs/method.md "BDF2", "Contact with BDF2"): the
// analytic cases of tests/contact/validation_contact.cpp behave with BDF2 as with
// implicit Euler:
//  - a cube on an incline (mu = 0.5): stuck at 25 degrees, sliding at 30 with the
//    acceleration g (sin a - mu cos a);
//  - a beam on two supports damped to rest: the normal forces carry the weight, no
//    penetration;
//  - a cube dropped on a plane (an impact): no bounce, no sinking.
// Every step's contact solution is checked independently (support/contact_checks.hpp).
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <support/contact.hpp>
#include <support/contact_checks.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <numbers>
#include <vector>

using namespace softdiff;

namespace bdf2_contact_validation {

constexpr double kG = 9.81;
constexpr double kDeg = std::numbers::pi / 180;

template <class F>
State run(const Model& model, Data& data, long steps, double tol, F&& after_step) {
  State s = model.initial, next = s, previous;
  for (long k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::time_step(model, data, s, k > 1 ? &previous : nullptr, next, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    if (!st.ok()) break;
    EXPECT_TRUE(data.contact.result.converged) << "step " << k;
    test::expect_valid_contact_solution(data, tol, "step " + std::to_string(k));
    std::swap(previous, s);
    std::swap(s, next);
    after_step(k, s);
  }
  return s;
}

// The incline of validation_contact.cpp (0.1 m cube, 3x3x3 cells, E 1e6, beta 1e-3,
// dt 2e-3, gravity tilted by the angle), with BDF2.
struct InclineResult {
  double slip = 0;          // max |x displacement| over 0.1-0.5 s of the bottom nodes in contact
  double acceleration = 0;  // mean x acceleration of the nodes' mean over 0.1-0.5 s
};

InclineResult incline(double angle_deg, double mu) {
  test::BodySpec spec;
  spec.young = 1e6;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_stiffness = 1e-3;
  const double a = angle_deg * kDeg;
  const Vec3 g(kG * std::sin(a), 0, -kG * std::cos(a));
  const double dt = 2e-3;
  Model model = test::make_model(test::box_mesh(3, 3, 3, 0.1, 0.1, 0.1), spec, g, dt, 250);
  model.step.integrator = IntegratorKind::bdf2;
  test::ContactSpec cs;
  cs.mu = mu;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  Data data(model);
  int bottom = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) bottom += model.fem.X(2, i) < 1e-12;
  InclineResult r;
  State at_start;
  const long k0 = std::lround(0.1 / dt), k1 = std::lround(0.5 / dt);
  double v0 = 0;
  auto mean_vx = [&](const State& st) {
    double m = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i) m += st.v[3 * i];
    return m / model.fem.num_nodes;
  };
  run(model, data, k1, 1e-9, [&](long k, const State& st) {
    EXPECT_EQ(data.contact.contacts.size(), bottom) << "step " << k;
    if (k == k0) {
      at_start = st;
      v0 = mean_vx(st);
    }
    if (k > k0) {
      const auto& cd = data.contact;
      for (int c = 0; c < cd.contacts.size(); ++c) {
        if (cd.modes[c] == contact::Mode::breaking) continue;
        const int i = cd.contacts.contacts[c].nodes[0];
        r.slip = std::max(r.slip, std::abs(st.x[3 * i] - at_start.x[3 * i]));
      }
    }
    if (k == k1) r.acceleration = (mean_vx(st) - v0) / 0.4;
  });
  return r;
}

}  // namespace bdf2_contact_validation

using namespace bdf2_contact_validation;

// The thresholds are those of implicit Euler's test (validation_contact.cpp): stuck
// below 1e-7 m of slip, the sliding acceleration within 1%.
TEST(Bdf2ContactValidation, InclineSticksAt25AndSlidesAt30Degrees) {
  EXPECT_LT(incline(25, 0.5).slip, 1e-7);  // tan 25 = 0.466 < 0.5
  const double a = 30 * kDeg;
  const double expected = kG * (std::sin(a) - 0.5 * std::cos(a));
  const InclineResult r = incline(30, 0.5);
  std::cout << "incline 30 degrees, bdf2: acceleration " << r.acceleration << " m/s^2, analytic " << expected << "\n";
  EXPECT_NEAR(r.acceleration, expected, 0.01 * expected);
}

// The beam of validation_contact.cpp on two box supports, damped to rest (alpha 20).
// At rest v_{n+1} = v_n = v_{n-1} = 0, so the BDF2 step reads h' (P + f_int + H^T
// lambda) = 0, and sum f_int = 0: the normal forces equal the weight (to the NCP's
// tolerance, 1e-6 relative as for implicit Euler).
TEST(Bdf2ContactValidation, BeamOnTwoSupportsCarriesItsWeight) {
  test::BodySpec spec;
  spec.young = 5e5;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 20;
  const double dt = 0.01;
  Model model = test::make_model(test::box_mesh(20, 2, 2, 0.5, 0.05, 0.05), spec, Vec3(0, 0, -kG), dt, 300);
  model.step.integrator = IntegratorKind::bdf2;
  test::ContactSpec cs;
  cs.mu = 0.3;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model,
                       {test::box(Vec3(0.03, 0.025, -0.05), Vec3(0.02, 0.05, 0.05), "left"),
                        test::box(Vec3(0.47, 0.025, -0.05), Vec3(0.02, 0.05, 0.05), "right")},
                       cs);
  Data data(model);
  double min_gap = 0;
  const State end = run(model, data, 300, 1e-9, [&](long, const State&) {
    for (const auto& c : data.contact.contacts.contacts) min_gap = std::min(min_gap, c.gap);
  });
  double weight = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) weight -= model.fem.gravity_force[3 * i + 2];
  double fz = 0;
  const auto& cd = data.contact;
  for (int i = 0; i < cd.contacts.size(); ++i) fz += (cd.contacts.contacts[i].frame * cd.lambda.segment<3>(3 * i))[2];
  EXPECT_GT(cd.contacts.size(), 0);
  EXPECT_NEAR(fz, weight, 1e-6 * weight);
  EXPECT_LT(end.v.cwiseAbs().maxCoeff(), 1e-6);
  // Gaps are measured at x^ (the BDF2 extrapolation), which can sit slightly below
  // the plane the last step reached; the step drives phi(x^) + h' v_N to zero, so the
  // penetration left is of the order of the solver tolerance.
  EXPECT_GT(min_gap, -1e-9);
}

// An impact: the cube dropped from 1 cm at rest onto a frictionless plane, damped as
// the sphere of validation_contact.cpp (E 1e5, alpha 10, beta 0.02: its elastic
// rebound is damped within the contact time, so the exact motion does not bounce
// either). The velocity-level NCP makes the contact inelastic. The criteria, as there:
//   - no bounce: once the normal forces carry it, they stay > 0 at every later step;
//   - no sinking: no node below the plane by more than 1e-9 m (the NCP drives
//     phi(x^) + h' v_N to 0 to its tolerance, 1e-10 relative);
//   - it comes to rest: kinetic energy at 0.8 s below 1e-3 of that at the impact.
// (The energy is not checked for monotone decrease step by step: BDF2 is dissipative
// in its own two-step norm, not in the energy of each frame.)
TEST(Bdf2ContactValidation, DroppedCubeDoesNotBounceOrSink) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_stiffness = 0.02;
  spec.rayleigh_mass = 10;
  const double dt = 2e-3;
  Model model = test::make_model(test::box_mesh(3, 3, 3, 0.1, 0.1, 0.1), spec, Vec3(0, 0, -kG), dt, 400);
  model.step.integrator = IntegratorKind::bdf2;
  for (int i = 0; i < model.fem.num_nodes; ++i) model.initial.x[3 * i + 2] += 0.01;
  test::ContactSpec cs;
  cs.mu = 0;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  Data data(model);
  auto kinetic = [&](const State& s) { return 0.5 * s.v.dot(model.fem.mass_diagonal.cwiseProduct(s.v)); };
  bool carried = false;
  long airborne_after = 0;
  double impact_kinetic = 0;
  const State end = run(model, data, 400, 1e-9, [&](long k, const State& s) {
    const auto& cd = data.contact;
    double fn = 0;
    for (int c = 0; c < cd.contacts.size(); ++c) fn += cd.lambda[3 * c + 2];
    if (!carried && fn > 0) {
      carried = true;
      impact_kinetic = kinetic(s);
    } else if (carried) {
      airborne_after += !(fn > 0);
    }
    double z = 1;
    for (int i = 0; i < model.fem.num_nodes; ++i) z = std::min(z, s.x[3 * i + 2]);
    EXPECT_GT(z, -1e-9) << "step " << k;
  });
  ASSERT_TRUE(carried);
  EXPECT_EQ(airborne_after, 0);
  EXPECT_LT(kinetic(end), 1e-3 * impact_kinetic);
}

// A soft impact restarts BDF2 (2026-12-04, rsoft; docs/method.md "BDF2", *Impacts: BDF2
// restarts*): a soft slab (0.1 x 0.1 x 0.01 m, 6 x 6 x 1 boxes of tets, E 1e5, nu 0.45,
// 1050 kg/m^3, alpha 20, beta 1e-3) dropped 1 mm at rest onto a plane (mu 0.5), dt 2 ms:
// it lands at ~0.137 m/s during step 8. Without the restart BDF2 bounced here (the slab
// of configs/slab_on_plane.yaml: +0.057 m/s the step after the landing, 0.92 mm rise).
// With it the landing step and the one after are implicit Euler steps (a few restarted
// steps, BDF2 otherwise). The criteria:
//   - no bounce: after the landing the mass-weighted mean v_z never exceeds 5 mm/s, the
//     restart threshold V = 0.01 margin / dt (the slab's own compression wave under the
//     sudden load moves its centroid up by less: measured below 1 mm/s under implicit
//     Euler on configs/slab_on_plane.yaml; the bounce was 0.057 m/s, 11 times V);
//   - no rise: the centroid never rises above its resting height (that at the end) by
//     more than 2% of the drop, 20 um (the bounce rose 0.92 mm = 92% of it); the lift
//     BDF2 leaves below the threshold is ~1.7 V dt = 17 um (bdf2.cpp);
//   - no sinking below the plane beyond 1e-9 m (as the cube above);
//   - at rest (300 steps, 0.6 s: alpha 20 damps the rigid mode as e^{-10 t}, 2.5e-3) the
//     normal forces carry the weight to 1e-6 relative (the NCP tolerance 1e-10 and
//     the residual velocity: |v| < 1e-6 asserted, as the beam above);
//   - the restarted steps are few: 1 to 4 of 300 (BDF2 does not degenerate).
// Measured (2026-12-04): landing at step 8, restarts at steps 8, 9, 10, max mean v_z
// 6.7e-4 m/s, rise 1.2e-7 m; with the restart switched off (a temporary switch) the same
// scene gave +0.030 m/s and 8.4e-5 m, failing the first two criteria.
TEST(Bdf2ContactValidation, SoftSlabDroppedOneMillimetreLandsWithoutBouncing) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.poisson = 0.45;
  spec.density = 1050;
  spec.rayleigh_mass = 20;
  spec.rayleigh_stiffness = 1e-3;
  const double dt = 2e-3;
  const long T = 300;
  Model model = test::make_model(test::box_mesh(6, 6, 1, 0.1, 0.1, 0.01), spec, Vec3(0, 0, -kG), dt, T);
  model.step.integrator = IntegratorKind::bdf2;
  for (int i = 0; i < model.fem.num_nodes; ++i) model.initial.x[3 * i + 2] += 1e-3;
  test::ContactSpec cs;
  cs.mu = 0.5;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  Data data(model);
  const VecX& m = model.fem.mass_diagonal;
  const double total = m.sum() / 3;
  auto mean_z = [&](const VecX& q) {
    double s = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i) s += m[3 * i + 2] * q[3 * i + 2];
    return s / total;
  };
  long landing = 0, restarted = 0;
  double max_up = -1, max_z_after = -1, min_z = 1;
  std::vector<long> restarts;
  const State end = run(model, data, T, 1e-9, [&](long k, const State& s) {
    if (k > 1 && data.history_weight == 0) {
      ++restarted;
      restarts.push_back(k);
    }
    double fn = 0;
    for (int c = 0; c < data.contact.contacts.size(); ++c) fn += data.contact.lambda[3 * c + 2];
    if (!landing && fn > 0) landing = k;
    if (landing) {
      max_up = std::max(max_up, mean_z(s.v));
      max_z_after = std::max(max_z_after, mean_z(s.x));
    }
    for (int i = 0; i < model.fem.num_nodes; ++i) min_z = std::min(min_z, s.x[3 * i + 2]);
  });
  double weight = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) weight -= model.fem.gravity_force[3 * i + 2];
  double fz = 0;
  const auto& cd = data.contact;
  for (int i = 0; i < cd.contacts.size(); ++i) fz += (cd.contacts.contacts[i].frame * cd.lambda.segment<3>(3 * i))[2];
  const double rest = mean_z(end.x), V = 0.01 * model.contact.detection.margin / dt;
  std::cout << "soft slab dropped 1 mm: landing at step " << landing << ", restarted steps " << restarted << " (";
  for (long k : restarts) std::cout << " " << k;
  std::cout << " ), max mean v_z after it " << max_up << " m/s, max rise above rest " << max_z_after - rest
            << " m, lowest node " << min_z << " m, normal force " << fz << " of weight " << weight << "\n";
  ASSERT_GT(landing, 0);
  EXPECT_LT(max_up, V);
  EXPECT_LT(max_z_after - rest, 2e-5);
  EXPECT_GT(min_z, -1e-9);
  EXPECT_NEAR(fz, weight, 1e-6 * weight);
  EXPECT_LT(end.v.cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_GE(restarted, 1);
  EXPECT_LE(restarted, 4);
}
