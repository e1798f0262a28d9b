// Derivatives of the implicit Euler step through frictional contact (the collision-
// detection derivatives, the NCP's implicit function theorem with modes fixed, and the
// corrected step) against central differences of the step, in configurations where
// the contact set and modes do not change within the step: a cube resting on a plane
// (sticking), sliding down a tilted gravity (sliding), tipped onto one edge (mixed:
// some contacts breaking), against a sphere (curved obstacle), and frictionless
// (mu = 0). Every block (x_i, v_i, the parameters) and the dot-product test.
//
// Steps as in test_step_derivatives.cpp (positions 1e-6 of the element size,
// velocities 1e-6 m/s, parameters 1e-5 of their value); the NCP is solved to 1e-14
// (polished to round-off), so that the differences see the exact map: tolerance 1e-6.
#include <softdiff/contact/contact_step_derivatives.hpp>
#include <softdiff/contact/sparse_delassus.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <support/contact.hpp>
#include <support/fd.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <limits>
#include <memory>
#include <cstdio>
#include <random>
#include <string>

using namespace softdiff;
using integrator::StateTangent;
using integrator::StepCotangent;
using integrator::StepTangent;

namespace {

enum class Case { sticking, sliding, tipped, sphere, frictionless };

const char* name_of(Case c) {
  const char* names[] = {"sticking", "sliding", "tipped", "sphere", "frictionless"};
  return names[static_cast<int>(c)];
}

struct Params {
  double young = 5e4, poisson = 0.3, density = 1000;
  double mu = -1;  // < 0: the case's own
  contact::NcpBackend backend = contact::NcpBackend::automatic;  // sparse: never a dense G (dense_max_contacts 0)
  // The mode-fixed system on the operator (mode_system.hpp): the polish and the
  // derivative never form G_AA (polish_max_active and derivative_dense_max_active 0).
  bool operator_mode = false;
  // Newton (newton_iterations > 1, docs/method.md "Newton iterations with contact"):
  // a larger step and a cube compressed by `squeeze` of its height (the Neo-Hookean
  // law's nonlinear range), sliding faster (`speed`), so that the converged step
  // differs from the linearized one.
  int newton = 1;
  double dt = 2e-3;
  double squeeze = 0;
  double speed = 0.05;
  // > 0: a slab of cells x cells x 1 elements, 1 cm thick with 1 cm cells, instead of
  // the 2x2x2 cube ((cells + 1)^2 bottom vertices on the plane).
  int cells = 0;
};

// The Newton variant of the cases: 40 iterations at most, converged to newton_tolerance
// 1e-13 (quadratic convergence reaches round-off, so that the differences see the
// converged map), h = 5 ms (about the elastic wave's crossing time of the 4 cm cube,
// 5.7 ms), compressed by 5 % and sliding at 1 m/s (faster than the friction impulse
// mu N h can stop). The linearized step is then off by 1.7 to 3.6 % of the velocity
// change (printed). At h = 10 ms the tangent turns indefinite within the step (the
// compressed cube's lateral modes: "not positive definite", what psd_projection is for).
Params newton_params() {
  Params p;
  p.newton = 40;
  p.dt = 5e-3;
  p.squeeze = 0.05;
  p.speed = 1.0;
  return p;
}

Model build(Case c, const Params& p) {
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = p.young;
  spec.poisson = p.poisson;
  spec.density = p.density;
  spec.rayleigh_mass = 0.5;
  spec.rayleigh_stiffness = 1e-3;
  const double a = c == Case::sliding ? 0.6 : 0.0;  // gravity tilted: tan 0.6 = 0.68 > mu = 0.3
  const Vec3 g(9.81 * std::sin(a), 0, -9.81 * std::cos(a));
  const double side = p.cells > 0 ? 0.01 * p.cells : 0.04;
  Model model = test::make_model(p.cells > 0 ? test::box_mesh(p.cells, p.cells, 1, side, side, 0.01)
                                             : test::box_mesh(2, 2, 2, 0.04, 0.04, 0.04),
                                 spec, g, p.dt, 1);
  model.step.newton_iterations = p.newton;
  model.step.newton_tolerance = 1e-13;
  test::ContactSpec cs;
  // The sphere: sliding (mu 0.2, moving along x), where the turning frame's h dH^T lambda
  // is not cancelled by the contact constraint (it would be for sticking vertex
  // contacts, whose H_i spans the vertex's three dofs).
  cs.mu = c == Case::sliding ? 0.3 : c == Case::frictionless ? 0.0 : c == Case::sphere ? 0.2 : 1.0;
  if (p.mu >= 0) cs.mu = p.mu;
  cs.margin = 2e-3;
  cs.ncp.tolerance = 1e-14;
  cs.ncp.max_iterations = 20000;
  cs.ncp.working_set = false;
  cs.ncp.backend = p.backend;
  if (p.backend == contact::NcpBackend::sparse) cs.ncp.dense_max_contacts = 0;
  if (p.operator_mode) {
    cs.ncp.polish_max_active = 0;
    cs.ncp.polish_at_scale_always = true;  // the polish on the operator even where ADMM converged
    cs.ncp.derivative_dense_max_active = 0;
    cs.ncp.derivative_mixed_dense_max_active = 0;
  }
  std::vector<collision::Obstacle> obstacles;
  if (c == Case::sphere) {
    collision::Obstacle s;
    s.name = "ball";
    s.kind = collision::ShapeKind::sphere;
    // Curved enough (R = 5 cm under a 4 cm cube) that the normals, frames and thus H_c
    // turn with the nodes: the h dH^T lambda term weighs.
    s.center = Vec3(0.021, 0.018, -0.05);
    s.radius = 0.05;
    collision::prepare(s);
    obstacles.push_back(s);
  } else {
    obstacles.push_back(test::plane(Vec3(0, 0, 1), 0));
  }
  test::enable_contact(model, obstacles, cs);
  return model;
}

// The state the derivative is taken at: the cube slightly pressed into the obstacle
// (gap -1e-4: every bottom contact pushes), moving, deformed a little (and compressed
// by p.squeeze of its height).
State start(const Model& model, Case c, const Params& params) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  State s = model.initial;
  const Eigen::Matrix3d R = c == Case::tipped
                                ? Eigen::Matrix3d(Eigen::AngleAxisd(0.08, Vec3::UnitY()).toRotationMatrix())
                                : Eigen::Matrix3d::Identity();
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    Vec3 p = R * s.x.segment<3>(3 * i);
    for (int k = 0; k < 3; ++k) p[k] += 2e-5 * u(rng);
    p.z() *= 1 - params.squeeze;
    p.z() -= 1e-4;
    s.x.segment<3>(3 * i) = p;
    const bool moving = c == Case::sliding || c == Case::sphere;
    const Vec3 v(moving ? params.speed : 0.002 * u(rng), 0.002 * u(rng), -0.01 + 0.002 * u(rng));
    s.v.segment<3>(3 * i) = v;
  }
  return s;
}

