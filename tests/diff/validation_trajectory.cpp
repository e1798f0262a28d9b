// Trajectory derivatives (diff/trajectory.hpp): forward sensitivities, the adjoint and
// central finite differences of whole simulations agree.
//  - 30 steps of a cantilever beam (corotational, Rayleigh damping, gravity):
//    d x_T / d young by forward sensitivity, by the adjoint (l = c . x_T for a random
//    c) and by central differences;
//  - every theta group (parameters, actuation offset, x0, v0) forward vs adjoint (10 steps);
//  - the gradient with respect to the whole per-step actuation sequence (adjoint)
//    against central differences on single steps' values.
// Steps: young 1e-5 of its value (the 30-step map carries round-off ~cond(A) eps per
// step, see tests/integrator/test_step_derivatives.cpp), actuation values 1e-5 of the
// value; tolerance 1e-6 relative, and 1e-9 between the two analytic modes (they differ
// by round-off only: the same products summed in another order).
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <support/fd.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;

namespace {

constexpr long kSteps = 30;

Model beam(double young, double tension = 0.0) {
  test::BodySpec spec;
  spec.law = material::Law::corotational;
  spec.young = young;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 0.5;
  spec.rayleigh_stiffness = 2e-3;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  // 0.2 x 0.02 x 0.02 m, 10 x 2 x 2 cells.
  Model model = test::make_model(test::box_mesh(10, 2, 2, 0.2, 0.02, 0.02), spec, Vec3(0, 0, -9.81), 0.01, kSteps);
  // A translation servo pulling the tip sideways (the actuation columns).
  std::vector<int> tip;
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (model.fem.X(0, i) > 0.2 - 1e-9) tip.push_back(i);
  actuation::ActuatorModel a;
  a.name = "pull";
  actuation::Servo s;
  EXPECT_TRUE(actuation::Servo::translation(tip, Vec3(0, 1, 0.3), model.initial.x, s).ok());
  a.kind = s;
  a.value.constant = tension;
  model.actuation.actuators.push_back(a);
  return model;
}

VecX random_vector(Eigen::Index n, unsigned seed) { return test::random_vector(n, 1.0, seed); }

State run(const Model& model, const MatX& actuation = {}) {
  Data data(model);
  diff::Tape tape;
  const StepStatus st = diff::record(model, data, model.initial, kSteps, tape, actuation);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  return tape.frames.back();
}

TEST(TrajectoryDerivatives, BeamYoungForwardAdjointAndFiniteDifferencesAgree) {
  const double E = 5e4;
  const Model model = beam(E, 0.05);
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}};
  // Forward sensitivities.
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, kSteps, theta, final, dx, dv).ok());
  // Finite differences of the whole run.
  const double e = 1e-5 * E;
  const VecX fd = (run(beam(E + e, 0.05)).x - run(beam(E - e, 0.05)).x) / (2 * e);
  ASSERT_GT(fd.norm(), 0);
  EXPECT_LE((dx.col(0) - fd).norm(), 1e-6 * fd.norm()) << "forward " << (dx.col(0) - fd).norm() / fd.norm();
  // The adjoint of l = c . x_T.
  const VecX c = random_vector(dx.rows(), 1);
  Data data2(model);
  diff::Tape tape;
  ASSERT_TRUE(diff::record(model, data2, model.initial, kSteps, tape).ok());
  EXPECT_EQ((tape.frames.back().x - final.x).norm(), 0);  // the same run, bit for bit
  diff::AdjointResult adj;
  const auto loss = [&](long k, const State&, VecX& bar_x, VecX&) {
    if (k == kSteps) bar_x += c;
  };
  ASSERT_TRUE(diff::adjoint(model, data2, tape, theta, loss, adj).ok());
  EXPECT_EQ(adj.recompute_mismatch, 0.0);
  const double forward = c.dot(dx.col(0));
  EXPECT_NEAR(adj.theta[0], forward, 1e-9 * std::abs(forward));
  EXPECT_NEAR(adj.theta[0], c.dot(fd), 1e-6 * c.cwiseAbs().dot(fd.cwiseAbs()));
  // Memory of the tape: 2 (3n) doubles per frame plus the time, and the actuation.
  const std::size_t n3 = static_cast<std::size_t>(dx.rows());
  EXPECT_EQ(tape.bytes(), (kSteps + 1) * 8 * (2 * n3 + 1) + kSteps * 8 * 1);
}

