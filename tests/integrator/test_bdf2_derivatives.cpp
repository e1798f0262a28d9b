// Derivatives of the BDF2 step (bdf2_derivatives.hpp) against central finite
// differences of bdf2_step itself, block by block:
//   d(x_f, v_f) / d x_n, v_n, x_{n-1}, v_{n-1}, lambda_a, young, poisson, density,
//   rayleigh_mass, rayleigh_stiffness
// for the linearized step (corotational with a cable, damping and fixed nodes; stvk
// with psd_projection under compression; the linear law) and Newton (Neo-Hookean with
// a cavity); and the reverse mode against the forward one (<w, J d> = <J^T w, d>).
//
// Steps as in test_step_derivatives.cpp (support/fd.hpp): positions 1e-8 m (1e-6 of the
// 0.01 m cells), velocities 1e-6 m/s (the linearized step is affine in v_n, v_{n-1}),
// parameters 1e-5 of max(|value|, natural scale) (the round-off argument there:
// small parameter derivatives lose accuracy at 1e-6). Central differences then carry
// ~1e-8 relative error or less: tolerance 1e-6 on each block's norm-wise relative error.
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/bdf2_derivatives.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <support/fd.hpp>
#include <support/model_builder.hpp>

#include "actuation/helpers.hpp"

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;

namespace bdf2_derivatives_test {

using integrator::StateTangent;
using integrator::StepCotangent;
using integrator::StepTangent;

enum class Act { none, cable, cavity };

struct Scenario {
  material::Law law = material::Law::corotational;
  bool psd = false;
  Act actuator = Act::none;
  int newton = 1;
};

struct Params {
  double young = 2e4, poisson = 0.35, density = 1100, alpha = 0.6, beta = 0.02, lambda = 0;
};

Model build(const Scenario& s, const Params& p) {
  std::mt19937 rng(7);
  const test::ActuatorSet set(rng, Vec3(1, 2, -0.5));  // 0.03 x 0.02 x 0.02 m, 3 x 2 x 2 cells
  test::BodySpec spec;
  spec.law = s.law;
  spec.psd_projection = s.psd;
  spec.young = p.young;
  spec.poisson = p.poisson;
  spec.density = p.density;
  spec.rayleigh_mass = p.alpha;
  spec.rayleigh_stiffness = p.beta;
  spec.fixed = [](const Vec3& x) { return x.x() < 1e-9; };
  // dt = 3 ms: h' = 2 ms, where h'^2 K weighs about as much as M (test_step_derivatives.cpp).
  Model model = test::make_model(set.mesh, spec, Vec3(0.5, -1, -9.81), 3e-3, 2);
  model.step.integrator = IntegratorKind::bdf2;
  model.step.newton_iterations = s.newton;
  model.step.newton_tolerance = 1e-13;
  if (s.actuator != Act::none) {
    actuation::ActuatorModel a;
    a.name = "a";
    if (s.actuator == Act::cable) a.kind = set.cable;
    if (s.actuator == Act::cavity) a.kind = set.cavity;
    a.value.constant = p.lambda;
    model.actuation.actuators.push_back(a);
  }
  return model;
}

// Two states away from rest, the previous one and the current one (deformed, moving):
// compressed by 4% along z (or 35% with the projection, where it acts), sheared,
// jittered; the previous state differs by a further random displacement.
void states(const Model& model, State& previous, State& in) {
  const double squeeze = model.fem.bodies[0].psd_projection ? 0.65 : 0.96;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  in = model.initial;
  previous = model.initial;
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    Vec3 p = in.x.segment<3>(3 * i);
    p.z() *= squeeze;
    p.x() += 0.05 * p.z();
    for (int c = 0; c < 3; ++c) p[c] += 2e-4 * u(rng);
    in.x.segment<3>(3 * i) = p;
    for (int c = 0; c < 3; ++c) {
      const bool fixed = model.fem.fixed[3 * i + c];
      in.v[3 * i + c] = fixed ? 0.0 : 0.05 * u(rng);
      previous.x[3 * i + c] = p[c] + (fixed ? 0.0 : 1e-4 * u(rng));
      previous.v[3 * i + c] = fixed ? 0.0 : 0.05 * u(rng);
    }
  }
  previous.t = 0;
  in.t = model.step.dt;
}

double default_lambda(Act a) { return a == Act::cable ? 0.4 : a == Act::cavity ? 3e3 : 0; }

