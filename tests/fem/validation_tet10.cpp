// Validation of the quadratic tetrahedron: the static cantilever of
// tests/integrator/validation_cantilever.cpp, at poisson 0.45 (silicone, where linear
// tetrahedra lock), against Timoshenko beam theory, for 10-node tets (straight
// mid-edge nodes added to the same box meshes) and 4-node tets.
//
// Beam: L = 0.2 m, square section H = 0.02 m, E = 1e6 Pa, nu = 0.45, rho = 1070 kg/m^3
// (configs/beam_cantilever.yaml's material), clamped at x = 0, gravity 0.0981 m/s^2
// along -z (the tip moves ~0.3% of L: docs/accuracy.md's case A), corotational law.
//     w = q L^4 / (8 E I) + q L^2 / (2 kappa G A),  q = rho g A,
// kappa = 10 (1 + nu) / (12 + 11 nu) (Cowper). The tip deflection is the mean vertical
// displacement of the tip face's vertex nodes.
//
// The 3D clamped beam is not exactly a Timoshenko beam (the clamp also stops the
// section's Poisson contraction, and Cowper's kappa is itself an approximation): the
// converged 3D answer, estimated by Richardson extrapolation of the 10-node sequence
// (480, 1620, 3840 tets; observed order 1.88), is 2.2% stiffer than Timoshenko at
// poisson 0.45 (measured 2026-12-02; a first guess of 1% was wrong). The tests check
// (a) the extrapolated 3D value within 3% of Timoshenko (an independent sanity check
// of the reference), (b) the 10-node element at the coarse mesh (480 tets)
// within 2.5% of it (the issue: CalculiX C3D10 is 2% off at 480 tets; softdiff: 1.95%),
// where 4-node tets on the same mesh are 70% too stiff, (c) an observed order of at
// least 1.7, and (d) 10-node elements on 480 tets more accurate than 4-node ones on
// 30720 (64 times the elements).
#include <softdiff/data.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <cmath>
#include <cstdio>
#include <gtest/gtest.h>

using namespace softdiff;

