// Validation: static cantilever under its own weight against Timoshenko beam theory,
// over a sequence of refined meshes, with the observed order of convergence.
//
// Beam: L = 0.2 m, square section H = W = 0.02 m, E = 3e8 Pa, nu = 0.3, rho = 1000,
// clamped at x = 0 (all dofs of the face), gravity -z. The tip deflection is about
// 1e-3 L, so geometric nonlinearity changes it by ~1e-6 relative: the small-strain
// Timoshenko value is the reference,
//     w = q L^4 / (8 E I) + q L^2 / (2 kappa G A),  q = rho g A,
// kappa = 10 (1 + nu) / (12 + 11 nu) (Cowper, rectangular section). The tip
// deflection is measured as the mean vertical displacement of the tip face's nodes.
// Linear tetrahedra are too stiff in bending (shear locking) and converge from
// below (observed order ~1.5-2 in h); the finest mesh (n = 12 elements across,
// 103680 tets) must be within 5%.
#include <softdiff/data.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <cmath>
#include <gtest/gtest.h>

using namespace softdiff;

namespace {

constexpr double L = 0.2, H = 0.02, E = 3e8, nu = 0.3, rho = 1000, g = 9.81;

double timoshenko_tip() {
  const double A = H * H, I = H * H * H * H / 12, G = E / (2 * (1 + nu));
  const double kappa = 10 * (1 + nu) / (12 + 11 * nu);
  const double q = rho * g * A;
  return q * std::pow(L, 4) / (8 * E * I) + q * L * L / (2 * kappa * G * A);
}

double softdiff_tip(int n, material::Law law) {
  test::BodySpec spec;
  spec.law = law;
  spec.young = E;
  spec.poisson = nu;
  spec.density = rho;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  Model model = test::make_model(test::box_mesh(10 * n, n, n, L, H, H), spec, Vec3(0, 0, -g));
  model.step.integrator = IntegratorKind::static_equilibrium;
  model.step.static_tolerance = 1e-10;
  Data data(model);
  State out;
  const auto status = integrator::solve_static(model, data, model.initial, out);
  EXPECT_TRUE(status.ok()) << describe(model, status);
  double sum = 0;
  int count = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (model.fem.X(0, i) > L - 1e-9) {
      sum += out.x[3 * i + 2] - model.fem.X(2, i);
      ++count;
    }
  return -sum / count;
}

TEST(CantileverValidation, StaticTipDeflectionConvergesToTimoshenko) {
  const double reference = timoshenko_tip();
  const int sizes[] = {3, 6, 12};
  double errors[3];
  for (int k = 0; k < 3; ++k) {
    const double tip = softdiff_tip(sizes[k], material::Law::corotational);
    errors[k] = (reference - tip) / reference;
    std::printf("n = %d across (%d tets): tip %.6e m, Timoshenko %.6e m, relative error %+.4f\n", sizes[k],
                60 * sizes[k] * sizes[k] * sizes[k], tip, reference, -errors[k]);
    EXPECT_GT(errors[k], 0) << "linear tets should be stiffer than the beam";
  }
  for (int k = 0; k + 1 < 3; ++k) {
    const double order = std::log(errors[k] / errors[k + 1]) / std::log(2.0);
    std::printf("observed order between n = %d and n = %d: %.2f\n", sizes[k], sizes[k + 1], order);
    // Linear tets converge at order 2 in displacement asymptotically; on these meshes
    // the bending (locking) error is still pre-asymptotic (observed 1.46 then 1.57).
    // Require clearly better than first order, and no more than second.
    EXPECT_GT(order, 1.3);
    EXPECT_LT(order, 2.2);
    EXPECT_LT(errors[k + 1], errors[k]);
  }
  EXPECT_LT(errors[2], 0.05);
}

// At small strain the three laws agree (they share the linearization at rest).
TEST(CantileverValidation, LawsAgreeAtSmallStrain) {
  const double co = softdiff_tip(2, material::Law::corotational);
  const double st = softdiff_tip(2, material::Law::stvk);
  const double nh = softdiff_tip(2, material::Law::neo_hookean);
  EXPECT_NEAR(st, co, 1e-3 * co);
  EXPECT_NEAR(nh, co, 1e-3 * co);
}

}  // namespace
