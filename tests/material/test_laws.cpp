// Tests of the constitutive laws (lib/softdiff/material): psi, P = dpsi/dF, dP/dF and
// the directional derivative of dP/dF, checked against central finite differences,
// against Eigen's AutoDiff (first order for P, nested for dP/dF), and against physical
// invariants (frame indifference, rest state, linearization = linear elasticity,
// major symmetry); plus the PSD projection and the absence of heap allocation.

// Heap check (test NoHeap below): Eigen's allocation hook, live in this translation unit
// even in Release builds (NDEBUG would turn eigen_assert into a no-op), reporting by
// exception. Only this file sees these macros; the library is compiled without them.
// GCC 12 reports false -W(maybe-)uninitialized warnings inside its own AVX-512 intrinsics
// (avx512fintrin.h, _mm512_extractf64x4_pd / _mm512_insertf64x4; GCC PR 105593, fixed
// in GCC 13) whenever Eigen uses 8-wide double packets under -march=native. Including
// <immintrin.h> first with the warning off silences it for the intrinsics' own lines
// only; our code keeps the warning.
#include <softdiff/core/avx512_gcc12.hpp>  // first: see there
#include <stdexcept>
#define EIGEN_RUNTIME_NO_MALLOC
#define eigen_assert(x)                                                          \
  do {                                                                           \
    if (!(x)) throw std::runtime_error("Eigen assertion failed: " #x);           \
  } while (0)

#include <softdiff/material/corotational.hpp>
#include <softdiff/material/material.hpp>
#include <softdiff/material/neo_hookean.hpp>
#include <softdiff/material/psd.hpp>
#include <softdiff/material/linear.hpp>
#include <softdiff/material/stvk.hpp>

#include <gtest/gtest.h>
#include <unsupported/Eigen/AutoDiff>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace {

using namespace softdiff;
using namespace softdiff::material;

using AD1 = Eigen::AutoDiffScalar<Vec9>;                          // first derivatives
using AD2 = Eigen::AutoDiffScalar<Eigen::Matrix<AD1, 9, 1>>;      // second derivatives

// Moderately compressible (nu = 0.3) and nearly incompressible (nu = 0.49) rubber-like
// parameters; the relative errors below do not depend on the overall scale.
const Lame kLame = lame_from_young_poisson(1.0e5, 0.3);
const Lame kLameStiff = lame_from_young_poisson(1.0e5, 0.49);

constexpr Law kLaws[] = {Law::corotational, Law::stvk, Law::neo_hookean};

// ---------------------------------------------------------------------------
// Worst relative errors seen, printed at the end of the run (for the report).
std::map<std::string, double>& worst() {
  static std::map<std::string, double> w;
  return w;
}
void record(const std::string& what, double err) {
  double& w = worst()[what];
  w = std::max(w, err);
}
class PrintWorst : public ::testing::Environment {
 public:
  void TearDown() override {
    std::printf("Worst relative errors measured:\n");
    for (const auto& [k, v] : worst()) std::printf("  %-52s %.2e\n", k.c_str(), v);
  }
};
const auto* const kPrintWorst = ::testing::AddGlobalTestEnvironment(new PrintWorst);

// max |a - ref| / max |ref|, and a message naming the worst entry (row, col, a, ref).
template <class A, class B>
double rel_error(const A& a, const B& ref, std::string* where = nullptr) {
  const double scale = ref.cwiseAbs().maxCoeff();
  Eigen::Index r = 0, c = 0;
  const double diff = (a - ref).cwiseAbs().maxCoeff(&r, &c);
  if (where != nullptr) {
    std::ostringstream os;
    os << "worst entry (" << r << ", " << c << "): got " << a(r, c) << ", expected " << ref(r, c)
       << ", scale " << scale;
    *where = os.str();
  }
  return scale > 0 ? diff / scale : diff;
}

// ---------------------------------------------------------------------------
// Samples
Mat3 random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::Quaterniond q(n(rng), n(rng), n(rng), n(rng));
  q.normalize();
  return q.toRotationMatrix();
}

