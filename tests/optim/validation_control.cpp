// Inverse dynamics (optim/control.hpp) on the shipped Trunk (configs/trunk.yaml: 8
// cables with tension limits, gravity along -y):
//   - a reachable goal: the tip's static equilibrium under cableL0 = 0.15 N and
//     cableS1 = 0.2 N (the static solver, with gravity); from rest, 100 control steps
//     (1 s) bring the tip within 1 mm of it;
//   - an unreachable goal (0.3 m above the base, beyond the trunk's length): the run
//     ends where the linearized problem is stationary (the QP's solution d -> 0: the
//     first-order optimality of min |X_e - goal| over the admissible tensions), with
//     every tension within its limits at every step and some at a limit;
//   - every step's QP satisfies its KKT conditions to 1e-8 (relative);
//   - the paper's gripper (configs/gripper.yaml, eq. 13, Table II): closing on the object
//     with the heuristic (both servos at the maximal torque, 0.03 N m: the scene's final
//     value, whose tips end 11.8 mm from the axis as the paper's) against the optimized
//     policy (alpha |X_e|^2 + beta |lambda_c,nodes|^2 with alpha = 1, beta = 10, one change
//     for both servos, low-pass 0.2): over the last 10 of 70 steps (the paper runs 70; the fingers reach
//     the object at ~0.3 s) the optimized tip stays within 10% of the heuristic's
//     distance while the mean contact-force norm is at least 5x smaller.
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/control.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

using namespace softdiff;

namespace {

const std::string kScene = std::string(SOFTDIFF_SOURCE_DIR) + "/configs/trunk.yaml";

Vec3 static_tip() {
  const io::SceneDesc scene = io::load_scene(
      kScene, {"simulation.integrator=static", "simulation.dt=null", "simulation.newton_iterations=null",
               "simulation.duration=null", "bodies.trunk.actuators.cableL0.schedule=null",
               "bodies.trunk.actuators.cableL0.force=0.15", "bodies.trunk.actuators.cableS1.force=0.2"});
  const Model model = io::build_model(scene);
  Data data(model);
  State out;
  const StepStatus st = integrator::solve_static(model, data, model.initial, out);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  return model.actuation.effectors[0].effector.position(out.x);
}

struct ControlRun {
  double final_distance = 0, last_delta = 0, kkt_max = 0;
  bool within_limits = true;
  int at_limit = 0;
  VecX lambda;
};

ControlRun control(const Vec3& goal, long steps) {
  const io::SceneDesc scene = io::load_scene(kScene);
  const Model model = io::build_model(scene);
  optim::InverseDynamics id(model, optim::ControlOptions{});
  Data data(model);
  State s = model.initial, next;
  VecX lambda = VecX::Zero(static_cast<Eigen::Index>(model.actuation.actuators.size())), out;
  ControlRun r;
  for (long k = 1; k <= steps; ++k) {
    optim::ControlStep info;
    const StepStatus st = id.compute(model, s, k, goal, lambda, out, info);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    EXPECT_TRUE(info.qp_converged) << k;
    r.kkt_max = std::max(r.kkt_max, info.kkt);
    r.last_delta = info.delta.norm();
    lambda = out;
    for (Eigen::Index j = 0; j < lambda.size(); ++j) {
      const auto& a = model.actuation.actuators[static_cast<std::size_t>(j)];
      if (lambda[j] < a.limits[0] || lambda[j] > a.limits[1]) r.within_limits = false;
    }
    EXPECT_TRUE(integrator::implicit_euler_step(model, data, s, next, k, &lambda).ok());
    std::swap(s, next);
  }
  r.final_distance = (model.actuation.effectors[0].effector.position(s.x) - goal).norm();
  for (Eigen::Index j = 0; j < lambda.size(); ++j) {
    const auto& a = model.actuation.actuators[static_cast<std::size_t>(j)];
    r.at_limit += lambda[j] == a.limits[0] || lambda[j] == a.limits[1];
  }
  r.lambda = lambda;
  return r;
}

TEST(Control, TrunkReachesAReachableGoal) {
  const Vec3 goal = static_tip();
  const ControlRun r = control(goal, 100);
  EXPECT_LT(r.final_distance, 1e-3) << r.lambda.transpose();
  EXPECT_TRUE(r.within_limits);
  EXPECT_LE(r.kkt_max, 1e-8);
}

TEST(Control, TrunkTowardsAnUnreachableGoalStopsAtTheNearestPoint) {
  const Vec3 goal(0, 0.1, 0.3);
  const ControlRun r = control(goal, 100);
  EXPECT_GT(r.final_distance, 0.05);  // unreachable indeed
  EXPECT_TRUE(r.within_limits);
  EXPECT_GE(r.at_limit, 1) << r.lambda.transpose();
  // Stationary: the QP asks for (almost) no change, relative to the tensions' range.
  EXPECT_LT(r.last_delta, 1e-3 * 0.25) << r.lambda.transpose();
  EXPECT_LE(r.kkt_max, 1e-8);
}

struct GripperRun {
  double distance = 0, force = 0;  // means over the last 10 steps: |x| of finger_a's tip (m), |lambda_c,nodes| (N)
};

GripperRun gripper(bool optimized, long steps) {
  const io::SceneDesc scene = io::load_scene(std::string(SOFTDIFF_SOURCE_DIR) + "/configs/gripper.yaml",
                                             {"bodies.finger_a.actuators.servo_a.limits=[0,0.03]",
                                              "bodies.finger_b.actuators.servo_b.limits=[0,0.03]"});
  const Model model = io::build_model(scene);
  optim::ControlOptions co;
  co.effector = 0;  // finger_a.tip
  co.axes = {true, false, false};
  co.alpha = 1;
  co.beta = 10;
  co.shared = true;
  co.filter = 0.2;
  optim::InverseDynamics id(model, co);
  Data data(model);
  State s = model.initial, next;
  VecX lambda = VecX::Constant(2, 0.0042), out;  // the scene's initial torque
  GripperRun r;
  for (long k = 1; k <= steps; ++k) {
    if (optimized) {
      optim::ControlStep info;
      EXPECT_TRUE(id.compute(model, s, k, Vec3::Zero(), lambda, out, info).ok());
      lambda = out;
    } else {
      lambda.setConstant(0.03);
    }
    EXPECT_TRUE(integrator::implicit_euler_step(model, data, s, next, k, &lambda).ok());
    std::swap(s, next);
    if (k > steps - 10) {
      r.distance += std::abs(model.actuation.effectors[0].effector.position(s.x).x()) / 10;
      r.force += id.contact_force_norm(model, data) / 10;
    }
  }
  return r;
}

TEST(Control, GripperOptimizedKeepsTheGraspWithFarLessForce) {
  const GripperRun h = gripper(false, 70), o = gripper(true, 70);
  std::printf("gripper: heuristic |X_e| %.3f mm, |lambda_c| %.4f N; optimized %.3f mm, %.4f N\n", 1e3 * h.distance, h.force,
              1e3 * o.distance, o.force);
  EXPECT_GT(h.force, 0.01);  // the heuristic presses on the object
  EXPECT_LE(std::abs(o.distance - h.distance), 0.1 * h.distance);
  EXPECT_LE(5 * o.force, h.force);
}

}  // namespace

