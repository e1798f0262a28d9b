// Validation: Newton's method (newton_iterations > 1) with contact (docs/method.md
// "Newton iterations with contact"). A Neo-Hookean block (4 x 4 x 2 cm, E = 5e3 Pa,
// 1000 kg/m^3) falls at 1 m/s onto a plane (mu = 0.5) from 0.1 mm above it: within one
// step of 10 ms its bottom stops while its top keeps moving (the elastic wave,
// sqrt(E / rho) = 2.2 m/s, crosses it in 9 ms): large strain, where the linearized step
// and Newton differ.
//  - Newton converges, and its answer satisfies the nonlinear implicit Euler equations
//    with contact, recomputed here independently of the step:
//        (1 + h alpha) M v - M v_i - h (P + f_int(x_i + h v)) - h f_c = 0,
//    f_int from a fresh FEM evaluation at x_i + h v and f_c spread from each contact's
//    frame C_i lambda_i with its weights (not the solver's H_c);
//  - the contact solution satisfies the NCP at that velocity: sigma = C_i^T sum_k w_k v_k
//    + (0, 0, phi_i / h) recomputed from the frames and weights, the NCP residuals
//    (ncp_residuals_at) within the contact tolerance;
//  - the linearized step misses the same equations by orders of magnitude more;
//  - with a small step both agree: their relative difference shrinks with h.
#include <softdiff/contact/ncp.hpp>
#include <softdiff/data.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <support/contact.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <cstdio>
#include <string>

using namespace softdiff;

namespace newton_contact_validation {

constexpr double kAlpha = 0.5;  // Rayleigh mass damping (1/s): D = alpha M

Model block(double h, int newton, double mu = 0.5) {
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = 5e3;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = kAlpha;
  Model model = test::make_model(test::box_mesh(3, 3, 2, 0.04, 0.04, 0.02), spec, Vec3(0, 0, -9.81), h, 1);
  model.step.newton_iterations = newton;
  model.step.newton_tolerance = 1e-12;
  test::ContactSpec cs;
  cs.mu = mu;
  cs.margin = 1e-3;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  return model;
}

State falling(const Model& model, double speed) {
  State s = model.initial;
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    s.x[3 * i + 2] += 1e-4;
    s.v[3 * i + 2] = -speed;
  }
  return s;
}

// World contact force on the nodes, from each contact's frame and weights.
VecX nodal_contact_force(const Model& model, const Data& data) {
  VecX f = VecX::Zero(3L * model.fem.num_nodes);
  const auto& cd = data.contact;
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
    const Vec3 world = c.frame * cd.lambda.segment<3>(3 * i);
    for (int k = 0; k < c.count; ++k) f.segment<3>(3 * c.nodes[k]) += c.weights[k] * world;
  }
  return f;
}

// ||(1 + h alpha) M v - M v_i - h (P + f_int(x_i + h v)) - h f_c|| / ||M v_i|| (no fixed
// dofs: nothing projected).
double dynamics_residual(const Model& model, const Data& data, const State& in, const State& out, double h) {
  fem::FemData d;
  d.resize(model.fem);
  EXPECT_TRUE(fem::evaluate(model.fem, in.x + h * out.v, {false, true, false}, d));
  VecX Mv(out.v.size()), Mvi(out.v.size());
  fem::symmetric_multiply(model.fem, model.fem.mass_values, out.v, Mv);
  fem::symmetric_multiply(model.fem, model.fem.mass_values, in.v, Mvi);
  const VecX r = (1 + h * kAlpha) * Mv - Mvi - h * (model.fem.gravity_force + d.f_int + nodal_contact_force(model, data));
  return r.norm() / Mvi.norm();
}

// The NCP's residuals at the step's velocity, sigma from the frames and weights.
contact::NcpResiduals contact_residuals(const Data& data, const State& out, double h) {
  const auto& cd = data.contact;
  VecX sigma(3L * cd.contacts.size());
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
    Vec3 v = Vec3::Zero();
    for (int k = 0; k < c.count; ++k) v += c.weights[k] * out.v.segment<3>(3 * c.nodes[k]);
    sigma.segment<3>(3 * i) = c.frame.transpose() * v;
    sigma[3 * i + 2] += c.gap / h;
  }
  return contact::ncp_residuals_at(sigma, cd.g, cd.mu, cd.lambda);
}

