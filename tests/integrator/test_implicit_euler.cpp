// Implicit Euler: exact results where they exist, invariants elsewhere.
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

using namespace softdiff;

namespace {

// A free body under gravity: f_int = 0 and K annihilates the uniform velocity, so
// the linearized step is exact: v_k = g k h, x_k = x_0 + g h^2 k (k + 1) / 2.
TEST(ImplicitEuler, FreeFallIsExact) {
  for (auto law : {material::Law::corotational, material::Law::stvk, material::Law::neo_hookean}) {
    test::BodySpec spec;
    spec.law = law;
    spec.rayleigh_stiffness = 0.01;  // damping acts on deformation only
    const Vec3 g(0, 0, -9.81);
    Model model = test::make_model(test::box_mesh(2, 2, 2, 0.1, 0.1, 0.1), spec, g, 0.01);
    Data data(model);
    State s = model.initial, next;
    const int steps = 20;
    for (int k = 1; k <= steps; ++k) {
      ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, next, k).ok());
      std::swap(s, next);
    }
    const double h = model.step.dt;
    for (int i = 0; i < model.fem.num_nodes; ++i) {
      EXPECT_LT((s.v.segment<3>(3 * i) - g * h * steps).norm(), 1e-10);
      const Vec3 expected = model.fem.X.col(i) + g * h * h * steps * (steps + 1) / 2.0;
      EXPECT_LT((s.x.segment<3>(3 * i) - expected).norm(), 1e-10);
    }
    EXPECT_NEAR(s.t, steps * h, 1e-12);
  }
}

double total_energy(const Model& model, const State& s) {
  fem::FemData d;
  d.resize(model.fem);
  fem::evaluate(model.fem, s.x, {true, false, false}, d);
  VecX Mv;
  fem::symmetric_multiply(model.fem, model.fem.mass_values, s.v, Mv);
  return d.energy + 0.5 * s.v.dot(Mv) - model.fem.gravity_force.dot(s.x);
}

Model cantilever(material::Law law, double alpha, double beta, int newton) {
  test::BodySpec spec;
  spec.law = law;
  spec.young = 2e5;
  spec.poisson = 0.4;
  spec.rayleigh_mass = alpha;
  spec.rayleigh_stiffness = beta;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  Model m = test::make_model(test::box_mesh(10, 2, 2, 0.2, 0.04, 0.04), spec, Vec3(0, 0, -9.81), 0.005);
  m.step.newton_iterations = newton;
  return m;
}

// Implicit Euler is dissipative: without damping, the total energy (kinetic +
// elastic + gravitational) does not grow, step after step, for every law, for the
// linearized step and for the full Newton solve.
TEST(ImplicitEuler, EnergyDoesNotGrowWithoutDamping) {
  for (auto law : {material::Law::corotational, material::Law::stvk, material::Law::neo_hookean})
    for (int newton : {1, 20}) {
      Model model = cantilever(law, 0, 0, newton);
      // 1e-10: the residual's round-off floor is ~1e-12 of ||R(0)|| (R subtracts h f
      // from h P, both O(||R(0)||)), so tighter tolerances need not be reachable.
      model.step.newton_tolerance = 1e-10;
      Data data(model);
      State s = model.initial, next;
      double e = total_energy(model, s);
      const double scale = std::abs(model.fem.gravity_force.dot(model.initial.x)) + 1e-12;
      for (int k = 1; k <= 60; ++k) {
        const auto status = integrator::implicit_euler_step(model, data, s, next, k);
        ASSERT_TRUE(status.ok()) << describe(model, status);
        std::swap(s, next);
        const double e1 = total_energy(model, s);
        EXPECT_LE(e1, e + 1e-10 * scale) << material::law_name(law) << " newton " << newton << " step " << k;
        e = e1;
      }
    }
}

// With damping, the dynamic beam settles on the static equilibrium.
TEST(ImplicitEuler, DampedBeamApproachesStaticSolution) {
  Model model = cantilever(material::Law::corotational, 5.0, 0.002, 1);
  Data data(model);
  State s = model.initial, next;
  for (int k = 1; k <= 800; ++k) {
    ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, next, k).ok());
    std::swap(s, next);
  }
  Model stat = model;
  stat.step.integrator = IntegratorKind::static_equilibrium;
  Data sdata(stat);
  State equilibrium;
  ASSERT_TRUE(integrator::solve_static(stat, sdata, stat.initial, equilibrium).ok());
  const double deflection = (equilibrium.x - model.initial.x).cwiseAbs().maxCoeff();
  EXPECT_GT(deflection, 1e-3);
  EXPECT_LT((s.x - equilibrium.x).cwiseAbs().maxCoeff(), 1e-4 * deflection);
  EXPECT_LT(s.v.cwiseAbs().maxCoeff(), 1e-3 * deflection);
}