TEST(TrajectoryDerivatives, EveryThetaGroupForwardMatchesAdjoint) {
  const Model model = beam(5e4, 0.05);
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0},
                      {Parameter::rayleigh_mass, 0}, {Parameter::rayleigh_stiffness, 0}};
  theta.actuation = true;
  theta.x0 = theta.v0 = true;
  Data data(model);
  State final;
  MatX dx, dv;
  // 10 steps: x0 and v0 make 594 columns.
  const long steps = 10;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, steps, theta, final, dx, dv).ok());
  const VecX cx = random_vector(dx.rows(), 2), cv = random_vector(dx.rows(), 3);
  Data data2(model);
  diff::Tape tape;
  ASSERT_TRUE(diff::record(model, data2, model.initial, steps, tape).ok());
  diff::AdjointResult adj;
  const auto loss = [&](long k, const State&, VecX& bar_x, VecX& bar_v) {
    if (k == steps) {
      bar_x += cx;
      bar_v += cv;
    }
  };
  ASSERT_TRUE(diff::adjoint(model, data2, tape, theta, loss, adj).ok());
  const VecX forward = dx.transpose() * cx + dv.transpose() * cv;
  ASSERT_EQ(forward.size(), adj.theta.size());
  const auto names = theta.column_names(model);
  // Per column, relative to the column's own scale |c| |S_col|.
  for (Eigen::Index j = 0; j < forward.size(); ++j) {
    const double scale = cx.norm() * dx.col(j).norm() + cv.norm() * dv.col(j).norm();
    EXPECT_NEAR(adj.theta[j], forward[j], 1e-9 * scale + 1e-300) << "column " << j;
  }
  EXPECT_EQ(names.size(), 8u);
  EXPECT_EQ(names[0], "young[body]");
  EXPECT_EQ(names[5], "actuation[pull]");
}

TEST(TrajectoryDerivatives, ActuationSequenceGradientMatchesFiniteDifferences) {
  // l = c . x_T as a function of the servo's value at each step: the adjoint gives all
  // T entries at once; central differences check three of them.
  const Model model = beam(5e4);
  MatX actuation(1, kSteps);
  for (long k = 0; k < kSteps; ++k) actuation(0, k) = 0.02 + 0.001 * k;
  Data data(model);
  diff::Tape tape;
  ASSERT_TRUE(diff::record(model, data, model.initial, kSteps, tape, actuation).ok());
  const VecX c = random_vector(3L * model.fem.num_nodes, 4);
  diff::AdjointResult adj;
  ASSERT_TRUE(diff::adjoint(model, data, tape, {}, [&](long k, const State&, VecX& bx, VecX&) {
                if (k == kSteps) bx += c;
              }, adj).ok());
  ASSERT_EQ(adj.lambda_a.cols(), kSteps);
  // The step: the runs' positions carry round-off of ~1e-13 relative (30 steps of
  // CHOLMOD solves), so the difference quotient's round-off is ~1e-13 |c.x| / (2 e). At
  // e = 1e-5 lambda it reached 2.7e-6 relative on the portable build (it shrinks as 1/e:
  // 8e-8 at 1e-4, 1.4e-9 at 1e-3), too close to the 1e-6 bound and dependent on the
  // instruction set's rounding. At e = 1e-3 lambda both the round-off and the truncation
  // error (e^2 times the third derivative) stay below 2e-9 relative at all three steps
  // (measured).
  for (long k : {0L, 14L, 29L}) {
    const double e = 1e-3 * actuation(0, k);
    MatX ap = actuation, am = actuation;
    ap(0, k) += e;
    am(0, k) -= e;
    const double fd = (c.dot(run(model, ap).x) - c.dot(run(model, am).x)) / (2 * e);
    EXPECT_NEAR(adj.lambda_a(0, k), fd, 1e-6 * std::abs(fd)) << "step " << k + 1;
    EXPECT_NE(fd, 0);
  }
}

}  // namespace