Mat3 axis_angle(const Vec3& axis, double angle) { return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix(); }

struct Sample {
  std::string name;
  Mat3 F;
};

// Deformation gradients for the derivative checks, fixed seed:
// - 6 general ones, F = R1 diag(s) R2^T with distinct stretches and det F drawn in [0.5, 1.8];
// - 2 near the identity (I + 1e-3 X), 2 with large rotations (2.5 to 3.1 rad) of a stretch;
// - with_inverted: 2 inverted ones (det F < 0, |sigma_3| < sigma_2, sigma_2 + sigma_3 well
//   away from 0), for the corotational law, which is defined there.
std::vector<Sample> samples(bool with_inverted) {
  std::mt19937 rng(20240531);
  std::uniform_real_distribution<double> stretch(0.6, 1.5), det(0.5, 1.8), angle(2.5, 3.1);
  std::normal_distribution<double> n(0.0, 1.0);
  std::vector<Sample> out;
  for (int k = 0; k < 6; ++k) {
    Vec3 s(stretch(rng), stretch(rng), stretch(rng));
    s *= std::cbrt(det(rng) / s.prod());
    out.push_back({"random " + std::to_string(k), random_rotation(rng) * s.asDiagonal() * random_rotation(rng).transpose()});
  }
  for (int k = 0; k < 2; ++k) {
    Mat3 X;
    for (int i = 0; i < 9; ++i) X(i) = n(rng);
    out.push_back({"near identity " + std::to_string(k), Mat3::Identity() + 1e-3 * X});
  }
  for (int k = 0; k < 2; ++k) {
    Mat3 X;
    for (int i = 0; i < 9; ++i) X(i) = n(rng);
    const Mat3 stretch_part = Mat3::Identity() + 0.1 * (X + X.transpose());
    const Vec3 axis(n(rng), n(rng), n(rng));
    out.push_back({"large rotation " + std::to_string(k), axis_angle(axis, angle(rng)) * stretch_part});
  }
  if (with_inverted) {
    out.push_back({"inverted 0", random_rotation(rng) * Vec3(1.3, 1.0, -0.6).asDiagonal() * random_rotation(rng).transpose()});
    out.push_back({"inverted 1", random_rotation(rng) * Vec3(0.9, 0.8, -0.3).asDiagonal() * random_rotation(rng).transpose()});
  }
  return out;
}

Mat3 random_matrix(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Mat3 X;
  for (int i = 0; i < 9; ++i) X(i) = n(rng);
  return X;
}

// ---------------------------------------------------------------------------
// Evaluation helpers
template <class T>
T psi_t(Law law, const Eigen::Matrix<T, 3, 3>& F, const Lame& l) {
  switch (law) {
    case Law::corotational: return corotational::psi(F, l.mu, l.lambda);
    case Law::stvk: return stvk::psi(F, l.mu, l.lambda);
    case Law::neo_hookean: return neo_hookean::psi(F, l.mu, l.lambda);
    case Law::linear: return linear::psi(F, l.mu, l.lambda);  // tested in test_linear.cpp
  }
  return T(std::numeric_limits<double>::quiet_NaN());
}

Mat3 P_of(Law law, const Mat3& F, const Lame& l) {
  Mat3 P;
  EXPECT_TRUE(stress(law, F, l, P, nullptr));
  return P;
}
Mat9 dP_dF_of(Law law, const Mat3& F, const Lame& l) {
  Mat3 P;
  Mat9 H;
  EXPECT_TRUE(stress(law, F, l, P, &H));
  return H;
}
Mat9 directional_of(Law law, const Mat3& F, const Lame& l, const Mat3& dF) {
  Mat9 T;
  EXPECT_TRUE(stress_hessian_directional(law, F, l, dF, T));
  return T;
}

