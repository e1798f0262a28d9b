// Calibration with a rigidified part (issue 21; optim/calibration.hpp, docs/method.md
// "Calibration", "Rigidified parts"): the clamped beam with its last quarter rigidified
// (free: it falls with the bending beam under gravity; rigidify_optim_scene.hpp), the
// target made with known values and observed only at two markers on the part (each the
// mean of three of the part's nodes: they move with it). The beam's young and its
// Rayleigh mass coefficient are identified together from guesses on both sides.
#include <optim/rigidify_optim_scene.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>  // time_step
#include <softdiff/optim/calibration.hpp>

#include <gtest/gtest.h>

#include <iostream>
#include <utility>

using namespace softdiff;

namespace calibration_rigidify_validation {

using namespace softdiff::test::rigidify_optim;

// Truth: young 1e6 Pa, rayleigh_mass 0.5 1/s. The part's fall over 10 steps of 10 ms
// depends on the beam's bending stiffness (young) and on the damping of its motion
// (rayleigh_mass), both identifiable from the part's pose alone.
// Tolerance: no contact (the Jacobian's columns match central differences to 1.4e-7 ..
// 5.4e-6, the differences' own accuracy, test_rigidify_optim.cpp); noise-free markers: the
// minimum is the truth, Levenberg-Marquardt converges quadratically to it. Measured
// (2026-12-03): young to 5e-11 and 3e-12, rayleigh_mass to 2.9e-9 and 3.4e-8, in 7 and 16
// iterations (7 and 21 runs). Tolerance 1e-5 relative.
TEST(CalibrationRigidify, RecoversYoungAndDampingFromMarkersOnThePart) {
  const long steps = 10;
  const Model truth = load_beam_with_tip("validation", false, steps);
  ASSERT_EQ(truth.rigidify.size(), 1);
  const std::vector<int> part = part_nodes(truth);
  optim::CalibrationTarget target;
  for (const auto& nodes : {std::vector<int>{part[0], part[1], part[2]},
                            std::vector<int>{part[part.size() - 1], part[part.size() - 2], part[part.size() / 2]}}) {
    optim::Marker mk;
    mk.name = "m" + std::to_string(target.markers.size());
    mk.point.count = 3;
    for (int a = 0; a < 3; ++a) {
      mk.point.nodes[static_cast<std::size_t>(a)] = nodes[static_cast<std::size_t>(a)];
      mk.point.w[a] = 1.0 / 3;
    }
    target.markers.push_back(mk);
  }
  Data data(truth);
  State s = truth.initial, next = truth.initial;
  for (long k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::time_step(truth, data, s, nullptr, next, k);
    ASSERT_TRUE(st.ok()) << describe(truth, st);
    std::swap(s, next);
    target.frames.push_back(k);
    for (int j = 0; j < 2; ++j)
      target.observations.push_back({static_cast<int>(k - 1), j, target.markers[static_cast<std::size_t>(j)].point.position(s.x)});
  }
  // The part moves: its markers fall by millimetres (not a test of a static target).
  ASSERT_GT((target.observations.back().position - target.markers[1].point.position(truth.initial.x)).norm(), 1e-4);
  const std::vector<ParameterId> ids = {{Parameter::young, 0}, {Parameter::rayleigh_mass, 0}};
  for (const auto& [fy, fd] : {std::pair{0.6, 2.0}, std::pair{1.6, 0.4}}) {
    SCOPED_TRACE("from " + std::to_string(fy) + " young, " + std::to_string(fd) + " rayleigh_mass");
    const optim::CalibrationResult r = optim::calibrate(truth, ids, {fy * 1e6, fd * 0.5}, target, optim::CalibrationOptions{});
    std::cout << "from (" << fy << ", " << fd << "): young - 1 " << r.values[0] / 1e6 - 1 << ", rayleigh_mass - 1 "
              << r.values[1] / 0.5 - 1 << " after " << r.iterations << " iterations, " << r.evaluations << " runs, cost "
              << r.cost << " (" << r.stop_reason << ")\n";
    EXPECT_TRUE(r.converged) << r.stop_reason;
    EXPECT_NEAR(r.values[0] / 1e6, 1.0, 1e-5);
    EXPECT_NEAR(r.values[1] / 0.5, 1.0, 1e-5);
  }
}

}  // namespace calibration_rigidify_validation
