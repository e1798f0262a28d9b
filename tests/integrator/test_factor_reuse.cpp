// Factor reuse (linear_solver.factor_reuse: pcg, docs/method.md "Reusing the factor"):
// CHOLMOD keeps the factor of an earlier matrix and solves the new one by PCG to the
// relative residual pcg_tolerance. Checked here:
//   - a kept factor solves the new matrix to the tolerance (the residual is computed
//     here, independently of the solver's own test), and the answer is the direct one
//     within cond(A) times the tolerance;
//   - the refactorization rule: a solve that needed more than refactor_iterations
//     iterations makes the next factorize() factorize (and exactly then: the same
//     sequence with the threshold at the iteration count keeps the factor); a solve
//     that has not converged after pcg_max_iterations factorizes and solves directly;
//     a matrix that is not positive definite is reported with its column;
//   - the Delassus congruence B^T A^{-1} B (which needs A's own factor) refactorizes;
//   - trajectories in lockstep with the direct solve (implicit Euler, BDF2, control's
//     keep_linearization): every step's answer satisfies the direct step's own system
//     A dv = b to pcg_tolerance.
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include <cmath>
#include <string>

using namespace softdiff;

namespace factor_reuse_test {

// A clamped corotational beam, 8 x 2 x 2 cells (243 dofs), soft enough (E = 1e5 Pa) to
// sag visibly within a few steps, with Rayleigh damping.
Model beam(double dt = 0.01) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.poisson = 0.4;
  spec.rayleigh_mass = 0.1;
  spec.rayleigh_stiffness = 0.001;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  return test::make_model(test::box_mesh(8, 2, 2, 0.1, 0.02, 0.02), spec, Vec3(0, 0, -9.81), dt, 100);
}

Model with_reuse(Model model, int refactor_iterations = 8, int max_iterations = 40) {
  model.solver.factor_reuse = true;
  model.solver.refactor_iterations = refactor_iterations;
  model.solver.pcg_max_iterations = max_iterations;
  return model;
}

// ||A x - b|| / ||b|| with A given by its upper triangle.
double relative_residual(const SparseMatrix& A_upper, const VecX& x, const VecX& b) {
  const SparseMatrix full = A_upper.selfadjointView<Eigen::Upper>();
  return (full * x - b).norm() / b.norm();
}

double condition(const SparseMatrix& A_upper) {
  const SparseMatrix full = A_upper.selfadjointView<Eigen::Upper>();
  const Eigen::SelfAdjointEigenSolver<MatX> eig{MatX(full)};
  return eig.eigenvalues().maxCoeff() / eig.eigenvalues().minCoeff();
}

// The step matrices of two consecutive steps of the beam (from rest and from the
// state one step later), and the second step's right-hand side.
struct TwoMatrices {
  SparseMatrix A1, A2;
  VecX b2;
  TwoMatrices() {
    const Model model = beam();
    Data data(model);
    State s = model.initial, next;
    for (int k = 1; k <= 2; ++k) {
      EXPECT_TRUE(integrator::implicit_euler_step(model, data, s, next, k).ok());
      (k == 1 ? A1 : A2) = data.A;
      std::swap(s, next);
    }
    b2 = data.rhs;
  }
};

std::unique_ptr<integrator::LinearSolver> reuse_solver(int refactor_iterations = 8, int max_iterations = 40) {
  integrator::SolverOptions o;
  o.factor_reuse = true;
  o.refactor_iterations = refactor_iterations;
  o.pcg_max_iterations = max_iterations;
  return integrator::make_linear_solver(o);
}

TEST(FactorReuse, KeptFactorSolvesTheNewMatrixToTheTolerance) {
  const TwoMatrices m;
  auto solver = reuse_solver();
  solver->analyze(m.A1);
  ASSERT_TRUE(solver->factorize(m.A1).ok);
  ASSERT_TRUE(solver->factorize(m.A2).ok);
  EXPECT_EQ(solver->counters().numeric_factorizations, 1);
  EXPECT_EQ(solver->counters().kept_factors, 1);
  VecX x;
  ASSERT_TRUE(solver->solve(m.b2, x));
  EXPECT_GE(solver->counters().last_pcg_iterations, 1);  // A2 != A1: not a direct solve
  const double tol = integrator::SolverOptions{}.pcg_tolerance;
  EXPECT_LE(relative_residual(m.A2, x, m.b2), tol);
  // Against the direct solve of A2: ||x - x_d|| <= cond(A2) tol ||x_d|| (plus the
  // direct solve's own round-off, far below).
  auto direct = integrator::make_linear_solver({});
  direct->analyze(m.A2);
  ASSERT_TRUE(direct->factorize(m.A2).ok);
  VecX x_d;
  direct->solve(m.b2, x_d);
  EXPECT_LE((x - x_d).norm(), condition(m.A2) * tol * x_d.norm());
  EXPECT_GT((x - x_d).norm(), 0.0);  // not the direct answer: PCG did the work
}