// Central differences, step h_b = 1e-6 * max(|F_b|, 1) (F is dimensionless, natural size 1).
// Truncation error is h^2 |f'''| / 6 ~ 1e-12 relative; round-off is ~ eps |f| / h ~ 1e-10
// relative (eps = 2.2e-16); the optimum h ~ eps^(1/3) ~ 6e-6 is close. Both are far
// below the 1e-6 acceptance threshold, and an error in a formula shows up as O(1).
double fd_step(double x) { return 1e-6 * std::max(std::abs(x), 1.0); }

template <class Fn>  // Fn: Mat3 -> Eigen matrix with N coefficients; returns N x 9
auto fd_jacobian(const Fn& f, const Mat3& F) {
  using Out = decltype(f(F));
  constexpr int N = Out::SizeAtCompileTime;
  Eigen::Matrix<double, N, 9> J;
  for (int b = 0; b < 9; ++b) {
    const double h = fd_step(F(b));
    Mat3 Fp = F, Fm = F;
    Fp(b) += h;
    Fm(b) -= h;
    const Out d = (f(Fp) - f(Fm)) / (2.0 * h);
    J.col(b) = Eigen::Map<const Eigen::Matrix<double, N, 1>>(d.data());
  }
  return J;
}

Vec9 fd_gradient_of_psi(Law law, const Mat3& F, const Lame& l) {
  Vec9 g;
  for (int b = 0; b < 9; ++b) {
    const double h = fd_step(F(b));
    Mat3 Fp = F, Fm = F;
    Fp(b) += h;
    Fm(b) -= h;
    g(b) = (psi(law, Fp, l) - psi(law, Fm, l)) / (2.0 * h);
  }
  return g;
}

// AutoDiff gradient of psi (first-order scalars) and Hessian (nested scalars).
Vec9 ad_gradient(Law law, const Mat3& F, const Lame& l) {
  Eigen::Matrix<AD1, 3, 3> X;
  for (int b = 0; b < 9; ++b) X(b) = AD1(F(b), 9, b);
  return psi_t(law, X, l).derivatives();
}

Mat9 ad_hessian(Law law, const Mat3& F, const Lame& l, Vec9* gradient = nullptr) {
  Eigen::Matrix<AD2, 3, 3> X;
  for (int b = 0; b < 9; ++b) {
    Eigen::Matrix<AD1, 9, 1> d;
    for (int c = 0; c < 9; ++c) d(c) = AD1(c == b ? 1.0 : 0.0, Vec9::Zero());
    X(b) = AD2(AD1(F(b), 9, b), d);
  }
  const AD2 v = psi_t(law, X, l);
  Mat9 H;
  for (int a = 0; a < 9; ++a) H.row(a) = v.derivatives()(a).derivatives().transpose();
  if (gradient != nullptr) *gradient = v.value().derivatives();
  return H;
}

// vec(Q X) = blockdiag(Q, Q, Q) vec(X).
Mat9 left_rotation(const Mat3& Q) {
  Mat9 K = Mat9::Zero();
  for (int j = 0; j < 3; ++j) K.block<3, 3>(3 * j, 3 * j) = Q;
  return K;
}

// Linear elasticity: C_(ij)(kl) = mu (d_ik d_jl + d_il d_jk) + lambda d_ij d_kl.
Mat9 linear_elasticity(const Lame& l) {
  Mat9 C;
  auto d = [](int a, int b) { return a == b ? 1.0 : 0.0; };
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 3; ++i)
      for (int m = 0; m < 3; ++m)
        for (int k = 0; k < 3; ++k)
          C(3 * j + i, 3 * m + k) = l.mu * (d(i, k) * d(j, m) + d(i, m) * d(j, k)) + l.lambda * d(i, j) * d(k, m);
  return C;
}

std::string tag(Law law, const std::string& what) { return std::string(law_name(law)) + ": " + what; }

// ---------------------------------------------------------------------------
class Laws : public ::testing::TestWithParam<Law> {
 protected:
  Law law() const { return GetParam(); }
  // The corotational law is defined (and smooth) for inverted F; the others are not tested there.
  std::vector<Sample> fd_samples() const { return samples(law() == Law::corotational); }
};