VecX step_output(const Model& model, const State& previous, const State& in) {
  Data data(model);
  State out;
  const StepStatus st = integrator::bdf2_step(model, data, in, &previous, out, 2);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  VecX y(2 * in.x.size());
  y << out.x, out.v;
  return y;
}

VecX step_output(const Model& model) {
  State previous, in;
  states(model, previous, in);
  return step_output(model, previous, in);
}

const std::vector<ParameterId> kParams = {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0},
                                          {Parameter::rayleigh_mass, 0}, {Parameter::rayleigh_stiffness, 0}};
constexpr double kParameterStep = 1e-5;
constexpr double kParameterScale[] = {1e4, 0.1, 1e3, 1.0, 1e-2, 0.0};

Params perturbed(Params p, int j, double e) {
  double* v[] = {&p.young, &p.poisson, &p.density, &p.alpha, &p.beta, &p.lambda};
  *v[j] += e;
  return p;
}
double value(const Params& p, int j) {
  const double v[] = {p.young, p.poisson, p.density, p.alpha, p.beta, p.lambda};
  return v[j];
}

struct Analytic {
  Model model;
  Data data;
  State previous, in, out;
  integrator::StepDerivatives d;
  Analytic(const Scenario& s, const Params& p) : model(build(s, p)), data(model), d(model, kParams) {
    states(model, previous, in);
    const StepStatus st = integrator::bdf2_step(model, data, in, &previous, out, 2);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    EXPECT_DOUBLE_EQ(data.h, 2 * model.step.dt / 3);
  }
  VecX jvp(const StepTangent& t, const StateTangent& tp) {
    StateTangent r;
    EXPECT_TRUE(integrator::multistep_jvp(d, model, data, out, t, tp, r));
    VecX y(2 * r.x.size());
    y << r.x, r.v;
    return y;
  }
};

std::string name(const Scenario& s) {
  const char* acts[] = {"none", "cable", "cavity"};
  return std::string(material::law_name(s.law)) + (s.psd ? " psd" : "") + " actuator " +
         acts[static_cast<int>(s.actuator)] + (s.newton > 1 ? " newton" : "");
}

void check_blocks(const Scenario& s) {
  Params p;
  p.lambda = default_lambda(s.actuator);
  Analytic a(s, p);
  const Eigen::Index n = a.in.x.size();
  // x_n, v_n, x_{n-1}, v_{n-1}: one column per dof.
  const char* blocks[] = {"x_n", "v_n", "x_{n-1}", "v_{n-1}"};
  for (int which = 0; which < 4; ++which) {
    const double e = which % 2 == 0 ? 1e-6 * 0.01 : 1e-6;
    MatX J(2 * n, n), J_fd(2 * n, n);
    for (Eigen::Index k = 0; k < n; ++k) {
      StepTangent t;
      StateTangent tp;
      VecX& slot = which == 0 ? t.x : which == 1 ? t.v : which == 2 ? tp.x : tp.v;
      slot = VecX::Unit(n, k);
      J.col(k) = a.jvp(t, tp);
      State pp = a.previous, pm = a.previous, ip = a.in, im = a.in;
      VecX& plus = which == 0 ? ip.x : which == 1 ? ip.v : which == 2 ? pp.x : pp.v;
      VecX& minus = which == 0 ? im.x : which == 1 ? im.v : which == 2 ? pm.x : pm.v;
      plus[k] += e;
      minus[k] -= e;
      J_fd.col(k) = (step_output(a.model, pp, ip) - step_output(a.model, pm, im)) / (2 * e);
    }
    const auto c = test::compare(J, J_fd);
    EXPECT_GT(J.norm(), 0) << name(s) << " " << blocks[which];
    EXPECT_LT(c.rel_error, 1e-6) << name(s) << " d/d" << blocks[which] << ": " << c.str();
  }
  const int np = s.actuator == Act::none ? 5 : 6;
  for (int j = 0; j < np; ++j) {
    const double e = kParameterStep * std::max(std::abs(value(p, j)), kParameterScale[j]);
    StepTangent t;
    if (j < 5)
      t.p = VecX::Unit(5, j);
    else
      t.lambda_a = VecX::Ones(1);
    const VecX col = a.jvp(t, {});
    const VecX fd = (step_output(build(s, perturbed(p, j, e))) - step_output(build(s, perturbed(p, j, -e)))) / (2 * e);
    const auto c = test::compare(col, fd);
    const char* names[] = {"young", "poisson", "density", "rayleigh_mass", "rayleigh_stiffness", "lambda_a"};
    EXPECT_GT(col.norm(), 0) << name(s) << " " << names[j];
    EXPECT_LT(c.rel_error, 1e-6) << name(s) << " d/d" << names[j] << ": " << c.str();
  }
}