struct StepRun {
  State out;
  double dynamics = 0;
  contact::NcpResiduals ncp;
  int iterations = 0, contacts = 0;
  double compression = 0;  // 1 - (height at the end of the step) / (rest height)
};

// `steps` steps of size h; the residuals are those of the last step.
StepRun run(double h, int newton, int steps = 1) {
  const Model model = block(h, newton);
  State in = falling(model, 1.0);
  Data data(model);
  StepRun r;
  for (int k = 1; k <= steps; ++k) {
    if (k > 1) in = r.out;
    const StepStatus st = integrator::implicit_euler_step(model, data, in, r.out, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    EXPECT_TRUE(data.contact.result.converged);
  }
  r.dynamics = dynamics_residual(model, data, in, r.out, h);
  r.ncp = contact_residuals(data, r.out, h);
  r.iterations = data.newton_iterations_used;
  r.contacts = data.contact.contacts.size();
  double top = -1e300, bottom = 1e300;
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    top = std::max(top, r.out.x[3 * i + 2]);
    bottom = std::min(bottom, r.out.x[3 * i + 2]);
  }
  r.compression = 1 - (top - bottom) / 0.02;
  return r;
}

TEST(ValidationNewtonContact, ConvergedStepSatisfiesTheNonlinearEquationsWithContact) {
  const double h = 1e-2;
  const StepRun newton = run(h, 30), linearized = run(h, 1);
  std::printf("block falling at 1 m/s, h = %g s, %d contacts: compression %.3f (Newton, %d iterations), %.3f "
              "(linearized)\n  residual of the implicit Euler equations with contact (relative to ||M v_i||): "
              "Newton %.2e, linearized %.2e\n  NCP residuals at v: Newton %.2e, linearized %.2e\n",
              h, newton.contacts, newton.compression, newton.iterations, linearized.compression, newton.dynamics,
              linearized.dynamics, newton.ncp.max(), linearized.ncp.max());
  ASSERT_GT(newton.contacts, 0);
  EXPECT_GT(newton.compression, 0.08) << "not the large strain the case is about";
  EXPECT_GE(newton.iterations, 3);
  // Newton: converged to newton_tolerance 1e-12 of max(||R(0)||, ...) >= ||M v_i||
  // (R(0) = -(M v_i + h P + h f(x_i)), dominated by the momentum); 1e-10 leaves room for
  // the round-off of the recomputation.
  EXPECT_LT(newton.dynamics, 1e-10);
  EXPECT_LT(newton.ncp.max(), 1e-10);  // the contact tolerance
  // The linearized step solves only the first linearization: its error is the
  // nonlinearity of f_int over the step, a large multiple of Newton's.
  EXPECT_GT(linearized.dynamics, 1e4 * std::max(newton.dynamics, 1e-14));
  // Both steps' velocities differ by more than the tolerances.
  const double differ = (newton.out.v - linearized.out.v).norm() / newton.out.v.norm();
  std::printf("  relative difference of v_f: %.2e\n", differ);
  EXPECT_GT(differ, 1e-3);
}

// With small steps the nonlinearity within a step vanishes: over the same 20 ms of the
// impact, the linearized step and Newton agree as h shrinks. Both are first-order
// implicit Euler schemes whose steps differ by O(h^2) (the linearization's error), so
// their states at a fixed time differ by O(h): a tenfold smaller h must shrink the
// difference by far more than 3 (a third of the asymptotic factor 10: contact
// switches within the 20 ms make the rate uneven).
TEST(ValidationNewtonContact, SmallStepsAgreeWithTheLinearizedStep) {
  double previous = 0;
  for (const double h : {1e-2, 1e-3, 1e-4}) {
    const int steps = static_cast<int>(std::lround(0.02 / h));
    const StepRun newton = run(h, 30, steps), linearized = run(h, 1, steps);
    const double differ = (newton.out.x - linearized.out.x).norm() / (newton.out.x - block(h, 1).initial.x).norm();
    std::printf("h = %g s, %d steps: relative difference of x(20 ms) %.2e (of the displacement); last step: Newton "
                "%d iterations, residual %.2e\n",
                h, steps, differ, newton.iterations, newton.dynamics);
    EXPECT_LT(newton.dynamics, 1e-10) << h;
    EXPECT_LT(newton.ncp.max(), 1e-10) << h;
    if (previous > 0) {
      EXPECT_LT(differ, previous / 3) << h;
    }
    previous = differ;
  }
}