struct Outcome {
  VecX y;
  std::vector<contact::Mode> modes;
  std::vector<collision::Contact::Key> keys;
};

Outcome step(const Model& model, const State& in) {
  Data data(model);
  State out;
  const StepStatus st = integrator::implicit_euler_step(model, data, in, out, 1);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  EXPECT_TRUE(data.contact.result.converged) << data.contact.result.residuals.max();
  Outcome o;
  o.y.resize(2 * out.x.size());
  o.y << out.x, out.v;
  o.modes = data.contact.modes;
  for (const auto& c : data.contact.contacts.contacts) o.keys.push_back(c.key());
  return o;
}

// The dot-product test <w, J t> = <J^T w, t> to 1e-10 for the tangent t and a cotangent w
// drawn from rng (entries in [-1, 1]); returns J t.
StateTangent expect_forward_reverse_agree(integrator::StepDerivatives& d, const Model& model, const Data& data,
                                          const State& in, const State& out, const StepTangent& t, std::mt19937& rng,
                                          const std::string& what) {
  std::uniform_real_distribution<double> u(-1, 1);
  StateTangent Jd;
  EXPECT_TRUE(d.jvp(model, data, in, out, t, Jd)) << what;
  const Eigen::Index n = in.x.size();
  StateTangent w;
  w.x = VecX(n);
  w.v = VecX(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    w.x[k] = u(rng);
    w.v[k] = u(rng);
  }
  StepCotangent JTw;
  EXPECT_TRUE(d.vjp(model, data, in, out, w, JTw)) << what;
  const double lhs = w.x.dot(Jd.x) + w.v.dot(Jd.v);
  const double rhs = JTw.x.dot(t.x) + JTw.v.dot(t.v) + JTw.p.dot(t.p);
  EXPECT_NEAR(lhs, rhs, 1e-10 * (w.x.norm() * Jd.x.norm() + w.v.norm() * Jd.v.norm())) << what;
  return Jd;
}

// Newton: more than the linearized step's one iteration, and a converged step that the
// linearized step misses by more than the tolerances of the differences (1e-3 of the
// step's velocity change): the derivative below is that of the nonlinear step.
void expect_newton_matters(const Model& model, const Data& data, const State& in, const State& out,
                           const std::string& what) {
  EXPECT_GE(data.newton_iterations_used, 3) << what;
  Model linearized = model;
  linearized.step.newton_iterations = 1;
  Data d1(linearized);
  State o1;
  ASSERT_TRUE(integrator::implicit_euler_step(linearized, d1, in, o1, 1).ok()) << what;
  const double differ = (o1.v - out.v).norm() / (out.v - in.v).norm();
  std::printf("%s: Newton %d iterations, linearized step off by %.2e of the velocity change\n", what.c_str(),
              data.newton_iterations_used, differ);
  EXPECT_GT(differ, 1e-3) << what;
}

