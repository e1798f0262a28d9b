// The cheap psd_projection of fem/element_psd.hpp against the 12 x 12 eigendecomposition
// it replaces (material::clamp_negative_eigenvalues, PsdProjectionDerivative<12>), and
// its derivative against central finite differences, for every law, on random rest
// tetrahedra and deformations from stretched to compressed by half (where the element
// Hessians of all three nonlinear laws are indefinite), and on synthetic tangents with
// near-repeated eigenvalues.
#include <softdiff/fem/element_psd.hpp>
#include <softdiff/material/material.hpp>

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <Eigen/QR>
#include <random>

using namespace softdiff;
using material::Law;

namespace element_psd_test {

struct Tet {
  Eigen::Matrix<double, 3, 4> G;  // shape gradients
  double V;
};

// A random, well-shaped rest tet with edges ~ 1 cm.
Tet random_tet(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Mat3 Dm = Mat3::Identity();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) Dm(i, j) += 0.25 * u(rng);
  if (Dm.determinant() < 0) Dm.col(0).swap(Dm.col(1));
  Dm *= 0.01;
  return {fem::shape_gradients(Dm.inverse()), Dm.determinant() / 6};
}

// F = R diag(s) R2 with stretches in [0.5, 1.3]: compressed elements make the tangent
// of every nonlinear law indefinite.
Mat3 random_F(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1), s(0.5, 1.3);
  const Mat3 R = Eigen::AngleAxisd(3 * u(rng), Vec3(u(rng), u(rng), u(rng)).normalized()).toRotationMatrix();
  const Mat3 R2 = Eigen::AngleAxisd(3 * u(rng), Vec3(u(rng), u(rng), u(rng)).normalized()).toRotationMatrix();
  return R * Vec3(s(rng), s(rng), s(rng)).asDiagonal() * R2;
}

Mat12 unprojected(const Mat9& C, const Tet& t) {
  Mat12 K;
  fem::element_stiffness_from_tangent(C, t.G, t.V, K);
  return K;
}

Mat12 projected(const Mat9& C, const Tet& t) {
  Mat12 K;
  fem::tet4_stiffness(C, t.G, t.V, true, K);
  return K;
}

// The matrix of w -> D(V B^T dC B) w (12 x 12), column by column.
Mat12 derivative_matrix(const fem::Tet4PsdDerivative& D, const Mat9& dC, double V) {
  Mat12 M;
  for (int k = 0; k < 12; ++k) M.col(k) = D.apply_tangent(dC, V, Vec12::Unit(k));
  return M;
}

Mat9 random_symmetric9(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Mat9 A;
  for (int i = 0; i < 81; ++i) A(i) = n(rng);
  return A + A.transpose();
}

const material::Lame kLame = material::lame_from_young_poisson(1e5, 0.4);

class ElementPsd : public ::testing::TestWithParam<Law> {};

// The projection is the old one: Q_b (C^)+ Q_b^T = (K_e)+ to round-off (1e-12 of |K_e|:
// both are eigendecompositions, accurate to ~1e-15 |K_e| per eigenpair, reconstructed
// with sums of 9 or 12 products), and the skip (tangent_is_psd) leaves K_e alone exactly
// when the old projection would (to the same round-off). Both paths must occur.
TEST_P(ElementPsd, EqualsTheTwelveByTwelveProjection) {
  const Law law = GetParam();
  std::mt19937 rng(11);
  int skipped = 0, clamped = 0;
  for (int k = 0; k < 200; ++k) {
    const Tet t = random_tet(rng);
    const Mat3 F = random_F(rng);
    Mat3 P;
    Mat9 C;
    ASSERT_TRUE(material::stress(law, F, kLame, P, &C));
    const Mat12 K = unprojected(C, t);
    Mat12 K_old = K;
    material::clamp_negative_eigenvalues(K_old);
    const Mat12 K_new = projected(C, t);
    EXPECT_LE((K_new - K_old).norm(), 1e-12 * K.norm()) << "sample " << k;
    if (fem::tangent_is_psd(C)) {
      ++skipped;
      EXPECT_EQ(K_new, K) << "sample " << k;  // kept bit for bit
    } else {
      ++clamped;
      // For a linear tet the skip is exact: a C that fails has K_e indefinite.
      EXPECT_LT(Eigen::SelfAdjointEigenSolver<Mat12>(K).eigenvalues()(0), 0.0) << "sample " << k;
    }
  }
  if (law == Law::linear) {
    EXPECT_EQ(clamped, 0);  // constant, PSD C: always skipped
  } else {
    EXPECT_GT(skipped, 0);
    EXPECT_GT(clamped, 0);
  }
}

