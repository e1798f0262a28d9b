// FEM derivatives (fem_derivatives.hpp) against central finite differences of the
// forward assembly, for every law, with and without the PSD projection:
//   K u             vs  -(f(x + e u) - f(x - e u)) / 2e
//   dK~[u] w        vs  (K~(x + e u) w - K~(x - e u) w) / 2e
//   df/dp, dK~/dp w vs  central differences in young and poisson
// and the reverse products against the forward ones (dot-product test).
//
// Step: e = 1e-6 on positions x + e u with u of the size of the element edges
// (0.05 m), i.e. 5e-8 m; for parameters e = 1e-6 p. The central difference's truncation
// error is O(e^2) relative to the quantity's variation over the edge length, ~1e-12;
// round-off is eps |f| / e ~ 1e-10 relative: tolerance 1e-6 leaves four orders of margin.
#include <softdiff/data.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/fem_derivatives.hpp>
#include <support/fd.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>

using namespace softdiff;
using material::Law;

namespace {

constexpr double kEdge = 0.05;
constexpr double kStep = 1e-6;
constexpr double kTol = 1e-6;

struct Case {
  Law law;
  bool psd;
};

std::string name_of(const Case& c) {
  return std::string(material::law_name(c.law)) + (c.psd ? " (psd)" : "");
}

using test::random_vector;

Model make(const Case& c) {
  test::BodySpec spec;
  spec.law = c.law;
  spec.psd_projection = c.psd;
  spec.young = 1e5;
  spec.poisson = 0.35;
  return test::make_model(test::box_mesh(2, 2, 2, 0.1, 0.1, 0.1), spec);
}

// A large, rotated deformation with elements compressed by 45% (where the stvk and
// Neo-Hookean element Hessians are indefinite, so that the projection acts), no
// element inverted.
VecX deformed(const Model& model, unsigned seed) {
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  VecX x = model.initial.x + random_vector(model.initial.x.size(), 0.004, seed);
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    Vec3 p = x.segment<3>(3 * i);
    p.z() *= 0.55;
    x.segment<3>(3 * i) = R * p;
  }
  return x;
}

VecX forces(const Model& model, const VecX& x) {
  fem::FemData d;
  d.resize(model.fem);
  EXPECT_TRUE(fem::evaluate(model.fem, x, {false, true, false}, d));
  return d.f_int;
}

VecX stiffness_times(const Model& model, const VecX& x, const VecX& w) {
  fem::FemData d;
  d.resize(model.fem);
  EXPECT_TRUE(fem::evaluate(model.fem, x, {false, false, true}, d));
  VecX y;
  fem::symmetric_multiply(model.fem, d.K_values, w, y);
  return y;
}

class FemDerivatives : public ::testing::TestWithParam<Case> {};

TEST_P(FemDerivatives, StiffnessProductsMatchFiniteDifferences) {
  const Case c = GetParam();
  const Model model = make(c);
  const VecX x = deformed(model, 1);
  const Eigen::Index n = x.size();
  const VecX u = random_vector(n, kEdge, 2), w = random_vector(n, 1.0, 3);
  const VecX one = VecX::Ones(1), none = VecX::Zero(1);

  VecX Ku = VecX::Zero(n), dKw = VecX::Zero(n);
  ASSERT_EQ(fem::add_stiffness_jvp(model.fem, x, u, w, one, none, Ku), -1);
  ASSERT_EQ(fem::add_stiffness_jvp(model.fem, x, u, w, none, one, dKw), -1);
  const VecX Ku_fd = -(forces(model, x + kStep * u) - forces(model, x - kStep * u)) / (2 * kStep);
  const VecX dKw_fd = (stiffness_times(model, x + kStep * u, w) - stiffness_times(model, x - kStep * u, w)) / (2 * kStep);
  ASSERT_GT(Ku.norm(), 0);
  EXPECT_LE((Ku - Ku_fd).norm(), kTol * Ku_fd.norm()) << name_of(c);
  if (c.law == Law::linear) {
    // Constant stiffness: exactly zero (and the differences vanish to round-off).
    EXPECT_EQ(dKw.norm(), 0);
    EXPECT_LE(dKw_fd.norm(), 1e-6 * Ku.norm() / kEdge);
  } else {
    ASSERT_GT(dKw.norm(), 0);
    EXPECT_LE((dKw - dKw_fd).norm(), kTol * dKw_fd.norm()) << name_of(c);
  }
}