TEST_P(Laws, StressMatchesFiniteDifferencesOfPsi) {
  for (const Lame& l : {kLame, kLameStiff})
    for (const auto& s : fd_samples()) {
      SCOPED_TRACE(s.name);
      const Mat3 P = P_of(law(), s.F, l);
      const Vec9 fd = fd_gradient_of_psi(law(), s.F, l);
      std::string where;
      const double err = rel_error(detail::vec(P), fd, &where);
      record(tag(law(), "P vs FD of psi"), err);
      EXPECT_LT(err, 1e-6) << where;
    }
}

TEST_P(Laws, StressDerivativeMatchesFiniteDifferencesOfStress) {
  for (const Lame& l : {kLame, kLameStiff})
    for (const auto& s : fd_samples()) {
      SCOPED_TRACE(s.name);
      const Mat9 H = dP_dF_of(law(), s.F, l);
      const Mat9 fd = fd_jacobian([&](const Mat3& X) { return P_of(law(), X, l); }, s.F);
      std::string where;
      const double err = rel_error(H, fd, &where);
      record(tag(law(), "dP/dF vs FD of P"), err);
      EXPECT_LT(err, 1e-6) << where;
    }
}

TEST_P(Laws, MatchesAutoDiff) {
  // det F > 0 samples only: the AutoDiff corotational energy uses a Newton polar iteration.
  for (const Lame& l : {kLame, kLameStiff})
    for (const auto& s : samples(false)) {
      SCOPED_TRACE(s.name);
      Mat3 P;
      Mat9 H;
      ASSERT_TRUE(stress(law(), s.F, l, P, &H));
      // The energy itself (SVD vs Newton iteration for corotational).
      const double psi_ad = psi_t<AD1>(law(), Eigen::Matrix<AD1, 3, 3>(s.F.cast<AD1>()), l).value();
      // Both values are exact up to round-off in the polar factor R (an SVD against a
      // Newton iteration for corotational), which moves psi by about P : dF with |dF| ~
      // eps |F|: the bound is 100 eps |P| |F|, plus 1e-12 relative. (A bound of 1e-12 |psi|
      // alone sat at the round-off floor near identity, where psi ~ |strain|^2 is much
      // smaller than |P| |F| ~ |strain|: it passed with FMA and failed by 3% without.)
      const double scale = 100 * std::numeric_limits<double>::epsilon() * P.norm() * s.F.norm();
      EXPECT_NEAR(psi_ad, psi(law(), s.F, l), scale + 1e-12 * std::max(1.0, std::abs(psi_ad)));
      std::string where;
      const double err_P = rel_error(detail::vec(P), ad_gradient(law(), s.F, l), &where);
      record(tag(law(), "P vs AutoDiff"), err_P);
      EXPECT_LT(err_P, 1e-11) << where;
      Vec9 g2;
      const Mat9 H_ad = ad_hessian(law(), s.F, l, &g2);
      const double err_H = rel_error(H, H_ad, &where);
      record(tag(law(), "dP/dF vs nested AutoDiff"), err_H);
      EXPECT_LT(err_H, 1e-10) << where;
      EXPECT_LT(rel_error(detail::vec(P), g2), 1e-11);
    }
}

TEST_P(Laws, StressDerivativeIsSymmetric) {
  for (const auto& s : fd_samples()) {
    SCOPED_TRACE(s.name);
    const Mat9 H = dP_dF_of(law(), s.F, kLame);
    const double err = rel_error(H, Mat9(H.transpose()));
    record(tag(law(), "dP/dF asymmetry"), err);
    EXPECT_LT(err, 1e-14);
  }
}

