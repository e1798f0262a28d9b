// Derivatives of the implicit Euler step (implicit_euler_derivatives.hpp) against
// central finite differences of the step itself, block by block:
//   d(x_f, v_f) / d x_i, v_i, lambda_a, young, poisson, density, rayleigh_mass, rayleigh_stiffness
// for every law (with and without the PSD projection), with and without damping, with
// fixed nodes, and with each actuator kind; and the reverse mode against the forward
// one (<w, J d> = <J^T w, d>).
//
// Steps (support/fd.hpp): positions 1e-6 of the element size (1e-8 m on these 0.01 m
// cells); parameters 1e-5 of their value (see kParameterStep); velocities 1e-6 m/s and
// actuation 1e-5 of its value: the linearized step is affine in v_i and lambda_a, so
// there only round-off matters. Central differences then carry ~1e-8 relative error or
// less: tolerance 1e-6 on the norm-wise relative error of each block.
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <support/fd.hpp>
#include <support/model_builder.hpp>

#include "actuation/helpers.hpp"

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include <random>

using namespace softdiff;
using material::Law;
using integrator::StateTangent;
using integrator::StepCotangent;
using integrator::StepTangent;

namespace {

enum class Act { none, cable, cavity, open_face, translation, rotation };

struct Scenario {
  Law law = Law::corotational;
  bool psd = false;
  bool damping = true;
  bool fixed = true;
  Act actuator = Act::none;
  int newton = 1;  // newton_iterations (> 1: the implicit function theorem on the converged residual)
  // linear_solver.factor_reuse: pcg: the step and its JVP/VJP solve by PCG preconditioned
  // by the factor of an earlier matrix (that of the step one dt before), to the default
  // pcg_tolerance; the finite differences use the direct solve (the exact map).
  bool reuse = false;
};

struct Params {
  double young = 2e4, poisson = 0.35, density = 1100, alpha = 0.6, beta = 0.02, lambda = 0;
};

double default_lambda(Act a) {
  switch (a) {
    case Act::cable: return 0.4;             // N
    case Act::cavity: return 3e3;            // Pa
    case Act::open_face: return -2e3;        // Pa
    case Act::translation: return 0.3;       // N
    case Act::rotation: return 2e-3;         // N m
    case Act::none: return 0;
  }
  return 0;
}

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
  if (s.fixed) spec.fixed = [](const Vec3& x) { return x.x() < 1e-9; };
  // h = 2 ms: h^2 K (~ E h^2 times the 0.01 m cell size) is about M (~0.4 g per node),
  // so the stiffness terms weigh as much as the inertia.
  Model model = test::make_model(set.mesh, spec, Vec3(0.5, -1, -9.81), 2e-3, 1);
  // Newton converges quadratically: its last iterate is at round-off, far below this
  // tolerance, so that the finite differences see the converged map.
  model.step.newton_iterations = s.newton;
  model.step.newton_tolerance = 1e-13;
  if (s.actuator != Act::none) {
    actuation::ActuatorModel a;
    a.name = "a";
    switch (s.actuator) {
      case Act::cable: a.kind = set.cable; break;
      case Act::cavity: a.kind = set.cavity; break;
      case Act::open_face: {
        actuation::Cavity c;
        EXPECT_TRUE(actuation::Cavity::create(set.mesh.X, set.mesh.tets, test::box_boundary(set.mesh, set.size, 5), 0, c).ok());
        a.kind = c;
        break;
      }
      case Act::translation: a.kind = set.translation; break;
      case Act::rotation: {
        actuation::Servo r;
        EXPECT_TRUE(actuation::Servo::rotation({0, 1, 2, 5, 7}, Vec3(0.2, 0.1, 1), Vec3(0.01, 0.01, 0), set.x_rest, r).ok());
        a.kind = r;
        break;
      }
      case Act::none: break;
    }
    a.value.constant = p.lambda;
    model.actuation.actuators.push_back(a);
  }
  return model;
}

