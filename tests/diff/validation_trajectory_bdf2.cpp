// Trajectory derivatives of BDF2 runs (docs/method.md "Derivatives of the BDF2 step"):
// the state a step depends on includes the previous step, so forward sensitivities
// carry two frames and the adjoint sends each step's cotangent to two frames.
//  - a damped Neo-Hookean bar with a cable, 12 steps (the first implicit Euler): d x_T
//    / d (young, density, rayleigh_mass, the cable's constant offset, two x0 and two v0
//    directions) by forward sensitivities, by the adjoint, and by central differences of
//    whole runs agree; so does the adjoint's per-step actuation gradient;
//  - a cube resting on a plane (sticking) for 10 BDF2 steps: the same through contact,
//    and the adjoint's recomputed steps are the recorded ones bit for bit.
// Steps: parameters 1e-5 of their value (test_step_derivatives.cpp: round-off of the
// solves), x0 directions 1e-8 m (1e-6 of the 0.01 m cells), v0 directions 1e-6 m/s,
// actuation 1e-5 of its value; central differences carry ~1e-8 relative error: 1e-6
// tolerance against differences, 1e-9 between forward and adjoint (the same
// linear algebra in two orders).
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <support/contact.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include "actuation/helpers.hpp"

#include <gtest/gtest.h>

#include <iostream>
#include <random>

using namespace softdiff;

namespace bdf2_trajectory_test {

Model bar(double young, double density, double alpha, double cable_offset, long steps) {
  std::mt19937 rng(7);
  const test::ActuatorSet set(rng, Vec3(1, 2, -0.5));  // 0.03 x 0.02 x 0.02 m, 3 x 2 x 2 cells
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = young;
  spec.poisson = 0.35;
  spec.density = density;
  spec.rayleigh_mass = alpha;
  spec.rayleigh_stiffness = 0.01;
  spec.fixed = [](const Vec3& x) { return x.x() < 1e-9; };
  Model model = test::make_model(set.mesh, spec, Vec3(0.5, -1, -9.81), 3e-3, steps);
  model.step.integrator = IntegratorKind::bdf2;
  actuation::ActuatorModel a;
  a.name = "cable";
  a.kind = set.cable;
  a.value.constant = 0.4 + cable_offset;
  model.actuation.actuators.push_back(a);
  return model;
}

Model cube(double young, long steps, double lift = -1e-4) {
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = young;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 0.5;
  spec.rayleigh_stiffness = 1e-3;
  mesh::TetMesh m = test::box_mesh(2, 2, 2, 0.04, 0.04, 0.04);
  m.X.row(2).array() += lift;  // default: pressed 0.1 mm into the plane
  Model model = test::make_model(m, spec, Vec3(0, 0, -9.81), 2e-3, steps);
  model.step.integrator = IntegratorKind::bdf2;
  test::ContactSpec cs;
  cs.mu = 1.0;
  cs.margin = 2e-3;
  cs.ncp.tolerance = 1e-13;
  cs.ncp.max_iterations = 20000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  return model;
}

VecX final_x(const Model& model, const State& initial, long steps, const MatX& actuation = {}) {
  Data data(model);
  diff::Tape tape;
  EXPECT_TRUE(diff::record(model, data, initial, steps, tape, actuation).ok());
  return tape.frames.back().x;
}

struct Both {
  MatX dx, dv;   // forward
  VecX adjoint;  // c . x_T by the adjoint
  MatX adjoint_lambda_a;
  VecX c;
};

Both both(const Model& model, long steps, const diff::ThetaLayout& theta) {
  Both b;
  Data d1(model);
  State final;
  EXPECT_TRUE(diff::forward_sensitivities(model, d1, model.initial, steps, theta, final, b.dx, b.dv).ok());
  b.c = test::random_vector(final.x.size(), 1.0, 3);
  Data d2(model);
  diff::Tape tape;
  EXPECT_TRUE(diff::record(model, d2, model.initial, steps, tape).ok());
  EXPECT_EQ((tape.frames.back().x - final.x).norm(), 0);
  diff::AdjointResult g;
  EXPECT_TRUE(diff::adjoint(model, d2, tape, theta, [&](long k, const State&, VecX& bx, VecX&) {
                if (k == steps) bx += b.c;
              }, g).ok());
  EXPECT_EQ(g.recompute_mismatch, 0.0);
  b.adjoint = g.theta;
  b.adjoint_lambda_a = g.lambda_a;
  return b;
}

void expect_forward_equals_adjoint(const Both& b) {
  for (Eigen::Index j = 0; j < b.dx.cols(); ++j) {
    const double fwd = b.c.dot(b.dx.col(j));
    EXPECT_NEAR(b.adjoint[j], fwd, 1e-9 * b.c.norm() * b.dx.col(j).norm()) << "column " << j;
  }
}

void expect_close(const VecX& analytic, const VecX& fd, const std::string& what) {
  ASSERT_GT(fd.norm(), 0) << what;
  EXPECT_LE((analytic - fd).norm(), 1e-6 * fd.norm()) << what << ": relative error " << (analytic - fd).norm() / fd.norm();
}

}  // namespace bdf2_trajectory_test

