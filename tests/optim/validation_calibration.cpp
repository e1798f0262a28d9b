// Material identification (optim/calibration.hpp) on a small cantilever beam under
// gravity (8 x 2 x 2 cells, 192 tets, corotational, undamped, 30 steps of 10 ms: about
// three quarters of its first period), the target made with known parameters:
//   - young from 0.2x and 5x the truth, all frames, to 1e-6 relative in <= 20
//     iterations; poisson likewise, with truth 0.04: this clamped beam's deflection
//     under gravity is not monotone in poisson (largest at about 0.23: the clamp's
//     restraint of the lateral contraction stiffens it at small poisson, volumetric
//     locking of linear tets at large), so a truth of 0.09 leaves a second, spurious
//     minimum near 0.31 that a guess of 0.45 falls into (measured; docs/method.md
//     "Calibration"); 0.008 and 0.2 lie on the same branch as 0.04;
//   - the beam resting on two supports (contact, friction 0.5) from guesses that keep
//     the contacts, to 1e-4;
//   - 8 markers with 0.1 mm Gaussian noise: over repeated draws, the estimates scatter
//     as the linearized noise propagation predicts (sigma_E = 0.1 mm / |dr/dE|): each
//     within 4 predicted standard deviations and their sample standard deviation within
//     a factor 2.5 of the prediction (10 draws: the sample std of 10 normal draws lies
//     within [0.4, 1.6] of the true one with probability > 0.99);
//   - the residual's Jacobian against central differences (relative step 1e-6 in E:
//     truncation ~1e-12, round-off ~1e-10 relative of the Newton-free linear step).
#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/diff/parameters.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/optim/calibration.hpp>
#include <support/contact.hpp>
#include <optim/calibration_targets.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;