TEST(FactorReuse, RefactorizationRuleFiresWhenTheIterationsExceedTheThreshold) {
  const TwoMatrices m;
  // A big change of the matrix that keeps it positive definite: A3 = S A2 S with S
  // diagonal, s_i = 1 + 0.5 sin(i) (the dofs rescaled by up to 3x against each other).
  // The iteration count k this needs is measured, then the rule is checked on either
  // side of it.
  SparseMatrix A3 = m.A2;
  for (int j = 0; j < A3.outerSize(); ++j)
    for (SparseMatrix::InnerIterator it(A3, j); it; ++it)
      it.valueRef() *= (1 + 0.5 * std::sin(it.row())) * (1 + 0.5 * std::sin(j));
  auto probe = reuse_solver(1000, 1000);
  probe->analyze(m.A1);
  ASSERT_TRUE(probe->factorize(m.A1).ok);
  ASSERT_TRUE(probe->factorize(A3).ok);
  VecX x;
  ASSERT_TRUE(probe->solve(m.b2, x));
  const int k = probe->counters().last_pcg_iterations;
  ASSERT_GE(k, 2);
  EXPECT_LE(relative_residual(A3, x, m.b2), integrator::SolverOptions{}.pcg_tolerance);

  for (int threshold : {k - 1, k}) {
    auto solver = reuse_solver(threshold, 1000);
    solver->analyze(m.A1);
    ASSERT_TRUE(solver->factorize(m.A1).ok);
    ASSERT_TRUE(solver->factorize(A3).ok);
    ASSERT_TRUE(solver->solve(m.b2, x));
    EXPECT_EQ(solver->counters().last_pcg_iterations, k);
    ASSERT_TRUE(solver->factorize(m.A2).ok);
    const bool fired = threshold < k;
    EXPECT_EQ(solver->counters().numeric_factorizations, fired ? 2 : 1) << "threshold " << threshold;
    EXPECT_EQ(solver->counters().kept_factors, fired ? 1 : 2) << "threshold " << threshold;
    ASSERT_TRUE(solver->solve(m.b2, x));
    if (fired) {
      EXPECT_EQ(solver->counters().last_pcg_iterations, 0);  // a fresh factor: direct
    }
    EXPECT_LE(relative_residual(m.A2, x, m.b2), integrator::SolverOptions{}.pcg_tolerance);
  }

  // A budget below k: the solve factorizes A3 and solves directly.
  auto solver = reuse_solver(1000, k - 1);
  solver->analyze(m.A1);
  ASSERT_TRUE(solver->factorize(m.A1).ok);
  ASSERT_TRUE(solver->factorize(A3).ok);
  ASSERT_TRUE(solver->solve(m.b2, x));
  EXPECT_EQ(solver->counters().pcg_fallbacks, 1);
  EXPECT_EQ(solver->counters().numeric_factorizations, 2);
  // Direct: the residual is CHOLMOD's round-off, below the tolerance.
  EXPECT_LE(relative_residual(A3, x, m.b2), integrator::SolverOptions{}.pcg_tolerance);
}

TEST(FactorReuse, NotPositiveDefiniteIsReportedWithColumn) {
  const TwoMatrices m;
  SparseMatrix negative = m.A2;
  negative.coeffs() *= -1.0;
  auto solver = reuse_solver();
  solver->analyze(m.A1);
  ASSERT_TRUE(solver->factorize(m.A1).ok);
  ASSERT_TRUE(solver->factorize(negative).ok);  // kept: not yet factorized
  VecX x;
  EXPECT_FALSE(solver->solve(m.b2, x));  // p^T A p < 0: factorizes, which fails
  EXPECT_FALSE(solver->solve_factor_status().ok);
  EXPECT_GE(solver->solve_factor_status().column, 0);
  // The next matrix is factorized (no valid factor is kept after a failure).
  ASSERT_TRUE(solver->factorize(m.A2).ok);
  ASSERT_TRUE(solver->solve(m.b2, x));
  EXPECT_EQ(solver->counters().last_pcg_iterations, 0);
  EXPECT_EQ(solver->counters().numeric_factorizations, 3);
}

TEST(FactorReuse, CongruenceRefactorizesAStaleFactor) {
  const TwoMatrices m;
  const Eigen::Index n = m.A1.rows();
  SparseMatrix B(n, 3);  // three unit columns at free dofs far from the clamp
  std::vector<Eigen::Triplet<double>> t = {{static_cast<int>(n - 1), 0, 1.0},
                                           {static_cast<int>(n - 5), 1, 1.0},
                                           {static_cast<int>(n - 20), 2, 1.0}};
  B.setFromTriplets(t.begin(), t.end());
  auto solver = reuse_solver();
  solver->analyze(m.A1);
  ASSERT_TRUE(solver->factorize(m.A1).ok);
  ASSERT_TRUE(solver->factorize(m.A2).ok);
  MatX G, G_d;
  ASSERT_TRUE(solver->inverse_congruence(B, G));
  EXPECT_EQ(solver->counters().numeric_factorizations, 2);
  auto direct = integrator::make_linear_solver({});
  direct->analyze(m.A2);
  ASSERT_TRUE(direct->factorize(m.A2).ok);
  ASSERT_TRUE(direct->inverse_congruence(B, G_d));
  // The same factorization of the same matrix: equal up to round-off of the reach solves.
  EXPECT_LE((G - G_d).norm(), 1e-12 * G_d.norm());
}

