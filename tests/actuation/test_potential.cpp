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
  const Vec3 size(0.03, 0.02, 0.02);
  const mesh::TetMesh m = test::jittered_box(3, 2, 2, size[0], size[1], size[2], 0.2, rng);
  const PointLocator locator(m.X, m.tets);
  std::vector<EmbeddedPoint> points;
  for (const Vec3& p : {Vec3(0.001, 0.01, 0.01), Vec3(0.015, 0.017, 0.006), Vec3(0.029, 0.003, 0.009)})
    points.push_back(embedded_point(locator.locate(p).embedding, m.tets, 0));
  const VecX x_rest = test::flatten(m.X);
  ActuationModel model;
  model.actuators.resize(3);
  model.actuators[0].kind = Cable(points, Vec3(-0.01, 0.01, 0.01));
  Cavity cavity;
  ASSERT_TRUE(Cavity::create(m.X, m.tets, test::box_boundary(m, size), 0, cavity).ok());
  ASSERT_TRUE(cavity.closed());
  model.actuators[1].kind = cavity;
  Servo servo;
  ASSERT_TRUE(Servo::translation({0, 1, 2, 5}, Vec3(1, 2, -0.5), x_rest, servo).ok());
  model.actuators[2].kind = servo;
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