void check(Case c, const Params& p = Params{}) {
  const Model model = build(c, p);
  const State in = start(model, c, p);
  Data data(model);
  State out;
  const StepStatus status = integrator::implicit_euler_step(model, data, in, out, 1);
  ASSERT_TRUE(status.ok()) << name_of(c) << ": " << describe(model, status);
  const auto& cd = data.contact;
  ASSERT_GT(cd.contacts.size(), 0) << name_of(c);
  if (p.newton > 1) expect_newton_matters(model, data, in, out, name_of(c));
  ASSERT_EQ(cd.result.sparse, p.backend == contact::NcpBackend::sparse) << name_of(c);
  // The operator's polish ran (and reached the tolerance: converged is checked by step()).
  if (p.operator_mode) { EXPECT_GT(cd.result.operator_polishes, 0) << name_of(c); }
  int counts[3] = {0, 0, 0};
  for (auto m : cd.modes) ++counts[static_cast<int>(m)];
  // The case holds what it says.
  switch (c) {
    case Case::sticking: EXPECT_EQ(counts[1], cd.contacts.size()) << "all sticking"; break;
    case Case::sliding: EXPECT_EQ(counts[2], cd.contacts.size()) << "all sliding"; break;
    case Case::tipped: EXPECT_GT(counts[0], 0) << "some breaking"; EXPECT_GT(counts[1] + counts[2], 0); break;
    case Case::sphere: EXPECT_EQ(counts[2], cd.contacts.size()) << "all sliding"; break;
    case Case::frictionless: EXPECT_EQ(counts[2] + counts[0], cd.contacts.size()); break;
  }
  // Friction (pair rule 0's coefficient) where the contacts slide: its derivative is zero
  // for sticking or breaking contacts.
  const bool sliding = c == Case::sliding || c == Case::sphere;
  const std::vector<ParameterId> params = {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0},
                                           {Parameter::friction, 0}};
  integrator::StepDerivatives d(model, params);
  const Eigen::Index n = in.x.size();
  const Outcome base = step(model, in);
  auto jvp = [&](const StepTangent& t) {
    StateTangent r;
    EXPECT_TRUE(d.jvp(model, data, in, out, t, r));
    VecX y(2 * n);
    y << r.x, r.v;
    return y;
  };
  for (int which = 0; which < 2; ++which) {
    const double e = which == 0 ? 1e-6 * 0.02 : 1e-6;
    MatX J(2 * n, n), J_fd(2 * n, n);
    for (Eigen::Index k = 0; k < n; ++k) {
      StepTangent t;
      (which == 0 ? t.x : t.v) = VecX::Unit(n, k);
      J.col(k) = jvp(t);
      State sp = in, sm = in;
      (which == 0 ? sp.x : sp.v)[k] += e;
      (which == 0 ? sm.x : sm.v)[k] -= e;
      const Outcome op = step(model, sp), om = step(model, sm);
      ASSERT_EQ(op.keys, base.keys) << name_of(c) << ": the contact set changed within the step";
      ASSERT_EQ(op.modes, base.modes) << name_of(c) << ": the modes switched within the step";
      ASSERT_EQ(om.modes, base.modes) << name_of(c);
      J_fd.col(k) = (op.y - om.y) / (2 * e);
    }
    const auto cmp = test::compare(J, J_fd);
    EXPECT_LT(cmp.rel_error, 1e-6) << name_of(c) << (which == 0 ? " d/dx_i: " : " d/dv_i: ") << cmp.str();
  }
  const double mu = cd.mu[0];
  for (int j = 0; j < (sliding ? 4 : 3); ++j) {
    const double value = j == 0 ? p.young : j == 1 ? p.poisson : j == 2 ? p.density : mu;
    const double e = 1e-5 * value;
    Params pp = p, pm = p;
    if (j == 3) {
      pp.mu = mu + e;
      pm.mu = mu - e;
    }
    (j == 0 ? pp.young : j == 1 ? pp.poisson : j == 2 ? pp.density : pp.mu) += j < 3 ? e : 0;
    (j == 0 ? pm.young : j == 1 ? pm.poisson : j == 2 ? pm.density : pm.mu) -= j < 3 ? e : 0;
    StepTangent t;
    t.p = VecX::Unit(4, j);
    const VecX col = jvp(t);
    const Model mp = build(c, pp), mm = build(c, pm);
    const Outcome op = step(mp, start(mp, c, p)), om = step(mm, start(mm, c, p));
    ASSERT_EQ(op.modes, base.modes) << name_of(c);
    ASSERT_EQ(om.modes, base.modes) << name_of(c);
    const VecX fd = (op.y - om.y) / (2 * e);
    const auto cmp = test::compare(col, fd);
    EXPECT_LT(cmp.rel_error, 1e-6) << name_of(c) << " parameter " << j << ": " << cmp.str();
  }
  // The path that the derivative took.
  EXPECT_EQ(d.ncp_derivative().on_operator(), p.operator_mode) << name_of(c);
  // ... preconditioned by (G_AA + c I)^{-1} (mode_system.hpp) where every active contact
  // sticks (J = G_AA: PCG), unpreconditioned CGLS otherwise (contact_step_derivatives.cpp).
  if (p.operator_mode) {
    EXPECT_EQ(d.ncp_derivative().operator_system().preconditioned(), counts[2] == 0) << name_of(c);
  }
  // ... and with sliding contacts by GMRES with the reduced preconditioner (mode_system.hpp
  // "Mixed sets"; the step passes A, so it is factorized).
  if (p.operator_mode && counts[2] > 0) {
    EXPECT_TRUE(d.ncp_derivative().operator_system().reduced_used()) << name_of(c);
  }
  // Reverse mode.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  StepTangent t;
  t.x = VecX(n);
  t.v = VecX(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    t.x[k] = 1e-4 * u(rng);
    t.v[k] = 1e-2 * u(rng);
  }
  t.p = (VecX(4) << p.young, p.poisson, p.density, 1.0).finished() * 0.1;
  expect_forward_reverse_agree(d, model, data, in, out, t, rng, name_of(c));
  EXPECT_EQ(d.nondifferentiable_contacts(), 0) << name_of(c);
}

