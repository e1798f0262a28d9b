// Trajectory derivatives with actuators on a quadratic body (issue 18): a cable
// embedded in curved 10-node tets and a pressure load on a curved 6-node-triangle face,
// on a clamped 0.04 x 0.02 x 0.02 m bar (4 x 2 x 2 cells, test::curved_box: mid-edge
// nodes moved by up to 0.05 of the cell, the surface's included), 10 implicit Euler steps.
//  - forward sensitivities d x_T / d(young, cable tension, pressure) against central
//    differences of whole runs;
//  - the adjoint against the forward mode for every theta group (parameters,
//    actuation, x0, v0), and x0 directions against central differences.
// Steps: young 1e-5 of its value; actuation 1e-3 of its value (the reasoning of
// validation_trajectory.cpp: the runs carry ~1e-13 relative round-off, so smaller
// steps make the quotient's round-off approach 1e-6, while the truncation error at
// 1e-3 is ~1e-9 relative); x0 along a random direction d (entries in [-1, 1]) with
// the step 1e-7 m (1e-5 of the cell): at 1e-8 the runs' round-off (~1e-13 of |x|)
// over the step gave 2e-7 relative (measured), at 1e-7 ten times less, while the
// truncation error stays ~(1e-7 / 1e-2)^2 = 1e-10. Tolerance 1e-6 relative; 1e-9 between the two analytic modes (the same
// products summed in another order).
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <support/fd.hpp>
#include <support/model_builder.hpp>

#include "actuation/helpers.hpp"

#include <gtest/gtest.h>

#include <random>

namespace trajectory_quadratic_test {

using namespace softdiff;

constexpr long kSteps = 10;
constexpr double kYoung = 5e4, kTension = 0.05, kPressure = 300;

Model bar(double young, double tension, double pressure) {
  std::mt19937 rng(60);
  const mesh::TetMesh m = test::curved_box(4, 2, 2, 0.04, 0.02, 0.02, 0.05, rng);
  test::BodySpec spec;
  spec.law = material::Law::corotational;
  spec.young = young;
  spec.poisson = 0.45;
  spec.density = 1000;
  spec.rayleigh_mass = 0.5;
  spec.rayleigh_stiffness = 2e-3;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  Model model = test::make_model(m, spec, Vec3(0, 0, -9.81), 0.01, kSteps);
  EXPECT_EQ(model.fem.bodies[0].mesh.order, 2);
  const actuation::PointLocator locator(m.X, m.tets, m.tets10);
  std::vector<actuation::EmbeddedPoint> points;
  for (const Vec3& p : {Vec3(0.039, 0.013, 0.017), Vec3(0.021, 0.011, 0.016), Vec3(0.003, 0.009, 0.017)})
    points.push_back(actuation::embedded_point(locator.locate(p).embedding, locator, 0));
  actuation::ActuatorModel cable;
  cable.name = "cable";
  cable.kind = actuation::Cable(points);
  cable.value.constant = tension;
  model.actuation.actuators.push_back(cable);
  // The tip face x = 0.04 (open), 6-node triangles.
  const Triangles tip = test::box_boundary(m, Vec3(0.04, 0.02, 0.02), 1);
  const mesh::Triangles6 tip6 = mesh::quadratic_triangles(m, tip);
  actuation::Cavity face;
  EXPECT_TRUE(actuation::Cavity::create(m.X, m.tets, tip, 0, face, &tip6).ok());
  EXPECT_EQ(face.order(), 2);
  actuation::ActuatorModel press;
  press.name = "press";
  press.kind = face;
  press.value.constant = pressure;
  model.actuation.actuators.push_back(press);
  return model;
}

State run(const Model& model, const State& initial) {
  Data data(model);
  diff::Tape tape;
  const StepStatus st = diff::record(model, data, initial, kSteps, tape);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  return tape.frames.back();
}

TEST(TrajectoryQuadratic, ForwardSensitivitiesMatchFiniteDifferences) {
  const Model model = bar(kYoung, kTension, kPressure);
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}};
  theta.actuation = true;
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, kSteps, theta, final, dx, dv).ok());
  ASSERT_EQ(dx.cols(), 3);
  struct Column {
    const char* name;
    double e;
    Model plus, minus;
  };
  const double ey = 1e-5 * kYoung, et = 1e-3 * kTension, ep = 1e-3 * kPressure;
  Column cols[] = {
      {"young", ey, bar(kYoung + ey, kTension, kPressure), bar(kYoung - ey, kTension, kPressure)},
      {"cable", et, bar(kYoung, kTension + et, kPressure), bar(kYoung, kTension - et, kPressure)},
      {"pressure", ep, bar(kYoung, kTension, kPressure + ep), bar(kYoung, kTension, kPressure - ep)},
  };
  for (int j = 0; j < 3; ++j) {
    const Column& c = cols[j];
    const VecX fd = (run(c.plus, c.plus.initial).x - run(c.minus, c.minus.initial).x) / (2 * c.e);
    ASSERT_GT(fd.norm(), 0) << c.name;
    const double err = (dx.col(j) - fd).norm() / fd.norm();
    std::printf("quadratic bar, d x_T / d %s: forward vs central differences %.2e\n", c.name, err);
    EXPECT_LT(err, 1e-6) << c.name;
  }
}

