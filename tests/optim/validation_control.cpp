// Inverse dynamics (optim/control.hpp) on the shipped Trunk (configs/trunk.yaml: 8
// cables with tension limits, gravity along -y):
//   - a reachable goal: the tip's static equilibrium under cableL0 = 0.15 N and
//     cableS1 = 0.2 N (the static solver, with gravity); from rest, 100 control steps
//     (1 s) bring the tip within 1 mm of it;
//   - an unreachable goal (0.3 m above the base, beyond the trunk's length): the run
//     ends where the linearized problem is stationary (the QP's solution d -> 0: the
//     first-order optimality of min |X_e - goal| over the admissible tensions), with
//     every tension within its limits at every step and some at a limit;
//   - every step's QP satisfies its KKT conditions to 1e-8 (relative).
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/control.hpp>

#include <gtest/gtest.h>

#include <string>

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

}  // namespace