TEST(StepDerivativesContact, Sticking) { check(Case::sticking); }
TEST(StepDerivativesContact, Sliding) { check(Case::sliding); }
TEST(StepDerivativesContact, TippedMixedModes) { check(Case::tipped); }
TEST(StepDerivativesContact, CurvedObstacle) { check(Case::sphere); }
TEST(StepDerivativesContact, Frictionless) { check(Case::frictionless); }
// The sparse backend (docs/method.md "Contact at scale"): ADMM on the operator, the
// polish and the mode-fixed system on G_AA of the active contacts; the same
// differences and tolerances.
// Newton with contact (docs/method.md "Newton iterations with contact"): the implicit
// function theorem at the converged step, A_f and G_f = h H_c A_f^{-1} H_c^T in place of
// the linearized step's; the same differences and tolerances (the Newton step converges
// to round-off: newton_tolerance 1e-13, see newton_params).
TEST(StepDerivativesContact, NewtonSticking) { check(Case::sticking, newton_params()); }
TEST(StepDerivativesContact, NewtonSliding) { check(Case::sliding, newton_params()); }
TEST(StepDerivativesContact, NewtonTippedMixedModes) { check(Case::tipped, newton_params()); }
TEST(StepDerivativesContact, NewtonFrictionless) { check(Case::frictionless, newton_params()); }
TEST(StepDerivativesContact, NewtonSparseBackend) {
  for (const Case c : {Case::sticking, Case::sliding}) {
    Params p = newton_params();
    p.backend = contact::NcpBackend::sparse;
    check(c, p);
  }
}
TEST(StepDerivativesContact, SparseBackend) {
  Params p;
  p.backend = contact::NcpBackend::sparse;
  for (const Case c : {Case::sticking, Case::sliding, Case::tipped, Case::frictionless}) check(c, p);
}
// The mode-fixed system on the operator (docs/method.md "The mode-fixed system at
// scale"): the polish's Newton steps and the derivative's jvp / vjp by CGLS on
// J = S G_AA + T applied with the step's factorization, forced on these small problems
// by crossovers of 0; the same differences and tolerances as the dense path.
TEST(StepDerivativesContact, OperatorModeSystem) {
  Params p;
  p.backend = contact::NcpBackend::sparse;
  p.operator_mode = true;
  for (const Case c : {Case::sticking, Case::sliding, Case::tipped, Case::sphere, Case::frictionless}) check(c, p);
}
TEST(StepDerivativesContact, NewtonOperatorModeSystem) {
  for (const Case c : {Case::sticking, Case::sliding}) {
    Params p = newton_params();
    p.backend = contact::NcpBackend::sparse;
    p.operator_mode = true;
    check(c, p);
  }
}

// A solve that fails inside the contact derivative (a PCG with a kept factor that misses
// its tolerance, an operator product that fails) makes jvp and vjp return false, which
// the trajectory reports as the derivative's failure at its step (diff/trajectory.cpp);
// it is not a programming error (it threw std::logic_error, "internal error", before).
// The step's solver is wrapped after the forward step: the wrapper delegates everything
// but the congruence (the sparse backend's record holds no G, so the derivative forms
// G_AA with it) or, on the operator path, every solve (the power iteration's products).
class FailingSolver : public integrator::LinearSolver {
 public:
  FailingSolver(std::unique_ptr<integrator::LinearSolver> inner, bool fail_solves)
      : inner_(std::move(inner)), fail_solves_(fail_solves) {}
  std::string name() const override { return inner_->name(); }
  void analyze(const SparseMatrix& A) override { inner_->analyze(A); }
  integrator::FactorStatus factorize(const SparseMatrix& A) override { return inner_->factorize(A); }
  bool solve(const VecX& b, VecX& x) override { return !fail_solves_ && inner_->solve(b, x); }
  bool inverse_congruence(const SparseMatrix&, MatX&) override { return false; }

 private:
  std::unique_ptr<integrator::LinearSolver> inner_;
  bool fail_solves_;
};

TEST(StepDerivativesContact, AFailedSolveInTheContactDerivativeIsAFailedDerivative) {
  for (const bool on_operator : {false, true}) {
    SCOPED_TRACE(on_operator ? "operator path" : "dense G_AA");
    Params p;
    p.backend = contact::NcpBackend::sparse;
    p.operator_mode = on_operator;
    const Model model = build(Case::sticking, p);
    const State in = start(model, Case::sticking, p);
    Data data(model);
    State out;
    ASSERT_TRUE(integrator::implicit_euler_step(model, data, in, out, 1).ok());
    ASSERT_GT(data.contact.contacts.size(), 0);
    const Eigen::Index n = in.x.size();
    StepTangent t;
    t.x = VecX::Unit(n, 0);
    {
      // The same derivative with the step's own solver succeeds: the failure below is
      // the wrapper's.
      integrator::StepDerivatives ok(model, {});
      StateTangent r;
      EXPECT_TRUE(ok.jvp(model, data, in, out, t, r));
    }
    data.solver = std::make_unique<FailingSolver>(std::move(data.solver), on_operator);
    integrator::StepDerivatives d(model, {});
    StateTangent r;
    bool jvp_ok = true;
    EXPECT_NO_THROW(jvp_ok = d.jvp(model, data, in, out, t, r));
    EXPECT_FALSE(jvp_ok);
    if (!on_operator) {
      // vjp: its first solve succeeds, then the contact derivative's congruence fails.
      StateTangent w;
      w.x = VecX::Ones(n);
      w.v = VecX::Zero(n);
      StepCotangent g;
      bool vjp_ok = true;
      EXPECT_NO_THROW(vjp_ok = d.vjp(model, data, in, out, w, g));
      EXPECT_FALSE(vjp_ok);
    }
  }
}

}  // namespace