namespace tet10_cantilever {

constexpr double L = 0.2, H = 0.02, E = 1e6, nu = 0.45, rho = 1070, g = 0.0981;

double timoshenko_tip(double poisson) {
  const double A = H * H, I = H * H * H * H / 12, G = E / (2 * (1 + poisson));
  const double kappa = 10 * (1 + poisson) / (12 + 11 * poisson);
  const double q = rho * g * A;
  return q * std::pow(L, 4) / (8 * E * I) + q * L * L / (2 * kappa * G * A);
}

double tip(int n, bool quadratic, double poisson = nu, int* tets = nullptr) {
  test::BodySpec spec;
  spec.law = material::Law::corotational;
  spec.young = E;
  spec.poisson = poisson;
  spec.density = rho;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  mesh::TetMesh m = test::box_mesh(10 * n, n, n, L, H, H);
  const int vertices = m.num_nodes();
  if (quadratic) mesh::elevate_to_quadratic(m);
  Model model = test::make_model(m, spec, Vec3(0, 0, -g));
  if (tets) *tets = model.fem.num_tets;
  model.step.integrator = IntegratorKind::static_equilibrium;
  model.step.static_tolerance = 1e-10;
  Data data(model);
  State out;
  const auto status = integrator::solve_static(model, data, model.initial, out);
  EXPECT_TRUE(status.ok()) << describe(model, status);
  double sum = 0;
  int count = 0;
  for (int i = 0; i < vertices; ++i)
    if (model.fem.X(0, i) > L - 1e-9) {
      sum += out.x[3 * i + 2] - model.fem.X(2, i);
      ++count;
    }
  return -sum / count;
}

TEST(Tet10Cantilever, LockingOfLinearTetsIsGone) {
  const double reference = timoshenko_tip(nu);
  int tets = 0;
  const double p2_480 = tip(2, true, nu, &tets);
  EXPECT_EQ(tets, 480);
  const double p1_480 = tip(2, false);
  const double p1_30720 = tip(8, false);
  const double p2_1620 = tip(3, true);
  const double p2_3840 = tip(4, true);
  auto err = [&](double w) { return w / reference - 1; };
  std::printf("Timoshenko tip %.6e m\n", reference);
  std::printf("TET4   480 tets: %.6e m (%+.4f)\n", p1_480, err(p1_480));
  std::printf("TET4 30720 tets: %.6e m (%+.4f)\n", p1_30720, err(p1_30720));
  std::printf("TET10  480 tets: %.6e m (%+.4f)\n", p2_480, err(p2_480));
  std::printf("TET10 1620 tets: %.6e m (%+.4f)\n", p2_1620, err(p2_1620));
  std::printf("TET10 3840 tets: %.6e m (%+.4f)\n", p2_3840, err(p2_3840));
  // Richardson extrapolation of the 10-node sequence (h = 1/2, 1/3, 1/4 of H).
  const double d1 = p2_1620 - p2_480, d2 = p2_3840 - p2_1620;
  ASSERT_GT(d1, 0);
  ASSERT_GT(d2, 0);
  // Successive differences scale as h^p: d1 ~ (1/2^p - 1/3^p), d2 ~ (1/3^p - 1/4^p);
  // solve for p by bisection.
  auto ratio = [](double p) { return (std::pow(2.0, -p) - std::pow(3.0, -p)) / (std::pow(3.0, -p) - std::pow(4.0, -p)); };
  double lo = 0.5, hi = 6;
  for (int k = 0; k < 100; ++k) {
    const double mid = 0.5 * (lo + hi);
    (ratio(mid) < d1 / d2 ? lo : hi) = mid;
  }
  const double order = 0.5 * (lo + hi);
  const double extrapolated = p2_3840 + d2 * std::pow(4.0, -order) / (std::pow(3.0, -order) - std::pow(4.0, -order));
  std::printf("TET10 observed order %.2f, extrapolated %.6e m (%+.4f of Timoshenko)\n", order, extrapolated,
              err(extrapolated));
  EXPECT_GT(p1_480, 0);
  EXPECT_LT(err(p1_480), -0.30) << "linear tets lock at poisson 0.45";
  std::printf("relative to the extrapolated 3D value: TET10 480 tets %+.4f, TET4 30720 tets %+.4f\n",
              p2_480 / extrapolated - 1, p1_30720 / extrapolated - 1);
  EXPECT_LT(std::abs(err(extrapolated)), 0.03);
  EXPECT_LT(std::abs(p2_480 / extrapolated - 1), 0.025);
  EXPECT_LT(std::abs(p2_480 / extrapolated - 1), std::abs(p1_30720 / extrapolated - 1));
  EXPECT_GT(order, 1.7);
  // Monotone convergence from below (the element is still slightly stiff).
  EXPECT_LT(p2_480, p2_1620);
  EXPECT_LT(p2_1620, p2_3840);
}

// At poisson 0.49 and 0.499 (documented in method.md and docs/accuracy.md): how much
// TET10 still locks, against Timoshenko at that poisson and against the 3D value
// extrapolated from the TET10 sequence (480, 1620, 3840 tets) as above. The locking
// figure is the 480-tet deflection's deficit against the extrapolation; printed, and
// bounded by the checks below only where the physics says so (10-node elements less
// stiff than 4-node ones, the finest within 5% of beam theory).
TEST(Tet10Cantilever, NearIncompressibility) {
  for (double poisson : {0.45, 0.49, 0.499}) {
    const double reference = timoshenko_tip(poisson);
    const double p2 = tip(2, true, poisson), p2_mid = tip(3, true, poisson), p2_fine = tip(4, true, poisson);
    const double p1 = tip(2, false, poisson);
    std::printf("poisson %.3f: TET10 480 tets %+.4f, 1620 tets %+.4f, 3840 tets %+.4f; TET4 480 tets %+.4f (relative "
                "to Timoshenko)\n",
                poisson, p2 / reference - 1, p2_mid / reference - 1, p2_fine / reference - 1, p1 / reference - 1);
    const double d1 = p2_mid - p2, d2 = p2_fine - p2_mid;
    if (d1 > 0 && d2 > 0 && d1 > d2) {
      auto ratio = [](double p) {
        return (std::pow(2.0, -p) - std::pow(3.0, -p)) / (std::pow(3.0, -p) - std::pow(4.0, -p));
      };
      double lo = 0.2, hi = 8;
      for (int k = 0; k < 100; ++k) {
        const double mid = 0.5 * (lo + hi);
        (ratio(mid) < d1 / d2 ? lo : hi) = mid;
      }
      const double order = 0.5 * (lo + hi);
      const double ex = p2_fine + d2 * std::pow(4.0, -order) / (std::pow(3.0, -order) - std::pow(4.0, -order));
      std::printf("poisson %.3f: observed order %.2f, extrapolated %.6e m (%+.4f of Timoshenko); against it TET10 "
                  "480 tets %+.4f, 1620 tets %+.4f, 3840 tets %+.4f, TET4 480 tets %+.4f\n",
                  poisson, order, ex, ex / reference - 1, p2 / ex - 1, p2_mid / ex - 1, p2_fine / ex - 1, p1 / ex - 1);
    } else {
      std::printf("poisson %.3f: the TET10 sequence is not monotone (differences %.3e, %.3e): no extrapolation\n",
                  poisson, d1, d2);
    }
    EXPECT_GT(p2, p1) << "10-node elements are less stiff than 4-node ones";
    EXPECT_LT(std::abs(p2_fine / reference - 1), 0.05) << "10-node elements do not lock at poisson " << poisson;
  }
}

}  // namespace tet10_cantilever
