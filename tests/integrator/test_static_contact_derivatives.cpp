// Derivatives of the static equilibrium through contact (static_solver_derivatives.hpp,
// docs/method.md "Derivatives", "Static equilibrium with contact") against central
// differences of the whole static solve, in configurations whose contacts and modes are
// the same at theta +/- e (checked: otherwise the difference is not a valid test):
//  - a cube resting on a plane with no fixed node (held by contact alone: the augmented
//    tangent), mu = 2, every loaded contact sticking (with mu = 0.5 the corners end on
//    the cone: sliding, see below);
//  - the same cube under gravity tilted by 25 degrees (mu = 1: the tangential load,
//    tan 25 = 0.47 of the normal one, is carried by friction, every contact inside its
//    cone);
// with respect to young, poisson, density and friction; and the reverse mode
// (static_vjp) against the transpose of the forward columns.
//
// Steps and tolerances: the solve is converged to a relative residual of 1e-12 with the
// NCP at 1e-12 and polished (the modes' equations exact to round-off), so the
// equilibrium x*(theta) carries an error of about 1e-12 of its displacement u; with the
// step e = 1e-5 of the parameter's scale (young, density: their value; poisson and
// friction: 0.1, their range's size) that error becomes 1e-12 / 1e-5 = 1e-7 of
// dx*/dtheta * scale, and the truncation error e^2 |x'''| ~ 1e-10 relative. The
// tolerance 1e-5 keeps two orders of margin over the round-off estimate and catches any
// missing term (a missing geometry or proximal term is 1e-2 or more).
#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/diff/parameters.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/integrator/static_solver_derivatives.hpp>
#include <support/contact.hpp>
#include <support/fd.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <numbers>
#include <string>
#include <vector>

using namespace softdiff;

namespace static_contact_derivatives {

constexpr double kG = 9.81;
constexpr double kDeg = std::numbers::pi / 180;
constexpr double kStep = 1e-5;
constexpr double kTolerance = 1e-5;

void set_static(Model& model) {
  model.step.integrator = IntegratorKind::static_equilibrium;
  model.step.static_tolerance = 1e-12;
  model.step.static_max_iterations = 100;
}

test::ContactSpec contact_spec(double mu) {
  test::ContactSpec cs;
  cs.mu = mu;
  cs.ncp.tolerance = 1e-12;
  cs.ncp.max_iterations = 20000;
  return cs;
}

// A 0.1 m cube (3 x 3 x 3 boxes) on the plane z = 0, no fixed node, gravity g.
Model cube(const Vec3& g, double mu) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.poisson = 0.3;
  spec.density = 1000;
  Model model = test::make_model(test::box_mesh(3, 3, 3, 0.1, 0.1, 0.1), spec, g);
  set_static(model);
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, contact_spec(mu));
  return model;
}

// A 0.06 m cube (2 x 2 x 2 boxes, no fixed node) resting on a 0.1 m cube (3 x 3 x 3
// boxes) whose base is fixed (the reverse-mode test): soft-soft contacts (the top cube's vertices on the lower
// cube's top faces, 3 or 4 nodes each: the proximal refinement and the geometry term
// dH^T lambda of the face's weights). The top cube's vertices sit inside the lower
// faces' triangles, away from their edges (>= 2.8e-4 m), so each feature pair is unique.
Model stacked_cubes(double mu, const Vec3& g = Vec3(0, 0, -kG)) {
  test::BodySpec lower, upper;
  lower.young = 2e5;
  upper.young = 1e5;
  lower.fixed = [](const Vec3& p) { return p.z() < 1e-9; };
  mesh::TetMesh top = test::box_mesh(2, 2, 2, 0.06, 0.06, 0.06);
  for (int i = 0; i < top.X.cols(); ++i) top.X.col(i) += Vec3(0.025, 0.012, 0.1);
  Model model = test::make_model({{test::box_mesh(3, 3, 3, 0.1, 0.1, 0.1), lower}, {top, upper}}, g);
  set_static(model);
  test::enable_contact(model, {}, contact_spec(mu));
  model.contact.detection.pairs.push_back({1, 0, mu});
  return model;
}

struct Solution {
  State x;
  std::vector<contact::Mode> modes;
  int contacts = 0;
};

Solution solve(const Model& model, Data& data) {
  Solution s;
  const StepStatus st = integrator::solve_static(model, data, model.initial, s.x);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  EXPECT_TRUE(data.contact.result.converged);
  VecX sigma;
  integrator::equilibrium_modes(model, data.contact, s.x.x, data.static_load_step_start, s.modes, sigma);
  s.contacts = data.contact.contacts.size();
  return s;
}

