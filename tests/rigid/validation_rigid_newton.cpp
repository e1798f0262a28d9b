// Newton iterations (newton_iterations > 1) with rigid bodies in contact (docs/method.md
// "Newton with rigid contact", issue 21): run build/tests/validation_rigid
// --gtest_filter='RigidNewton*' (it prints the figures the docs quote).
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>

#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <iostream>

using namespace softdiff;

namespace rigid_newton_validation {

constexpr double g0 = 9.81;

using test::rigid_scenes::contact_force_on;

// The cube on a soft slab of validation_rigid_contact.cpp (CubeRestsOnASoftSlab), the
// slab Neo-Hookean: 0.12 x 0.12 x 0.01 m, E = 50 kPa, bottom fixed, damped; the 40 mm
// cube (32 g) released at zero gap.
Model cube_on_slab(double h, int newton_iterations, IntegratorKind integrator = IntegratorKind::implicit_euler) {
  test::BodySpec spec = test::rigid_scenes::damped_slab_spec();
  spec.law = material::Law::neo_hookean;
  const mesh::TetMesh m = test::box_mesh(8, 8, 2, 0.12, 0.12, 0.01);
  Model model = test::make_model(m, spec, Vec3(0, 0, -g0), h);
  model.step.newton_iterations = newton_iterations;
  model.step.integrator = integrator;
  rigid::RigidState s;
  s.position = Vec3(0.06, 0.06, 0.01 + 0.02);
  test::add_rigid_body(model, "cube", test::box_shape(Vec3(0.02, 0.02, 0.02)), 500, s);
  test::enable_rigid_contact(model, {}, {{"body", "cube", 0.5}}, 1e-3, contact::NcpOptions{});
  return model;
}

// Runs `steps` steps from model.initial; asserts every step ok (Newton converged).
// Counts the steps whose contact solve missed its tolerance (reported, not a failure:
// the NCP's own stall on the cube's redundant manifold, as in the linearized step) and
// the largest Newton iteration count.
struct RunResult {
  State end;
  int ncp_misses = 0, max_newton = 0;
  double max_ncp_residual = 0;
};
RunResult run(const Model& model, Data& data, long steps) {
  RunResult out;
  State a = model.initial, b, prev;
  const bool bdf2 = model.step.integrator == IntegratorKind::bdf2;
  for (long n = 1; n <= steps; ++n) {
    // BDF2: the first step is implicit Euler (no previous state), then from (s_{n-1}, s_n).
    const StepStatus st = integrator::time_step(model, data, a, bdf2 && n > 1 ? &prev : nullptr, b, n);
    EXPECT_TRUE(st.ok()) << describe(model, st) << " (contact residual " << data.contact.result.residuals.max()
                         << ", " << data.contact.contacts.size() << " contacts)";
    if (!st.ok()) break;
    if (!data.contact.result.converged) ++out.ncp_misses;
    out.max_ncp_residual = std::max(out.max_ncp_residual, data.contact.result.residuals.max());
    out.max_newton = std::max(out.max_newton, data.newton_iterations_used);
    if (bdf2) prev = a;
    std::swap(a, b);
  }
  out.end = a;
  return out;
}

double min_gap_at(const Model& model, Data& data, const State& s) {
  data.contact.rigid.in = s.rigid;
  contact::extend_for_detection(model, data, s.x, s.v, s.v);
  collision::ContactSet after;
  data.contact.detector->detect(data.contact.rigid.x, after, 1e-3);
  double g = 1;
  for (const auto& c : after.contacts) g = std::min(g, c.gap);
  return g;
}

// The rigid cube on the Neo-Hookean slab with newton_iterations 8 (h = 2 ms, 0.4 s):
// every step's Newton converges; at rest the reaction equals the weight, no contact
// penetrates beyond the contact solve's tolerance, and the cube's height is the static
// solution's (integrator::solve_static on the same scene: the reference).
// Under bdf2 too (rnewtd; it was refused): BDF2's stage (implicit Euler of size 2h/3 from
// the extrapolated states) with Newton, the same assertions.
class RigidNewtonIntegrator : public ::testing::TestWithParam<IntegratorKind> {};
std::string integrator_name(IntegratorKind k) { return k == IntegratorKind::bdf2 ? "bdf2" : "implicit_euler"; }

TEST_P(RigidNewtonIntegrator, CubeRestsOnANeoHookeanSlab) {
  const Model model = cube_on_slab(2e-3, 8, GetParam());
  Data data(model);
  const RunResult r = run(model, data, 200);
  const auto& e = r.end.rigid[0];
  int count = 0;
  const Vec3 f = contact_force_on(data, 1, &count);
  const double weight = model.rigid[0].mass * g0;
  const double min_gap = min_gap_at(model, data, r.end);
  // The reference: the static equilibrium of the same scene.
  Model stat = model;
  stat.step.integrator = IntegratorKind::static_equilibrium;
  stat.step.newton_iterations = 1;
  stat.step.static_max_iterations = 60;
  stat.step.static_tolerance = 1e-10;
  Data sdata(stat);
  State eq;
  const StepStatus st = integrator::solve_static(stat, sdata, stat.initial, eq);
  ASSERT_TRUE(st.ok()) << describe(stat, st);
  const double sink = 0.03 - e.position.z(), sink_static = 0.03 - eq.rigid[0].position.z();
  std::cout << integrator_name(GetParam()) << ", Newton (8) cube on a Neo-Hookean slab: reaction " << f.transpose() << " N, weight " << weight
            << " N, contacts " << count << ", speed " << e.velocity.norm() << " m/s, sink " << sink
            << " m (static " << sink_static << " m, difference " << sink - sink_static << " m), min gap " << min_gap
            << " m, Newton iterations <= " << r.max_newton << ", contact solves missing 1e-8: " << r.ncp_misses
            << " of 200 steps (largest residual " << r.max_ncp_residual << ")\n";
  EXPECT_GT(count, 4);
  EXPECT_LT(e.velocity.norm(), 1e-8);
  // At rest to 1e-8 m/s: the reaction differs from the weight by the momentum change of
  // the last step, m |dv| / h <= 0.032 * 2e-8 / 2e-3 = 3.2e-7 N, 1e-6 of the weight.
  EXPECT_NEAR(f.z(), weight, 1e-6 * weight);
  EXPECT_GT(min_gap, -1e-8);
  EXPECT_LT(e.angular_velocity.norm(), 1e-3);
  // The static height: the dynamic run at rest (1e-8 m/s) is the equilibrium up to the
  // slab's remaining motion; 1e-3 of the sink bounds that (the slab's stiffness k ~ m g /
  // sink: a residual force of 1e-6 of the weight moves it by 1e-6 of the sink).
  EXPECT_NEAR(sink, sink_static, 1e-3 * sink_static);
  EXPECT_LE(r.max_newton, 8);
}

// A rigid block on a 20 degree incline pushed by a Neo-Hookean pad (the setup of
// validation_rigid_contact.cpp SoftPadPushesABlockAtTheFrictionThreshold, below the
// threshold: the pad of 14.4 g, the 64 g block, mu = 0.5), h = 1 ms, 0.3 s. In this
// linear limit (the pad's strain ~1e-4) Newton (8 iterations) and the linearized step
// (1) come to the same rest: the block stays put, the push is m_p g sin a, and the
// pad's positions agree.
struct PadAndBlock {
  Model model;
  double m_pad = 0;
};
PadAndBlock pad_and_block(int newton_iterations, IntegratorKind integrator = IntegratorKind::implicit_euler) {
  const double a = 20 * std::numbers::pi / 180, mu = 0.5, h = 1e-3;
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = 2e5;
  spec.poisson = 0.3;
  spec.density = 800;
  spec.rayleigh_stiffness = 0.005;
  mesh::TetMesh m = test::box_mesh(3, 2, 3, 0.03, 0.02, 0.03);
  for (Eigen::Index i = 0; i < m.X.cols(); ++i) m.X.col(i) += Vec3(-0.015, -0.02, 0.005);
  PadAndBlock pb{test::make_model(m, spec, Vec3(0, g0 * std::sin(a), -g0 * std::cos(a)), h)};
  pb.model.step.newton_iterations = newton_iterations;
  pb.model.step.integrator = integrator;
  pb.m_pad = pb.model.fem.mass_diagonal.sum() / 3;
  rigid::RigidState s;
  s.position = Vec3(0, 0.02, 0.02);
  test::add_rigid_body(pb.model, "block", test::box_shape(Vec3(0.02, 0.02, 0.02)), 1000, s);
  test::enable_rigid_contact(pb.model, {test::plane(Vec3::UnitZ(), 0, "table"), test::plane(Vec3::UnitZ(), 0.005, "step")},
                             {{"body", "step", 0.0}, {"block", "table", mu}, {"body", "block", 0.0}}, 1e-3,
                             contact::NcpOptions{});
  return pb;
}

double push_on_block(const Data& data) {
  double f = 0;
  for (int i = 0; i < data.contact.contacts.size(); ++i) {
    const auto& c = data.contact.contacts.contacts[static_cast<std::size_t>(i)];
    const Vec3 w = c.frame * data.contact.lambda.segment<3>(3 * i);
    if (c.side_a == 1 && c.side_b == 0) f += w.y();
    else if (c.side_a == 0 && c.side_b == 1) f -= w.y();
  }
  return f;
}

TEST_P(RigidNewtonIntegrator, NeoHookeanPadOnABlockNewtonMatchesLinearized) {
  const double a = 20 * std::numbers::pi / 180;
  PadAndBlock newton = pad_and_block(8, GetParam()), linear = pad_and_block(1, GetParam());
  Data dn(newton.model), dl(linear.model);
  const RunResult rn = run(newton.model, dn, 300), rl = run(linear.model, dl, 300);
  const double expected = newton.m_pad * g0 * std::sin(a);
  const double push_n = push_on_block(dn), push_l = push_on_block(dl);
  const double drift = (rn.end.rigid[0].position - newton.model.initial.rigid[0].position).norm();
  // The pad's deformation, free of its rigid motion (its x motion and yaw are free on the
  // frictionless step and keep what the transient gave them, different in the two runs):
  // the changes of all node-to-node distances from the rest mesh, and the two runs'
  // difference in them.
  const auto& X = newton.model.fem.X;
  const Eigen::Index nn = X.cols();
  VecX strain_n(nn * (nn - 1) / 2), strain_l(nn * (nn - 1) / 2);
  for (Eigen::Index i = 0, k = 0; i < nn; ++i)
    for (Eigen::Index j = i + 1; j < nn; ++j, ++k) {
      const double rest = (X.col(i) - X.col(j)).norm();
      strain_n[k] = (rn.end.x.segment<3>(3 * i) - rn.end.x.segment<3>(3 * j)).norm() - rest;
      strain_l[k] = (rl.end.x.segment<3>(3 * i) - rl.end.x.segment<3>(3 * j)).norm() - rest;
    }
  const double deformation = strain_l.norm(), difference = (strain_n - strain_l).norm();
  std::cout << integrator_name(GetParam()) << ", Newton (8) vs linearized: Neo-Hookean pad on a block, push " << push_n << " / " << push_l
            << " N (m_p g sin a = " << expected << "), block drift " << drift << " m, pad deformation (distance changes) "
            << deformation << " m, Newton - linearized " << difference << " m, Newton iterations <= "
            << rn.max_newton << "\n";
  EXPECT_LT(drift, 1e-7);
  EXPECT_LT(rn.end.rigid[0].velocity.norm(), 1e-6);
  // The tolerance of the corotational pad's test (its elastic transient dies out to 1e-6 m/s).
  EXPECT_NEAR(push_n, expected, 1e-4 * expected);
  EXPECT_NEAR(push_l, expected, 1e-4 * expected);
  // Both runs at rest solve the same equilibrium f(x) + P + contact = 0 (the linearized
  // step's fixed point v = 0 is exact): they differ by the remaining transients only
  // (the pad below 1e-6 m/s, its deformation changing by less than 1e-6 of itself per
  // step; measured: 1e-12 of it, round-off).
  EXPECT_LT(difference, 1e-6 * deformation);
  EXPECT_GT(rn.max_newton, 1);  // Newton did iterate
}

INSTANTIATE_TEST_SUITE_P(RigidNewton, RigidNewtonIntegrator,
                         ::testing::Values(IntegratorKind::implicit_euler, IntegratorKind::bdf2),
                         [](const ::testing::TestParamInfo<IntegratorKind>& p) { return integrator_name(p.param); });

}  // namespace rigid_newton_validation
