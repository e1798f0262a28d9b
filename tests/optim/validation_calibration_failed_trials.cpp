// Calibration (optim/calibration.hpp) from guesses so stiff that a Levenberg-Marquardt
// trial step asks for a beam soft enough to invert: the 192-tet cantilever of
// validation_calibration.cpp with the material and damping of configs/calib_beam.yaml
// (corotational, young 1e6, poisson 0.45, density 1070, Rayleigh 0.1 and 0.001; 30
// steps of 10 ms), from 10x and 100x its young. From 10x the first trial asks for
// young ~1.6e3 and inverts an element at step 28 (measured; before failed trials
// were rejected, the calibration stopped there with that error). A trial whose run
// fails is rejected like a step that raises the cost (the damping grows, the step
// shrinks) and the calibration goes on to the truth, to the tolerance of
// validation_calibration.cpp (1e-6 relative). Checks that a trial did fail (the path
// is exercised), that failures are counted among the rejections, and that the
// accepted costs decrease.
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/optim/calibration.hpp>
#include <optim/calibration_targets.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

using namespace softdiff;

namespace {

constexpr long kFailedTrialSteps = 30;

Model stiff_guess_beam(double young) {
  test::BodySpec spec;
  spec.law = material::Law::corotational;
  spec.young = young;
  spec.poisson = 0.45;
  spec.density = 1070;
  spec.rayleigh_mass = 0.1;
  spec.rayleigh_stiffness = 0.001;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  return test::make_model(test::box_mesh(8, 2, 2, 0.2, 0.02, 0.02), spec, Vec3(0, 0, -9.81), 0.01, kFailedTrialSteps);
}

TEST(CalibrationFailedTrials, RecoversYoungFromTenAndAHundredTimesTheTruth) {
  const double truth = 1e6;
  const Model model = stiff_guess_beam(truth);
  const optim::CalibrationTarget target = test::every_frame_target(model, kFailedTrialSteps);
  int failed = 0;
  for (const double factor : {10.0, 100.0}) {
    const optim::CalibrationResult r =
        optim::calibrate(model, {{Parameter::young, 0}}, {factor * truth}, target, optim::CalibrationOptions{});
    EXPECT_TRUE(r.converged) << "from " << factor << "x: " << r.stop_reason;
    EXPECT_NEAR(r.values[0] / truth, 1.0, 1e-6) << "from " << factor << "x: " << r.values[0] << " after "
                                               << r.iterations << " iterations (" << r.stop_reason << ")";
    int rejected = 0, failed_here = 0;
    for (std::size_t i = 1; i < r.history.size(); ++i) {
      EXPECT_LE(r.history[i].cost, r.history[i - 1].cost);
      EXPECT_LE(r.history[i].failed, r.history[i].rejected);
      rejected += r.history[i].rejected;
      failed_here += r.history[i].failed;
      if (r.history[i].failed > 0) {
        EXPECT_FALSE(r.history[i].last_failure.empty());
      }
    }
    EXPECT_EQ(rejected, r.rejected);
    EXPECT_EQ(failed_here, r.failed);
    std::printf("from %gx: young %.10g after %d iterations, %d runs, %d trials rejected (%d failed to run)\n", factor,
                r.values[0], r.iterations, r.evaluations, r.rejected, r.failed);
    failed += r.failed;
  }
  EXPECT_GE(failed, 1) << "no trial failed: this case does not exercise the rejection of failed runs";
}

}  // namespace