std::string mode_counts(const std::vector<contact::Mode>& modes) {
  int n[3] = {0, 0, 0};
  for (auto m : modes) ++n[static_cast<int>(m)];
  return std::to_string(n[0]) + " breaking, " + std::to_string(n[1]) + " sticking, " + std::to_string(n[2]) +
         " sliding";
}

double scale_of(const Model& model, const ParameterId& id) {
  const double v = std::abs(diff::get_parameter(model, id));
  return id.kind == Parameter::poisson || id.kind == Parameter::friction ? std::max(v, 0.1) : v;
}

// The analytic columns against central differences of the solve; every column must see
// the same contacts and modes at theta +/- e. Returns the analytic Jacobian.
MatX check(const Model& model, const std::vector<ParameterId>& parameters, const std::string& what) {
  SCOPED_TRACE(what);
  Data data(model);
  const Solution base = solve(model, data);
  std::cout << "[ " << what << " ] " << base.contacts << " contacts: " << mode_counts(base.modes) << "\n";
  MatX J;
  EXPECT_TRUE(integrator::static_sensitivities(model, data, base.x, {parameters, false, {}}, J));
  MatX J_fd(J.rows(), J.cols());
  for (std::size_t j = 0; j < parameters.size(); ++j) {
    const double e = kStep * scale_of(model, parameters[j]);
    const double p = diff::get_parameter(model, parameters[j]);
    Model mp = model, mm = model;
    diff::set_parameter(mp, parameters[j], p + e);
    diff::set_parameter(mm, parameters[j], p - e);
    Data dp(mp), dm(mm);
    const Solution sp = solve(mp, dp), sm = solve(mm, dm);
    EXPECT_EQ(sp.contacts, base.contacts) << "column " << j;
    EXPECT_EQ(sm.contacts, base.contacts) << "column " << j;
    EXPECT_TRUE(sp.modes == base.modes && sm.modes == base.modes)
        << "column " << j << ": the modes change within the step (not a valid test): " << mode_counts(sp.modes)
        << " / " << mode_counts(sm.modes);
    J_fd.col(static_cast<Eigen::Index>(j)) = (sp.x.x - sm.x.x) / (2 * e);
  }
  // A column without effect (friction where every contact sticks): its differences are
  // round-off, below 1e-7 of the largest column; the analytic column must be as small.
  double largest = 0;
  for (Eigen::Index j = 0; j < J.cols(); ++j)
    largest = std::max(largest, J_fd.col(j).norm() * scale_of(model, parameters[static_cast<std::size_t>(j)]));
  for (Eigen::Index j = 0; j < J.cols(); ++j) {
    const double s = scale_of(model, parameters[static_cast<std::size_t>(j)]);
    const test::Comparison c = test::compare(J.col(j) * s, J_fd.col(j) * s);
    std::cout << "[ " << what << " ] column " << j << " (" << parameter_name(parameters[static_cast<std::size_t>(j)].kind)
              << "): |J e| = " << J_fd.col(j).norm() * s << ", " << c.str() << "\n";
    if (J_fd.col(j).norm() * s > 1e-7 * largest) EXPECT_LT(c.rel_error, kTolerance) << "column " << j << ": " << c.str();
    else EXPECT_LE((J.col(j) * s).norm(), 1e-7 * largest) << "column " << j;
  }
  return J;
}

// The reverse mode against the forward columns J of the same equilibrium: bar_theta =
// J^T bar_x for a random bar_x, to 1e-10 relative (the same factorization and mode-fixed
// system; the refinements stop at 1e-13 of their iterate, or at their round-off floor).
void expect_vjp_is_transpose(const Model& model, Data& data, const State& x, const std::vector<ParameterId>& params,
                             const MatX& J) {
  const VecX bar_x = test::random_vector(J.rows(), 1.0, 7);
  VecX bar_theta;
  ASSERT_TRUE(integrator::static_vjp(model, data, x, {params, false, {}}, bar_x, bar_theta));
  const VecX expected = J.transpose() * bar_x;
  for (Eigen::Index j = 0; j < expected.size(); ++j)
    EXPECT_NEAR(bar_theta[j], expected[j], 1e-10 * expected.cwiseAbs().maxCoeff()) << "parameter " << j;
}

std::vector<ParameterId> elastic_and_density() {
  return {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0}};
}

TEST(StaticContactDerivatives, CubeOnPlaneSticking) {
  const Model model = cube(Vec3(0, 0, -kG), 2.0);
  check(model, elastic_and_density(), "cube, sticking");
}

TEST(StaticContactDerivatives, TiltedBlockSticking) {
  const double a = 25 * kDeg;
  const Model model = cube(Vec3(kG * std::sin(a), 0, -kG * std::cos(a)), 1.0);
  auto params = elastic_and_density();
  params.push_back({Parameter::friction, 0});
  check(model, params, "tilted block, 25 deg");
}

