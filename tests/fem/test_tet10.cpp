// The quadratic (10-node) tetrahedron (lib/softdiff/fem/tet10.hpp and its use in
// fem_model.cpp / assembly.cpp): quadrature exactness, shape functions, forces and
// stiffness of every law against finite differences, rigid-motion invariance, the
// patch test, consistent and HRZ-lumped mass and the consistent gravity load.
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/fem_derivatives.hpp>
#include <softdiff/fem/tet10.hpp>
#include <support/fd.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <cmath>
#include <random>

using namespace softdiff;

namespace tet10_test {

using material::Law;
namespace t10 = fem::tet10;

double factorial(int k) { return k <= 1 ? 1.0 : k * factorial(k - 1); }

// int over the reference tet of u^a v^b w^c = a! b! c! / (a + b + c + 3)!
double exact_monomial(int a, int b, int c) {
  return factorial(a) * factorial(b) * factorial(c) / factorial(a + b + c + 3);
}

template <std::size_t K>
double rule_monomial(const std::array<t10::QuadraturePoint, K>& rule, int a, int b, int c) {
  double s = 0;
  for (const auto& q : rule) s += q.weight * std::pow(q.u, a) * std::pow(q.v, b) * std::pow(q.w, c);
  return s;
}

// Reference coordinates of the 10 nodes (gmsh order).
Eigen::Matrix<double, 3, 10> reference_nodes() {
  Eigen::Matrix<double, 3, 10> xi;
  xi.leftCols(4) << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1;
  for (int k = 0; k < 6; ++k)
    xi.col(4 + k) = 0.5 * (xi.col(mesh::kTet10Edge[k][0]) + xi.col(mesh::kTet10Edge[k][1]));
  return xi;
}

TEST(Tet10Quadrature, RulesAreExactToTheirDegree) {
  // Round-off of a sum of <= 14 products of O(1) numbers: 1e-15 relative; the rules'
  // tabulated digits (16 significant) allow 1e-14.
  for (int d = 0; d <= 5; ++d)
    for (int a = 0; a <= d; ++a)
      for (int b = 0; a + b <= d; ++b) {
        const int c = d - a - b;
        const double exact = exact_monomial(a, b, c);
        EXPECT_NEAR(rule_monomial(t10::kMassRule, a, b, c), exact, 1e-14 * exact) << a << b << c;
        if (d <= 2) {
          EXPECT_NEAR(rule_monomial(t10::kStiffnessRule, a, b, c), exact, 1e-14 * exact) << a << b << c;
        }
      }
  // And not beyond (what "degree 2" and "degree 5" mean): some monomial of the next degree is missed.
  EXPECT_GT(std::abs(rule_monomial(t10::kStiffnessRule, 3, 0, 0) - exact_monomial(3, 0, 0)), 1e-6);
  double worst = 0;
  for (int a = 0; a <= 6; ++a)
    for (int b = 0; a + b <= 6; ++b)
      worst = std::max(worst, std::abs(rule_monomial(t10::kMassRule, a, b, 6 - a - b) - exact_monomial(a, b, 6 - a - b)));
  EXPECT_GT(worst, 1e-8);
  for (const auto& q : t10::kMassRule) EXPECT_GT(q.weight, 0);
}

TEST(Tet10Shape, NodalInterpolationPartitionOfUnityAndGradients) {
  const auto xi = reference_nodes();
  for (int b = 0; b < 10; ++b) {
    const auto N = t10::shape(xi(0, b), xi(1, b), xi(2, b));
    for (int a = 0; a < 10; ++a) EXPECT_NEAR(N(a), a == b ? 1.0 : 0.0, 1e-15) << a << " at node " << b;
  }
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0, 0.33);
  for (int trial = 0; trial < 5; ++trial) {
    const double p[3] = {u(rng), u(rng), u(rng)};
    EXPECT_NEAR(t10::shape(p[0], p[1], p[2]).sum(), 1.0, 1e-15);
    const auto dN = t10::shape_gradients_ref(p[0], p[1], p[2]);
    EXPECT_NEAR(dN.colwise().sum().norm(), 0.0, 1e-14);
    // Central differences of a quadratic are exact up to round-off: step 1e-4 (the
    // reference element has size 1), round-off ~1e-16 / 1e-4 = 1e-12.
    const double h = 1e-4;
    for (int c = 0; c < 3; ++c) {
      double pp[3] = {p[0], p[1], p[2]}, pm[3] = {p[0], p[1], p[2]};
      pp[c] += h;
      pm[c] -= h;
      const Eigen::Matrix<double, 10, 1> fd =
          (t10::shape(pp[0], pp[1], pp[2]) - t10::shape(pm[0], pm[1], pm[2])) / (2 * h);
      EXPECT_LT((fd - dN.col(c)).cwiseAbs().maxCoeff(), 1e-11) << "direction " << c;
    }
  }
}

