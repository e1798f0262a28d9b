// Calibration with rigid bodies (issue 21; optim/calibration.hpp, docs/method.md
// "Calibration"): a rigid cube landing on a soft slab (rigid_calibration_scene.hpp), the
// target made with known values, matched by the cube's pose only (its position and
// orientation at every frame; no soft node observed). The slab's young and the cube's
// mass are identified together, from guesses on both sides of the truth.
#include <optim/rigid_calibration_scene.hpp>

#include <gtest/gtest.h>

#include <iostream>

using namespace softdiff;

namespace calibration_rigid_validation {

using namespace softdiff::test::rigid_calibration;

// Truth: young 5e4 Pa, the cube's mass 4 g (500 kg/m^3). Both set the landing: how deep
// the cube sinks (m g / k) and how fast the slab stops it (sqrt(k / m), overdamped), so
// both are identifiable from the cube's pose alone.
// Tolerance: the runs carry a noise of about 1e-11 m from the contact solve (its 1e-12
// tolerance; test_calibration_rigid.cpp), against sensitivities of the cube's position of
// 6.5e-5 m (young) and 4e-5 m (mass) per unit of log: an error of about 1e-11 / 4e-5 =
// 2.5e-7 in the log of either; measured 5e-8 .. 1.2e-7 (8 and 6 iterations, 11 and 10
// runs); tolerance 1e-5 relative.
TEST(CalibrationRigid, RecoversTheSlabsYoungAndTheCubesMassFromTheCubesPose) {
  const double young = 5e4;
  const Model truth = cube_on_slab(young);
  const double mass = truth.rigid[0].mass;
  ASSERT_NEAR(mass, 0.004, 1e-15);
  const optim::CalibrationTarget target = poses_target(truth, false, {0});
  ASSERT_EQ(target.residual_size(), 6 * kCubeSteps);
  for (const auto& [fy, fm] : {std::pair{0.5, 1.5}, std::pair{2.0, 0.7}}) {
    SCOPED_TRACE("from " + std::to_string(fy) + " young, " + std::to_string(fm) + " mass");
    const optim::CalibrationResult r =
        optim::calibrate(truth, {{Parameter::young, 0}}, {{0, 0}}, {fy * young, fm * mass}, target, optim::CalibrationOptions{});
    std::cout << "from (" << fy << ", " << fm << "): young - 1 " << r.values[0] / young - 1 << ", mass - 1 " << r.values[1] / mass - 1 << " after "
              << r.iterations << " iterations, " << r.evaluations << " runs, cost " << r.cost << " (" << r.stop_reason << ")\n";
    EXPECT_TRUE(r.converged) << r.stop_reason;
    EXPECT_NEAR(r.values[0] / young, 1.0, 1e-5);
    EXPECT_NEAR(r.values[1] / mass, 1.0, 1e-5);
  }
}

}  // namespace calibration_rigid_validation