// The reverse mode equals the transpose of the forward columns: bar_theta =
// J^T bar_x for a random bar_x, to 1e-10 relative (the same factorization and
// mode-fixed system; the refinements stop at 1e-13 of their iterate, or at their
// round-off floor), on the tilted cube (the augmented tangent, one pass) and on the
// stacked cubes (soft-soft contacts: the proximal refinement with the geometry term,
// transposed).
TEST(StaticContactDerivatives, ReverseModeIsTheTranspose) {
  const double a = 25 * kDeg;
  for (int variant = 0; variant < 2; ++variant) {
    SCOPED_TRACE(variant == 0 ? "tilted cube" : "stacked cubes");
    const Model model = variant == 0 ? cube(Vec3(kG * std::sin(a), 0, -kG * std::cos(a)), 1.0) : stacked_cubes(2.0);
    const std::vector<ParameterId> params = {
        {Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0}, {Parameter::friction, 0}};
    Data data(model);
    const Solution base = solve(model, data);
    MatX J;
    ASSERT_TRUE(integrator::static_sensitivities(model, data, base.x, {params, false, {}}, J));
    expect_vjp_is_transpose(model, data, base.x, params, J);
  }
}

// Beyond 64 active contacts on the operator (contact_step_derivatives.cpp: never a
// dense G_AA; both crossovers 0): a 9 x 9 x 1-element slab
// (0.09 x 0.09 x 0.01 m, nu = 0.45, no fixed node) resting on the plane under its
// weight. The weight compresses it and the Poisson effect pushes it outwards: with mu =
// 0.1 the rim slides (96 of the 100 contacts, 4 stick: a mixed set, GMRES with the
// reduced preconditioner), with mu = 2 every contact sticks (PCG).
Model slab(double mu, bool on_operator) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.poisson = 0.45;
  spec.density = 1000;
  Model model = test::make_model(test::box_mesh(9, 9, 1, 0.09, 0.09, 0.01), spec, Vec3(0, 0, -kG));
  set_static(model);
  test::ContactSpec cs = contact_spec(mu);
  cs.ncp.derivative_dense_max_active = on_operator ? 0 : 400;
  cs.ncp.derivative_mixed_dense_max_active = on_operator ? 0 : 400;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  return model;
}

// The mixed set. Central differences do not test it: where contacts slide, the static
// derivative is that of the straight slip path, an approximation of the solver's path
// (docs/method.md "Static equilibrium with contact"; measured here: young 1.05e-5,
// friction 4.9e-3 relative against the differences, on both paths alike). The
// reference is the dense G_AA path (crossovers 400; its own differences tests are the
// file's cases above and test_step_derivatives_contact.cpp) on the same equilibrium:
// the operator's Jacobian equals it to 1e-8 relative (GMRES stops at 1e-12 of the
// scaled residual, times J's conditioning, about 1e2 to 1e3 on these slabs: 1e-9; a
// factor 10 of margin). The operator path is the one taken (both crossovers 0); its
// scale L is the largest diagonal entry of G_AA over a sample of the active contacts
// (docs/method.md "The derivative's scale").
TEST(StaticContactDerivatives, MixedSetBeyond64OnTheOperator) {
  const Model model = slab(0.1, true), dense = slab(0.1, false);
  const std::vector<ParameterId> params = {{Parameter::young, 0}, {Parameter::friction, 0}};
  Data data(model);
  const Solution base = solve(model, data);
  int active = 0, sliding = 0;
  for (auto m : base.modes) {
    active += m != contact::Mode::breaking;
    sliding += m == contact::Mode::sliding;
  }
  std::cout << "[ slab ] " << base.contacts << " contacts: " << mode_counts(base.modes) << "\n";
  ASSERT_GT(active, 64);
  ASSERT_GT(sliding, 0);
  ASSERT_LT(sliding, active);
  MatX J_op, J_dense;
  ASSERT_TRUE(integrator::static_sensitivities(model, data, base.x, {params, false, {}}, J_op));
  ASSERT_TRUE(integrator::static_sensitivities(dense, data, base.x, {params, false, {}}, J_dense));
  for (Eigen::Index j = 0; j < J_op.cols(); ++j) {
    ASSERT_GT(J_dense.col(j).norm(), 0) << "column " << j;
    const double d = (J_op.col(j) - J_dense.col(j)).norm() / J_dense.col(j).norm();
    std::cout << "[ slab ] column " << j << ": operator against dense G_AA " << d << " relative\n";
    EXPECT_LT(d, 1e-8) << "column " << j;
  }
  // The sticking slab takes the operator too: its scale's power iteration (only that path
  // runs it; the mixed set's scale is the sampled diagonal of G_AA) capped at one product
  // makes the same derivative a ComputationError.
  Model capped = slab(2.0, true);
  capped.contact.ncp.derivative_scale_max_iterations = 1;
  Data capped_data(capped);
  const Solution sticking = solve(capped, capped_data);
  ASSERT_GT(sticking.contacts, 64);
  for (auto m : sticking.modes) ASSERT_NE(m, contact::Mode::sliding);
  MatX J;
  EXPECT_THROW(integrator::static_sensitivities(capped, capped_data, sticking.x, {params, false, {}}, J),
               ComputationError);
}