// One curved 10-node element of edge ~1 cm: a random well-shaped tet whose mid-edge
// nodes are moved off the midpoints by up to 8% of an edge.
mesh::TetMesh curved_element(std::mt19937& rng, double curve = 0.08) {
  std::uniform_real_distribution<double> u(-1, 1);
  mesh::TetMesh m;
  m.source = "curved_element";
  m.order = 2;
  m.X.resize(3, 10);
  m.X.leftCols(4) << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1;
  for (int a = 0; a < 4; ++a)
    for (int c = 0; c < 3; ++c) m.X(c, a) += 0.2 * u(rng);
  Mat3 D;
  for (int k = 0; k < 3; ++k) D.col(k) = m.X.col(k + 1) - m.X.col(0);
  if (D.determinant() < 0) m.X.col(1).swap(m.X.col(2));
  for (int k = 0; k < 6; ++k) {
    m.X.col(4 + k) = 0.5 * (m.X.col(mesh::kTet10Edge[k][0]) + m.X.col(mesh::kTet10Edge[k][1]));
    for (int c = 0; c < 3; ++c) m.X(c, 4 + k) += curve * u(rng);
  }
  m.X *= 0.01;
  m.tets.resize(4, 1);
  m.tets << 0, 1, 2, 3;
  m.tets10.resize(10, 1);
  for (int a = 0; a < 10; ++a) m.tets10(a, 0) = a;
  m.file_index.resize(10);
  m.file_tag.resize(10);
  for (int i = 0; i < 10; ++i) m.file_index[i] = i, m.file_tag[i] = i + 1;
  m.tet_file_tag = {1};
  return m;
}

// A random deformation of the element: rotation R, stretch, translation, and a
// non-affine perturbation of 3% of an edge per node.
VecX deformed(const Model& model, std::mt19937& rng, double nonaffine = 0.03) {
  std::uniform_real_distribution<double> u(-1, 1);
  const Mat3 R = Eigen::AngleAxisd(u(rng) * 3, Vec3(u(rng), u(rng), u(rng)).normalized()).toRotationMatrix();
  Mat3 S = Mat3::Identity();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) S(i, j) += 0.15 * u(rng);
  VecX x = model.initial.x;
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    const Vec3 X = model.fem.X.col(i);
    x.segment<3>(3 * i) = R * S * X + Vec3(0.01, -0.02, 0.005);
    for (int c = 0; c < 3; ++c) x[3 * i + c] += 0.01 * nonaffine * u(rng);
  }
  return x;
}

MatX dense_symmetric(const fem::FemModel& m, const VecX& values) {
  MatX K = MatX::Zero(3 * m.num_nodes, 3 * m.num_nodes);
  const auto& S = m.pattern.structure;
  for (int col = 0; col < S.outerSize(); ++col)
    for (int k = S.outerIndexPtr()[col]; k < S.outerIndexPtr()[col + 1]; ++k) {
      const int row = S.innerIndexPtr()[k];
      K(row, col) = values[k];
      K(col, row) = values[k];
    }
  return K;
}

struct LawCase {
  Law law;
  bool psd;
};

class Tet10Law : public ::testing::TestWithParam<LawCase> {};