// d(K~)[dF] against central differences of the projected K_e along F + h dF, and the
// reduced derivative against the 12 x 12 Daleckii-Krein derivative. Step h = 1e-6 on
// |F| ~ 1 (dF of norm 1): truncation O(h^2) ~ 1e-12 relative, round-off eps |K| / h ~
// 1e-10 relative: tolerance 1e-6. Samples whose tangent has an eigenvalue within 1e-4 of
// its spectral radius from 0 are left out: the projection is not differentiable where
// an eigenvalue crosses 0, and a crossing between F - h dF and F + h dF would break the
// difference.
TEST_P(ElementPsd, DerivativeMatchesFiniteDifferences) {
  const Law law = GetParam();
  if (law == Law::linear) GTEST_SKIP() << "linear: constant C, nothing to differentiate";
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> u(-1, 1);
  int tested = 0;
  for (int k = 0; k < 100 && tested < 20; ++k) {
    const Tet t = random_tet(rng);
    const Mat3 F = random_F(rng);
    Mat3 dF;
    for (int i = 0; i < 9; ++i) dF(i) = u(rng);
    dF /= dF.norm();
    Mat3 P;
    Mat9 C;
    ASSERT_TRUE(material::stress(law, F, kLame, P, &C));
    fem::Tet4PsdDerivative D;
    D.compute(C, t.G, t.V);
    if (D.identity) continue;
    const Mat9 C_hat = fem::tet4_reduced_stiffness(C, t.G * fem::tet4_deformation_basis(), t.V);
    const auto l = Eigen::SelfAdjointEigenSolver<Mat9>(C_hat).eigenvalues();
    if (l.cwiseAbs().minCoeff() < 1e-4 * l.cwiseAbs().maxCoeff()) continue;
    ++tested;
    Mat9 dC;
    ASSERT_TRUE(material::stress_hessian_directional(law, F, kLame, dF, dC));
    const Mat12 dK = derivative_matrix(D, dC, t.V);
    const double h = 1e-6;
    Mat9 Cp, Cm;
    ASSERT_TRUE(material::stress(law, F + h * dF, kLame, P, &Cp));
    ASSERT_TRUE(material::stress(law, F - h * dF, kLame, P, &Cm));
    const Mat12 dK_fd = (projected(Cp, t) - projected(Cm, t)) / (2 * h);
    ASSERT_GT(dK.norm(), 0);
    EXPECT_LE((dK - dK_fd).norm(), 1e-6 * dK.norm()) << "sample " << k;
    // The same as the 12 x 12 derivative (round-off: 1e-10 relative).
    material::PsdProjectionDerivative<12> D12;
    D12.compute(unprojected(C, t));
    ASSERT_FALSE(D12.identity);
    EXPECT_LE((dK - D12.apply(unprojected(dC, t))).norm(), 1e-10 * dK.norm()) << "sample " << k;
    // The reverse product: <S^, V dC> = y^T D(V B^T dC B) w for random y, w.
    Vec12 y, w;
    for (int i = 0; i < 12; ++i) y(i) = u(rng), w(i) = u(rng);
    const double lhs = t.V * D.reverse(y, w).cwiseProduct(dC).sum(), rhs = y.dot(dK * w);
    EXPECT_NEAR(lhs, rhs, 1e-12 * dK.norm() * y.norm() * w.norm()) << "sample " << k;
  }
  EXPECT_GE(tested, 10);
}

INSTANTIATE_TEST_SUITE_P(Laws, ElementPsd,
                         ::testing::Values(Law::corotational, Law::stvk, Law::neo_hookean, Law::linear),
                         [](const ::testing::TestParamInfo<Law>& p) { return std::string(material::law_name(p.param)); });