// A state away from rest: deformed and moving. Compressed by 4% along z (A stays
// positive definite without projection), or by 35% with the projection (where the
// stvk and Neo-Hookean element Hessians are indefinite, so that it acts).
State initial_state(const Model& model) {
  const double squeeze = model.fem.bodies[0].psd_projection ? 0.65 : 0.96;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  State s = model.initial;
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    Vec3 p = s.x.segment<3>(3 * i);
    p.z() *= squeeze;
    p.x() += 0.05 * p.z();
    for (int c = 0; c < 3; ++c) p[c] += 2e-4 * u(rng);
    s.x.segment<3>(3 * i) = p;
    for (int c = 0; c < 3; ++c) s.v[3 * i + c] = model.fem.fixed[3 * i + c] ? 0.0 : 0.05 * u(rng);
  }
  return s;
}

VecX step_output(const Model& model, const State& in) {
  Data data(model);
  State out;
  const StepStatus st = integrator::implicit_euler_step(model, data, in, out, 1);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  VecX y(2 * in.x.size());
  y << out.x, out.v;
  return y;
}

const std::vector<ParameterId> kParams = {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0},
                                          {Parameter::rayleigh_mass, 0}, {Parameter::rayleigh_stiffness, 0}};

Params perturbed(Params p, int j, double e) {
  switch (j) {
    case 0: p.young += e; break;
    case 1: p.poisson += e; break;
    case 2: p.density += e; break;
    case 3: p.alpha += e; break;
    case 4: p.beta += e; break;
    case 5: p.lambda += e; break;
  }
  return p;
}

Params params_of(const Scenario& s) {
  Params p;
  p.lambda = default_lambda(s.actuator);
  if (!s.damping) p.alpha = p.beta = 0;  // the derivatives at 0 still exist (and are checked)
  return p;
}

// Parameter steps: 1e-5 of max(|value|, natural scale) (scales: young 1e4 Pa, poisson
// 0.1, density 1e3 kg/m^3, alpha 1 /s, beta 1e-2 s, lambda its value). Not 1e-6: the
// outputs carry round-off of about cond(A) eps |v_f| from the solve, and a derivative
// as small as d/d alpha (1e-3 of the outputs' size here) then loses ~1e-6 of its
// accuracy at 1e-6 (measured: 1.5e-6 at 1e-6, 1e-5 at 1e-7, below 1e-7 at 1e-5), while
// the truncation error at 1e-5 is still ~1e-10 relative.
constexpr double kParameterStep = 1e-5;
constexpr double kParameterScale[] = {1e4, 0.1, 1e3, 1.0, 1e-2, 0.0};

double value(const Params& p, int j) {
  const double v[] = {p.young, p.poisson, p.density, p.alpha, p.beta, p.lambda};
  return v[j];
}

Model with_reuse(Model model, bool reuse) {
  model.solver.factor_reuse = reuse;
  return model;
}

