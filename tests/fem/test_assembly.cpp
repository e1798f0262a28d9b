// Global assembly: forces and stiffness of a multi-element mesh against finite
// differences, the fixed pattern, mass, thread-count independence and the patch test.
#include <softdiff/data.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <support/fd.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>
#include <omp.h>
#include <random>

using namespace softdiff;
using material::Law;

namespace {

MatX dense_from_upper(const Model& model, const VecX& values) {
  const int n = 3 * model.fem.num_nodes;
  MatX D = MatX::Zero(n, n);
  const auto& S = model.fem.pattern.structure;
  for (int col = 0; col < n; ++col)
    for (int k = S.outerIndexPtr()[col]; k < S.outerIndexPtr()[col + 1]; ++k) {
      const int row = S.innerIndexPtr()[k];
      D(row, col) = values[k];
      D(col, row) = values[k];
    }
  return D;
}

VecX random_deformation(const Model& model, double amplitude, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  VecX x = model.initial.x;
  for (int k = 0; k < x.size(); ++k) x[k] += amplitude * u(rng);
  return x;
}

class AssemblyLaw : public ::testing::TestWithParam<Law> {};

TEST_P(AssemblyLaw, GlobalForcesAndStiffnessMatchFiniteDifferences) {
  const auto mesh = test::box_mesh(2, 1, 1, 0.02, 0.01, 0.01);
  test::BodySpec spec;
  spec.law = GetParam();
  const Model model = test::make_model(mesh, spec);
  fem::FemData data;
  data.resize(model.fem);
  const VecX x = random_deformation(model, 1e-3, 1);
  ASSERT_TRUE(fem::evaluate(model.fem, x, {true, true, true}, data));
  const VecX f = data.f_int;
  const MatX K = dense_from_upper(model, data.K_values);
  auto energy = [&](const VecX& y) {
    fem::FemData d;
    d.resize(model.fem);
    fem::evaluate(model.fem, y, {true, false, false}, d);
    return d.energy;
  };
  auto forces = [&](const VecX& y) -> VecX {
    fem::FemData d;
    d.resize(model.fem);
    fem::evaluate(model.fem, y, {false, true, false}, d);
    return d.f_int;
  };
  const double h = 1e-6 * 0.01;  // 1e-6 of the element size
  const auto cf = test::compare(f, -test::fd_gradient(energy, x, h));
  EXPECT_LT(cf.rel_error, 1e-6) << cf.str();
  const auto cK = test::compare(K, -test::fd_jacobian(forces, x, h));
  EXPECT_LT(cK.rel_error, 1e-6) << cK.str();
  // symmetric_multiply agrees with the dense matrix.
  const VecX v = random_deformation(model, 1.0, 2) - model.initial.x;
  VecX Kv;
  fem::symmetric_multiply(model.fem, data.K_values, v, Kv);
  EXPECT_LT((Kv - K * v).norm(), 1e-12 * (K * v).norm());
}

INSTANTIATE_TEST_SUITE_P(AllLaws, AssemblyLaw, ::testing::Values(Law::corotational, Law::stvk, Law::neo_hookean),
                         [](const auto& p) { return std::string(material::law_name(p.param)); });

TEST(Mass, LumpedAndConsistentSumToBodyMassAndGravityIsWeight) {
  const auto mesh = test::box_mesh(3, 2, 2, 0.3, 0.1, 0.05);
  for (auto kind : {fem::MassKind::lumped, fem::MassKind::consistent}) {
    test::BodySpec spec;
    spec.density = 1200;
    spec.mass = kind;
    const Model model = test::make_model(mesh, spec, Vec3(0, 0, -9.81));
    const double expected = 1200 * 0.3 * 0.1 * 0.05;
    EXPECT_NEAR(model.fem.total_mass, expected, 1e-12 * expected);
    EXPECT_NEAR(model.fem.mass_diagonal.sum() / 3, expected, 1e-12 * expected);
    double fz = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i) fz += model.fem.gravity_force[3 * i + 2];
    EXPECT_NEAR(fz, -9.81 * expected, 1e-12 * 9.81 * expected);
    // 1^T M 1 per component = total mass (consistent mass rows sum to the lumped mass).
    const MatX M = dense_from_upper(model, model.fem.mass_values);
    VecX ones_x = VecX::Zero(M.rows());
    for (int i = 0; i < model.fem.num_nodes; ++i) ones_x[3 * i] = 1;
    EXPECT_NEAR(ones_x.dot(M * ones_x), expected, 1e-12 * expected);
    if (kind == fem::MassKind::consistent) {
      Eigen::SelfAdjointEigenSolver<MatX> eig(M);
      EXPECT_GT(eig.eigenvalues().minCoeff(), 0);
    }
  }
}

