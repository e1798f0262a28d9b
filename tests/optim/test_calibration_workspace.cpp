// Calibration's workspace (optim::CalibrationWorkspace): the runs of a calibration on one
// model copy whose parameter values are changed in place and one Data restarted for
// every run give the same residual and Jacobian, bit for bit, as a run on a fresh copy
// of the model and a fresh Data (optim::residual), for every parameter kind that
// `softdiff calibrate` accepts, whatever the order of the evaluated points: values
// that go up and down, a point evaluated twice, a point after a failed run, after an
// invalid value. The scenes cover what a run leaves behind in a Data: the factor of a
// constant system matrix (linear law), Newton's K(x_i) record, BDF2's history, the
// static solver, and the contact stage (detector with the pair rules' friction, warm
// start, NCP workspace, the sparse Delassus backend's analyzed pattern).
// The comparison is exact (==): both paths run the same code on the same numbers, so
// any difference is state carried over from a previous run.
#include <softdiff/core/error.hpp>
#include <softdiff/diff/parameters.hpp>
#include <softdiff/optim/calibration.hpp>
#include <support/contact.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <stdexcept>
#include <string>
#include <vector>

using namespace softdiff;

namespace calibration_workspace_test {

constexpr long kSteps = 8;

// Every frame 1..steps against the rest positions (any target of the right size does:
// the comparison is between two ways of computing the same residual).
optim::CalibrationTarget rest_target(const Model& model, long steps) {
  optim::CalibrationTarget t;
  for (long k = 1; k <= steps; ++k) {
    t.frames.push_back(k);
    t.states.push_back(model.initial.x);
  }
  return t;
}

Model beam(material::Law law, double rayleigh_mass, double rayleigh_stiffness) {
  test::BodySpec spec;
  spec.law = law;
  spec.young = 1e6;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = rayleigh_mass;
  spec.rayleigh_stiffness = rayleigh_stiffness;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  return test::make_model(test::box_mesh(8, 2, 2, 0.2, 0.02, 0.02), spec, Vec3(0, 0, -9.81), 0.01, kSteps);
}

// The beam resting on two supports (two pair rules, friction 0.5 each).
Model supported_beam(contact::NcpBackend backend) {
  test::BodySpec spec;
  spec.law = material::Law::corotational;
  spec.young = 1e5;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 1.0;
  Model model = test::make_model(test::box_mesh(8, 2, 2, 0.2, 0.02, 0.02), spec, Vec3(0, 0, -9.81), 0.01, kSteps);
  test::ContactSpec cs;
  cs.mu = 0.5;
  cs.margin = 1e-3;
  cs.ncp.backend = backend;
  // Sliding along x on both supports (friction's derivative vanishes where contacts stick).
  for (int i = 0; i < model.fem.num_nodes; ++i) model.initial.v[3 * i] = 0.2;
  test::enable_contact(model,
                       {test::box(Vec3(0.01, 0.01, -0.01), Vec3(0.02, 0.03, 0.01), "left"),
                        test::box(Vec3(0.19, 0.01, -0.01), Vec3(0.02, 0.03, 0.01), "right")},
                       cs);
  return model;
}

// Evaluates `points` in order on one workspace and compares every one with a fresh run.
void same_as_fresh(const Model& model, const std::vector<ParameterId>& parameters,
                   const std::vector<std::vector<double>>& points, const optim::CalibrationTarget& target,
                   const std::string& what) {
  optim::CalibrationWorkspace workspace(model, parameters);
  for (std::size_t i = 0; i < points.size(); ++i) {
    VecX r, r_fresh;
    MatX J, J_fresh;
    optim::residual(model, parameters, points[i], target, false, r_fresh, J_fresh);
    workspace.residual(points[i], target, false, r, J);
    ASSERT_EQ(r.size(), r_fresh.size());
    ASSERT_EQ(J.rows(), J_fresh.rows());
    ASSERT_EQ(J.cols(), J_fresh.cols());
    // A residual of zero would make the comparison empty.
    ASSERT_GT(r_fresh.norm(), 0) << what;
    for (Eigen::Index j = 0; j < J_fresh.cols(); ++j) ASSERT_GT(J_fresh.col(j).norm(), 0) << what << ", column " << j;
    EXPECT_TRUE(r == r_fresh) << what << ", point " << i << ": |r - r_fresh| = " << (r - r_fresh).norm();
    EXPECT_TRUE(J == J_fresh) << what << ", point " << i << ": |J - J_fresh| = " << (J - J_fresh).norm();
    // The workspace's model holds the values of the point.
    for (std::size_t j = 0; j < parameters.size(); ++j)
      EXPECT_EQ(diff::get_parameter(workspace.model(), parameters[j]), points[i][j]) << what;
  }
  EXPECT_EQ(workspace.runs(), static_cast<int>(points.size()));
}

const std::vector<ParameterId> kBodyParameters = {{Parameter::young, 0},
                                                  {Parameter::poisson, 0},
                                                  {Parameter::density, 0},
                                                  {Parameter::rayleigh_mass, 0},
                                                  {Parameter::rayleigh_stiffness, 0}};

// Up, down, back to the first point (whose density, set on top of the others' in
// place, would compound the rounding of the mass ratios).
const std::vector<std::vector<double>> kBodyPoints = {{1e6, 0.3, 1000, 0.1, 0.001},
                                                      {1.7e6, 0.35, 1300, 0.3, 0.004},
                                                      {0.6e6, 0.25, 800, 0.05, 0.0005},
                                                      {1e6, 0.3, 1000, 0.1, 0.001}};


TEST(CalibrationWorkspace, EveryBodyParameterSameAsAFreshRun) {
  const Model m = beam(material::Law::corotational, 0.1, 0.001);
  same_as_fresh(m, kBodyParameters, kBodyPoints, rest_target(m, kSteps), "corotational, linearized step");
}

// The sensitivities advance in the run's own pass: one factorization per step, the
// JVP columns (five here) solve with the step's factor.
TEST(CalibrationWorkspace, OneFactorizationPerStepWithTheSensitivities) {
  const Model m = beam(material::Law::corotational, 0.1, 0.001);
  optim::CalibrationWorkspace workspace(m, kBodyParameters);
  VecX r;
  MatX J;
  for (const auto& point : kBodyPoints) {
    workspace.residual(point, rest_target(m, kSteps), false, r, J);
    EXPECT_EQ(workspace.data().factorizations, kSteps);
  }
}

// The linear law's system matrix is constant: a run keeps its factor from step 1 on,
// which a restarted Data must not carry into the next run's values.
TEST(CalibrationWorkspace, ConstantSystemMatrixIsRefactorizedForNewValues) {
  const Model m = beam(material::Law::linear, 0.1, 0.001);
  same_as_fresh(m, kBodyParameters, kBodyPoints, rest_target(m, kSteps), "linear law");
}

// Factor reuse (linear_solver.factor_reuse: pcg) keeps the last factor inside the
// solver: a new run must start from a factorization, as a fresh Data does.
TEST(CalibrationWorkspace, FactorReuseStartsEachRunFromAFactorization) {
  Model m = beam(material::Law::corotational, 0.1, 0.001);
  m.solver.factor_reuse = true;
  same_as_fresh(m, kBodyParameters, kBodyPoints, rest_target(m, kSteps), "factor reuse");
}

TEST(CalibrationWorkspace, NewtonAndBdf2SameAsAFreshRun) {
  Model newton = beam(material::Law::neo_hookean, 0.1, 0.001);
  newton.step.newton_iterations = 4;
  same_as_fresh(newton, kBodyParameters, kBodyPoints, rest_target(newton, kSteps), "Newton");
  Model bdf2 = beam(material::Law::corotational, 0.1, 0.001);
  bdf2.step.integrator = IntegratorKind::bdf2;
  same_as_fresh(bdf2, kBodyParameters, kBodyPoints, rest_target(bdf2, kSteps), "BDF2");
}

TEST(CalibrationWorkspace, StaticEquilibriumSameAsAFreshRun) {
  Model m = beam(material::Law::neo_hookean, 0, 0);
  m.step.integrator = IntegratorKind::static_equilibrium;
  m.step.static_load_steps = 2;
  optim::CalibrationTarget target;
  target.frames = {m.step.static_load_steps};
  target.states = {m.initial.x};
  same_as_fresh(m, {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0}},
                {{1e6, 0.3, 1000}, {1.7e6, 0.35, 1300}, {0.6e6, 0.25, 800}, {1e6, 0.3, 1000}}, target, "static");
}