// One factorization per control step (issue 20): committing the step through the
// controller's record (InverseDynamics::data(), as `softdiff control` does) reuses the
// prediction's linearization and factorization, since the two steps differ only in
// the actuation, which enters the right-hand side. The trajectory is the one of a
// separate record bit for bit (same K, f_int and factor: the same arithmetic), with
// half the factorizations. The Trunk without contact, 10 steps towards a moving goal.
TEST(Control, CommittedStepReusesThePredictionsFactorization) {
  const io::SceneDesc scene = io::load_scene(kScene);
  const Model model = io::build_model(scene);
  ASSERT_FALSE(model.constant_system_matrix());  // else every step reuses one factor anyway
  const long steps = 10;
  auto run = [&](bool shared, long& factorizations) {
    optim::InverseDynamics id(model, optim::ControlOptions{});
    Data own(model);
    Data& data = shared ? id.data() : own;
    State s = model.initial, next;
    VecX lambda = VecX::Zero(static_cast<Eigen::Index>(model.actuation.actuators.size())), out;
    for (long k = 1; k <= steps; ++k) {
      optim::ControlStep info;
      const Vec3 goal(0.01 * static_cast<double>(k) / steps, 0.0, 0.12);
      EXPECT_TRUE(id.compute(model, s, k, goal, lambda, out, info).ok());
      lambda = out;
      EXPECT_TRUE(integrator::implicit_euler_step(model, data, s, next, k, &lambda).ok());
      std::swap(s, next);
    }
    factorizations = id.data().factorizations + (shared ? 0 : own.factorizations);
    return s;
  };
  long f_shared = 0, f_separate = 0;
  const State shared = run(true, f_shared), separate = run(false, f_separate);
  EXPECT_EQ(f_shared, steps);
  EXPECT_EQ(f_separate, 2 * steps);
  EXPECT_EQ((shared.x - separate.x).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ((shared.v - separate.v).cwiseAbs().maxCoeff(), 0.0);
}

// The control's actuation Jacobian without contact: StepDerivatives::actuation_jvps
// (all n_a columns in one solve with n_a right-hand sides) against one jvp() per
// column and against central differences of the step in each actuator, on the Trunk
// (no contact, 8 cables) after 3 steps under 0.05 N, for the linearized implicit Euler
// step, BDF2 (at its hat state, as control.cpp calls it) and Newton (up to 10
// iterations to the scene's tolerance, the derivative at A_f).
//   - one solve vs per-column solves: the same factor and right-hand sides, the
//     triangular solves ordered differently (BLAS-3 on the block): 1e-12 relative per
//     column (round-off; measured 5e-15 and 8e-15).
//   - central differences (x_f(lambda + eps e_j) - x_f(lambda - eps e_j)) / (2 eps):
//     the linearized step (both integrators) is affine in lambda (A does not depend on
//     it, b does linearly: h H_a(x_i)^T lambda), so the difference quotient has no
//     truncation error and eps = 0.01 N (a fifth of the tensions) only divides
//     round-off in x_f (|x_f| ~ 0.1 m, ~1e-17 m absolute) by 2 eps: 1e-7 relative per
//     column is far above it (measured 1e-12 to 7e-12) and far below any wrong term. Newton:
//     x_f is not affine; eps = 1e-4 N, truncation O(eps^2) and the Newton tolerance
//     (1e-10 relative residual) divided by 2 eps: 1e-5 relative (measured 1.4e-7, effector 3e-7).
//   - the effector's rows J_a = W dx (what the QP uses) against the difference of the
//     effector's positions, with the same tolerances.
TEST(Control, ActuationJacobianInOneSolveMatchesJvpsAndCentralDifferences) {
  struct Case {
    const char* name;
    std::vector<std::string> overrides;
    double eps, fd_tolerance;
  };
  const std::vector<Case> cases = {
      {"implicit_euler", {}, 1e-2, 1e-7},
      {"bdf2", {"simulation.integrator=bdf2"}, 1e-2, 1e-7},
      {"newton", {"simulation.newton_iterations=10"}, 1e-4, 1e-5},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Model model = io::build_model(io::load_scene(kScene, c.overrides));
    ASSERT_FALSE(model.contact.enabled);
    const auto na = static_cast<Eigen::Index>(model.actuation.actuators.size());
    ASSERT_GT(na, 1);
    const auto& effector = model.actuation.effectors[0].effector;
    Data data(model);
    State previous, s = model.initial, next;
    const VecX lambda = VecX::Constant(na, 0.05);
    for (long k = 1; k <= 3; ++k) {
      ASSERT_TRUE(integrator::time_step(model, data, s, k > 1 ? &previous : nullptr, next, k, &lambda).ok());
      previous = s;
      s = next;
    }
    State out;
    ASSERT_TRUE(integrator::time_step(model, data, s, &previous, out, 4, &lambda).ok());
    integrator::StepDerivatives derivatives(model, {});
    const MatX directions = MatX::Identity(na, na);
    MatX dx;
    ASSERT_TRUE(derivatives.actuation_jvps(model, data, data.hat, out, directions, dx));
    ASSERT_EQ(dx.rows(), out.x.size());
    ASSERT_EQ(dx.cols(), na);
    Data fd(model);  // the differenced steps (data keeps the record)
    double worst_solve = 0, worst_fd = 0, worst_effector = 0;
    for (Eigen::Index j = 0; j < na; ++j) {
      integrator::StepTangent t;
      t.lambda_a = directions.col(j);
      integrator::StateTangent r;
      ASSERT_TRUE(derivatives.jvp(model, data, data.hat, out, t, r));
      ASSERT_GT(r.x.norm(), 0);
      const double solve_error = (dx.col(j) - r.x).norm() / r.x.norm();
      EXPECT_LE(solve_error, 1e-12) << "column " << j;
      worst_solve = std::max(worst_solve, solve_error);
      State plus, minus;
      VecX l = lambda;
      l[j] += c.eps;
      ASSERT_TRUE(integrator::time_step(model, fd, s, &previous, plus, 4, &l).ok());
      l[j] = lambda[j] - c.eps;
      ASSERT_TRUE(integrator::time_step(model, fd, s, &previous, minus, 4, &l).ok());
      const VecX central = (plus.x - minus.x) / (2 * c.eps);
      const double fd_error = (dx.col(j) - central).norm() / central.norm();
      EXPECT_LE(fd_error, c.fd_tolerance) << "column " << j;
      worst_fd = std::max(worst_fd, fd_error);
      const VecX column = dx.col(j);
      const Vec3 Ja = effector.jacobian_times(column);
      const Vec3 Ja_fd = (effector.position(plus.x) - effector.position(minus.x)) / (2 * c.eps);
      const double effector_error = (Ja - Ja_fd).norm() / Ja_fd.norm();
      EXPECT_LE(effector_error, c.fd_tolerance) << "column " << j;
      worst_effector = std::max(worst_effector, effector_error);
    }
    std::printf("%s: one solve vs jvp %.2e, vs central differences %.2e (effector %.2e)\n", c.name, worst_solve,
                worst_fd, worst_effector);
  }
}
