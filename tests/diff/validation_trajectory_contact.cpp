// Trajectory derivatives through frictional contact:
//  - a cube resting on a plane (pressed 0.1 mm in, sticking) for 10 steps: d x_T/d young
//    by forward sensitivity, by the adjoint and by central differences agree, and so do
//    forward and adjoint for x0 directions; the adjoint's recomputed steps are the
//    recorded ones bit for bit (the tape keeps each step's NCP warm start);
//  - a cube dropped onto the plane: the contact set and the modes change during the
//    run (no contact, impact, rest); the derivatives stay finite, and forward and
//    adjoint still agree (both differentiate the same piecewise-smooth run).
// Steps: young 1e-5 of its value; tolerance 1e-6 against differences, 1e-9 between the
// two analytic modes.
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <support/contact.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;

namespace {

Model cube(double young, double lift, double vz, long steps) {
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = young;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 0.5;
  spec.rayleigh_stiffness = 1e-3;
  mesh::TetMesh m = test::box_mesh(2, 2, 2, 0.04, 0.04, 0.04);
  m.X.row(2).array() += lift;
  Model model = test::make_model(m, spec, Vec3(0, 0, -9.81), 2e-3, steps);
  for (int i = 0; i < model.fem.num_nodes; ++i) model.initial.v[3 * i + 2] = vz;
  test::ContactSpec cs;
  cs.mu = 1.0;
  cs.margin = 2e-3;
  cs.ncp.tolerance = 1e-13;
  cs.ncp.max_iterations = 20000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  return model;
}

VecX final_x(const Model& model, long steps) {
  Data data(model);
  diff::Tape tape;
  EXPECT_TRUE(diff::record(model, data, model.initial, steps, tape).ok());
  return tape.frames.back().x;
}

struct Both {
  MatX dx, dv;      // forward
  VecX adjoint;     // c . x_T by the adjoint
  VecX c;
  diff::Tape tape;
};

Both both(const Model& model, long steps, const diff::ThetaLayout& theta) {
  Both b;
  Data d1(model);
  State final;
  EXPECT_TRUE(diff::forward_sensitivities(model, d1, model.initial, steps, theta, final, b.dx, b.dv).ok());
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  b.c = VecX(final.x.size());
  for (Eigen::Index k = 0; k < b.c.size(); ++k) b.c[k] = u(rng);
  Data d2(model);
  EXPECT_TRUE(diff::record(model, d2, model.initial, steps, b.tape).ok());
  EXPECT_EQ((b.tape.frames.back().x - final.x).norm(), 0);
  diff::AdjointResult g;
  EXPECT_TRUE(diff::adjoint(model, d2, b.tape, theta, [&](long k, const State&, VecX& bx, VecX&) {
                if (k == steps) bx += b.c;
              }, g).ok());
  b.adjoint = g.theta;
  // The sweep recomputed the recorded run exactly (each step's NCP warm start is on the tape).
  EXPECT_EQ(g.recompute_mismatch, 0.0);
  return b;
}

diff::ThetaLayout young_and_directions(const Model& model) {
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}};
  theta.x0 = true;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  theta.x0_basis = MatX(model.initial.x.size(), 2);
  for (Eigen::Index r = 0; r < theta.x0_basis.rows(); ++r)
    for (int c = 0; c < 2; ++c) theta.x0_basis(r, c) = u(rng);
  return theta;
}

TEST(TrajectoryDerivativesContact, RestingCubeForwardAdjointAndDifferencesAgree) {
  const long steps = 10;
  const double E = 5e4;
  const Model model = cube(E, -1e-4, 0, steps);
  const diff::ThetaLayout theta = young_and_directions(model);
  const Both b = both(model, steps, theta);
  // Forward against the adjoint, column by column.
  for (Eigen::Index j = 0; j < b.dx.cols(); ++j) {
    const double fwd = b.c.dot(b.dx.col(j));
    EXPECT_NEAR(b.adjoint[j], fwd, 1e-9 * b.c.norm() * b.dx.col(j).norm()) << "column " << j;
  }
  // Young against central differences of whole runs.
  const double e = 1e-5 * E;
  const VecX fd = (final_x(cube(E + e, -1e-4, 0, steps), steps) - final_x(cube(E - e, -1e-4, 0, steps), steps)) / (2 * e);
  ASSERT_GT(fd.norm(), 0);
  EXPECT_LE((b.dx.col(0) - fd).norm(), 1e-6 * fd.norm()) << (b.dx.col(0) - fd).norm() / fd.norm();
  EXPECT_EQ(b.tape.warm_start.size(), static_cast<std::size_t>(steps));
}

TEST(TrajectoryDerivativesContact, ImpactKeepsDerivativesFinite) {
  // 5 mm above the plane at 0.3 m/s down (0.6 mm per step): contacts within the 2 mm
  // margin after ~5 steps, then the impact and the cube at rest within 25 steps.
  const long steps = 25;
  const Model model = cube(5e4, 5e-3, -0.3, steps);
  const diff::ThetaLayout theta = young_and_directions(model);
  Data data(model);
  State s = model.initial, next;
  int first_contact = -1;
  for (long k = 1; k <= steps; ++k) {
    ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, next, k).ok());
    if (first_contact < 0 && !data.contact.contacts.empty()) first_contact = static_cast<int>(k);
    std::swap(s, next);
  }
  ASSERT_GT(first_contact, 1);  // the run starts without contact and gets it
  const Both b = both(model, steps, theta);
  EXPECT_TRUE(b.dx.allFinite() && b.dv.allFinite() && b.adjoint.allFinite());
  for (Eigen::Index j = 0; j < b.dx.cols(); ++j) {
    const double fwd = b.c.dot(b.dx.col(j));
    EXPECT_NEAR(b.adjoint[j], fwd, 1e-9 * b.c.norm() * b.dx.col(j).norm()) << "column " << j;
  }
}

}  // namespace