void check_dot_product(const Scenario& s) {
  Params p;
  p.lambda = default_lambda(s.actuator);
  Analytic a(s, p);
  const Eigen::Index n = a.in.x.size();
  StepTangent t;
  StateTangent tp;
  t.x = test::random_vector(n, 1e-3, 1);
  t.v = test::random_vector(n, 0.1, 2);
  tp.x = test::random_vector(n, 1e-3, 3);
  tp.v = test::random_vector(n, 0.1, 4);
  t.p = test::random_vector(5, 1.0, 5).cwiseProduct((VecX(5) << p.young, p.poisson, p.density, 1.0, 1e-2).finished());
  if (s.actuator != Act::none) t.lambda_a = test::random_vector(1, std::abs(p.lambda), 6);
  StateTangent Jd;
  ASSERT_TRUE(integrator::multistep_jvp(a.d, a.model, a.data, a.out, t, tp, Jd));
  StateTangent w;
  w.x = test::random_vector(n, 1.0, 7);
  w.v = test::random_vector(n, 1.0, 8);
  StepCotangent JTw;
  StateTangent JTw_previous;
  ASSERT_TRUE(integrator::multistep_vjp(a.d, a.model, a.data, a.out, w, JTw, JTw_previous));
  const double lhs = w.x.dot(Jd.x) + w.v.dot(Jd.v);
  double rhs = JTw.x.dot(t.x) + JTw.v.dot(t.v) + JTw_previous.x.dot(tp.x) + JTw_previous.v.dot(tp.v) + JTw.p.dot(t.p);
  if (t.lambda_a.size()) rhs += JTw.lambda_a.dot(t.lambda_a);
  // Term by term the sums have magnitudes up to |w| |J d|: 1e-10 of that.
  const double scale = w.x.norm() * Jd.x.norm() + w.v.norm() * Jd.v.norm();
  EXPECT_NEAR(lhs, rhs, 1e-10 * scale) << name(s);
}

}  // namespace bdf2_derivatives_test

using namespace bdf2_derivatives_test;

class Bdf2StepDerivatives : public ::testing::TestWithParam<Scenario> {};

TEST_P(Bdf2StepDerivatives, EveryBlockMatchesCentralDifferences) { check_blocks(GetParam()); }
TEST_P(Bdf2StepDerivatives, ReverseModeIsTheTransposeOfTheForwardMode) { check_dot_product(GetParam()); }

INSTANTIATE_TEST_SUITE_P(Cases, Bdf2StepDerivatives,
                         ::testing::Values(Scenario{material::Law::corotational, false, Act::cable},
                                           Scenario{material::Law::stvk, true},
                                           Scenario{material::Law::linear},
                                           Scenario{material::Law::neo_hookean, false, Act::cavity, 30}));

// The first step of BDF2 (no previous state) is implicit Euler's: the same state, and
// the record says so (h = dt, no history weight).
TEST(Bdf2Step, FirstStepIsImplicitEuler) {
  const Model model = build(Scenario{material::Law::corotational, false, Act::cable}, Params{2e4, 0.35, 1100, 0.6, 0.02, 0.4});
  State previous, in, a, b;
  states(model, previous, in);
  Data d1(model), d2(model);
  ASSERT_TRUE(integrator::bdf2_step(model, d1, in, nullptr, a, 1).ok());
  ASSERT_TRUE(integrator::implicit_euler_step(model, d2, in, b, 1).ok());
  EXPECT_EQ(a.x, b.x);
  EXPECT_EQ(a.v, b.v);
  EXPECT_EQ(d1.h, model.step.dt);
  EXPECT_EQ(d1.history_weight, 0);
  // Fixed dofs keep v = 0 and their position through a BDF2 step.
  State out;
  ASSERT_TRUE(integrator::bdf2_step(model, d1, in, &previous, out, 2).ok());
  for (int k = 0; k < out.x.size(); ++k)
    if (model.fem.fixed[static_cast<std::size_t>(k)]) {
      EXPECT_EQ(out.v[k], 0);
      EXPECT_EQ(out.x[k], in.x[k]);
    }
}