struct Analytic {
  Model model;
  Data data;
  State in, out;
  integrator::StepDerivatives d;
  Analytic(const Scenario& s, const Params& p)
      : model(with_reuse(build(s, p), s.reuse)), data(model), in(initial_state(model)), d(model, kParams) {
    if (s.reuse) {
      // The step one dt earlier (x - h v) factorizes; the step from `in` keeps that
      // factor and solves by PCG.
      State previous = in, ignored;
      previous.x -= model.step.dt * in.v;
      const StepStatus st = integrator::implicit_euler_step(model, data, previous, ignored, 1);
      EXPECT_TRUE(st.ok()) << describe(model, st);
    }
    const StepStatus st = integrator::implicit_euler_step(model, data, in, out, 1);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    if (s.reuse) {
      const auto& c = data.solver->counters();
      EXPECT_EQ(c.numeric_factorizations, 1);
      EXPECT_EQ(c.kept_factors, 1);
      EXPECT_GE(c.last_pcg_iterations, 1);
      EXPECT_EQ(c.pcg_fallbacks, 0);
    }
  }
  // cond_2(A) of the step (dense: these models have ~100 dofs), for the error bound of
  // a PCG solve: ||x - A^{-1} b|| / ||A^{-1} b|| <= cond(A) ||b - A x|| / ||b||.
  double condition() const {
    const SparseMatrix full = data.A.selfadjointView<Eigen::Upper>();
    const MatX dense(full);
    const Eigen::SelfAdjointEigenSolver<MatX> eig(dense);
    return eig.eigenvalues().maxCoeff() / eig.eigenvalues().minCoeff();
  }
  // The relative error a PCG solve may add to a derivative (0 without reuse).
  double pcg_error(const Scenario& s) const { return s.reuse ? condition() * model.solver.pcg_tolerance : 0.0; }
  VecX jvp(const StepTangent& t) {
    StateTangent r;
    EXPECT_TRUE(d.jvp(model, data, in, out, t, r));
    VecX y(2 * r.x.size());
    y << r.x, r.v;
    return y;
  }
};

std::string describe_scenario(const Scenario& s) {
  const char* acts[] = {"none", "cable", "cavity", "open_face", "translation", "rotation"};
  return std::string(material::law_name(s.law)) + (s.psd ? " psd" : "") + (s.damping ? " damped" : "") +
         (s.fixed ? " fixed" : "") + " actuator " + acts[static_cast<int>(s.actuator)] +
         (s.newton > 1 ? " newton" : "") + (s.reuse ? " factor_reuse" : "");
}

void check_blocks(const Scenario& s) {
  const Params p = params_of(s);
  Analytic a(s, p);
  const Eigen::Index n = a.in.x.size();
  const std::string where = describe_scenario(s);
  // The finite differences step with the direct solve; the analytic columns may carry
  // the PCG solves' error (at most cond(A) pcg_tolerance relative, added to 1e-6).
  const Model direct = with_reuse(a.model, false);
  const double tolerance = 1e-6 + a.pcg_error(s);
  if (s.newton > 1) {
    EXPECT_GE(a.data.newton_iterations_used, 3) << where;  // not the linearized step
  }

  // x_i and v_i: one column per dof.
  for (int which = 0; which < 2; ++which) {
    const double e = which == 0 ? 1e-6 * 0.01 : 1e-6;
    MatX J(2 * n, n), J_fd(2 * n, n);
    for (Eigen::Index k = 0; k < n; ++k) {
      StepTangent t;
      (which == 0 ? t.x : t.v) = VecX::Unit(n, k);
      J.col(k) = a.jvp(t);
      State sp = a.in, sm = a.in;
      (which == 0 ? sp.x : sp.v)[k] += e;
      (which == 0 ? sm.x : sm.v)[k] -= e;
      J_fd.col(k) = (step_output(direct, sp) - step_output(direct, sm)) / (2 * e);
    }
    if (s.reuse) {
      EXPECT_GE(a.data.solver->counters().last_pcg_iterations, 1) << where;  // the JVPs ran PCG
    }
    const auto c = test::compare(J, J_fd);
    EXPECT_LT(c.rel_error, tolerance) << where << (which == 0 ? " d/dx_i: " : " d/dv_i: ") << c.str();
  }
  // Parameters (and lambda_a): rebuild the model at p +- e.
  const int np = s.actuator == Act::none ? 5 : 6;
  for (int j = 0; j < np; ++j) {
    const double e = kParameterStep * std::max(std::abs(value(p, j)), kParameterScale[j]);
    StepTangent t;
    if (j < 5) {
      t.p = VecX::Unit(5, j);
    } else {
      t.lambda_a = VecX::Ones(1);
    }
    const VecX col = a.jvp(t);
    const Model mp = build(s, perturbed(p, j, e)), mm = build(s, perturbed(p, j, -e));
    const VecX fd = (step_output(mp, initial_state(mp)) - step_output(mm, initial_state(mm))) / (2 * e);
    const auto c = test::compare(col, fd);
    const char* names[] = {"young", "poisson", "density", "rayleigh_mass", "rayleigh_stiffness", "lambda_a"};
    EXPECT_GT(col.norm(), 0) << where << " " << names[j];
    EXPECT_LT(c.rel_error, tolerance) << where << " d/d" << names[j] << ": " << c.str();
  }
}