TEST(TrajectoryQuadratic, AdjointMatchesForwardAndInitialPositionsMatchDifferences) {
  const Model model = bar(kYoung, kTension, kPressure);
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0}};
  theta.actuation = true;
  theta.x0 = theta.v0 = true;
  // x0 and v0 along one random direction each (free nodes only).
  VecX d = test::random_vector(3L * model.fem.num_nodes, 1.0, 4), dvel = test::random_vector(d.size(), 1.0, 5);
  for (Eigen::Index i = 0; i < d.size(); ++i)
    if (model.fem.fixed[i]) d[i] = dvel[i] = 0;
  theta.x0_basis = d;
  theta.v0_basis = dvel;
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, kSteps, theta, final, dx, dv).ok());
  ASSERT_EQ(dx.cols(), 7);
  const VecX cx = test::random_vector(dx.rows(), 1.0, 2), cv = test::random_vector(dx.rows(), 1.0, 3);
  Data data2(model);
  diff::Tape tape;
  ASSERT_TRUE(diff::record(model, data2, model.initial, kSteps, tape).ok());
  diff::AdjointResult adj;
  const auto loss = [&](long k, const State&, VecX& bar_x, VecX& bar_v) {
    if (k == kSteps) {
      bar_x += cx;
      bar_v += cv;
    }
  };
  ASSERT_TRUE(diff::adjoint(model, data2, tape, theta, loss, adj).ok());
  const VecX forward = dx.transpose() * cx + dv.transpose() * cv;
  ASSERT_EQ(forward.size(), adj.theta.size());
  for (Eigen::Index j = 0; j < forward.size(); ++j) {
    const double scale = cx.norm() * dx.col(j).norm() + cv.norm() * dv.col(j).norm();
    EXPECT_NEAR(adj.theta[j], forward[j], 1e-9 * scale + 1e-300) << "column " << j;
  }
  const auto names = theta.column_names(model);
  EXPECT_EQ(names[3], "actuation[cable]");
  EXPECT_EQ(names[4], "actuation[press]");
  // The x0 column (after the 3 parameters and 2 actuators) against central differences.
  const double e = 1e-7;
  State sp = model.initial, sm = model.initial;
  sp.x += e * d;
  sm.x -= e * d;
  const VecX fd = (run(model, sp).x - run(model, sm).x) / (2 * e);
  const VecX an = dx.col(5);
  ASSERT_GT(fd.norm(), 0);
  const double err = (an - fd).norm() / fd.norm();
  std::printf("quadratic bar, d x_T / d x0 . d: forward vs central differences %.2e\n", err);
  EXPECT_LT(err, 1e-6);
}

}  // namespace trajectory_quadratic_test