TEST_P(FemDerivatives, ReverseProductsAreTheTransposes) {
  // <y, J u> = <J^T y, u> for the map u -> a K u + c dK~[u] w, random u, y, w.
  const Case c = GetParam();
  const Model model = make(c);
  const VecX x = deformed(model, 4);
  const Eigen::Index n = x.size();
  const VecX u = random_vector(n, kEdge, 5), y = random_vector(n, 1.0, 6), w = random_vector(n, 1.0, 7);
  const VecX a = VecX::Constant(1, -0.3), cc = VecX::Constant(1, 1.7);
  VecX Ju = VecX::Zero(n), JTy = VecX::Zero(n);
  ASSERT_EQ(fem::add_stiffness_jvp(model.fem, x, u, w, a, cc, Ju), -1);
  ASSERT_EQ(fem::add_stiffness_vjp(model.fem, x, y, w, a, cc, JTy), -1);
  const double lhs = y.dot(Ju), rhs = JTy.dot(u);
  EXPECT_NEAR(lhs, rhs, 1e-10 * (y.norm() * Ju.norm() + JTy.norm() * u.norm())) << name_of(c);
}

// The products from the record of an evaluation (add_stiffness_product, the forward
// sensitivities' path: K u from the assembled K, dK[u] w from the kept polar
// decompositions, no SVD): against the same central differences (kStep, kTol above),
// and against the element-pass products, which they equal up to rounding (1e-12).
TEST_P(FemDerivatives, ProductsFromTheRecordMatchFiniteDifferences) {
  const Case c = GetParam();
  const Model model = make(c);
  const VecX x = deformed(model, 10);
  const Eigen::Index n = x.size();
  const VecX u = random_vector(n, kEdge, 11), w = random_vector(n, 1.0, 12);
  const VecX one = VecX::Ones(1), none = VecX::Zero(1);
  fem::FemData record;
  record.resize(model.fem);
  ASSERT_TRUE(fem::evaluate(model.fem, x, {false, true, true}, record));
  VecX work(n);
  VecX Ku = VecX::Zero(n), dKw = VecX::Zero(n);
  ASSERT_EQ(fem::add_stiffness_product(model.fem, record, x, fem::StiffnessProduct::jvp, u, w, one, none, Ku, work), -1);
  ASSERT_EQ(fem::add_stiffness_product(model.fem, record, x, fem::StiffnessProduct::jvp, u, w, none, one, dKw, work), -1);
  const VecX Ku_fd = -(forces(model, x + kStep * u) - forces(model, x - kStep * u)) / (2 * kStep);
  const VecX dKw_fd = (stiffness_times(model, x + kStep * u, w) - stiffness_times(model, x - kStep * u, w)) / (2 * kStep);
  ASSERT_GT(Ku.norm(), 0);
  EXPECT_LE((Ku - Ku_fd).norm(), kTol * Ku_fd.norm()) << name_of(c);
  if (c.law == Law::linear) {
    EXPECT_EQ(dKw.norm(), 0);
  } else {
    ASSERT_GT(dKw.norm(), 0);
    EXPECT_LE((dKw - dKw_fd).norm(), kTol * dKw_fd.norm()) << name_of(c);
  }
  // The element-pass products, forward and reverse, with both terms at once.
  const VecX a = VecX::Constant(1, -0.3), cc = VecX::Constant(1, 1.7);
  for (auto kind : {fem::StiffnessProduct::jvp, fem::StiffnessProduct::vjp}) {
    VecX got = VecX::Zero(n), ref = VecX::Zero(n);
    ASSERT_EQ(fem::add_stiffness_product(model.fem, record, x, kind, u, w, a, cc, got, work), -1);
    if (kind == fem::StiffnessProduct::jvp) {
      ASSERT_EQ(fem::add_stiffness_jvp(model.fem, x, u, w, a, cc, ref), -1);
    } else {
      ASSERT_EQ(fem::add_stiffness_vjp(model.fem, x, u, w, a, cc, ref), -1);
    }
    ASSERT_GT(ref.norm(), 0);
    EXPECT_LE((got - ref).norm(), 1e-12 * ref.norm()) << name_of(c) << (kind == fem::StiffnessProduct::jvp ? " jvp" : " vjp");
  }
}