TEST(Assembly, ResultDoesNotDependOnThreadCount) {
  const auto mesh = test::box_mesh(6, 4, 4, 0.06, 0.04, 0.04);
  test::BodySpec spec;
  const Model model = test::make_model(mesh, spec);
  const VecX x = random_deformation(model, 2e-3, 9);
  fem::FemData a, b;
  a.resize(model.fem);
  b.resize(model.fem);
  const int saved = omp_get_max_threads();
  omp_set_num_threads(1);
  ASSERT_TRUE(fem::evaluate(model.fem, x, {true, true, true}, a));
  omp_set_num_threads(2);
  ASSERT_TRUE(fem::evaluate(model.fem, x, {true, true, true}, b));
  omp_set_num_threads(saved);
  // Coloring fixes the summation order: bitwise identical.
  EXPECT_EQ((a.f_int - b.f_int).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ((a.K_values - b.K_values).cwiseAbs().maxCoeff(), 0.0);
}

TEST(Assembly, ColoringSeparatesElementsSharingNodes) {
  const auto mesh = test::box_mesh(5, 5, 5, 1, 1, 1);
  const Model model = test::make_model(mesh, {});
  const auto& p = model.fem.pattern;
  for (size_t c = 0; c + 1 < p.color_begin.size(); ++c) {
    std::vector<int> seen(model.fem.num_nodes, 0);
    for (int k = p.color_begin[c]; k < p.color_begin[c + 1]; ++k)
      for (int a = 0; a < 4; ++a) EXPECT_EQ(seen[model.fem.tets(a, p.color_elements[k])]++, 0);
  }
  EXPECT_EQ(static_cast<int>(p.color_elements.size()), model.fem.num_tets);
}

TEST(Assembly, InvertedElementIsReportedByIndex) {
  const auto mesh = test::box_mesh(2, 2, 2, 1, 1, 1);
  const Model model = test::make_model(mesh, {});
  VecX x = model.initial.x;
  // Push the centre node (1,1,1) through the corner: the tets around it invert.
  const int centre = 1 + 3 * (1 + 3 * 1);
  x.segment<3>(3 * centre) = Vec3(-0.5, -0.5, -0.5);
  fem::FemData data;
  data.resize(model.fem);
  EXPECT_FALSE(fem::evaluate(model.fem, x, {false, true, true}, data));
  ASSERT_GE(data.bad_element, 0);
  bool touches = false;
  for (int a = 0; a < 4; ++a) touches = touches || model.fem.tets(a, data.bad_element) == centre;
  EXPECT_TRUE(touches);
  EXPECT_LE(data.bad_det, 0);
  EXPECT_EQ(fem::find_inverted_element(model.fem, x), data.bad_element);
}

// Patch test: with every boundary node placed by an affine map x = A X + c, the
// static solution reproduces that map exactly at the interior nodes (linear tets
// represent uniform strain exactly), for every law, even at finite strain.
TEST_P(AssemblyLaw, PatchTestReproducesUniformStrain) {
  const auto mesh = test::box_mesh(3, 3, 3, 0.03, 0.03, 0.03);
  test::BodySpec spec;
  spec.law = GetParam();
  spec.fixed = [](const Vec3& p) {
    for (int c = 0; c < 3; ++c)
      if (p[c] < 1e-9 || p[c] > 0.03 - 1e-9) return true;
    return false;
  };
  Model model = test::make_model(mesh, spec, Vec3::Zero());
  model.step.integrator = IntegratorKind::static_equilibrium;
  model.step.static_tolerance = 1e-12;
  Mat3 A;
  A << 1.08, 0.05, -0.02, 0.03, 0.95, 0.04, -0.01, 0.02, 1.1;
  const Vec3 c(0.001, -0.002, 0.0005);
  State in = model.initial;
  VecX affine = in.x;
  for (int i = 0; i < model.fem.num_nodes; ++i) affine.segment<3>(3 * i) = A * model.fem.X.col(i) + c;
  for (int k = 0; k < affine.size(); ++k)
    if (model.fem.fixed[k]) in.x[k] = affine[k];  // interior nodes start at rest: Newton must find them
  // The boundary displacement applied in one go can invert elements next to the
  // boundary on the first Newton step; the line search handles it.
  Data data(model);
  State out;
  const StepStatus s = integrator::solve_static(model, data, in, out);
  ASSERT_TRUE(s.ok()) << describe(model, s);
  EXPECT_LT((out.x - affine).cwiseAbs().maxCoeff(), 1e-12) << material::law_name(GetParam());
}

}  // namespace