// The preconditioned mode-fixed system on the operator (mode_system.hpp) against the
// dense path on more than 64 active contacts: a 9 x 9 slab (100 bottom vertices), the
// cases' initial states (on the slab: "sticking" has a few sliding contacts and
// "sliding" all sliding, so GMRES with the reduced preconditioner; "tipped" 10 breaking
// and the rest sticking, so PCG), one step. The NCP derivative of the operator path
// (derivative_dense_max_active 0) and of the dense G_AA path (the default 400) of the
// same step, for random b and dmu, forward and reverse.
// Tolerance (derived, with J's dense matrix from the dense path): all sticking, PCG
// stops at ||r - J x|| <= 1e-12 ||r||, so ||x - x*|| <= 1e-12 kappa(J) ||x*||; mixed, see
// compare_paths; plus rounding, eps kappa(J) ||x*|| for the dense decomposition; a
// factor 10 of margin. Also: the preconditioned solve takes fewer products than the
// unpreconditioned one on the same system (printed).
namespace test_precond_local {

double condition(const MatX& X, double* s_max = nullptr) {
  const Eigen::JacobiSVD<MatX> svd(X);
  const VecX s = svd.singularValues();
  double s_min = s[0];
  for (Eigen::Index k = 0; k < s.size(); ++k)
    if (s[k] > 1e-12 * s[0]) s_min = s[k];
  if (s_max) *s_max = s[0];
  return s[0] / s_min;
}

void compare_paths(Case c) {
  Params p;
  p.backend = contact::NcpBackend::sparse;
  p.cells = 9;
  p.operator_mode = true;  // derivative_dense_max_active 0 (and the polish on the operator)
  const Model model = build(c, p);
  Model dense_model = model;
  // Both crossovers set explicitly: the dense G_AA for the 100 contacts, sticking or mixed.
  dense_model.contact.ncp.derivative_dense_max_active = 400;
  dense_model.contact.ncp.derivative_mixed_dense_max_active = 400;
  const State in = start(model, c, p);
  Data data(model);
  State out;
  const StepStatus status = integrator::implicit_euler_step(model, data, in, out, 1);
  ASSERT_TRUE(status.ok()) << name_of(c) << ": " << describe(model, status);
  const auto& cd = data.contact;
  const std::vector<ParameterId> params = {{Parameter::friction, 0}};
  integrator::StepDerivatives d_op(model, params), d_dense(dense_model, params);
  StateTangent r_op, r_dense;
  StepTangent t;
  t.v = VecX::Unit(in.v.size(), 0);
  ASSERT_TRUE(d_op.jvp(model, data, in, out, t, r_op)) << name_of(c);
  ASSERT_TRUE(d_dense.jvp(dense_model, data, in, out, t, r_dense)) << name_of(c);
  const auto& dense = d_dense.ncp_derivative();
  ASSERT_FALSE(dense.on_operator()) << name_of(c);
  const std::vector<int> act = dense.active_contacts();
  const int na = static_cast<int>(act.size()), nc = cd.contacts.size(), n = 3 * nc;
  std::printf("%s: %d contacts, %d active\n", name_of(c), nc, na);
  ASSERT_GT(na, 64) << name_of(c);
  const bool sticking = std::all_of(act.begin(), act.end(), [&](int i) { return cd.modes[i] == contact::Mode::sticking; });
  // Dense J, G_AA and M.
  const MatX& J = dense.jacobian();
  ASSERT_EQ(J.rows(), 3 * na);
  SparseMatrix HtA;
  contact::select_contact_columns(cd.Ht, act, HtA);
  MatX G;
  ASSERT_TRUE(data.solver->inverse_congruence(HtA, G));
  G *= model.step.dt;
  // The operator path's scale L: the power iteration's lambda_max(G_AA) (docs/method.md
  // "The derivative's scale"), a lower bound within its stopping rule of the eigenvalue
  // (checked against the dense eigen-decomposition: see PowerIterationScale below).
  const double L = d_op.ncp_derivative().scale(), shift = contact::operator_shift_fraction * L;
  if (!sticking) {
    // Mixed: L is G_AA's largest diagonal entry over the deterministic sample of at most
    // scale_sample_contacts active contacts (evenly spaced in the active list), not
    // lambda_max (a row scale that must match G's diagonal: docs/method.md "The
    // derivative's scale"); the same entries of the dense G, to round-off.
    const int ns = std::min(na, contact::ContactStageDerivative::scale_sample_contacts);
    double sampled = 0;
    for (int j = 0; j < ns; ++j) {
      const int a = static_cast<int>((static_cast<long>(j) * na) / ns);
      for (int k = 0; k < 3; ++k) sampled = std::max(sampled, G(3 * a + k, 3 * a + k));
    }
    EXPECT_NEAR(L, sampled, 1e-10 * sampled) << name_of(c);
    EXPECT_LE(L, G.diagonal().maxCoeff() * (1 + 1e-10)) << name_of(c);
  }
  const MatX M = (G + shift * MatX::Identity(3 * na, 3 * na)).inverse();
  // The path: the step's operator; every active contact sticking with its Woodbury
  // preconditioner (PCG), with sliding contacts GMRES with the reduced preconditioner.
  const contact::NcpDerivative* opp = &d_op.ncp_derivative();
  ASSERT_TRUE(opp->on_operator()) << name_of(c);
  ASSERT_EQ(opp->active_contacts(), act) << name_of(c);
  if (sticking) { ASSERT_TRUE(opp->operator_system().preconditioned()) << name_of(c); }
  const contact::NcpDerivative& op = *opp;
  const MatX JM = J * M;
  const double kJ = condition(J), kJM = condition(JM);
  const double eps = std::numeric_limits<double>::epsilon();
  const auto sliding = std::count_if(act.begin(), act.end(), [&](int i) { return cd.modes[i] == contact::Mode::sliding; });
  std::printf("%s: %ld of the active contacts sliding (%s); kappa(J) %.2e, kappa(J M) %.2e\n", name_of(c),
              static_cast<long>(sliding), sticking ? "PCG" : "GMRES, reduced preconditioner", kJ, kJM);
  // GMRES (mixed) stops at ||Dl Rot (r - J x)|| <= 1e-12 ||Dl Rot r|| (mode_system.hpp;
  // Rot orthogonal, Dl = 1 or 1 / (L w) per row, L w = L mu lambda_N / |sigma_T| on a
  // sliding row p), so ||r - J x|| <= kappa(Dl) 1e-12 ||r|| and ||x - x*|| <= that /
  // s_min(J) (forward); the adjoint's ||r - J^T y|| <= 1e-12 ||r|| (kappa(Dl) covers it).
  double dmax = 1, dmin = 1;
  for (int a = 0; a < na; ++a)
    if (cd.modes[act[a]] == contact::Mode::sliding && cd.mu[act[a]] > 0) {
      const double Lw = L * cd.mu[act[a]] * cd.lambda[3 * act[a] + 2] / cd.sigma.segment<2>(3 * act[a]).norm();
      dmax = std::max(dmax, 1 / Lw);
      dmin = std::min(dmin, 1 / Lw);
    }
  double s_max_j = 0;
  const double kJ_s = condition(J, &s_max_j), s_min_j = s_max_j / kJ_s;
  for (unsigned seed = 20; seed < 22; ++seed) {
    const VecX b = test::random_vector(n, 1.0, seed), dmu = 0.2 * test::random_vector(nc, 1.0, seed + 100);
    for (int transposed = 0; transposed < 2; ++transposed) {
      VecX x_op, x_dense, r;
      if (!transposed) {
        op.jvp(b, dmu, x_op);
        dense.jvp(b, dmu, x_dense);
        dense.right_hand_side(b, dmu, r);
      } else {
        VecX bm_op, bm_dense;
        op.vjp(b, x_op, bm_op);
        dense.vjp(b, x_dense, bm_dense);
        r.resize(3 * na);
        for (int a = 0; a < na; ++a) r.segment<3>(3 * a) = b.segment<3>(3 * act[a]);
      }
      const int iterations = op.operator_system().last_iterations();
      // The bound on dlambda (forward); the reverse's bar_b = R^T y has |R| <= 1 + |L P|
      // (sliding: L mu lambda_N / |sigma_T|), on y's bound.
      double R = 1;
      for (int a = 0; a < na; ++a)
        if (cd.modes[act[a]] == contact::Mode::sliding && cd.mu[act[a]] > 0)
          R = std::max(R, 1 + L * cd.mu[act[a]] * cd.lambda[3 * act[a] + 2] / cd.sigma.segment<2>(3 * act[a]).norm());
      const double xs = transposed ? J.transpose().completeOrthogonalDecomposition().solve(r).norm() : x_dense.norm();
      double tol = 0;
      if (sticking) tol = (1e-12 + eps) * kJ * xs;  // J = J^T = G_AA
      if (!sticking) {
        EXPECT_TRUE(op.operator_system().reduced_used()) << name_of(c);
        tol = (1e-12 + eps) * (dmax / dmin) * r.norm() / s_min_j + eps * kJ * xs;
      }
      tol *= 10 * (transposed ? R : 1);
      const double diff = (x_op - x_dense).norm();
      std::printf("%s %s: difference %.2e, bound %.2e (|x| %.2e), %d iterations\n", name_of(c),
                  transposed ? "vjp" : "jvp", diff, tol, x_dense.norm(), iterations);
      EXPECT_LE(diff, tol) << name_of(c) << (transposed ? " vjp" : " jvp") << ", seed " << seed;
    }
  }
  // The preconditioner pays: the same mode-fixed system on the same G_AA, unpreconditioned,
  // takes more products (with G_AA, plus those with M) for the same right-hand side.
  {
    contact::NcpDerivative plain_ncp;
    plain_ncp.compute_operator(
        [&](const VecX& y, VecX& o) {
          o = G * y;
          return true;
        },
        L, cd.mu, cd.lambda, cd.sigma, cd.modes);
    const VecX b = test::random_vector(n, 1.0, 30);
    VecX x_plain, x_pre;
    const int before_plain = plain_ncp.operator_system().solves();
    plain_ncp.jvp(b, VecX(), x_plain);
    const int products_plain = plain_ncp.operator_system().solves() - before_plain;
    const int before_pre = op.operator_system().solves() + op.operator_system().preconditioner_solves();
    op.jvp(b, VecX(), x_pre);
    const int products_pre = op.operator_system().solves() + op.operator_system().preconditioner_solves() - before_pre;
    std::printf("%s: the mode-fixed system, %d products unpreconditioned (%d iterations), %d preconditioned "
                "(%d iterations)\n",
                name_of(c), products_plain, plain_ncp.operator_system().last_iterations(), products_pre,
                op.operator_system().last_iterations());
    // PCG against CG; GMRES with the reduced preconditioner against CGLS.
    EXPECT_LT(products_pre, products_plain) << name_of(c);
  }
  // The same for J = G_AA (PCG against CG).
  contact::OperatorModeSystem plain, pre;
  std::vector<Mat3> S(static_cast<std::size_t>(na), Mat3::Identity()), T(static_cast<std::size_t>(na), Mat3::Zero());
  auto apply = [&](const VecX& y, VecX& o) {
    o = G * y;
    return true;
  };
  plain.set(apply, S, T);
  pre.set(apply, S, T);
  pre.set_preconditioner([&](VecX& v) {
    v = M * v;
    return true;
  });
  const VecX rhs = test::random_vector(3 * na, 1.0, 7);
  VecX x1, x2;
  plain.solve(rhs, x1);
  pre.solve(rhs, x2);
  std::printf("%s, J = G_AA: %d products unpreconditioned, %d preconditioned (+ %d of M)\n", name_of(c),
              plain.solves(), pre.solves(), pre.preconditioner_solves());
  EXPECT_LT(pre.solves() + pre.preconditioner_solves(), plain.solves()) << name_of(c);
}

}  // namespace test_precond_local

