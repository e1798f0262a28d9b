// Calibration and control with rigidified parts (issue 21; docs/method.md "Calibration",
// "Control", "Rigidified parts"): the calibration residual's Jacobian (nodal states, and
// markers on the part: they move with it) and the controller's actuation Jacobian J_a
// (one jvp() per actuation column through the reduced step and the part's exact
// placement) against central differences of whole runs / of integrator::time_step.
#include <optim/rigidify_optim_scene.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>  // time_step
#include <softdiff/optim/calibration.hpp>
#include <softdiff/optim/control.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <utility>

using namespace softdiff;

namespace rigidify_optim_test {

using namespace softdiff::test::rigidify_optim;

constexpr long kSteps = 5;

// The target: every frame 1..kSteps of a run of `model` (its nodes).
optim::CalibrationTarget states_target(const Model& model) {
  optim::CalibrationTarget t;
  Data data(model);
  State s = model.initial, next = model.initial;
  for (long k = 1; k <= kSteps; ++k) {
    const StepStatus st = integrator::time_step(model, data, s, nullptr, next, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    std::swap(s, next);
    t.frames.push_back(k);
    t.states.push_back(s.x);
  }
  return t;
}

// The residual's columns against central differences of whole runs. No contact: every
// run is the linearized step's smooth function of the parameters (the reduced solve and
// the part's placement, exp of the rotation), so the quotient's error is its truncation,
// O(h^2) relative, and the runs' round-off over 2h. The runs are not smooth to 1e-16: a
// sweep of check-grad on this scene (one step, relative eps 1e-3 .. 1e-6) gives errors
// growing as 1/eps below 1e-4 (1e-5 at 1e-5, 3e-5 .. 5e-5 at 1e-6: the factorization's
// round-off), and truncation above (poisson, near 0.5: 4.4e-5 at 1e-3, 4.2e-7 at 1e-4).
// Relative step 1e-4 of each value: measured 1.4e-7 (poisson) .. 5.4e-6 (rayleigh_mass,
// whose effect per unit log, 5e-3 m, is the smallest: the round-off is relatively the
// largest there), printed. Tolerance 1e-5 of each column's norm.
void expect_columns_match(const Model& m, const std::vector<ParameterId>& ids, const std::vector<double>& values,
                          const optim::CalibrationTarget& target) {
  VecX r;
  MatX J;
  optim::residual(m, ids, values, target, true, r, J);
  ASSERT_EQ(r.size(), target.residual_size());
  ASSERT_EQ(J.cols(), static_cast<Eigen::Index>(ids.size()));
  ASSERT_GT(r.norm(), 0.0);
  for (Eigen::Index j = 0; j < J.cols(); ++j) {
    SCOPED_TRACE("column " + std::to_string(j));
    const auto c = static_cast<std::size_t>(j);
    const double h = 1e-4 * values[c];
    std::vector<double> vp = values, vm = values;
    vp[c] += h;
    vm[c] -= h;
    VecX rp, rm;
    MatX Jp, Jm;
    optim::residual(m, ids, vp, target, true, rp, Jp);
    optim::residual(m, ids, vm, target, true, rm, Jm);
    const VecX fd = (rp - rm) / (2 * h);
    ASSERT_GT(fd.norm(), 0.0);
    const double err = (J.col(j) - fd).norm() / fd.norm();
    std::printf("column %ld: |dr/dp| %.4e, relative error %.2e\n", static_cast<long>(j), fd.norm(), err);
    EXPECT_LE(err, 1e-5);
  }
}

const std::vector<ParameterId> kParams = {{Parameter::young, 0},
                                          {Parameter::poisson, 0},
                                          {Parameter::density, 0},
                                          {Parameter::rayleigh_mass, 0},
                                          {Parameter::rayleigh_stiffness, 0}};

// Away from the truth (E 1e6, nu 0.45, rho 1070, 0.5 1/s, 0.002 s).
const std::vector<double> kValues = {1.3e6, 0.42, 900, 0.8, 0.003};

TEST(CalibrationRigidify, ResidualJacobianAgainstCentralDifferences) {
  const Model m = load_beam_with_tip("states", false, kSteps);
  ASSERT_EQ(m.rigidify.size(), 1);
  const optim::CalibrationTarget target = states_target(m);
  expect_columns_match(m, kParams, kValues, target);
}

// Markers on the part (two points, each the mean of three of the part's nodes: the
// embedding's weights need not be a tet's) and one on the soft span, observed at every
// frame; the marker rows of the Jacobian as above. The part's markers move with the part:
// their rows' columns are rigid motions of the part's points.
TEST(CalibrationRigidify, MarkersOnThePartAgainstCentralDifferences) {
  const Model m = load_beam_with_tip("markers", false, kSteps);
  const optim::CalibrationTarget states = states_target(m);
  const std::vector<int> part = part_nodes(m);
  ASSERT_GE(part.size(), 6u);
  optim::CalibrationTarget target;
  target.frames = states.frames;
  auto marker = [&](const std::string& name, const std::vector<int>& nodes) {
    optim::Marker mk;
    mk.name = name;
    mk.point.count = static_cast<int>(nodes.size());
    for (std::size_t a = 0; a < nodes.size(); ++a) {
      mk.point.nodes[a] = nodes[a];
      mk.point.w[static_cast<Eigen::Index>(a)] = 1.0 / static_cast<double>(nodes.size());
    }
    target.markers.push_back(mk);
  };
  marker("part_a", {part[0], part[1], part[2]});
  marker("part_b", {part[part.size() - 1], part[part.size() - 2], part[part.size() / 2]});
  int soft = -1;  // a node of the soft span, not fixed (x near 0.1)
  for (int i = 0; i < m.fem.num_nodes && soft < 0; ++i)
    if (std::abs(m.initial.x[3 * i] - 0.1) < 0.011 && m.rigidify.dof_part[static_cast<std::size_t>(3 * i)] < 0) soft = i;
  ASSERT_GE(soft, 0);
  marker("span", {soft});
  for (int f = 0; f < static_cast<int>(target.frames.size()); ++f)
    for (int k = 0; k < 3; ++k) {
      const Vec3 y = target.markers[static_cast<std::size_t>(k)].point.position(states.states[static_cast<std::size_t>(f)]);
      target.observations.push_back({f, k, y + Vec3(2e-4, -2e-4, 2e-4)});
    }
  expect_columns_match(m, kParams, kValues, target);
}

// J_a of the controller (InverseDynamics) with the tip part attached to the torque servo:
// after 5 steps at 1 mN m, the effector (the tip's top corner, on the part) against
// central differences of integrator::time_step in the torque. The linearized step is
// linear in the torque up to the part's placement (exp of h omega): the quotient's
// truncation is O(eps^2) relative; eps = 1e-5 N m (1% of the torque): measured 3e-7 at
// this step in check-grad on this scene (tests/app/test_cli_rigidify.cpp), round-off
// 1e-16 |x| / (eps |J_a|) ~ 1e-9. Tolerance 1e-5 relative (measured: printed).
TEST(ControlRigidify, ActuationJacobianAgainstCentralDifferences) {
  const Model model = load_beam_with_tip("control", true, 20);
  ASSERT_EQ(model.rigidify.size(), 1);
  ASSERT_EQ(model.rigidify.parts.front().servo, 0);
  const VecX torque = VecX::Constant(1, 0.001);
  Data data(model);
  State s = model.initial, next;
  const long warm = 5;
  for (long k = 1; k <= warm; ++k) {
    const StepStatus st = integrator::time_step(model, data, s, nullptr, next, k, &torque);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    std::swap(s, next);
  }
  optim::ControlOptions options;
  options.alpha = 1;
  options.beta = 0;
  optim::InverseDynamics id(model, options);
  const auto& e = model.actuation.effectors[0].effector;
  const Vec3 goal = e.position(s.x) + Vec3(0, -1e-3, 1e-3);
  VecX lambda;
  optim::ControlStep info;
  const StepStatus st = id.compute(model, s, warm + 1, goal, torque, lambda, info);
  ASSERT_TRUE(st.ok()) << describe(model, st);
  ASSERT_EQ(info.Ja.cols(), 1);
  const double eps = 1e-5;
  Data plus(model), minus(model);
  State sp, sm;
  const VecX lp = torque + VecX::Constant(1, eps), lm = torque - VecX::Constant(1, eps);
  ASSERT_TRUE(integrator::time_step(model, plus, s, nullptr, sp, warm + 1, &lp).ok());
  ASSERT_TRUE(integrator::time_step(model, minus, s, nullptr, sm, warm + 1, &lm).ok());
  const Vec3 fd = (e.position(sp.x) - e.position(sm.x)) / (2 * eps);
  const Vec3 Ja = info.Ja.col(0);
  const double err = (Ja - fd).norm() / fd.norm();
  std::printf("|J_a| %.4e m/(N m), relative error %.2e\n", fd.norm(), err);
  ASSERT_GT(fd.norm(), 0.0);
  EXPECT_LE(err, 1e-5);
  // The controller moved the torque towards the goal (its QP's unconstrained step is
  // along J_a^T (goal - X_f) when it is not at a limit).
  EXPECT_NE(lambda[0], torque[0]);
}

}  // namespace rigidify_optim_test