TEST_P(Laws, FrameIndifference) {
  std::mt19937 rng(7);
  for (const auto& s : fd_samples()) {
    SCOPED_TRACE(s.name);
    const Mat3 P = P_of(law(), s.F, kLame);
    const Mat9 H = dP_dF_of(law(), s.F, kLame);
    for (int k = 0; k < 3; ++k) {
      const Mat3 Q = random_rotation(rng);
      const Mat3 QF = Q * s.F;
      // psi relative to the energy scale (mu + lambda) ||F||^2: near the identity psi is
      // tiny while Q F is far from I, so psi(Q F) carries round-off ~ eps (mu + lambda).
      const double e0 = std::abs(psi(law(), QF, kLame) - psi(law(), s.F, kLame)) /
                        ((kLame.mu + kLame.lambda) * s.F.squaredNorm());
      EXPECT_LT(e0, 1e-13);
      const double e1 = rel_error(P_of(law(), QF, kLame), Mat3(Q * P));
      EXPECT_LT(e1, 1e-11);
      const Mat9 K = left_rotation(Q);
      const double e2 = rel_error(dP_dF_of(law(), QF, kLame), Mat9(K * H * K.transpose()));
      EXPECT_LT(e2, 1e-12);
      record(tag(law(), "frame indifference psi (energy scale)"), e0);
      record(tag(law(), "frame indifference P"), e1);
      record(tag(law(), "frame indifference dP/dF"), e2);
    }
  }
}

TEST_P(Laws, RestStateAndLinearization) {
  for (const Lame& l : {kLame, kLameStiff}) {
    const Mat3 I = Mat3::Identity();
    EXPECT_NEAR(psi(law(), I, l), 0.0, 1e-16 * l.lambda);
    Mat3 P;
    Mat9 H;
    ASSERT_TRUE(stress(law(), I, l, P, &H));
    EXPECT_LT(P.cwiseAbs().maxCoeff(), 1e-15 * l.lambda);
    std::string where;
    const double err = rel_error(H, linear_elasticity(l), &where);
    record(tag(law(), "dP/dF(I) vs linear elasticity"), err);
    EXPECT_LT(err, 1e-14) << where;
    // Rigid motion: zero energy and stress at any rotation.
    const Mat3 Q = axis_angle(Vec3(1, 2, 3), 2.9);
    EXPECT_NEAR(psi(law(), Q, l), 0.0, 1e-12 * l.lambda);
    EXPECT_LT(P_of(law(), Q, l).cwiseAbs().maxCoeff(), 1e-12 * l.lambda);
  }
}

TEST_P(Laws, DirectionalDerivativeOfStressDerivative) {
  std::mt19937 rng(11);
  for (const Lame& l : {kLame, kLameStiff}) {
    std::vector<Sample> all = fd_samples();
    all.push_back({"identity", Mat3::Identity()});  // repeated singular values
    for (const auto& s : all) {
      SCOPED_TRACE(s.name);
      const Mat3 E1 = random_matrix(rng).normalized(), E2 = random_matrix(rng).normalized();
      const Mat9 T1 = directional_of(law(), s.F, l, E1);
      // Central differences of dP/dF along E1 (same step rationale as fd_step).
      const double h = 1e-6 * std::max(1.0, s.F.cwiseAbs().maxCoeff());
      const Mat9 fd = (dP_dF_of(law(), s.F + h * E1, l) - dP_dF_of(law(), s.F - h * E1, l)) / (2.0 * h);
      std::string where;
      const double err = rel_error(T1, fd, &where);
      record(tag(law(), "d(dP/dF)[dF] vs FD of dP/dF"), err);
      EXPECT_LT(err, 1e-6) << where;
      // A third derivative: symmetric, and T[E1] vec(E2) = T[E2] vec(E1).
      EXPECT_LT(rel_error(T1, Mat9(T1.transpose())), 1e-13);
      const Mat9 T2 = directional_of(law(), s.F, l, E2);
      const Vec9 a = T1 * detail::vec(E2), b = T2 * detail::vec(E1);
      EXPECT_LT(rel_error(a, b), 1e-12);
    }
  }
}