using namespace bdf2_trajectory_test;

TEST(Bdf2TrajectoryDerivatives, ForwardAdjointAndDifferencesAgree) {
  const long steps = 12;
  const double E = 2e4, rho = 1100, alpha = 0.6;
  const Model model = bar(E, rho, alpha, 0, steps);
  const Eigen::Index n = model.initial.x.size();
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}, {Parameter::density, 0}, {Parameter::rayleigh_mass, 0}};
  theta.actuation = true;
  theta.x0 = theta.v0 = true;
  theta.x0_basis = MatX(n, 2);
  theta.v0_basis = MatX(n, 2);
  for (int c = 0; c < 2; ++c) {
    theta.x0_basis.col(c) = test::random_vector(n, 1.0, 10 + c);
    theta.v0_basis.col(c) = test::random_vector(n, 1.0, 20 + c);
    for (Eigen::Index k = 0; k < n; ++k)
      if (model.fem.fixed[static_cast<std::size_t>(k)]) theta.x0_basis(k, c) = theta.v0_basis(k, c) = 0;
  }
  const Both b = both(model, steps, theta);
  expect_forward_equals_adjoint(b);
  // Parameters and the cable's offset: whole runs at p +- e.
  const double values[] = {E, rho, alpha, 0.4};
  for (int j = 0; j < 4; ++j) {
    const double e = 1e-5 * values[j];
    double p[4] = {E, rho, alpha, 0}, m[4] = {E, rho, alpha, 0};
    p[j] += e;
    m[j] -= e;
    const Model mp = bar(p[0], p[1], p[2], p[3], steps), mm = bar(m[0], m[1], m[2], m[3], steps);
    const VecX fd = (final_x(mp, mp.initial, steps) - final_x(mm, mm.initial, steps)) / (2 * e);
    expect_close(b.dx.col(j), fd, "column " + std::to_string(j));
  }
  // x0 and v0 directions.
  for (int c = 0; c < 4; ++c) {
    const bool is_x = c < 2;
    const double e = is_x ? 1e-8 : 1e-6;
    State sp = model.initial, sm = model.initial;
    const VecX dir = is_x ? VecX(theta.x0_basis.col(c)) : VecX(theta.v0_basis.col(c - 2));
    (is_x ? sp.x : sp.v) += e * dir;
    (is_x ? sm.x : sm.v) -= e * dir;
    const VecX fd = (final_x(model, sp, steps) - final_x(model, sm, steps)) / (2 * e);
    expect_close(b.dx.col(4 + c), fd, std::string(is_x ? "x0" : "v0") + " direction " + std::to_string(c % 2));
  }
  // The adjoint's per-step actuation gradient at steps 1, 2 and 7: runs with that
  // step's value moved by +- e (the cable's own value is 0.4 N).
  for (long k : {1L, 2L, 7L}) {
    const double e = 1e-5 * 0.4;
    MatX up = MatX::Constant(1, steps, 0.4), down = up;
    up(0, k - 1) += e;
    down(0, k - 1) -= e;
    const double fd = b.c.dot(final_x(model, model.initial, steps, up) - final_x(model, model.initial, steps, down)) / (2 * e);
    EXPECT_NEAR(b.adjoint_lambda_a(0, k - 1), fd, 1e-6 * std::abs(fd)) << "step " << k;
  }
}

TEST(Bdf2TrajectoryDerivatives, ThroughStickingContact) {
  const long steps = 10;
  const double E = 5e4;
  const Model model = cube(E, steps);
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}};
  theta.x0 = true;
  theta.x0_basis = MatX(model.initial.x.size(), 2);
  for (int c = 0; c < 2; ++c) theta.x0_basis.col(c) = test::random_vector(model.initial.x.size(), 1.0, 30 + c);
  const Both b = both(model, steps, theta);
  expect_forward_equals_adjoint(b);
  {
    Data data(model);
    diff::Tape tape;
    ASSERT_TRUE(diff::record(model, data, model.initial, steps, tape).ok());
    EXPECT_GT(data.contact.contacts.size(), 0);  // the run is in contact to the end
  }
  const double e = 1e-5 * E;
  const Model mp = cube(E + e, steps), mm = cube(E - e, steps);
  expect_close(b.dx.col(0), (final_x(mp, mp.initial, steps) - final_x(mm, mm.initial, steps)) / (2 * e), "young");
  for (int c = 0; c < 2; ++c) {
    const double h = 1e-8;
    State sp = model.initial, sm = model.initial;
    sp.x += h * theta.x0_basis.col(c);
    sm.x -= h * theta.x0_basis.col(c);
    expect_close(b.dx.col(1 + c), (final_x(model, sp, steps) - final_x(model, sm, steps)) / (2 * h),
                 "x0 direction " + std::to_string(c));
  }
}

