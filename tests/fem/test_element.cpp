// Element-level checks of forces and stiffness for every law (issue: "Forces vs finite
// differences of the energy, and K vs finite differences of the forces, for each law on
// random deformed tets; zero force and unchanged energy under rigid motions").
#include <softdiff/fem/assembly.hpp>
#include <support/fd.hpp>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <random>

using namespace softdiff;
using material::Law;

namespace {

struct Sample {
  Mat3 Dm_inv;
  double volume;
  Eigen::Matrix<double, 3, 4> x;  // deformed positions
  double edge;                    // rest edge scale
};

// A random, well-shaped rest tet (edge ~ 1 cm) and a random deformation: a random
// rotation times a stretch with det F in about [0.6, 1.6], plus a translation.
Sample random_sample(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Sample s;
  Eigen::Matrix<double, 3, 4> X;
  X << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1;
  for (int a = 0; a < 4; ++a)
    for (int c = 0; c < 3; ++c) X(c, a) += 0.25 * u(rng);
  X *= 0.01;
  Mat3 Dm;
  for (int k = 0; k < 3; ++k) Dm.col(k) = X.col(k + 1) - X.col(0);
  if (Dm.determinant() < 0) {
    X.col(1).swap(X.col(2));
    for (int k = 0; k < 3; ++k) Dm.col(k) = X.col(k + 1) - X.col(0);
  }
  s.Dm_inv = Dm.inverse();
  s.volume = Dm.determinant() / 6;
  s.edge = 0.01;
  Mat3 stretch = Mat3::Identity();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) stretch(i, j) += 0.25 * u(rng);
  if (stretch.determinant() < 0.6) stretch += 0.5 * Mat3::Identity();
  const Mat3 R = Eigen::AngleAxisd(3 * u(rng), Vec3(u(rng), u(rng), u(rng)).normalized()).toRotationMatrix();
  const Vec3 t(u(rng), u(rng), u(rng));
  for (int a = 0; a < 4; ++a) s.x.col(a) = R * stretch * X.col(a) + 0.01 * t;
  return s;
}

struct Eval {
  double energy;
  Vec12 f;
  Mat12 K;
  bool ok;
};

Eval eval(Law law, const Sample& s, const Eigen::Matrix<double, 3, 4>& x, bool psd = false) {
  const auto lame = material::lame_from_young_poisson(1e5, 0.35);
  Eval r;
  Mat3 F, R;
  r.ok = fem::element_forces_stiffness(law, lame, s.volume, s.Dm_inv, x, psd, F, r.f, &r.K, &r.energy, &R);
  return r;
}

VecX flat(const Eigen::Matrix<double, 3, 4>& x) { return Eigen::Map<const VecX>(x.data(), 12); }
Eigen::Matrix<double, 3, 4> unflat(const VecX& v) { return Eigen::Map<const Eigen::Matrix<double, 3, 4>>(v.data()); }

class ElementLaw : public ::testing::TestWithParam<Law> {};    // rotation-invariant laws
class ElementLawFd : public ::testing::TestWithParam<Law> {};  // every law, incl. linear

TEST_P(ElementLawFd, ForcesAreMinusEnergyGradient) {
  std::mt19937 rng(7);
  for (int sample = 0; sample < 10; ++sample) {
    const Sample s = random_sample(rng);
    const Eval e = eval(GetParam(), s, s.x);
    ASSERT_TRUE(e.ok);
    // Step: 1e-6 of the edge length (see support/fd.hpp).
    const VecX g = test::fd_gradient([&](const VecX& x) { return eval(GetParam(), s, unflat(x)).energy; }, flat(s.x),
                                     1e-6 * s.edge);
    const auto c = test::compare(e.f, -g);
    EXPECT_LT(c.rel_error, 1e-6) << material::law_name(GetParam()) << " sample " << sample << ": " << c.str();
  }
}