// BDF2 runs its implicit Euler stage (integrator/bdf2.hpp): Newton with contact there
// too. Three steps of the falling block: every step converges and satisfies the contact
// problem.
TEST(ValidationNewtonContact, Bdf2WithNewtonAndContact) {
  Model model = block(2e-3, 30);
  model.step.integrator = IntegratorKind::bdf2;
  State a = falling(model, 1.0), b;
  State previous;
  Data data(model);
  int steps_with_contact = 0;
  for (long k = 1; k <= 20; ++k) {
    const StepStatus st = integrator::time_step(model, data, a, k == 1 ? nullptr : &previous, b, k);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    EXPECT_TRUE(data.contact.result.converged) << k;
    if (data.contact.contacts.size() > 0) {
      ++steps_with_contact;
      EXPECT_LT(contact_residuals(data, b, data.h).max(), 1e-10) << k;
    }
    previous = a;
    a = b;
  }
  EXPECT_GT(steps_with_contact, 5);
}

// The incline of tests/contact/validation_contact.cpp (a 0.1 m cube, 3x3x3 cells, on
// the plane z = 0 with gravity tilted by a, mu = 0.5, beta = 1e-3 damping the elastic
// transient) with newton_iterations 5: every step converges, the cube sticks at 25
// degrees (tan 25 = 0.466 < mu) and slides at 30 with Coulomb's acceleration
// g (sin a - mu cos a) within 1% (the mean x velocity of the nodes over 0.1-0.5 s, as
// the linearized step's test).
double incline_acceleration(double angle_deg, double* slip) {
  test::BodySpec spec;
  spec.young = 1e6;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_stiffness = 1e-3;
  const double a = angle_deg * 3.14159265358979323846 / 180, g = 9.81;
  const double dt = 2e-3;
  Model model = test::make_model(test::box_mesh(3, 3, 3, 0.1, 0.1, 0.1), spec,
                                 Vec3(g * std::sin(a), 0, -g * std::cos(a)), dt, 250);
  model.step.newton_iterations = 5;
  test::ContactSpec cs;
  cs.mu = 0.5;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  Data data(model);
  State s = model.initial, next;
  const long k0 = 50, k1 = 250;
  auto mean_vx = [&](const State& st) {
    double m = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i) m += st.v[3 * i];
    return m / model.fem.num_nodes;
  };
  double v0 = 0;
  State at_start;
  *slip = 0;
  int max_iterations = 0;
  for (long k = 1; k <= k1; ++k) {
    const StepStatus st = integrator::implicit_euler_step(model, data, s, next, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);  // not_converged included
    if (!st.ok()) return 0;
    max_iterations = std::max(max_iterations, data.newton_iterations_used);
    s = next;
    if (k == k0) {
      at_start = s;
      v0 = mean_vx(s);
    }
    if (k > k0) {
      const auto& cd = data.contact;
      for (int c = 0; c < cd.contacts.size(); ++c) {
        if (cd.modes[c] == contact::Mode::breaking) continue;
        const int i = cd.contacts.contacts[c].nodes[0];
        *slip = std::max(*slip, std::abs(s.x[3 * i] - at_start.x[3 * i]));
      }
    }
  }
  std::printf("incline %g degrees, newton_iterations 5: at most %d iterations per step\n", angle_deg, max_iterations);
  return (mean_vx(s) - v0) / ((k1 - k0) * dt);
}

TEST(ValidationNewtonContact, InclineWithNewton) {
  double slip = 0;
  incline_acceleration(25, &slip);
  EXPECT_LT(slip, 1e-7);
  const double a = 30 * 3.14159265358979323846 / 180;
  const double expected = 9.81 * (std::sin(a) - 0.5 * std::cos(a));
  EXPECT_NEAR(incline_acceleration(30, &slip), expected, 0.01 * expected);
}

}  // namespace newton_contact_validation