TEST(StepDerivativesContact, PreconditionedOperatorMatchesDenseBeyond64) {
  for (const Case c : {Case::sticking, Case::sliding, Case::tipped}) test_precond_local::compare_paths(c);
}

// The contact derivative's preconditioner B shares its storage (pattern, values, CHOLMOD
// factor) with the step's NCP (sparse_delassus.hpp, docs/method.md "The derivative's
// memory"). When the NCP's B is written into it after the derivative was prepared (as a
// replay of the same step does: the derivative's cache key, v_f, then matches and it is
// not prepared again), the derivative's next solve refactorizes its own B: the same
// matrix, the same factorization, so the jvp and vjp are bit for bit those before
// (exact equality, no tolerance). The 9 x 9 slab beyond 64 active contacts on the
// operator: all sticking (the sticking case with mu = 2: PCG, B factorized in prepare)
// and mixed (the sticking case as it is, 1 of 100 sliding: GMRES, the reduced
// preconditioner factorized at the first solve).
TEST(StepDerivativesContact, OperatorPreconditionerSharedWithTheNcpSurvivesItsOverwrite) {
  for (const bool all_sticking : {true, false}) {
    const Case c = Case::sticking;
    Params p;
    p.backend = contact::NcpBackend::sparse;
    p.cells = 9;
    p.operator_mode = true;
    if (all_sticking) p.mu = 2;
    const Model model = build(c, p);
    const State in = start(model, c, p);
    Data data(model);
    State out;
    const StepStatus status = integrator::implicit_euler_step(model, data, in, out, 1);
    ASSERT_TRUE(status.ok()) << name_of(c) << ": " << describe(model, status);
    const std::vector<ParameterId> params = {{Parameter::friction, 0}};
    integrator::StepDerivatives d(model, params);
    StepTangent t;
    t.v = VecX::Unit(in.v.size(), 0);
    t.p = VecX::Ones(1);
    StateTangent first, second;
    ASSERT_TRUE(d.jvp(model, data, in, out, t, first)) << name_of(c);
    ASSERT_TRUE(d.ncp_derivative().on_operator()) << name_of(c);
    const auto& act = d.ncp_derivative().active_contacts();
    const auto sliding = std::count_if(act.begin(), act.end(), [&](int i) {
      return data.contact.modes[static_cast<std::size_t>(i)] == contact::Mode::sliding;
    });
    ASSERT_GT(act.size(), 64u) << name_of(c);
    if (all_sticking)
      EXPECT_EQ(sliding, 0) << "expected every active contact sticking";
    else
      EXPECT_GT(sliding, 0) << "expected a mixed set";
    // PCG's M (all sticking); the mixed path's reduced preconditioner is not M.
    EXPECT_EQ(d.ncp_derivative().operator_system().preconditioned(), all_sticking);
    StateTangent bar;
    bar.x = test::random_vector(in.x.size(), 1.0, 3);
    bar.v = test::random_vector(in.v.size(), 1.0, 4);
    StepCotangent vjp_first, vjp_second;
    ASSERT_TRUE(d.vjp(model, data, in, out, bar, vjp_first)) << name_of(c);
    // The NCP's operator writes a B of its own (every contact, c = 1) into the storage.
    ASSERT_TRUE(data.contact.sparse.factorize_shifted(1.0)) << name_of(c);
    ASSERT_TRUE(d.jvp(model, data, in, out, t, second)) << name_of(c);
    EXPECT_EQ(first.x, second.x) << name_of(c);
    EXPECT_EQ(first.v, second.v) << name_of(c);
    ASSERT_TRUE(data.contact.sparse.factorize_shifted(1.0)) << name_of(c);
    ASSERT_TRUE(d.vjp(model, data, in, out, bar, vjp_second)) << name_of(c);
    EXPECT_EQ(vjp_first.x, vjp_second.x) << name_of(c);
    EXPECT_EQ(vjp_first.v, vjp_second.v) << name_of(c);
    EXPECT_EQ(vjp_first.p, vjp_second.p) << name_of(c);
  }
}

