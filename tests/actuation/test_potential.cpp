// The actuators' potential (used by the static solver's line search): for
// conservative actuators (cable, closed cavity, translation servo) the forces are
// minus its gradient: -dU/dx = sum_a lambda_a H_a^T, against central differences.
#include <softdiff/actuation/actuation_model.hpp>
#include <support/fd.hpp>

#include "helpers.hpp"

#include <gtest/gtest.h>
#include <random>

using namespace softdiff;
using namespace softdiff::actuation;

namespace {

TEST(Potential, ForcesAreMinusItsGradientForConservativeActuators) {
  std::mt19937 rng(12);
  const test::ActuatorSet set(rng, Vec3(1, 2, -0.5));
  ASSERT_TRUE(set.ok);
  ASSERT_TRUE(set.cavity.closed());
  const VecX& x_rest = set.x_rest;
  ActuationModel model;
  model.actuators.resize(3);
  model.actuators[0].kind = set.cable;
  model.actuators[1].kind = set.cavity;
  model.actuators[2].kind = set.translation;
  ASSERT_TRUE(model.conservative());

  const VecX x = test::deform(x_rest, 1e-3, rng);
  const VecX lambda = (VecX(3) << 0.7, 250.0, -0.3).finished();
  VecX f = VecX::Zero(x.size());
  model.add_forces(x, lambda, 1.0, f);
  // Step 1e-8 m = 1e-6 of the element size (see support/fd.hpp).
  const VecX g = test::fd_gradient([&](const VecX& y) { return model.potential(y, lambda); }, x, 1e-8);
  const auto c = test::compare(f, -g);
  EXPECT_LT(c.rel_error, 1e-6) << c.str();

  ActuationModel rotation;
  rotation.actuators.resize(1);
  Servo r;
  ASSERT_TRUE(Servo::rotation({0, 1, 2, 5}, Vec3::UnitZ(), Vec3(0.01, 0.01, 0), x_rest, r).ok());
  rotation.actuators[0].kind = r;
  EXPECT_FALSE(rotation.conservative());
}

}  // namespace
