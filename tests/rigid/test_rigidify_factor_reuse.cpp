// Factor reuse with rigidified parts (linear_solver.factor_reuse: pcg; issue 21, rpcg;
// docs/method.md "Rigidified parts", *Factor reuse*): the step keeps an earlier
// factorization and solves its reduced system P^T A P by PCG, preconditioned by the kept
// factorization's reduced inverse (integrator/rigidify_pcg.hpp).
//  - Lockstep: a run with reuse, every step repeated from the same input without reuse;
//    the reuse step's answer is checked against the direct step's own reduced system
//    (its residual, formed from the direct record: A, C, D = S + C^T Y, an operator the
//    PCG code never sees) to the PCG tolerance, and against the direct answer to
//    cond(P^T A P) times it (the condition number computed from that operator).
//  - The step derivative with a kept factor (its reduced solves are PCG too) against the
//    direct step's derivative, to the same bound.
// Scenes: the 81-node bar of test_rigidify_derivatives.cpp clamped at one end, with two
// free parts (its middle block and its tip), and with its tip attached to a torque servo.
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <softdiff/integrator/rigidify.hpp>
#include <rigid/rigid_scenes.hpp>
#include <support/fd.hpp>

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cstdio>
#include <string>

using namespace softdiff;

namespace rigidify_factor_reuse_test {

Model load(const std::string& name, const std::string& body_extra, bool reuse) {
  return test::rigid_scenes::load_scene_text(
      "rigidify_factor_reuse", name,
      "softdiff: 1\n"
      "simulation: {dt: 0.01, steps: 30}\n" +
          std::string(reuse ? "linear_solver: {type: cholmod, factor_reuse: pcg}\n" : "") +
          "bodies:\n"
          "  - name: bar\n"
          "    mesh: bar.msh\n"
          "    material: {law: corotational, young: 2.0e4, poisson: 0.4, density: 1000}\n"
          "    damping: {rayleigh_mass: 0.5, rayleigh_stiffness: 0.01}\n" +
          body_extra,
      {{"bar.msh", test::rigid_scenes::box_msh_text(8, 2, 2, 0.2, 0.04, 0.02)}});
}

const std::string kClamp = "    fixed: [{box: [-1, -1, -1, 0.001, 1, 1]}]\n";
const std::string kTwoParts =
    kClamp + "    rigidify: [{box: [0.07, -1, -1, 0.13, 1, 1], attach: free}, {box: [0.17, -1, -1, 1, 1, 1], attach: free}]\n";
const std::string kServoTip =
    kClamp +
    "    rigidify: [{box: [0.17, -1, -1, 1, 1, 1], attach: turn}]\n"
    "    actuators:\n"
    "      - {name: turn, type: servo, nodes: {box: [0.17, -1, -1, 1, 1, 1]}, axis: [1, 0, 0], "
    "center: [0.2, 0.02, 0.01], force: 2.0e-3}\n";

// The direct record's reduced operator P^T A P in reduced coordinates (the soft dofs'
// rows, then 6 per part), from its A (identity rows on the parts' and fixed dofs), C and
// D = S + C^T Y; and the reduced vector of a full one (soft rows, the parts' rigid fits).
struct Reduced {
  const Model& model;
  const Data& data;
  Eigen::Index n, m6;
  VecX apply(const VecX& f, const VecX& u) const {
    const auto& w = data.rigidify;
    const MatX D = w.S + w.C.transpose() * w.Y;
    VecX q(n + m6);
    q.head(n) = data.A.selfadjointView<Eigen::Upper>() * f + w.C * u;
    q.tail(m6) = w.C.transpose() * f + D * u;
    return q;
  }
  // (soft rows of v, zero on the parts) and each part's (v_p, omega) fit.
  void split(const VecX& v, VecX& f, VecX& u) const {
    const auto& w = data.rigidify;
    f = v;
    u.resize(m6);
    for (int p = 0; p < model.rigidify.size(); ++p) {
      const auto& part = model.rigidify.parts[static_cast<std::size_t>(p)];
      u.segment<6>(6 * p) = integrator::part_velocity(model, part, w.x, w.centre[static_cast<std::size_t>(p)], v);
      for (int i : part.nodes) f.segment<3>(3 * i).setZero();
    }
  }
  // The right-hand side (b_f, T^T b_r).
  VecX rhs(const VecX& b) const {
    const auto& w = data.rigidify;
    VecX r = VecX::Zero(n + m6);
    r.head(n) = b;
    for (int p = 0; p < model.rigidify.size(); ++p)
      for (int i : model.rigidify.parts[static_cast<std::size_t>(p)].nodes) {
        const Vec3 a = w.x.segment<3>(3 * i) - w.centre[static_cast<std::size_t>(p)];
        const Vec3 bi = b.segment<3>(3 * i);
        r.head(n).segment<3>(3 * i).setZero();
        r.segment<3>(n + 6 * p) += bi;
        r.segment<3>(n + 6 * p + 3) += a.cross(bi);
      }
    return r;
  }
  // cond(P^T A P) on the reduced space (the rows of the soft free dofs and the parts).
  double condition() const {
    std::vector<Eigen::Index> rows;
    for (Eigen::Index i = 0; i < n; ++i)
      if (!model.fem.fixed[static_cast<std::size_t>(i)] && model.rigidify.dof_part[static_cast<std::size_t>(i)] < 0)
        rows.push_back(i);
    for (Eigen::Index j = 0; j < m6; ++j) rows.push_back(n + j);
    const auto k = static_cast<Eigen::Index>(rows.size());
    MatX R(k, k);
    for (Eigen::Index c = 0; c < k; ++c) {
      VecX e = VecX::Zero(n + m6);
      e[rows[static_cast<std::size_t>(c)]] = 1;
      const VecX q = apply(e.head(n), e.tail(m6));
      for (Eigen::Index r = 0; r < k; ++r) R(r, c) = q[rows[static_cast<std::size_t>(r)]];
    }
    const Eigen::SelfAdjointEigenSolver<MatX> eig(0.5 * (R + R.transpose()), Eigen::EigenvaluesOnly);
    return eig.eigenvalues().maxCoeff() / eig.eigenvalues().minCoeff();
  }
};

// Runs `steps` steps with reuse; each step also without reuse from the same input.
// Checks the reduced residual and the difference to the direct answer (see the top);
// then the step derivative of the last step with the kept factor against the direct one.
void check_lockstep(const std::string& name, const std::string& body, int steps) {
  const Model model = load(name, body, true), direct = load(name + "_direct", body, false);
  ASSERT_TRUE(model.solver.factor_reuse);
  ASSERT_FALSE(model.rigidify.empty());
  Data data(model), ref(direct);
  State s = model.initial, next, next_d;
  const double tol = model.solver.pcg_tolerance;
  const Eigen::Index n = s.x.size(), m6 = 6 * model.rigidify.size();
  double worst_residual = 0, worst_difference = 0, worst_bound = 0;
  long reduced_steps = 0;
  // After `steps` steps, on to the next step that keeps its factor (at most 3 more: a
  // kept step above refactor_iterations makes only the next one factorize), whose
  // derivative is checked below.
  int k = 1;
  for (; k <= steps || (!data.rigidify.reduced_pcg && k <= steps + 3); ++k) {
    const StepStatus st = integrator::implicit_euler_step(model, data, s, next, k);
    ASSERT_TRUE(st.ok()) << name << ": " << describe(model, st);
    ASSERT_TRUE(integrator::implicit_euler_step(direct, ref, s, next_d, k).ok());
    const Reduced red{direct, ref, n, m6};
    const VecX b = red.rhs(ref.rhs);
    VecX f, u, fd, ud;
    red.split(data.dv, f, u);
    red.split(ref.dv, fd, ud);
    const double direct_residual = (red.apply(fd, ud) - b).norm() / b.norm();
    const double r = (red.apply(f, u) - b).norm() / b.norm();
    // The PCG's own test is this residual with the step's operator: tol, plus the direct
    // answer's round-off (its own residual) for the check's arithmetic.
    EXPECT_LE(r, tol + direct_residual) << name << " step " << k;
    VecX z(n + m6), zd(n + m6);
    z << f, u;
    zd << fd, ud;
    const double difference = (z - zd).norm() / zd.norm();
    // |z - z_d| / |z_d| <= cond * (relative residual of z + that of z_d).
    const double bound = red.condition() * (r + direct_residual);
    EXPECT_LE(difference, bound) << name << " step " << k;
    worst_residual = std::max(worst_residual, r);
    worst_difference = std::max(worst_difference, difference);
    worst_bound = std::max(worst_bound, bound);
    if (data.rigidify.reduced_pcg) ++reduced_steps;
    if (k >= steps && data.rigidify.reduced_pcg) break;
    std::swap(s, next);
  }
  const auto& c = data.solver->counters();
  // The factor was kept for half the steps or more: a kept step whose PCG needs more
  // than refactor_iterations (8) iterations makes the next step factorize, and these
  // need 9-10 (printed), so every other step keeps it.
  EXPECT_GE(c.kept_factors, steps / 2) << name;
  EXPECT_EQ(reduced_steps, c.kept_factors) << name;
  EXPECT_GE(c.pcg_iterations, c.pcg_solves) << name;
  std::printf("[rigidify factor reuse] %s: %d steps, %ld factorizations, %ld PCG solves, %.2f iterations per "
              "solve, worst reduced residual %.2e, worst difference to the direct answer %.2e (bound %.2e)\n",
              name.c_str(), std::min(k, steps + 3), c.numeric_factorizations, c.pcg_solves,
              c.pcg_solves ? static_cast<double>(c.pcg_iterations) / static_cast<double>(c.pcg_solves) : 0.0,
              worst_residual, worst_difference, worst_bound);

  // The derivative of the last step (s -> next, factor kept): against the direct record's
  // (s -> next_d). Both are the linear map of the same step; their reduced solves differ
  // by the PCG tolerance, so the columns by cond times it (of the column's norm); the
  // placement's terms also see the two outputs, which differ by the bound above.
  ASSERT_TRUE(data.rigidify.reduced_pcg) << name << ": the last step did not keep its factor";
  const double cond = Reduced{direct, ref, n, m6}.condition();
  integrator::StepDerivatives D(model, {{Parameter::young, 0}}), Dd(direct, {{Parameter::young, 0}});
  integrator::StepTangent t;
  t.x = test::random_vector(n, 1.0, 21);
  t.v = test::random_vector(n, 1.0, 22);
  t.p = VecX::Ones(1);
  if (!model.actuation.empty()) t.lambda_a = VecX::Ones(static_cast<Eigen::Index>(model.actuation.actuators.size()));
  integrator::StateTangent o, od;
  const long pcg_before = data.solver->counters().pcg_solves;
  ASSERT_TRUE(D.jvp(model, data, s, next, t, o));
  ASSERT_TRUE(Dd.jvp(direct, ref, s, next_d, t, od));
  EXPECT_GT(data.solver->counters().pcg_solves, pcg_before) << "the derivative's solves are PCG";
  VecX j(2 * n), jd(2 * n);
  j << o.x, o.v;
  jd << od.x, od.v;
  const double err = (j - jd).norm() / jd.norm();
  const double bound = 10 * cond * tol + worst_bound;  // 10: a few solves per column, each to tol
  std::printf("[rigidify factor reuse] %s: step derivative with the kept factor against the direct one: %.2e "
              "(cond %.3g, bound %.2e)\n", name.c_str(), err, cond, bound);
  EXPECT_LE(err, bound) << name;
  EXPECT_GT(jd.norm(), 0);
}

TEST(RigidifyFactorReuse, TwoFreePartsMatchTheDirectReducedSolveStepByStep) {
  check_lockstep("two_parts", kTwoParts, 30);
}

TEST(RigidifyFactorReuse, ServoAttachedTipMatchesTheDirectReducedSolveStepByStep) {
  check_lockstep("servo_tip", kServoTip, 30);
}

}  // namespace rigidify_factor_reuse_test
