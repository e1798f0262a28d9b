// Validation: static equilibrium of a cube in uniaxial stress, compressed to a stretch
// of 0.7 and stretched to 1.5, for every law, against the closed form.
//
// The cube [0, l]^3 (2 x 2 x 2 boxes, 48 tets; 3 x 3 x 3, 162 tets) has sliding-symmetric (roller)
// boundary conditions: the face x = 0 is fixed in x only, y = 0 in y only, z = 0 in z
// only; the face x = l is fixed in x at a l (displacement control), free in y and z.
// No gravity. The solution is homogeneous, F = diag(a, b, b), which linear tets
// represent exactly, so the discrete equilibrium equals the closed form to the
// solver's tolerance. With F diagonal, the first Piola-Kirchhoff stress of each energy
// of docs/method.md is diagonal:
//   linear:       P_i = 2 mu (F_i - 1) + lambda (a + 2 b - 3)
//   corotational: R = I, S = F for a diagonal positive F: the same as linear
//   stvk:         P_i = F_i (2 mu E_i + lambda (E_a + 2 E_b)), E_i = (F_i^2 - 1) / 2
//   neo_hookean:  P_i = mu (F_i - 1 / F_i) + lambda ln(J) / F_i, J = a b^2
// The lateral stretch b solves P_b(a, b) = 0 (uniaxial stress; bisection below), and
// the axial force on the face x = l is P_a(a, b) l^2.
//
// The start is the rest state with only the face x = l moved to a l: the elements next
// to it are then at a stretch 2 a - 1 (0.4 in compression; 3 a - 2 = 0.1 with 3 boxes
// a side), where the corotational,
// StVK and Neo-Hookean element Hessians are indefinite: the solver must get from there
// to the stable equilibrium (solve_static shifts the tangent where it is not positive
// definite). StVK under uniaxial stress has a limit point in compression: its force
// P_a = E a (a^2 - 1) / 2 is largest in magnitude at a = 1/sqrt(3) ~ 0.577 and falls
// beyond; at a = 0.7 (displacement control) the equilibrium exists and is stable
// (dP_a/da = E (3 a^2 - 1) / 2 > 0).
//
// Tolerances: the solver stops at a relative residual of 1e-10 (static_tolerance);
// positions within 1e-8 l and the axial force within 1e-8 relative.
#include <softdiff/data.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <support/meshes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <string>

using namespace softdiff;