// The same slab with every contact sticking (mu = 2; exact, so central differences
// apply) on the operator: against the differences of the whole static solve with the
// file's steps and tolerance (e = 1e-5 of the scale, solves to 1e-12, 1e-5 relative,
// the same contacts and modes at theta +/- e, checked).
TEST(StaticContactDerivatives, StickingSetBeyond64OnTheOperator) {
  check(slab(2.0, true), {{Parameter::young, 0}, {Parameter::poisson, 0}}, "slab, sticking, on the operator");
}

// static.friction load_step (docs/method.md "Static equilibrium with contact",
// *Load-step-anchored friction*; 2026-12-04, branch sfric): each Newton iteration's NCP
// acts on the slip since the load step's start, so the equilibrium is a function of the
// parameters and the start state, and the derivative (a sticking contact holds its total
// slip at zero, a sliding one slides along its total slip: equilibrium_modes) is exact
// where contacts slide too. The cases that iterate could not check against central
// differences (the derivative approximated its path-dependent answer), with this file's
// steps and tolerance (e = 1e-5 of the scale, solves to 1e-12, 1e-5 relative, the same
// contacts and modes at theta +/- e, checked):
//  - the cube on the plane with mu 0.5 (its corners end on the cone: sliding);
//  - the slab of MixedSetBeyond64OnTheOperator with mu 0.1 (96 of 100 contacts slide, the
//    rest stick; dense G_AA crossovers, and the operator).
//  - soft-soft contacts (LoadStepFrictionSoftSoftStackedCubes below).
Model load_step(Model model) {
  model.step.static_friction = StaticFriction::load_step;
  return model;
}

TEST(StaticContactDerivatives, LoadStepFrictionCubeWithSlidingCorners) {
  const Model model = load_step(cube(Vec3(0, 0, -kG), 0.5));
  auto params = elastic_and_density();
  params.push_back({Parameter::friction, 0});
  check(model, params, "cube, mu 0.5, load_step");
}

TEST(StaticContactDerivatives, LoadStepFrictionMixedSlab) {
  for (const bool on_operator : {false, true}) {
    const Model model = load_step(slab(0.1, on_operator));
    check(model, {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::friction, 0}},
          on_operator ? "slab, mu 0.1, load_step, operator" : "slab, mu 0.1, load_step, dense");
  }
}

// Soft-soft contacts under load_step (2026-12-04, branch ffric): the stacked cubes under
// gravity tilted by 20 degrees about y, mu 0.5 (the top cube's vertices on the lower
// cube's deforming top faces: some stick, some slide). A face contact measures its slip
// through its current barycentric weights and frame, s = t . sum_k w_k (X_k - X_k^start),
// so its mode rows carry the face terms dt . d + t . sum_k dw_k (X_k - X_k^start)
// (contact_step_derivatives.hpp add_slip_jvp) beside H_T dx; without them (sfric) the
// friction column was 2.1e-4 off, young and density 7.7e-7 to 5.2e-6. The file's steps and
// tolerance (e = 1e-5 of the scale, solves to 1e-12, 1e-5 relative, the same contacts and
// modes at theta +/- e, checked); every column of both bodies, and the reverse mode against
// the transpose of the forward columns (1e-10 relative, as ReverseModeIsTheTranspose: the
// transposed refinement carries the face terms' transpose).
TEST(StaticContactDerivatives, LoadStepFrictionSoftSoftStackedCubes) {
  const double a = 20 * kDeg;
  const Model model = load_step(stacked_cubes(0.5, Vec3(kG * std::sin(a), 0, -kG * std::cos(a))));
  const std::vector<ParameterId> params = {{Parameter::young, 0},   {Parameter::young, 1},
                                           {Parameter::poisson, 1}, {Parameter::density, 1},
                                           {Parameter::friction, 0}};
  const MatX J = check(model, params, "stacked cubes, 20 deg, mu 0.5, load_step");
  Data data(model);
  const Solution base = solve(model, data);
  int sticking = 0, sliding = 0;
  for (auto m : base.modes) {
    sticking += m == contact::Mode::sticking;
    sliding += m == contact::Mode::sliding;
  }
  EXPECT_GT(sticking, 0);
  EXPECT_GT(sliding, 0);
  expect_vjp_is_transpose(model, data, base.x, params, J);
}

}  // namespace static_contact_derivatives