// Friction is copied into the detector's pair rules: the workspace rebuilds it.
TEST(CalibrationWorkspace, ContactAndFrictionSameAsAFreshRun) {
  const std::vector<ParameterId> parameters = {{Parameter::young, 0}, {Parameter::friction, 0}, {Parameter::friction, 1},
                                               {Parameter::density, 0}};
  const std::vector<std::vector<double>> points = {
      {1e5, 0.5, 0.5, 1000}, {1.4e5, 0.2, 0.8, 1200}, {0.8e5, 0.9, 0.1, 900}, {1e5, 0.5, 0.5, 1000}};
  for (const auto backend : {contact::NcpBackend::dense, contact::NcpBackend::sparse}) {
    const Model m = supported_beam(backend);
    same_as_fresh(m, parameters, points, rest_target(m, kSteps),
                  backend == contact::NcpBackend::dense ? "contact, dense" : "contact, sparse");
  }
}

// A run that throws (an invalid value; a run that fails) leaves the workspace usable:
// the next point is still the same as a fresh run.
TEST(CalibrationWorkspace, AfterAFailedRunSameAsAFreshRun) {
  // Compressed along x from the start (v_x = -50 X_x): a stiff beam (E ~ 1e6 Pa, h^2
  // omega^2 >> 1 for the element modes) stops it in a step; at E = 1 Pa the elements
  // near the free end invert.
  Model m = beam(material::Law::corotational, 0.1, 0.001);
  for (int i = 0; i < m.fem.num_nodes; ++i) m.initial.v[3 * i] = -50 * m.fem.X(0, i);
  const optim::CalibrationTarget target = rest_target(m, kSteps);
  optim::CalibrationWorkspace workspace(m, kBodyParameters);
  VecX r, r_fresh;
  MatX J, J_fresh;
  workspace.residual(kBodyPoints[1], target, false, r, J);
  // young is set, then poisson throws: the model is left half changed.
  EXPECT_THROW(workspace.residual({2e6, 0.7, 1000, 0.1, 0.001}, target, false, r, J), std::invalid_argument);
  EXPECT_THROW(workspace.residual({1, 0.3, 1000, 0.1, 0.001}, target, false, r, J), ComputationError);
  optim::residual(m, kBodyParameters, kBodyPoints[2], target, false, r_fresh, J_fresh);
  workspace.residual(kBodyPoints[2], target, false, r, J);
  EXPECT_TRUE(r == r_fresh) << "|r - r_fresh| = " << (r - r_fresh).norm();
  EXPECT_TRUE(J == J_fresh) << "|J - J_fresh| = " << (J - J_fresh).norm();
}

}  // namespace calibration_workspace_test