TEST_P(FemDerivatives, ElasticParameterDerivativesMatchFiniteDifferences) {
  const Case c = GetParam();
  const Model model = make(c);
  const VecX x = deformed(model, 8);
  const Eigen::Index n = x.size();
  const VecX w = random_vector(n, 1.0, 9);
  for (auto p : {fem::ElasticParameter::young, fem::ElasticParameter::poisson}) {
    VecX df = VecX::Zero(n), dKw = VecX::Zero(n);
    ASSERT_EQ(fem::add_elastic_parameter_derivative(model.fem, x, 0, p, w, df, dKw), -1);
    Model mp = model, mm = model;
    auto& bp = mp.fem.bodies[0];
    auto& bm = mm.fem.bodies[0];
    const double value = p == fem::ElasticParameter::young ? bp.young : bp.poisson;
    const double e = kStep * value;
    (p == fem::ElasticParameter::young ? bp.young : bp.poisson) += e;
    (p == fem::ElasticParameter::young ? bm.young : bm.poisson) -= e;
    bp.lame = material::lame_from_young_poisson(bp.young, bp.poisson);
    bm.lame = material::lame_from_young_poisson(bm.young, bm.poisson);
    const VecX df_fd = (forces(mp, x) - forces(mm, x)) / (2 * e);
    const VecX dKw_fd = (stiffness_times(mp, x, w) - stiffness_times(mm, x, w)) / (2 * e);
    const char* pn = p == fem::ElasticParameter::young ? "young" : "poisson";
    ASSERT_GT(df.norm(), 0);
    EXPECT_LE((df - df_fd).norm(), kTol * df_fd.norm()) << name_of(c) << " " << pn;
    EXPECT_LE((dKw - dKw_fd).norm(), kTol * dKw_fd.norm()) << name_of(c) << " " << pn;
  }
}

INSTANTIATE_TEST_SUITE_P(Laws, FemDerivatives,
                         ::testing::Values(Case{Law::corotational, false}, Case{Law::stvk, false},
                                           Case{Law::neo_hookean, false}, Case{Law::linear, false},
                                           Case{Law::corotational, true}, Case{Law::stvk, true},
                                           Case{Law::neo_hookean, true}),
                         [](const ::testing::TestParamInfo<Case>& param) {
                           return std::string(material::law_name(param.param.law)) + (param.param.psd ? "_psd" : "");
                         });

// The projection acts in the PSD cases above (otherwise they would test nothing new).
TEST(FemDerivatives, CompressedStateMakesElementHessiansIndefinite) {
  for (Law law : {Law::stvk, Law::neo_hookean}) {
    const Model plain = make({law, false}), projected = make({law, true});
    const VecX x = deformed(plain, 1);
    const VecX w = random_vector(x.size(), 1.0, 3);
    EXPECT_GT((stiffness_times(plain, x, w) - stiffness_times(projected, x, w)).norm(),
              1e-3 * stiffness_times(plain, x, w).norm())
        << material::law_name(law);
  }
}

}  // namespace