// Near-repeated and exactly repeated eigenvalues. Ties do not hurt: f = max(., 0) is
// linear on each side of 0, so Gamma_ij = (f(l_i) - f(l_j)) / (l_i - l_j) is exactly 1
// for two positive eigenvalues and 0 for two negative ones however close they are (the
// quotient of two equal floating-point numbers is 1), and psd.hpp's tie rule (|l_i - l_j|
// <= 1e-12 of the spectral radius: (f'(l_i) + f'(l_j)) / 2) gives the same 1 and 0. The
// projection is analytic where no eigenvalue is near 0, so the central difference is
// valid; a pair straddling 0 (here -0.2 and 0.3) gets the quotient 0.3 / 0.5. C is built
// from a prescribed C^ = U diag(l) U^T: C = B_H^-T C^ B_H^-1 / V. Step h = 1e-6 on |dC^| = 1
// against eigenvalues of size 1: the same truncation/round-off balance as above, and the
// gap at 0 (0.2) is far above h.
TEST(ElementPsdTies, DerivativeWithRepeatedEigenvaluesMatchesFiniteDifferences) {
  std::mt19937 rng(13);
  const Tet t = random_tet(rng);
  const Mat3 H = t.G * fem::tet4_deformation_basis();
  Mat9 B_H = Mat9::Zero();  // B_H(3j+i, 3l+i) = H(j, l)
  for (int j = 0; j < 3; ++j)
    for (int l = 0; l < 3; ++l)
      for (int i = 0; i < 3; ++i) B_H(3 * j + i, 3 * l + i) = H(j, l);
  const Mat9 B_H_inv = B_H.inverse();
  Eigen::Matrix<double, 9, 1> l;
  l << -3, -3 * (1 + 1e-9), -3, -0.2, 0.3, 1, 1, 1 + 1e-13, 5 * (1 + 1e-8);
  const Mat9 U = Eigen::HouseholderQR<Mat9>(random_symmetric9(rng)).householderQ();
  const Mat9 C_hat = U * l.asDiagonal() * U.transpose();
  Mat9 C = B_H_inv.transpose() * C_hat * B_H_inv / t.V;
  C = (0.5 * (C + C.transpose())).eval();
  ASSERT_FALSE(fem::tangent_is_psd(C));
  fem::Tet4PsdDerivative D;
  D.compute(C, t.G, t.V);
  ASSERT_FALSE(D.identity);
  Mat9 dC_hat = random_symmetric9(rng);
  dC_hat /= dC_hat.norm();
  Mat9 dC = B_H_inv.transpose() * dC_hat * B_H_inv / t.V;
  dC = (0.5 * (dC + dC.transpose())).eval();
  const Mat12 dK = derivative_matrix(D, dC, t.V);
  const double h = 1e-6;
  const Mat12 dK_fd = (projected(C + h * dC, t) - projected(C - h * dC, t)) / (2 * h);
  ASSERT_GT(dK.norm(), 0);
  EXPECT_LE((dK - dK_fd).norm(), 1e-6 * dK.norm());
  // The projection itself: eigenvalues max(l, 0) (1e-12 of the spectral radius 5).
  const auto lp = Eigen::SelfAdjointEigenSolver<Mat12>(projected(C, t)).eigenvalues();
  EXPECT_GE(lp(0), -1e-12 * 5);
  EXPECT_NEAR(lp.sum(), 0.3 + 1 + 1 + 1 + 1e-13 + 5 * (1 + 1e-8), 1e-11 * 5);
}

// The linear law's tangent (constant, positive definite for 0 < nu < 0.5) and every
// law's at rest (the twist modes' zero eigenvalues: semidefinite) pass the skip.
TEST(ElementPsdSkip, RestAndLinearTangentsAreKept) {
  for (Law law : {Law::corotational, Law::stvk, Law::neo_hookean, Law::linear}) {
    Mat3 P;
    Mat9 C;
    ASSERT_TRUE(material::stress(law, Mat3::Identity(), kLame, P, &C));
    EXPECT_TRUE(fem::tangent_is_psd(C)) << material::law_name(law);
  }
  // and a clearly negative eigenvalue fails it.
  Mat9 C = Mat9::Identity();
  C(4, 4) = -1e-9;
  EXPECT_FALSE(fem::tangent_is_psd(C));
}

}  // namespace element_psd_test
