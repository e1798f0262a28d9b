// The `linear` (small-strain) law: exact P and constant dP/dF, equal to the other
// laws' tangent at rest. (Not rotation invariant by construction: no rigid tests.)
#include <softdiff/material/material.hpp>
#include <support/fd.hpp>

#include <gtest/gtest.h>
#include <random>

using namespace softdiff;
using material::Law;

namespace {

VecX vec(const Mat3& M) { return Eigen::Map<const VecX>(M.data(), 9); }
Mat3 unvec(const VecX& v) { return Eigen::Map<const Mat3>(v.data()); }

TEST(LinearLaw, StressAndTangentMatchFiniteDifferences) {
  const auto lame = material::lame_from_young_poisson(2e5, 0.4);
  std::mt19937 rng(1);
  std::normal_distribution<double> n(0, 0.2);
  for (int s = 0; s < 5; ++s) {
    Mat3 F = Mat3::Identity();
    for (int k = 0; k < 9; ++k) F(k) += n(rng);
    Mat3 P;
    Mat9 dP;
    ASSERT_TRUE(material::stress(Law::linear, F, lame, P, &dP));
    // Step 1e-6 (F is O(1)): see support/fd.hpp.
    const VecX g = test::fd_gradient([&](const VecX& f) { return material::psi(Law::linear, unvec(f), lame); }, vec(F), 1e-6);
    EXPECT_LT(test::compare(vec(P), g).rel_error, 1e-8);
    const MatX J = test::fd_jacobian(
        [&](const VecX& f) -> VecX {
          Mat3 Q;
          material::stress(Law::linear, unvec(f), lame, Q, nullptr);
          return vec(Q);
        },
        vec(F), 1e-6);
    EXPECT_LT(test::compare(dP, J).rel_error, 1e-8);
  }
}

TEST(LinearLaw, TangentEqualsOtherLawsAtRest) {
  const auto lame = material::lame_from_young_poisson(1e6, 0.3);
  Mat3 P;
  Mat9 lin, other;
  material::stress(Law::linear, Mat3::Identity(), lame, P, &lin);
  EXPECT_EQ(P.norm(), 0.0);
  for (Law law : {Law::corotational, Law::stvk, Law::neo_hookean}) {
    material::stress(law, Mat3::Identity(), lame, P, &other);
    EXPECT_LT((lin - other).norm(), 1e-9 * lin.norm()) << material::law_name(law);
  }
}

}  // namespace