// newton_iterations > 1 converges the nonlinear implicit Euler residual; its first
// iterate is the linearized step.
TEST(ImplicitEuler, NewtonConvergesAndStartsFromTheLinearizedStep) {
  Model lin = cantilever(material::Law::neo_hookean, 0.5, 0.001, 1);
  Model newton = cantilever(material::Law::neo_hookean, 0.5, 0.001, 30);
  newton.step.newton_tolerance = 1e-10;  // above the ~1e-12 round-off floor of the residual
  Data dl(lin), dn(newton);
  State a = lin.initial, b = lin.initial, na, nb;
  for (int k = 1; k <= 30; ++k) {
    ASSERT_TRUE(integrator::implicit_euler_step(lin, dl, a, na, k).ok());
    const auto st = integrator::implicit_euler_step(newton, dn, a, nb, k);  // same start state
    ASSERT_TRUE(st.ok()) << describe(newton, st);
    EXPECT_LE(dn.newton_residual, 1e-10);
    EXPECT_LT(dn.newton_iterations_used, 30);
    // One Newton step differs from the converged solution by O(h^2): small but not zero.
    const double diff = (na.x - nb.x).cwiseAbs().maxCoeff();
    EXPECT_LT(diff, 1e-3 * (na.x - lin.initial.x).cwiseAbs().maxCoeff() + 1e-9);
    std::swap(a, na);
  }
  Model one = cantilever(material::Law::neo_hookean, 0.5, 0.001, 2);
  one.step.newton_tolerance = 1e-300;  // force the maximum number of iterations
  Data d1(one);
  State c;
  const auto st = integrator::implicit_euler_step(one, d1, a, c, 31);
  EXPECT_EQ(st.code, StepStatus::Code::not_converged);
  EXPECT_EQ(d1.newton_iterations_used, 2);
}

TEST(ImplicitEuler, NonFiniteStateIsReported) {
  Model model = cantilever(material::Law::corotational, 0, 0, 1);
  Data data(model);
  State s = model.initial, next;
  s.v[3 * 5 + 1] = std::nan("");
  const auto st = integrator::implicit_euler_step(model, data, s, next, 1);
  EXPECT_EQ(st.code, StepStatus::Code::non_finite);
  EXPECT_NE(describe(model, st).find("NaN"), std::string::npos);
}

TEST(ImplicitEuler, DivergenceIsReported) {
  Model model = cantilever(material::Law::corotational, 0, 0, 1);
  Data data(model);
  State s = model.initial, next;
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (!model.fem.fixed[3 * i]) s.v[3 * i + 2] = 1e4;  // 50 m per step
  const auto st = integrator::implicit_euler_step(model, data, s, next, 1);
  EXPECT_TRUE(st.code == StepStatus::Code::diverged || st.code == StepStatus::Code::inverted_element)
      << describe(model, st);
  EXPECT_FALSE(describe(model, st).empty());
}

TEST(StaticSolver, LoadStepsReachTheSameEquilibrium) {
  Model one = cantilever(material::Law::neo_hookean, 0, 0, 1);
  one.step.integrator = IntegratorKind::static_equilibrium;
  Model four = one;
  four.step.static_load_steps = 4;
  Data d1(one), d4(four);
  State a, b;
  long calls = 0;
  ASSERT_TRUE(integrator::solve_static(one, d1, one.initial, a).ok());
  ASSERT_TRUE(integrator::solve_static(four, d4, four.initial, b, [&](long, const State&) { ++calls; }).ok());
  EXPECT_EQ(calls, 4);
  EXPECT_LT((a.x - b.x).cwiseAbs().maxCoeff(), 1e-9);
  // Residual check, independent of the solver: f_int + P = 0 on free dofs.
  fem::FemData d;
  d.resize(one.fem);
  fem::evaluate(one.fem, a.x, {false, true, false}, d);
  VecX r = d.f_int + one.fem.gravity_force;
  for (int k = 0; k < r.size(); ++k)
    if (one.fem.fixed[k]) r[k] = 0;
  EXPECT_LT(r.norm(), 1e-9 * one.fem.gravity_force.norm());
}

}  // namespace

namespace {

// A scene of `linear` bodies has a constant system matrix: one factorization per
// run, and the same trajectory as refactorizing every step.
TEST(ImplicitEuler, LinearLawFactorizesOnce) {
  Model model = cantilever(material::Law::linear, 0.5, 0.002, 1);
  ASSERT_TRUE(model.constant_system_matrix());
  Model refactor = model;
  refactor.fem.bodies[0].psd_projection = true;  // same matrix (already PSD) but not flagged constant
  ASSERT_FALSE(refactor.constant_system_matrix());
  Data a(model), b(refactor);
  State sa = model.initial, sb = model.initial, na, nb;
  for (int k = 1; k <= 20; ++k) {
    ASSERT_TRUE(integrator::implicit_euler_step(model, a, sa, na, k).ok());
    ASSERT_TRUE(integrator::implicit_euler_step(refactor, b, sb, nb, k).ok());
    std::swap(sa, na);
    std::swap(sb, nb);
  }
  EXPECT_EQ(a.factorizations, 1);
  EXPECT_EQ(b.factorizations, 20);
  EXPECT_LT((sa.x - sb.x).cwiseAbs().maxCoeff(), 1e-9 * (sb.x - model.initial.x).cwiseAbs().maxCoeff());
}

}  // namespace
