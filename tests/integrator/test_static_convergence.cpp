// The static solver's answer criterion (static.convergence: answer; method.md "Static
// equilibrium") against the residual criterion at 1e-10 on a cantilever under its
// weight with a large deflection (geometrically nonlinear: several Newton iterations
// with line search per load step): fewer factorizations, and the same
// answer to within the criterion's bound.
#include <softdiff/data.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <cstdio>

using namespace softdiff;

namespace static_convergence_test {

// 0.2 x 0.02 x 0.02 m, E = 1 MPa, nu = 0.45, rho = 1070 kg/m^3 (configs/beam_cantilever_static.yaml's
// material), clamped at x = 0; 960 linear tets.
Model beam(int load_steps) {
  test::BodySpec spec;
  spec.law = material::Law::corotational;
  spec.young = 1e6;
  spec.poisson = 0.45;
  spec.density = 1070;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  Model model = test::make_model(test::box_mesh(20, 2, 2, 0.2, 0.02, 0.02), spec, Vec3(0, 0, -9.81));
  model.step.integrator = IntegratorKind::static_equilibrium;
  model.step.static_tolerance = 1e-10;
  model.step.static_load_steps = load_steps;
  return model;
}

struct Solved {
  State out;
  long factorizations;
};

Solved solve(const Model& model) {
  Data data(model);
  Solved r;
  const StepStatus st = integrator::solve_static(model, data, model.initial, r.out);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  r.factorizations = data.factorizations;
  return r;
}

TEST(StaticConvergence, AnswerCriterionStopsEarlierAtTheSameAnswer) {
  for (int load_steps : {1, 4}) {
    const Model residual = beam(load_steps);  // static_displacement_tolerance = 0: residual criterion
    Model answer = residual;
    answer.step.static_displacement_tolerance = 1e-4;  // the scene defaults
    answer.step.static_residual_tolerance = 1e-3;
    const Solved ref = solve(residual), ans = solve(answer);
    const double u = (ref.out.x - residual.initial.x).cwiseAbs().maxCoeff();
    const double diff = (ans.out.x - ref.out.x).cwiseAbs().maxCoeff();
    std::printf("load_steps %d: factorizations %ld (residual 1e-10) -> %ld (answer); max |u| %.4e m, "
                "max |x_answer - x_residual| %.3e m (%.2e of max |u|)\n",
                load_steps, ref.factorizations, ans.factorizations, u, diff, diff / u);
    ASSERT_GE(ref.factorizations, 4 * load_steps);  // nonlinear: several Newton iterations per load step
    EXPECT_LT(ans.factorizations, ref.factorizations) << "load_steps " << load_steps;
    // The criterion bounds the change still to come by displacement_tolerance of the
    // displacement (for linear convergence; Newton's is quadratic, far below).
    EXPECT_LE(diff, 1e-4 * u) << "load_steps " << load_steps;
  }
}

}  // namespace static_convergence_test