TEST_P(Tet10Law, ForcesAndStiffnessMatchFiniteDifferences) {
  std::mt19937 rng(11 + static_cast<int>(GetParam().law));
  test::BodySpec spec;
  spec.law = GetParam().law;
  spec.young = 1e5;
  spec.poisson = 0.45;
  spec.psd_projection = GetParam().psd;
  const Model model = test::make_model(curved_element(rng), spec, Vec3::Zero());
  ASSERT_EQ(model.fem.num_quadratic, 1);
  fem::FemData data;
  data.resize(model.fem);
  VecX x = deformed(model, rng);
  if (GetParam().psd) {
    // Compressed to 60% along z: the unprojected element Hessian is indefinite there,
    // so the projection is exercised (checked below).
    for (int i = 0; i < model.fem.num_nodes; ++i)
      x.segment<3>(3 * i) = Vec3(model.fem.X(0, i), model.fem.X(1, i), 0.6 * model.fem.X(2, i)) +
                            2e-4 * Vec3(std::sin(7.0 * i), std::cos(5.0 * i), std::sin(3.0 * i));
  }
  ASSERT_TRUE(fem::evaluate(model.fem, x, {true, true, true}, data));
  const VecX f = data.f_int;
  const MatX K = dense_symmetric(model.fem, data.K_values);
  ASSERT_GT(f.norm(), 0);
  ASSERT_GT(K.norm(), 0);
  // Step 1e-6 of the edge (1 cm): truncation ~(1e-8)^2 |psi'''| and round-off
  // eps |E| / 1e-8 are both ~1e-8 relative; tolerance 1e-6 (fd.hpp).
  const double h = 1e-6 * 0.01;
  fem::FemData scratch;
  scratch.resize(model.fem);
  auto energy = [&](const VecX& y) {
    EXPECT_TRUE(fem::evaluate(model.fem, y, {true, false, false}, scratch));
    return scratch.energy;
  };
  auto forces = [&](const VecX& y) {
    EXPECT_TRUE(fem::evaluate(model.fem, y, {false, true, false}, scratch));
    return VecX(scratch.f_int);
  };
  const auto cf = test::compare(f, -test::fd_gradient(energy, x, h));
  EXPECT_LT(cf.rel_error, 1e-6) << "f = -dE/dx: " << cf.str();
  if (!GetParam().psd) {
    const auto cK = test::compare(K, -test::fd_jacobian(forces, x, h));
    EXPECT_LT(cK.rel_error, 1e-6) << "K = -df/dx: " << cK.str();
  } else {
    // The projected K is PSD, and the unprojected one at the same x was not.
    Eigen::SelfAdjointEigenSolver<MatX> eig(K);
    EXPECT_GT(eig.eigenvalues().minCoeff(), -1e-9 * eig.eigenvalues().cwiseAbs().maxCoeff());
    test::BodySpec plain = spec;
    plain.psd_projection = false;
    std::mt19937 rng2(11 + static_cast<int>(GetParam().law));
    const Model unprojected = test::make_model(curved_element(rng2), plain, Vec3::Zero());
    fem::FemData d2;
    d2.resize(unprojected.fem);
    ASSERT_TRUE(fem::evaluate(unprojected.fem, x, {false, false, true}, d2));
    Eigen::SelfAdjointEigenSolver<MatX> eig2(dense_symmetric(unprojected.fem, d2.K_values));
    EXPECT_LT(eig2.eigenvalues().minCoeff(), -1e-6 * eig2.eigenvalues().cwiseAbs().maxCoeff())
        << "the test state should make the element Hessian indefinite";
  }
}

