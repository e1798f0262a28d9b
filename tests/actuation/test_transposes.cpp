// The reverse-mode products of the actuators (used by the step's VJP):
//   (d(H_a^T lambda)/dx)^T y   against the forward derivative (dot-product test), for a
//   cable, a closed cavity, an open face, a translation and a rotation servo;
//   H_a y                      against the dense gradient H_a^T.
#include <softdiff/actuation/actuation_model.hpp>

#include "helpers.hpp"

#include <gtest/gtest.h>
#include <random>

using namespace softdiff;
using namespace softdiff::actuation;

namespace {

VecX random_vector(Eigen::Index n, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  VecX v(n);
  for (Eigen::Index k = 0; k < n; ++k) v[k] = u(rng);
  return v;
}

TEST(ActuatorTransposes, ForceDerivativeTransposeMatchesForwardAndJacobianProduct) {
  std::mt19937 rng(31);
  const test::ActuatorSet set(rng, Vec3(1, 2, -0.5));
  ASSERT_TRUE(set.ok);
  Cavity open_face;
  ASSERT_TRUE(Cavity::create(set.mesh.X, set.mesh.tets, test::box_boundary(set.mesh, set.size, 4), 0, open_face).ok());
  ASSERT_FALSE(open_face.closed());
  Servo rotation;
  ASSERT_TRUE(Servo::rotation({0, 1, 2, 5, 7}, Vec3(0.2, 0.1, 1), Vec3(0.01, 0.01, 0), set.x_rest, rotation).ok());
  ActuationModel model;
  model.actuators.resize(5);
  model.actuators[0].kind = set.cable;
  model.actuators[1].kind = set.cavity;
  model.actuators[2].kind = open_face;
  model.actuators[3].kind = set.translation;
  model.actuators[4].kind = rotation;
  const VecX lambda = (VecX(5) << 0.7, 250.0, -120.0, -0.3, 0.05).finished();
  const VecX x = test::deform(set.x_rest, 1e-3, rng);
  const Eigen::Index n = x.size();
  for (std::size_t a = 0; a < model.actuators.size(); ++a) {
    const VecX dx = random_vector(n, rng), y = random_vector(n, rng);
    VecX J_dx = VecX::Zero(n), JT_y = VecX::Zero(n);
    model.actuators[a].add_force_derivative(x, lambda[static_cast<Eigen::Index>(a)], dx, J_dx);
    model.actuators[a].add_force_derivative_transpose(x, lambda[static_cast<Eigen::Index>(a)], y, JT_y);
    const double lhs = y.dot(J_dx), rhs = JT_y.dot(dx);
    if (a != 3) {  // a translation servo's H_a is constant
      EXPECT_GT(std::abs(lhs), 0) << "actuator " << a;
    }
    EXPECT_NEAR(lhs, rhs, 1e-12 * (y.norm() * J_dx.norm() + JT_y.norm() * dx.norm())) << "actuator " << a;
  }
  // Sums over actuators with a scale, and H_a y against the dense H_a^T.
  const VecX dx = random_vector(n, rng), y = random_vector(n, rng);
  VecX J_dx = VecX::Zero(n), JT_y = VecX::Zero(n);
  model.add_force_derivatives(x, lambda, dx, 0.3, J_dx);
  model.add_force_derivatives_transpose(x, lambda, y, 0.3, JT_y);
  EXPECT_NEAR(y.dot(J_dx), JT_y.dot(dx), 1e-12 * (y.norm() * J_dx.norm() + JT_y.norm() * dx.norm()));
  VecX Hy = VecX::Zero(5);
  model.add_jacobian_product(x, y, 2.0, Hy);
  for (Eigen::Index a = 0; a < 5; ++a) {
    VecX e = VecX::Zero(5);
    e[a] = 1;
    VecX H = VecX::Zero(n);
    model.add_forces(x, e, 1.0, H);
    EXPECT_NEAR(Hy[a], 2.0 * H.dot(y), 1e-12 * H.norm() * y.norm()) << "actuator " << a;
  }
}

}  // namespace