namespace {

constexpr double kL = 0.1, kYoung = 1e5;

struct Closed {
  double b = 0;      // lateral stretch
  double P_a = 0;    // axial first Piola-Kirchhoff stress (Pa)
};

// P_i for F = diag(a, b, b): axial (i = 0) and lateral (i = 1).
double piola(material::Law law, double mu, double lambda, double a, double b, int i) {
  const double Fi = i == 0 ? a : b;
  switch (law) {
    case material::Law::linear:
    case material::Law::corotational: return 2 * mu * (Fi - 1) + lambda * (a + 2 * b - 3);
    case material::Law::stvk: {
      const double Ea = (a * a - 1) / 2, Eb = (b * b - 1) / 2, Ei = i == 0 ? Ea : Eb;
      return Fi * (2 * mu * Ei + lambda * (Ea + 2 * Eb));
    }
    case material::Law::neo_hookean: return mu * (Fi - 1 / Fi) + lambda * std::log(a * b * b) / Fi;
  }
  return 0;
}

Closed closed_form(material::Law law, double young, double poisson, double a) {
  const double mu = young / (2 * (1 + poisson)), lambda = young * poisson / ((1 + poisson) * (1 - 2 * poisson));
  // P_b is increasing in b on [0.2, 2] for every law here, negative at 0.2 and
  // positive at 2 for a in [0.7, 1.5] (checked below): bisection to round-off.
  double lo = 0.2, hi = 2.0;
  EXPECT_LT(piola(law, mu, lambda, a, lo, 1), 0);
  EXPECT_GT(piola(law, mu, lambda, a, hi, 1), 0);
  for (int k = 0; k < 200 && hi - lo > 1e-16; ++k) {
    const double m = 0.5 * (lo + hi);
    (piola(law, mu, lambda, a, m, 1) < 0 ? lo : hi) = m;
  }
  Closed c;
  c.b = 0.5 * (lo + hi);
  c.P_a = piola(law, mu, lambda, a, c.b, 0);
  return c;
}

struct Compression {
  StepStatus status;
  Model model;
  State out;
  int shifted = 0;
};

Compression compress(material::Law law, double poisson, double a, int cells = 2) {
  Compression run;
  Model& model = run.model;
  fem::BodyModel b;
  b.name = "cube";
  b.mesh = test::box_mesh(cells, cells, cells, kL, kL, kL);
  b.surface = mesh::boundary_triangles(b.mesh.tets);
  b.law = law;
  b.young = kYoung;
  b.poisson = poisson;
  b.density = 1000;
  const int n = b.mesh.num_nodes();
  std::vector<unsigned char> fixed(3 * static_cast<size_t>(n), 0);
  for (int i = 0; i < n; ++i) {
    const Vec3 p = b.mesh.X.col(i);
    if (p.x() < 1e-12 || p.x() > kL - 1e-12) fixed[3 * i] = 1;
    if (p.y() < 1e-12) fixed[3 * i + 1] = 1;
    if (p.z() < 1e-12) fixed[3 * i + 2] = 1;
  }
  std::vector<fem::BodyModel> bodies;
  bodies.push_back(std::move(b));
  fem::build_fem_model(std::move(bodies), fixed, Vec3::Zero(), model.fem);
  model.step.integrator = IntegratorKind::static_equilibrium;
  model.step.gravity = Vec3::Zero();
  model.step.static_tolerance = 1e-10;
  model.initial.x = Eigen::Map<const VecX>(model.fem.X.data(), 3 * n);
  model.initial.v = VecX::Zero(3 * n);
  for (int i = 0; i < n; ++i)
    if (model.fem.X(0, i) > kL - 1e-12) model.initial.x[3 * i] = a * kL;
  Data data(model);
  run.status = integrator::solve_static(model, data, model.initial, run.out);
  run.shifted = data.static_shifted_iterations;
  return run;
}

void check(material::Law law, double poisson, double a, int cells = 2) {
  const std::string name = std::string(material::law_name(law)) + " nu " + std::to_string(poisson) + " stretch " +
                           std::to_string(a) + " cells " + std::to_string(cells);
  const Compression run = compress(law, poisson, a, cells);
  ASSERT_TRUE(run.status.ok()) << name << ": " << describe(run.model, run.status);
  const Closed c = closed_form(law, kYoung, poisson, a);
  const auto& fem = run.model.fem;
  double worst = 0;
  for (int i = 0; i < fem.num_nodes; ++i) {
    const Vec3 X = fem.X.col(i);
    const Vec3 exact(a * X.x(), c.b * X.y(), c.b * X.z());
    worst = std::max(worst, (run.out.x.segment<3>(3 * i) - exact).norm());
  }
  EXPECT_LE(worst, 1e-8 * kL) << name << ": lateral stretch " << c.b;
  // The axial force on the face x = l: the reactions there, -f_int.
  Data data(run.model);
  ASSERT_TRUE(fem::evaluate(fem, run.out.x, {false, true, false}, data.fem));
  double force = 0;
  for (int i = 0; i < fem.num_nodes; ++i)
    if (fem.X(0, i) > kL - 1e-12) force -= data.fem.f_int[3 * i];
  const double expected = c.P_a * kL * kL;
  EXPECT_NEAR(force, expected, 1e-8 * std::abs(expected)) << name;
  std::printf("%-12s nu %.2f stretch %.1f, %d cells a side: lateral stretch %.10f, axial force %.8e N (closed form %.8e), "
              "shifted Newton iterations %d of %d\n",
              std::string(material::law_name(law)).c_str(), poisson, a, cells, c.b, force, expected, run.shifted, run.status.iterations);
}

const material::Law kLaws[] = {material::Law::linear, material::Law::corotational, material::Law::stvk,
                               material::Law::neo_hookean};

TEST(StaticUniaxial, CompressionToStretch07MatchesTheClosedFormForEveryLaw) {
  for (const auto law : kLaws) check(law, 0.3, 0.7);
}

TEST(StaticUniaxial, TensionToStretch15MatchesTheClosedFormForEveryLaw) {
  for (const auto law : kLaws) check(law, 0.3, 1.5);
}

TEST(StaticUniaxial, NearlyIncompressibleCompression) {
  for (const auto law : kLaws) check(law, 0.45, 0.7);
}

// 3 x 3 x 3 boxes: the start crushes the layer next to the moved face to a stretch of
// 0.1 (compression) or stretches it to 2.5 (tension).
TEST(StaticUniaxial, FinerMeshFromAHarderStart) {
  for (const auto law : kLaws) {
    check(law, 0.3, 0.7, 3);
    check(law, 0.3, 1.5, 3);
  }
}

// The linear law's tangent is constant and positive definite: exact Newton, one step,
// no shift.
TEST(StaticUniaxial, APositiveDefiniteTangentIsNeverShifted) {
  const Compression run = compress(material::Law::linear, 0.3, 0.7);
  ASSERT_TRUE(run.status.ok()) << describe(run.model, run.status);
  EXPECT_EQ(run.shifted, 0);
  EXPECT_LE(run.status.iterations, 1);
}

}  // namespace