void check_dot_product(const Scenario& s) {
  const Params p = params_of(s);
  Analytic a(s, p);
  const Eigen::Index n = a.in.x.size();
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  auto random = [&](Eigen::Index m, double scale) {
    VecX v(m);
    for (Eigen::Index k = 0; k < m; ++k) v[k] = scale * u(rng);
    return v;
  };
  StepTangent t;
  t.x = random(n, 1e-3);
  t.v = random(n, 0.1);
  t.p = random(5, 1.0).cwiseProduct((VecX(5) << p.young, p.poisson, p.density, 1.0, 1e-2).finished());
  if (s.actuator != Act::none) t.lambda_a = random(1, std::abs(p.lambda));
  StateTangent Jd;
  ASSERT_TRUE(a.d.jvp(a.model, a.data, a.in, a.out, t, Jd));
  StateTangent w;
  w.x = random(n, 1.0);
  w.v = random(n, 1.0);
  StepCotangent JTw;
  ASSERT_TRUE(a.d.vjp(a.model, a.data, a.in, a.out, w, JTw));
  const double lhs = w.x.dot(Jd.x) + w.v.dot(Jd.v);
  double rhs = JTw.x.dot(t.x) + JTw.v.dot(t.v) + JTw.p.dot(t.p);
  if (t.lambda_a.size()) rhs += JTw.lambda_a.dot(t.lambda_a);
  // Term by term the sums have magnitudes up to |w| |J d|: 1e-10 of that; with factor
  // reuse each of the JVP's and the VJP's PCG solves adds at most cond(A) pcg_tolerance
  // of it.
  const double scale = w.x.norm() * Jd.x.norm() + w.v.norm() * Jd.v.norm();
  EXPECT_NEAR(lhs, rhs, (1e-10 + 2 * a.pcg_error(s)) * scale) << describe_scenario(s);
}

class StepDerivatives : public ::testing::TestWithParam<Scenario> {};

TEST_P(StepDerivatives, EveryBlockMatchesCentralDifferences) { check_blocks(GetParam()); }
TEST_P(StepDerivatives, ReverseModeIsTheTransposeOfTheForwardMode) { check_dot_product(GetParam()); }

INSTANTIATE_TEST_SUITE_P(
    Cases, StepDerivatives,
    ::testing::Values(Scenario{Law::corotational}, Scenario{Law::stvk}, Scenario{Law::neo_hookean},
                      Scenario{Law::linear}, Scenario{Law::stvk, true}, Scenario{Law::neo_hookean, true},
                      Scenario{Law::corotational, false, false, true}, Scenario{Law::corotational, false, true, false},
                      Scenario{Law::corotational, false, true, true, Act::cable},
                      Scenario{Law::corotational, false, true, true, Act::cavity},
                      Scenario{Law::corotational, false, true, true, Act::open_face},
                      Scenario{Law::corotational, false, true, true, Act::translation},
                      Scenario{Law::neo_hookean, false, true, true, Act::rotation},
                      Scenario{Law::corotational, false, true, true, Act::none, 30},
                      Scenario{Law::neo_hookean, false, true, true, Act::cavity, 30},
                      Scenario{Law::stvk, false, false, false, Act::rotation, 30},
                      Scenario{Law::corotational, false, true, true, Act::none, 1, true},
                      Scenario{Law::neo_hookean, true, true, true, Act::none, 1, true},
                      Scenario{Law::corotational, false, true, true, Act::cable, 1, true}));

}  // namespace
