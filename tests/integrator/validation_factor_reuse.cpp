// Factor reuse on the shipped Trunk (configs/trunk.yaml: corotational, 8 embedded
// cables, each at 0.01 N, drooping under gravity from rest) and on a 1.6k-tet clamped
// beam falling from rest: the reuse trajectory in lockstep with the direct solve. Every
// step of the reuse trajectory is repeated from the same input with
// linear_solver: cholmod; the reuse step's dv satisfies the direct step's own system
// A dv = b to the relative residual pcg_tolerance (the derived tolerance, docs/method.md
// "Reusing the factor"; plus the direct answer's own residual, the round-off of the
// check), and the factor is kept on some steps (PCG did the work). The independent
// trajectories' final positions are reported (not asserted: their difference grows
// with the trajectory's own sensitivity, which this test does not bound).
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <bench/beam.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <cstdio>
#include <string>
#include <vector>

using namespace softdiff;

namespace validation_factor_reuse {

double relative_residual(const SparseMatrix& A_upper, const VecX& x, const VecX& b) {
  const SparseMatrix full = A_upper.selfadjointView<Eigen::Upper>();
  return (full * x - b).norm() / b.norm();
}

void check_lockstep(const Model& direct_model, int steps, const std::string& what) {
  Model model = direct_model;
  model.solver.factor_reuse = true;
  Data data(model), ref(direct_model), alone(direct_model);
  State s = model.initial, next, next_d, s_alone = model.initial, next_alone;
  const double tol = model.solver.pcg_tolerance;
  double worst = 0;
  for (int k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::implicit_euler_step(model, data, s, next, k);
    ASSERT_TRUE(st.ok()) << what << ": " << describe(model, st);
    ASSERT_TRUE(integrator::implicit_euler_step(direct_model, ref, s, next_d, k).ok());
    const double r = relative_residual(ref.A, data.dv, ref.rhs);
    EXPECT_LE(r, tol + relative_residual(ref.A, ref.dv, ref.rhs)) << what << " step " << k;
    worst = std::max(worst, r);
    std::swap(s, next);
    ASSERT_TRUE(integrator::implicit_euler_step(direct_model, alone, s_alone, next_alone, k).ok());
    std::swap(s_alone, next_alone);
  }
  const auto& c = data.solver->counters();
  EXPECT_GE(c.kept_factors, 1) << what;
  EXPECT_GE(c.pcg_iterations, c.kept_factors) << what;
  const Eigen::Map<const VecX> X(model.fem.X.data(), s.x.size());
  std::printf(
      "%s: %d steps, %ld factorizations, %ld kept, %.2f PCG iterations per kept step, worst residual %.2e; "
      "independent runs: max |x_pcg - x_direct| = %.2e m, max displacement %.2e m\n",
      what.c_str(), steps, c.numeric_factorizations, c.kept_factors,
      c.kept_factors ? static_cast<double>(c.pcg_iterations) / c.kept_factors : 0.0, worst,
      (s.x - s_alone.x).cwiseAbs().maxCoeff(), (s_alone.x - X).cwiseAbs().maxCoeff());
}

TEST(FactorReuseValidation, TrunkMatchesTheDirectSolveStepByStep) {
  std::vector<std::string> overrides;
  for (const char* cable : {"cableL0", "cableL1", "cableL2", "cableL3", "cableS0", "cableS1", "cableS2", "cableS3"})
    overrides.push_back(std::string("bodies.trunk.actuators.") + cable + ".force=0.01");
  const Model model =
      io::build_model(io::load_scene(std::string(SOFTDIFF_SOURCE_DIR) + "/configs/trunk.yaml", overrides));
  ASSERT_EQ(model.step.newton_iterations, 1);
  check_lockstep(model, 30, "trunk");
}

TEST(FactorReuseValidation, BeamMatchesTheDirectSolveStepByStep) {
  const Model model = bench::cantilever_beam(3, material::Law::corotational, 100);  // the benchmarks' 1.6k-tet beam
  check_lockstep(model, 100, "beam 1.6k tets");
}

}  // namespace validation_factor_reuse