// Lockstep: the reuse trajectory's every step is repeated from the same input with
// the direct solve; the reuse step's dv must satisfy the direct step's own system to
// pcg_tolerance (plus the direct answer's own residual, the round-off of the check).
void check_lockstep(const Model& direct_model, int steps, bool bdf2, const std::string& what) {
  const Model model = with_reuse(direct_model);
  Data data(model), ref(direct_model);
  State s = model.initial, previous, next, next_d;
  const double tol = model.solver.pcg_tolerance;
  double worst = 0;
  for (int k = 1; k <= steps; ++k) {
    const State* prev = bdf2 && k > 1 ? &previous : nullptr;
    const StepStatus st = integrator::time_step(model, data, s, prev, next, k);
    ASSERT_TRUE(st.ok()) << what << ": " << describe(model, st);
    ASSERT_TRUE(integrator::time_step(direct_model, ref, s, prev, next_d, k).ok());
    const double direct_residual = relative_residual(ref.A, ref.dv, ref.rhs);
    const double r = relative_residual(ref.A, data.dv, ref.rhs);
    EXPECT_LE(r, tol + direct_residual) << what << " step " << k;
    worst = std::max(worst, r);
    previous = s;
    std::swap(s, next);
  }
  const auto& c = data.solver->counters();
  // The factor was kept for most steps (the point of it) and PCG did the work.
  EXPECT_GT(c.kept_factors, steps / 2) << what;
  EXPECT_GE(c.pcg_iterations, c.pcg_solves) << what;
  EXPECT_GT(s.x.minCoeff(), -1.0) << what;  // a sane trajectory (the beam sags a few mm)
  std::printf("%s: %d steps, %ld factorizations, %ld PCG solves, %.2f iterations per solve, worst residual %.2e\n",
              what.c_str(), steps, c.numeric_factorizations, c.pcg_solves,
              c.pcg_solves ? static_cast<double>(c.pcg_iterations) / c.pcg_solves : 0.0, worst);
}

TEST(FactorReuse, ImplicitEulerTrajectoryMatchesTheDirectSolveStepByStep) {
  check_lockstep(beam(), 100, false, "implicit Euler");
}

TEST(FactorReuse, Bdf2TrajectoryMatchesTheDirectSolveStepByStep) {
  Model model = beam();
  model.step.integrator = IntegratorKind::bdf2;
  check_lockstep(model, 60, true, "BDF2");
}

// Control (data.keep_linearization): the committed step from the prediction's x keeps
// the prediction's record and solves with the solver as it stands (here a kept factor).
TEST(FactorReuse, KeepLinearizationSolvesWithTheKeptFactor) {
  const Model direct_model = beam();
  const Model model = with_reuse(direct_model);
  Data data(model), ref(direct_model);
  data.keep_linearization = true;
  State s = model.initial, next, again, next_d;
  for (int k = 1; k <= 5; ++k) {
    ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, next, k).ok());  // prediction
    const long formed = data.factorizations;
    ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, again, k).ok());  // committed
    EXPECT_EQ(data.factorizations, formed);  // the same linearization: no new matrix
    ASSERT_TRUE(integrator::implicit_euler_step(direct_model, ref, s, next_d, k).ok());
    EXPECT_LE(relative_residual(ref.A, data.dv, ref.rhs),
              model.solver.pcg_tolerance + relative_residual(ref.A, ref.dv, ref.rhs))
        << "step " << k;
    EXPECT_EQ(again.v, next.v);  // the same solve of the same system
    std::swap(s, again);
  }
  EXPECT_GE(data.solver->counters().kept_factors, 1);
}

// The step after a failed step factorizes, whatever the last PCG solve needed.
TEST(FactorReuse, StepAfterAFailureFactorizes) {
  const Model model = with_reuse(beam(), 1000, 1000);  // the iteration rule never fires
  Data data(model);
  State s = model.initial, next;
  ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, next, 1).ok());
  std::swap(s, next);
  ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, next, 2).ok());
  const auto& c = data.solver->counters();
  ASSERT_EQ(c.numeric_factorizations, 1);
  ASSERT_EQ(c.kept_factors, 1);
  State mirrored = next;  // every element inverted (z -> -z)
  for (Eigen::Index i = 2; i < mirrored.x.size(); i += 3) mirrored.x[i] = -mirrored.x[i];
  EXPECT_EQ(integrator::implicit_euler_step(model, data, mirrored, s, 3).code, StepStatus::Code::inverted_element);
  ASSERT_TRUE(integrator::implicit_euler_step(model, data, next, s, 3).ok());
  EXPECT_EQ(c.numeric_factorizations, 2);
  EXPECT_EQ(c.kept_factors, 1);
}

}  // namespace factor_reuse_test