// Through a soft impact with the BDF2 restart (2026-12-04, rsoft; integrator/bdf2.cpp
// impact, docs/method.md "BDF2", *Impacts: BDF2 restarts*): the cube above dropped 1 mm
// at rest onto the plane (mu 1), 14 steps of 2 ms: it lands at ~0.14 m/s during step 8;
// the landing steps are redone as implicit Euler steps of size h from s_n (their record
// history_weight 0, read by the forward and adjoint modes), BDF2 before and after. The
// run's branches are counted first (at least one restart, BDF2 steps after it). Then
// d x_T / d (young, two x0 directions, one v0 direction) by forward sensitivities against
// central differences of whole runs (each run decides its own branches: the closing
// speed at the landing, ~0.14 m/s, is 28 times the 5 mm/s threshold, and a step of 1e-8
// m or 1e-6 m/s moves no branch), and the adjoint against the forward mode; steps and
// tolerances as the file's (1e-6 relative against differences, 1e-9 forward/adjoint).
TEST(Bdf2TrajectoryDerivatives, ThroughASoftLandingWithTheRestart) {
  const long steps = 14;
  const double E = 5e4, lift = 1e-3;
  const Model model = cube(E, steps, lift);
  {
    Data data(model);
    State a = model.initial, b, previous;
    long restarted = 0, bdf2_after = 0;
    for (long k = 1; k <= steps; ++k) {
      ASSERT_TRUE(integrator::time_step(model, data, a, k > 1 ? &previous : nullptr, b, k).ok());
      if (k > 1 && data.history_weight == 0) ++restarted;
      if (restarted && data.history_weight != 0) ++bdf2_after;
      previous = a;
      std::swap(a, b);
    }
    std::cout << "cube dropped 1 mm, " << steps << " steps: " << restarted << " restarted, " << bdf2_after
              << " BDF2 steps after the first restart\n";
    EXPECT_GE(restarted, 1);
    EXPECT_GE(bdf2_after, 1);
    EXPECT_GT(data.contact.contacts.size(), 0);
  }
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}};
  theta.x0 = theta.v0 = true;
  const Eigen::Index n = model.initial.x.size();
  theta.x0_basis = MatX(n, 2);
  for (int c = 0; c < 2; ++c) theta.x0_basis.col(c) = test::random_vector(n, 1.0, 40 + c);
  theta.v0_basis = MatX(n, 1);
  theta.v0_basis.col(0) = test::random_vector(n, 1.0, 50);
  const Both b = both(model, steps, theta);
  expect_forward_equals_adjoint(b);
  const double e = 1e-5 * E;
  const Model mp = cube(E + e, steps, lift), mm = cube(E - e, steps, lift);
  const VecX fd_young = (final_x(mp, mp.initial, steps) - final_x(mm, mm.initial, steps)) / (2 * e);
  std::cout << "young: relative error " << (b.dx.col(0) - fd_young).norm() / fd_young.norm() << "\n";
  expect_close(b.dx.col(0), fd_young, "young");
  for (int c = 0; c < 3; ++c) {
    const bool is_x = c < 2;
    const double h = is_x ? 1e-8 : 1e-6;
    const VecX dir = is_x ? VecX(theta.x0_basis.col(c)) : VecX(theta.v0_basis.col(0));
    State sp = model.initial, sm = model.initial;
    (is_x ? sp.x : sp.v) += h * dir;
    (is_x ? sm.x : sm.v) -= h * dir;
    const VecX fd = (final_x(model, sp, steps) - final_x(model, sm, steps)) / (2 * h);
    std::cout << (is_x ? "x0" : "v0") << " direction " << c << ": relative error "
              << (b.dx.col(1 + c) - fd).norm() / fd.norm() << "\n";
    expect_close(b.dx.col(1 + c), fd, std::string(is_x ? "x0 direction " : "v0 direction ") + std::to_string(c));
  }
}