namespace {

constexpr long kSteps = 30;

Model beam(double young = 1e6, double poisson = 0.3) {
  test::BodySpec spec;
  spec.law = material::Law::corotational;
  spec.young = young;
  spec.poisson = poisson;
  spec.density = 1000;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  return test::make_model(test::box_mesh(8, 2, 2, 0.2, 0.02, 0.02), spec, Vec3(0, 0, -9.81), 0.01, kSteps);
}

// The beam on two supports: no clamp, resting on two boxes under its ends.
Model supported_beam(double young = 1e5) {
  test::BodySpec spec;
  spec.law = material::Law::corotational;
  spec.young = young;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 1.0;
  Model model = test::make_model(test::box_mesh(8, 2, 2, 0.2, 0.02, 0.02), spec, Vec3(0, 0, -9.81), 0.01, kSteps);
  auto support = [](const char* name, double x) {
    collision::Obstacle o;
    o.name = name;
    o.kind = collision::ShapeKind::box;
    o.center = Vec3(x, 0.01, -0.01);
    o.half_extents = Vec3(0.02, 0.03, 0.01);
    collision::prepare(o);
    return o;
  };
  test::ContactSpec cs;
  cs.mu = 0.5;
  cs.margin = 1e-3;
  test::enable_contact(model, {support("left", 0.01), support("right", 0.19)}, cs);
  return model;
}

void recovers(Parameter kind, double truth, double tolerance) {
  const Model truth_model = kind == Parameter::young ? beam(truth) : beam(1e6, truth);
  const optim::CalibrationTarget target = test::every_frame_target(truth_model, kSteps);
  for (const double factor : {0.2, 5.0}) {
    const optim::CalibrationResult r =
        optim::calibrate(truth_model, {{kind, 0}}, {factor * truth}, target, optim::CalibrationOptions{});
    EXPECT_TRUE(r.converged) << r.stop_reason;
    EXPECT_LE(r.iterations, 20) << parameter_name(kind) << " from " << factor << "x";
    EXPECT_NEAR(r.values[0] / truth, 1.0, tolerance) << parameter_name(kind) << " from " << factor << "x: " << r.values[0]
                                                     << " after " << r.iterations << " iterations (" << r.stop_reason << ")";
    // The cost decreased monotonically (the trust region accepts only decreases).
    for (std::size_t i = 1; i < r.history.size(); ++i) EXPECT_LE(r.history[i].cost, r.history[i - 1].cost);
  }
}

TEST(Calibration, RecoversYoungFromFarGuesses) { recovers(Parameter::young, 1e6, 1e-6); }
TEST(Calibration, RecoversPoissonFromFarGuesses) { recovers(Parameter::poisson, 0.04, 1e-6); }

// The step test (docs/method.md "Calibration", "Stopping"): the last iteration's trial
// step is below xtol and is not run, so the calibration ends with as many runs as
// iterations (the initial guess's run, one per iteration but the last), and its answer
// is MINPACK's own to the step test's bound: against the same calibration with xtol = 0
// (no step test and no trust-region test: MINPACK runs every trial, down to the cost's
// round-off floor and machine precision), young agrees to 1e-9 relative (the bound
// xtol |z| = 1e-10 log(1e6) = 1.4e-9 on the skipped step in z = log E, as
// dE / E = dz).
TEST(Calibration, StopsBeforeATrialStepBelowXtol) {
  const Model truth_model = beam(1e6);
  const optim::CalibrationTarget target = test::every_frame_target(truth_model, kSteps);
  const optim::CalibrationResult r =
      optim::calibrate(truth_model, {{Parameter::young, 0}}, {0.5e6}, target, optim::CalibrationOptions{});
  ASSERT_TRUE(r.converged) << r.stop_reason;
  EXPECT_EQ(r.stop_reason, "relative step below xtol (the trial was not run)");
  ASSERT_GE(r.history.size(), 2u);
  const auto& last = r.history.back();
  EXPECT_EQ(last.evaluations, r.history[r.history.size() - 2].evaluations) << "the last iteration ran a trial";
  EXPECT_EQ(last.rejected, 0);
  EXPECT_EQ(r.evaluations, r.iterations + r.rejected);
  optim::CalibrationOptions full;
  full.xtol = 0;
  const optim::CalibrationResult m =
      optim::calibrate(truth_model, {{Parameter::young, 0}}, {0.5e6}, target, full);
  EXPECT_GT(m.evaluations, r.evaluations);
  EXPECT_NEAR(r.values[0] / m.values[0], 1.0, 1e-9) << r.values[0] << " against " << m.values[0] << " (" << m.stop_reason
                                                    << ")";
}

TEST(Calibration, ResidualJacobianAgainstCentralDifferences) {
  const Model m = beam();
  const optim::CalibrationTarget target = test::every_frame_target(beam(1.3e6), kSteps);
  VecX r, rp, rm;
  MatX J, Jp, Jm;
  optim::residual(m, {{Parameter::young, 0}}, {1e6}, target, false, r, J);
  const double h = 1e-6 * 1e6;
  optim::residual(m, {{Parameter::young, 0}}, {1e6 + h}, target, false, rp, Jp);
  optim::residual(m, {{Parameter::young, 0}}, {1e6 - h}, target, false, rm, Jm);
  const VecX fd = (rp - rm) / (2 * h);
  EXPECT_LE((J.col(0) - fd).norm(), 1e-6 * fd.norm());
}

TEST(Calibration, ThroughContactFromGuessesThatKeepTheContacts) {
  const double truth = 1e5;
  const Model truth_model = supported_beam(truth);
  const optim::CalibrationTarget target = test::every_frame_target(truth_model, kSteps);
  {
    Data data(truth_model);
    State s = truth_model.initial, next;
    for (long k = 1; k <= 3; ++k) {
      ASSERT_TRUE(integrator::implicit_euler_step(truth_model, data, s, next, k).ok());
      std::swap(s, next);
    }
    ASSERT_GT(data.contact.contacts.size(), 0);  // the supports carry the beam
  }
  for (const double factor : {0.5, 2.0}) {
    const optim::CalibrationResult r =
        optim::calibrate(truth_model, {{Parameter::young, 0}}, {factor * truth}, target, optim::CalibrationOptions{});
    EXPECT_TRUE(r.converged) << r.stop_reason;
    EXPECT_NEAR(r.values[0] / truth, 1.0, 1e-4) << "from " << factor << "x: " << r.values[0] << " (" << r.stop_reason << ")";
  }
}

TEST(Calibration, MarkersWithNoiseScatterAsThePredictedAccuracy) {
  const double truth = 1e6, noise = 1e-4;
  const Model m = beam(truth);
  // 8 markers: nodes along the beam's top edge (embedded with weight 1 on one node),
  // observed at every frame.
  optim::CalibrationTarget clean;
  std::vector<int> nodes;
  for (int i = 0; i < m.fem.num_nodes && nodes.size() < 8; ++i) {
    const Vec3 X = m.fem.X.col(i);
    if (X.x() > 0.01 && std::abs(X.y()) < 1e-9 && std::abs(X.z() - 0.02) < 1e-9) nodes.push_back(i);
  }
  ASSERT_EQ(nodes.size(), 8u);
  for (int n : nodes) {
    optim::Marker mk;
    mk.name = "m" + std::to_string(n);
    mk.point.nodes = {n, n, n, n, -1, -1, -1, -1, -1, -1};
    mk.point.w.setZero();
    mk.point.w[0] = 1;
    mk.point.count = 4;
    clean.markers.push_back(mk);
  }
  const optim::CalibrationTarget states = test::every_frame_target(m, kSteps);
  clean.frames = states.frames;
  for (int f = 0; f < static_cast<int>(clean.frames.size()); ++f)
    for (int k = 0; k < 8; ++k)
      clean.observations.push_back({f, k, Vec3(states.states[static_cast<std::size_t>(f)].segment<3>(3 * nodes[static_cast<std::size_t>(k)]))});
  // Predicted standard deviation of the estimate: noise / |dr/dE| at the truth.
  VecX r;
  MatX J;
  optim::residual(m, {{Parameter::young, 0}}, {truth}, clean, false, r, J);
  ASSERT_LT(r.norm(), 1e-12);
  const double sigma_E = noise / J.col(0).norm();
  std::mt19937 rng(42);
  std::normal_distribution<double> normal(0, noise);
  constexpr int kDraws = 10;
  double sum2 = 0;
  for (int d = 0; d < kDraws; ++d) {
    optim::CalibrationTarget noisy = clean;
    for (auto& o : noisy.observations)
      for (int c = 0; c < 3; ++c) o.position[c] += normal(rng);
    const optim::CalibrationResult res =
        optim::calibrate(m, {{Parameter::young, 0}}, {0.5 * truth}, noisy, optim::CalibrationOptions{});
    EXPECT_TRUE(res.converged) << res.stop_reason;
    const double err = res.values[0] - truth;
    EXPECT_LE(std::abs(err), 4 * sigma_E) << "draw " << d << ": " << res.values[0] << " (sigma " << sigma_E << ")";
    sum2 += err * err;
  }
  const double sample_sigma = std::sqrt(sum2 / kDraws);
  EXPECT_GT(sample_sigma, sigma_E / 2.5);
  EXPECT_LT(sample_sigma, sigma_E * 2.5);
  std::printf("markers: predicted sigma_E %.4g (relative %.3g), sample %.4g over %d draws\n", sigma_E, sigma_E / truth,
              sample_sigma, kDraws);
}

}  // namespace