// Central differences of the step through the reduced preconditioner's GMRES on more
// than 64 active contacts: the 9 x 9 slab's "sticking" case (mixed: a few contacts
// slide) and "sliding" case (all slide), derivative_dense_max_active 0, along random
// directions of x_i and v_i (entries in [-1, 1]) and for friction: J t against
// (step(s + e t) - step(s - e t)) / (2 e). Steps as in check(): e = 1e-6 of the element
// size (1 cm) for positions, 1e-6 m/s for velocities, 1e-5 of mu; the NCP solved to
// 1e-14 and polished, the same modes at s +/- e t (checked); tolerance 1e-6 relative, as
// check()'s. Directions instead of every column: the slab has 600 dofs.
namespace test_precond_fd_local {

void check_directions(Case c) {
  Params p;
  p.backend = contact::NcpBackend::sparse;
  p.cells = 9;
  p.operator_mode = true;
  const Model model = build(c, p);
  const State in = start(model, c, p);
  Data data(model);
  State out;
  ASSERT_TRUE(integrator::implicit_euler_step(model, data, in, out, 1).ok()) << name_of(c);
  const auto& cd = data.contact;
  const std::vector<ParameterId> params = {{Parameter::friction, 0}};
  integrator::StepDerivatives d(model, params);
  const Outcome base = step(model, in);
  const Eigen::Index n = in.x.size();
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int which = 0; which < 3; ++which) {
    StepTangent t;
    double e = 1e-6;
    State sp = in, sm = in;
    Params pp = p, pm = p;
    if (which < 2) {
      VecX dir(n);
      for (Eigen::Index k = 0; k < n; ++k) dir[k] = u(rng);
      (which == 0 ? t.x : t.v) = dir;
      if (which == 0) e = 1e-6 * 0.01;
      (which == 0 ? sp.x : sp.v) += e * dir;
      (which == 0 ? sm.x : sm.v) -= e * dir;
    } else {
      t.p = VecX::Unit(1, 0);
      e = 1e-5 * cd.mu[0];
      pp.mu = cd.mu[0] + e;
      pm.mu = cd.mu[0] - e;
    }
    StateTangent r;
    ASSERT_TRUE(d.jvp(model, data, in, out, t, r)) << name_of(c);
    const auto& op = d.ncp_derivative();
    ASSERT_TRUE(op.on_operator()) << name_of(c);
    ASSERT_GT(op.active(), 64) << name_of(c);
    EXPECT_TRUE(op.operator_system().reduced_used()) << name_of(c);
    VecX y(2 * n);
    y << r.x, r.v;
    const Model mp = build(c, pp), mm = build(c, pm);
    const Outcome op_ = which < 2 ? step(model, sp) : step(mp, start(mp, c, p));
    const Outcome om_ = which < 2 ? step(model, sm) : step(mm, start(mm, c, p));
    ASSERT_EQ(op_.keys, base.keys) << name_of(c) << ": the contact set changed";
    ASSERT_EQ(op_.modes, base.modes) << name_of(c) << ": the modes switched";
    ASSERT_EQ(om_.modes, base.modes) << name_of(c);
    const VecX fd = (op_.y - om_.y) / (2 * e);
    const auto cmp = test::compare(y, fd);
    const auto sliding = std::count(base.modes.begin(), base.modes.end(), contact::Mode::sliding);
    std::printf("%s (%d active, %ld sliding), direction %d: %s, %d GMRES iterations\n", name_of(c), op.active(),
                static_cast<long>(sliding), which, cmp.str().c_str(), op.operator_system().last_iterations());
    EXPECT_GT(y.norm(), 0) << name_of(c);
    EXPECT_LT(cmp.rel_error, 1e-6) << name_of(c) << " direction " << which << ": " << cmp.str();
  }
}

}  // namespace test_precond_fd_local