TEST_P(ElementLawFd, StiffnessIsMinusForceJacobian) {
  std::mt19937 rng(11);
  for (int sample = 0; sample < 10; ++sample) {
    const Sample s = random_sample(rng);
    const Eval e = eval(GetParam(), s, s.x);
    ASSERT_TRUE(e.ok);
    const MatX J =
        test::fd_jacobian([&](const VecX& x) -> VecX { return eval(GetParam(), s, unflat(x)).f; }, flat(s.x), 1e-6 * s.edge);
    const auto c = test::compare(e.K, -J);
    EXPECT_LT(c.rel_error, 1e-6) << material::law_name(GetParam()) << " sample " << sample << ": " << c.str();
    EXPECT_LT((e.K - e.K.transpose()).norm(), 1e-10 * e.K.norm());
  }
}

TEST_P(ElementLaw, RigidMotionLeavesEnergyAndForcesInvariant) {
  std::mt19937 rng(3);
  const Sample s = random_sample(rng);
  const Eval e0 = eval(GetParam(), s, s.x);
  const Mat3 Q = Eigen::AngleAxisd(2.1, Vec3(1, -2, 0.5).normalized()).toRotationMatrix();
  Eigen::Matrix<double, 3, 4> xr;
  for (int a = 0; a < 4; ++a) xr.col(a) = Q * s.x.col(a) + Vec3(0.3, -0.2, 0.1);
  const Eval e1 = eval(GetParam(), s, xr);
  EXPECT_NEAR(e1.energy, e0.energy, 1e-12 * std::abs(e0.energy));
  for (int a = 0; a < 4; ++a)  // forces rotate with the body
    EXPECT_LT((e1.f.segment<3>(3 * a) - Q * e0.f.segment<3>(3 * a)).norm(), 1e-10 * e0.f.norm());
  // At rest (any rigid placement): zero energy, zero force; K annihilates rigid motions.
  Eigen::Matrix<double, 3, 4> X;
  const Mat3 Dm = s.Dm_inv.inverse();
  X.col(0).setZero();
  for (int k = 0; k < 3; ++k) X.col(k + 1) = Dm.col(k);
  for (int a = 0; a < 4; ++a) X.col(a) = Q * X.col(a) + Vec3(1, 2, 3);
  const Eval rest = eval(GetParam(), s, X);
  EXPECT_NEAR(rest.energy, 0, 1e-14);
  EXPECT_LT(rest.f.norm(), 1e-10 * e0.f.norm());
  Vec12 translation, rotation;
  for (int a = 0; a < 4; ++a) {
    translation.segment<3>(3 * a) = Vec3(0.3, -1, 2);
    rotation.segment<3>(3 * a) = Vec3(0.2, 1, -0.4).cross(X.col(a));
  }
  EXPECT_LT((rest.K * translation).norm(), 1e-10 * rest.K.norm() * translation.norm());
  EXPECT_LT((rest.K * rotation).norm(), 1e-10 * rest.K.norm() * rotation.norm());
}

TEST_P(ElementLaw, PsdProjectionGivesPositiveSemidefiniteStiffness) {
  // Strong compression makes the exact element Hessian indefinite for these laws.
  std::mt19937 rng(5);
  Sample s = random_sample(rng);
  const Mat3 Dm = s.Dm_inv.inverse();
  Eigen::Matrix<double, 3, 4> x;
  x.col(0).setZero();
  const Mat3 squash = Vec3(0.3, 1.0, 1.0).asDiagonal();
  for (int k = 0; k < 3; ++k) x.col(k + 1) = squash * Dm.col(k);
  const Eval projected = eval(GetParam(), s, x, true);
  ASSERT_TRUE(projected.ok);
  Eigen::SelfAdjointEigenSolver<Mat12> eig(projected.K);
  EXPECT_GE(eig.eigenvalues().minCoeff(), -1e-10 * eig.eigenvalues().cwiseAbs().maxCoeff());
}

INSTANTIATE_TEST_SUITE_P(AllLaws, ElementLawFd,
                         ::testing::Values(Law::corotational, Law::stvk, Law::neo_hookean, Law::linear),
                         [](const auto& p) { return std::string(material::law_name(p.param)); });
INSTANTIATE_TEST_SUITE_P(AllLaws, ElementLaw, ::testing::Values(Law::corotational, Law::stvk, Law::neo_hookean),
                         [](const auto& p) { return std::string(material::law_name(p.param)); });

}  // namespace