TEST_P(Tet10Law, RigidMotionGivesNoForceAndNoEnergy) {
  if (GetParam().law == Law::linear || GetParam().psd) GTEST_SKIP() << (GetParam().psd ? "psd: the same forces as its unprojected case, which runs" : "linear: not rotation invariant");
  std::mt19937 rng(5);
  test::BodySpec spec;
  spec.law = GetParam().law;
  const Model model = test::make_model(curved_element(rng), spec, Vec3::Zero());
  const Mat3 R = Eigen::AngleAxisd(1.1, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  VecX x = model.initial.x;
  for (int i = 0; i < model.fem.num_nodes; ++i) x.segment<3>(3 * i) = R * model.fem.X.col(i) + Vec3(1, 2, 3);
  fem::FemData data;
  data.resize(model.fem);
  ASSERT_TRUE(fem::evaluate(model.fem, x, {true, true, false}, data));
  // The force scale is mu V / edge ~ 3e4 * 1e-6 / 1e-2 = 3e-3 N; rotations are exact to
  // ~1e-15, hence forces ~1e-17 N and energies ~1e-20 J.
  EXPECT_LT(data.f_int.cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT(std::abs(data.energy), 1e-14);
}

INSTANTIATE_TEST_SUITE_P(Laws, Tet10Law,
                         ::testing::Values(LawCase{Law::linear, false}, LawCase{Law::corotational, false},
                                           LawCase{Law::stvk, false}, LawCase{Law::neo_hookean, false},
                                           LawCase{Law::corotational, true}, LawCase{Law::stvk, true}),
                         [](const ::testing::TestParamInfo<LawCase>& p) {
                           return std::string(material::law_name(p.param.law)) + (p.param.psd ? "_psd" : "");
                         });

// A 2 x 2 x 2 box of 48 quadratic tets (elevated, straight edges). Under an affine map
// x = A X + b every element has F = A at every point, so the interior nodes (and the
// mid-edge nodes inside the box) are in equilibrium and the energy is V psi(A).
TEST(Tet10Patch, AffineFieldIsReproduced) {
  mesh::TetMesh m = test::box_mesh(2, 2, 2, 0.02, 0.02, 0.02);
  mesh::elevate_to_quadratic(m);
  for (Law law : {Law::linear, Law::corotational, Law::stvk, Law::neo_hookean}) {
    test::BodySpec spec;
    spec.law = law;
    const Model model = test::make_model(m, spec, Vec3::Zero());
    Mat3 A;
    A << 1.05, 0.02, -0.01, 0.03, 0.97, 0.04, -0.02, 0.01, 1.02;
    VecX x(3 * model.fem.num_nodes);
    for (int i = 0; i < model.fem.num_nodes; ++i) x.segment<3>(3 * i) = A * model.fem.X.col(i) + Vec3(0.1, 0, 0);
    fem::FemData data;
    data.resize(model.fem);
    ASSERT_TRUE(fem::evaluate(model.fem, x, {true, true, false}, data));
    double scale = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i) scale = std::max(scale, data.f_int.segment<3>(3 * i).norm());
    ASSERT_GT(scale, 0);
    for (int i = 0; i < model.fem.num_nodes; ++i) {
      const Vec3 X = model.fem.X.col(i);
      const bool interior = (X.array() > 1e-9).all() && (X.array() < 0.02 - 1e-9).all();
      if (interior) {
        EXPECT_LT(data.f_int.segment<3>(3 * i).norm(), 1e-12 * scale) << "node " << i;
      }
    }
    const double V = 0.02 * 0.02 * 0.02;
    const double expected = V * material::psi(law, A, model.fem.bodies[0].lame);
    EXPECT_NEAR(data.energy, expected, 1e-12 * expected) << material::law_name(law);
    EXPECT_NEAR(model.fem.rest_volume.sum(), V, 1e-14);
  }
}

// The straight element's consistent mass: rho V (1/70 vertex, 8/105 edge on the
// diagonal; analytic integrals of barycentric monomials), the HRZ masses rho V / 36
// (vertex) and 4 rho V / 27 (edge), and the consistent load -rho g V / 20 (vertex),
// rho g V / 5 (edge).
TEST(Tet10Mass, StraightElementMatchesTheAnalyticIntegrals) {
  mesh::TetMesh m = test::box_mesh(1, 1, 1, 0.01, 0.01, 0.01);
  mesh::elevate_to_quadratic(m);
  // Keep one element only.
  mesh::TetMesh one;
  one.source = "one";
  one.order = 2;
  one.X.resize(3, 10);
  one.tets.resize(4, 1);
  one.tets10.resize(10, 1);
  for (int a = 0; a < 10; ++a) {
    one.X.col(a) = m.X.col(m.tets10(a, 0));
    one.tets10(a, 0) = a;
  }
  one.tets = one.tets10.topRows(4);
  one.file_index.assign(10, 0);
  one.file_tag.assign(10, 0);
  const double rho = 1200, g = 9.81;
  for (fem::MassKind kind : {fem::MassKind::consistent, fem::MassKind::lumped}) {
    test::BodySpec spec;
    spec.density = rho;
    spec.mass = kind;
    const Model model = test::make_model(one, spec, Vec3(0, 0, -g));
    const double V = model.fem.rest_volume[0];
    EXPECT_NEAR(V, 0.01 * 0.01 * 0.01 / 6, 1e-20);
    const double me = rho * V;
    const MatX M = dense_symmetric(model.fem, model.fem.mass_values);
    EXPECT_NEAR(model.fem.total_mass, me, 1e-14 * me);
    EXPECT_NEAR(M.sum() / 3, me, 1e-13 * me);
    for (int a = 0; a < 10; ++a) {
      const double diag = kind == fem::MassKind::consistent ? (a < 4 ? me / 70 : 8 * me / 105)
                                                            : (a < 4 ? me / 36 : 4 * me / 27);
      EXPECT_NEAR(M(3 * a + 2, 3 * a + 2), diag, 1e-13 * me) << "node " << a;
      EXPECT_GT(model.fem.mass_diagonal[3 * a], 0) << "node " << a;
      EXPECT_NEAR(model.fem.mass_diagonal[3 * a], a < 4 ? me / 36 : 4 * me / 27, 1e-13 * me);
      // Gravity is the consistent load whatever the lumping.
      EXPECT_NEAR(model.fem.gravity_force[3 * a + 2], -g * (a < 4 ? -me / 20 : me / 5), 1e-13 * me * g) << "node " << a;
    }
    if (kind == fem::MassKind::consistent) {
      // M 1 = int rho N_a: the consistent load divided by g.
      VecX e = VecX::Zero(30);
      for (int a = 0; a < 10; ++a) e[3 * a + 2] = 1;
      const VecX Me = M * e;
      for (int a = 0; a < 10; ++a) EXPECT_NEAR(Me[3 * a + 2] * -g, model.fem.gravity_force[3 * a + 2], 1e-13 * me * g);
      Eigen::SelfAdjointEigenSolver<MatX> eig(M);
      EXPECT_GT(eig.eigenvalues().minCoeff(), 0) << "the consistent mass is positive definite";
    }
  }
}

// On a curved mesh the masses still sum to rho V (V the curved volume) and the HRZ
// masses stay positive.
TEST(Tet10Mass, CurvedElementHasPositiveLumpedMassesSummingToTheMass) {
  std::mt19937 rng(9);
  test::BodySpec spec;
  spec.density = 1000;
  spec.mass = fem::MassKind::lumped;
  const Model model = test::make_model(curved_element(rng, 0.1), spec, Vec3(0, 0, -1));
  // total_mass: rho times the 14-point rule's volume, exact for the degree-3 det J.
  const double me = model.fem.total_mass;
  EXPECT_NEAR(me, 1000 * model.fem.rest_volume[0], 0.05 * me);
  EXPECT_NEAR(model.fem.mass_diagonal.sum() / 3, me, 1e-13 * me);
  EXPECT_NEAR(-model.fem.gravity_force.sum(), me, 1e-13 * me);
  for (int i = 0; i < 30; ++i) EXPECT_GT(model.fem.mass_diagonal[i], 0);
}

// The derivatives of the FEM stage on 10-node elements (fem_derivatives.hpp): the
// products with dK against central differences of K(x) w, the reverse products as
// their transposes, and the derivatives in young and poisson against differences of
// f_int and K w. A 2-element curved patch (a box of 6 straight tets would do, but a
// curved element exercises the quadrature-point geometry).
class Tet10Derivatives : public ::testing::TestWithParam<LawCase> {};

TEST_P(Tet10Derivatives, ProductsMatchFiniteDifferences) {
  std::mt19937 rng(21 + static_cast<int>(GetParam().law));
  test::BodySpec spec;
  spec.law = GetParam().law;
  spec.young = 1e5;
  spec.poisson = 0.45;
  spec.psd_projection = GetParam().psd;
  const Model model = test::make_model(curved_element(rng), spec, Vec3::Zero());
  VecX x = deformed(model, rng);
  if (GetParam().psd)  // an indefinite element Hessian, as in ForcesAndStiffnessMatchFiniteDifferences
    for (int i = 0; i < model.fem.num_nodes; ++i)
      x.segment<3>(3 * i) = Vec3(model.fem.X(0, i), model.fem.X(1, i), 0.6 * model.fem.X(2, i)) +
                            2e-4 * Vec3(std::sin(7.0 * i), std::cos(5.0 * i), std::sin(3.0 * i));
  const int n3 = 3 * model.fem.num_nodes;
  const VecX u = test::random_vector(n3, 0.01, 1), w = test::random_vector(n3, 1.0, 2), y = test::random_vector(n3, 1.0, 3);
  const VecX one = VecX::Ones(1), zero = VecX::Zero(1);
  fem::FemData d;
  d.resize(model.fem);
  auto Kw = [&](const VecX& at) {
    EXPECT_TRUE(fem::evaluate(model.fem, at, {false, false, true}, d));
    VecX out;
    fem::symmetric_multiply(model.fem, d.K_values, w, out);
    return out;
  };
  // K u (a = 1): the evaluated stiffness times u. The unprojected K is what a = 1 uses.
  VecX Ku = VecX::Zero(n3);
  ASSERT_EQ(fem::add_stiffness_jvp(model.fem, x, u, w, one, zero, Ku), -1);
  ASSERT_GT(Ku.norm(), 0);
  // dK~[u] w (c = 1) against (K~(x + h u) w - K~(x - h u) w) / 2h. u has entries up to
  // 1% of the 1 cm element; h = 1e-4 makes the step 1e-6 of the edge (fd.hpp).
  VecX dKw = VecX::Zero(n3);
  ASSERT_EQ(fem::add_stiffness_jvp(model.fem, x, u, w, zero, one, dKw), -1);
  // Fourth-order central stencil: with psd_projection, K~ has a large third derivative
  // where an eigenvalue of the element Hessian is near 0 (the projection's divided
  // differences Gamma_ij have small gaps), and the second-order stencil's h^2 term
  // was 1e-5 of the result for stvk_psd at h = 1e-4 (measured); this stencil's h^4 term
  // is far below round-off (eps |K w| / h ~ 1e-12).
  const double h = 1e-4;
  const VecX fd = (8 * (Kw(x + h * u) - Kw(x - h * u)) - (Kw(x + 2 * h * u) - Kw(x - 2 * h * u))) / (12 * h);
  if (GetParam().law == Law::linear) {
    EXPECT_EQ(dKw.norm(), 0);  // constant K
    EXPECT_LT(fd.norm(), 1e-9 * Kw(x).norm());  // round-off eps |K w| / h ~ 1e-12 |K w|
  } else {
    ASSERT_GT(dKw.norm(), 0);
    const auto c = test::compare(dKw, fd);
    EXPECT_LT(c.rel_error, 1e-6) << "dK[u] w: " << c.str();
  }
  // Reverse: y^T (a K u + c dK[u] w) = u^T vjp(y) for both parts (dot-product test;
  // round-off of sums of 90 products: 1e-12 relative).
  VecX jv = VecX::Zero(n3), vj = VecX::Zero(n3);
  const VecX ab = VecX::Constant(1, 0.7), cb = VecX::Constant(1, 1.3);
  ASSERT_EQ(fem::add_stiffness_jvp(model.fem, x, u, w, ab, cb, jv), -1);
  ASSERT_EQ(fem::add_stiffness_vjp(model.fem, x, y, w, ab, cb, vj), -1);
  EXPECT_NEAR(y.dot(jv), u.dot(vj), 1e-12 * std::abs(y.dot(jv)) + 1e-300);
  // young and poisson: df_int/dp and dK~/dp w against central differences of models
  // rebuilt at p +/- h p (h = 1e-6 relative: fd.hpp).
  for (auto param : {fem::ElasticParameter::young, fem::ElasticParameter::poisson}) {
    VecX df = VecX::Zero(n3), dK = VecX::Zero(n3);
    ASSERT_EQ(fem::add_elastic_parameter_derivative(model.fem, x, 0, param, w, df, dK), -1);
    const double p0 = param == fem::ElasticParameter::young ? spec.young : spec.poisson, hp = 1e-6 * p0;
    auto at = [&](double p) {
      test::BodySpec s2 = spec;
      (param == fem::ElasticParameter::young ? s2.young : s2.poisson) = p;
      std::mt19937 rng2(21 + static_cast<int>(GetParam().law));
      const Model m2 = test::make_model(curved_element(rng2), s2, Vec3::Zero());
      fem::FemData d2;
      d2.resize(m2.fem);
      EXPECT_TRUE(fem::evaluate(m2.fem, x, {false, true, true}, d2));
      VecX kw;
      fem::symmetric_multiply(m2.fem, d2.K_values, w, kw);
      return std::make_pair(VecX(d2.f_int), kw);
    };
    const auto plus = at(p0 + hp), minus = at(p0 - hp);
    const auto cf = test::compare(df, (plus.first - minus.first) / (2 * hp));
    const auto cK = test::compare(dK, (plus.second - minus.second) / (2 * hp));
    EXPECT_LT(cf.rel_error, 1e-6) << "df/dp: " << cf.str();
    EXPECT_LT(cK.rel_error, 1e-6) << "dK/dp w: " << cK.str();
  }
}

INSTANTIATE_TEST_SUITE_P(Laws, Tet10Derivatives,
                         ::testing::Values(LawCase{Law::linear, false}, LawCase{Law::corotational, false},
                                           LawCase{Law::stvk, false}, LawCase{Law::neo_hookean, false},
                                           LawCase{Law::corotational, true}, LawCase{Law::stvk, true},
                                           LawCase{Law::neo_hookean, true}),
                         [](const ::testing::TestParamInfo<LawCase>& p) {
                           return std::string(material::law_name(p.param.law)) + (p.param.psd ? "_psd" : "");
                         });

}  // namespace tet10_test