// stress_second_derivative (d^2P[E, W] from the polar decomposition stress() kept, the
// product the forward sensitivities use): against central differences of dP/dF along E
// applied to vec(W) (the step and tolerance of DirectionalDerivativeOfStressDerivative:
// truncation ~1e-12, round-off ~1e-10 relative, a formula error O(1)), and against the
// 9x9 directional derivative times vec(W), which it must equal up to rounding (1e-12).
TEST_P(Laws, SecondDerivativeOfStressFromTheKeptPolarDecomposition) {
  std::mt19937 rng(12);
  for (const Lame& l : {kLame, kLameStiff}) {
    std::vector<Sample> all = fd_samples();
    all.push_back({"identity", Mat3::Identity()});  // repeated singular values
    for (const auto& s : all) {
      SCOPED_TRACE(s.name);
      const Mat3 E = random_matrix(rng).normalized(), W = random_matrix(rng).normalized();
      Mat3 P;
      PointCache cache;
      ASSERT_TRUE(stress(law(), s.F, l, P, nullptr, &cache));
      Mat3 d2P;
      ASSERT_TRUE(stress_second_derivative(law(), s.F, cache, l, E, W, d2P));
      const Vec9 got = detail::vec(d2P);
      ASSERT_GT(got.norm(), 0);
      const double h = 1e-6 * std::max(1.0, s.F.cwiseAbs().maxCoeff());
      const Vec9 fd = (dP_dF_of(law(), s.F + h * E, l) - dP_dF_of(law(), s.F - h * E, l)) * detail::vec(W) / (2.0 * h);
      std::string where;
      EXPECT_LT(rel_error(got, fd, &where), 1e-6) << where;
      const Vec9 product = directional_of(law(), s.F, l, E) * detail::vec(W);
      EXPECT_LT(rel_error(got, product, &where), 1e-12) << where;
      // A third derivative: symmetric in E and W.
      Mat3 d2P_swapped;
      ASSERT_TRUE(stress_second_derivative(law(), s.F, cache, l, W, E, d2P_swapped));
      EXPECT_LT(rel_error(got, Vec9(detail::vec(d2P_swapped))), 1e-12);
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Material, Laws, ::testing::ValuesIn(kLaws),
                         [](const ::testing::TestParamInfo<Law>& param) { return std::string(law_name(param.param)); });

// ---------------------------------------------------------------------------
TEST(NeoHookean, UndefinedForNonPositiveJ) {
  const Mat3 cases[] = {Vec3(1.0, 1.0, -1.0).asDiagonal(), Vec3(1.2, 0.7, 0.0).asDiagonal(), Mat3::Zero(),
                        axis_angle(Vec3(0, 1, 1), 1.0) * Vec3(-0.5, 1.0, 1.0).asDiagonal()};
  for (const Mat3& F : cases) {
    EXPECT_EQ(psi(Law::neo_hookean, F, kLame), std::numeric_limits<double>::infinity());
    EXPECT_EQ(psi_t<AD1>(Law::neo_hookean, Eigen::Matrix<AD1, 3, 3>(F.cast<AD1>()), kLame).value(),
              std::numeric_limits<double>::infinity());
    Mat3 P;
    Mat9 H, T;
    EXPECT_FALSE(stress(Law::neo_hookean, F, kLame, P, &H));
    EXPECT_FALSE(stress(Law::neo_hookean, F, kLame, P, nullptr));
    EXPECT_FALSE(stress_hessian_directional(Law::neo_hookean, F, kLame, Mat3::Identity(), T));
  }
}

TEST(NeoHookean, PsiAndStressAgreeOnWhereTheLawIsDefined) {
  const Mat3 Q = axis_angle(Vec3(2, -1, 1), 0.8);
  for (double s3 : {1e-300, 1e-17, 1e-12, 0.0, -1e-300, -1e-17, -1e-12}) {
    const Mat3 F = Q * Vec3(1.3, 0.8, s3).asDiagonal();
    Mat3 P;
    const bool defined = stress(Law::neo_hookean, F, kLame, P, nullptr);
    EXPECT_EQ(defined, std::isfinite(psi(Law::neo_hookean, F, kLame))) << "sigma_3 = " << s3;
    EXPECT_EQ(defined, s3 > 0.0) << "sigma_3 = " << s3;
  }
}

TEST(Corotational, CacheHoldsPolarDecomposition) {
  for (const auto& s : samples(true)) {
    SCOPED_TRACE(s.name);
    PointCache cache;
    Mat3 P;
    ASSERT_TRUE(stress(Law::corotational, s.F, kLame, P, nullptr, &cache));
    EXPECT_LT((cache.R.transpose() * cache.R - Mat3::Identity()).norm(), 1e-14);
    EXPECT_NEAR(cache.R.determinant(), 1.0, 1e-14);
    EXPECT_LT((cache.S - cache.S.transpose()).norm(), 1e-14 * cache.S.norm());
    EXPECT_LT((cache.R * cache.S - s.F).norm(), 1e-14 * s.F.norm());
    // For det F > 0, S is positive definite (the usual polar decomposition).
    if (s.F.determinant() > 0) {
      EXPECT_GT(Eigen::SelfAdjointEigenSolver<Mat3>(cache.S).eigenvalues()(0), 0.0);
    }
  }
}

TEST(Corotational, FiniteWhereTheRotationGradientIsSingular) {
  // sigma_2 + sigma_3 = 0 (inverted, equal smallest stretches), rank 1 and F = 0: R(F) is
  // not differentiable there; dP/dF stays finite and symmetric through the clamp.
  const Mat3 Q = axis_angle(Vec3(1, -1, 2), 0.7);
  const Mat3 cases[] = {Vec3(1.0, 0.5, -0.5).asDiagonal(), Q * Vec3(1.0, 0.5, -0.5 + 1e-12).asDiagonal(),
                        Vec3(1.0, 0.0, 0.0).asDiagonal(), Mat3::Zero()};
  for (const Mat3& F : cases) {
    Mat3 P;
    Mat9 H, T;
    ASSERT_TRUE(stress(Law::corotational, F, kLame, P, &H));
    ASSERT_TRUE(stress_hessian_directional(Law::corotational, F, kLame, Q, T));
    EXPECT_TRUE(std::isfinite(psi(Law::corotational, F, kLame)));
    EXPECT_TRUE(P.allFinite());
    EXPECT_TRUE(H.allFinite());
    EXPECT_TRUE(T.allFinite());
    EXPECT_LT(rel_error(H, Mat9(H.transpose())), 1e-14);
  }
}

TEST(Corotational, ContinuousThroughInversion) {
  // psi and P are continuous as sigma_3 crosses 0 (the sign fix flips it, not R).
  const Mat3 Q1 = axis_angle(Vec3(1, 2, 0.5), 0.4), Q2 = axis_angle(Vec3(-1, 0.3, 1), 1.1);
  const auto F = [&](double s3) { return Mat3(Q1 * Vec3(1.2, 0.9, s3).asDiagonal() * Q2.transpose()); };
  const double psi_p = psi(Law::corotational, F(1e-9), kLame), psi_m = psi(Law::corotational, F(-1e-9), kLame);
  EXPECT_LT(std::abs(psi_p - psi_m), 1e-7 * psi_p);  // a jump in R would give O(1)
  EXPECT_LT(rel_error(P_of(Law::corotational, F(1e-9), kLame), P_of(Law::corotational, F(-1e-9), kLame)), 1e-7);
}

// ---------------------------------------------------------------------------
Mat12 random_symmetric(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Mat12 A;
  for (int i = 0; i < 144; ++i) A(i) = n(rng);
  return A + A.transpose();
}

TEST(ProjectPsd, ClampsNegativeEigenvalues) {
  std::mt19937 rng(3);
  for (int k = 0; k < 5; ++k) {
    const Mat12 K = 1e4 * random_symmetric(rng);
    Mat12 Kp = K;
    project_psd(Kp);
    const Eigen::SelfAdjointEigenSolver<Mat12> before(K), after(Kp);
    ASSERT_LT(before.eigenvalues()(0), 0.0);  // the input really was indefinite
    const double scale = before.eigenvalues().cwiseAbs().maxCoeff();
    EXPECT_GE(after.eigenvalues()(0), -1e-13 * scale);
    // The nearest PSD matrix: same eigenvectors, eigenvalues max(lambda, 0).
    const Eigen::Matrix<double, 12, 1> expected = before.eigenvalues().cwiseMax(0.0);
    EXPECT_LT((after.eigenvalues() - expected).cwiseAbs().maxCoeff(), 1e-13 * scale);
    EXPECT_LT(rel_error(Kp, Mat12(Kp.transpose())), 1e-15);
    // Idempotent.
    Mat12 Kpp = Kp;
    project_psd(Kpp);
    const double err = rel_error(Kpp, Kp);
    record("project_psd: idempotence", err);
    EXPECT_LT(err, 1e-12);
  }
}

TEST(ProjectPsd, KeepsPsdInput) {
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 1.0);
  for (int rank : {12, 6}) {  // full rank, and rank 6 like an element Hessian's rigid modes
    Eigen::Matrix<double, 12, 12> B = Mat12::Zero();
    for (int i = 0; i < 12 * rank; ++i) B(i) = n(rng);
    const Mat12 K = B * B.transpose();
    Mat12 Kp = K;
    project_psd(Kp);
    const double err = rel_error(Kp, K);
    record("project_psd: PSD input kept", err);
    EXPECT_LT(err, 1e-12) << "rank " << rank;
  }
  // The stiffness of an actual law at a stretched state, projected: PSD and kept.
  Mat3 P;
  Mat9 H;
  ASSERT_TRUE(stress(Law::neo_hookean, Vec3(1.1, 1.05, 0.95).asDiagonal(), kLame, P, &H));
  Eigen::Matrix<double, 9, 12> G = Eigen::Matrix<double, 9, 12>::Random();  // some dF/dx
  Mat12 K = G.transpose() * H * G;
  K = 0.5 * (K + K.transpose()).eval();
  if (Eigen::SelfAdjointEigenSolver<Mat12>(K).eigenvalues()(0) >= 0) {
    Mat12 Kp = K;
    project_psd(Kp);
    EXPECT_EQ(Kp, K);
  }
}

// ---------------------------------------------------------------------------
struct MallocGuard {
  MallocGuard() { Eigen::internal::set_is_malloc_allowed(false); }
  ~MallocGuard() { Eigen::internal::set_is_malloc_allowed(true); }
};

TEST(Material, NoHeap) {
  // The hook is live: a dynamic Eigen allocation is caught.
  {
    MallocGuard g;
    EXPECT_THROW(
        {
          Eigen::MatrixXd m(10, 10);
          m.setZero();
        },
        std::runtime_error);
  }
  std::mt19937 rng(9);
  const Mat3 F = samples(false)[0].F;
  const Mat3 dF = random_matrix(rng);
  Mat12 K = random_symmetric(rng);
  Mat3 P;
  Mat9 H, T;
  double sum = 0;
  {
    MallocGuard g;
    EXPECT_NO_THROW({
      sum += corotational::psi(F, kLame.mu, kLame.lambda);
      corotational::stress(F, kLame.mu, kLame.lambda, P, &H);
      corotational::stress_hessian_directional(F, kLame.mu, kLame.lambda, dF, T);
      sum += stvk::psi(F, kLame.mu, kLame.lambda);
      stvk::stress(F, kLame.mu, kLame.lambda, P, &H);
      stvk::stress_hessian_directional(F, kLame.mu, kLame.lambda, dF, T);
      sum += neo_hookean::psi(F, kLame.mu, kLame.lambda);
      neo_hookean::stress(F, kLame.mu, kLame.lambda, P, &H);
      neo_hookean::stress_hessian_directional(F, kLame.mu, kLame.lambda, dF, T);
      clamp_negative_eigenvalues(K);
    });
  }
  EXPECT_TRUE(std::isfinite(sum));
}

}  // namespace