TEST(StepDerivativesContact, ReducedPreconditionerFiniteDifferencesBeyond64) {
  for (const Case c : {Case::sticking, Case::sliding}) test_precond_fd_local::check_directions(c);
}

// Randomized smoothing in the step (model.contact.smoothing): the cube half over the
// edge of a box, its middle column of bottom vertices within sigma of the boundary
// between the box top's region and its edge's (and, pressed in, of the nearest-face
// switch between the top and the side). Those contacts take the smoothed geometry
// derivative (counted); the step's derivative stays a linear map whose forward and
// reverse products agree (<w, J d> = <J^T w, d> to 1e-10), and is finite. It is not
// compared with finite differences of the step: the step is not differentiable there,
// which is why the estimate is smoothed.
TEST(StepDerivativesContact, SmoothedGeometryAtARegionBoundary) {
  const Params p;
  Model model = build(Case::sticking, p);
  collision::Obstacle box;
  box.name = "box";
  box.kind = collision::ShapeKind::box;
  box.center = Vec3(0.02 - 0.1, 0.02, -0.05);  // top face z = 0, +x edge under x = 0.02
  box.half_extents = Vec3(0.1, 0.1, 0.05);
  collision::prepare(box);
  model.contact.detection.obstacles = {box};
  model.contact.detection.names.back() = "box";
  model.contact.smoothing = {16, 2e-4, 0};
  const State in = start(model, Case::sticking, p);
  Data data(model);
  State out;
  ASSERT_TRUE(integrator::implicit_euler_step(model, data, in, out, 1).ok());
  ASSERT_GT(data.contact.contacts.size(), 0);
  integrator::StepDerivatives d(model, {{Parameter::young, 0}});
  const Eigen::Index n = in.x.size();
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  StepTangent t;
  t.x = VecX(n);
  t.v = VecX(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    t.x[k] = 1e-4 * u(rng);
    t.v[k] = 1e-2 * u(rng);
  }
  t.p = VecX::Constant(1, 0.1 * p.young);
  const StateTangent Jd = expect_forward_reverse_agree(d, model, data, in, out, t, rng, "smoothed");
  EXPECT_GT(d.smoothed_contacts(), 0);
  EXPECT_EQ(d.nondifferentiable_contacts(), 0);
  EXPECT_TRUE(Jd.x.allFinite() && Jd.v.allFinite());
  // Without smoothing the same contacts take their recorded feature's one-sided
  // derivative: another (valid one-sided) linear map.
  Model exact = model;
  exact.contact.smoothing.samples = 0;
  integrator::StepDerivatives d0(exact, {{Parameter::young, 0}});
  StateTangent J0d;
  ASSERT_TRUE(d0.jvp(exact, data, in, out, t, J0d));
  EXPECT_EQ(d0.smoothed_contacts(), 0);
  EXPECT_GT((J0d.x - Jd.x).norm(), 0);
}
