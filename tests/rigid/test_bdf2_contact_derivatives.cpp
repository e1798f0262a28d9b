// Derivatives with BDF2 and rigid bodies in contact (issue 21, "rbd2";
// rigid/rigid_bdf2_derivatives.hpp, diff/trajectory.cpp): the stage of h' = 2h/3 from the
// extrapolated states (soft and rigid) through the one contact NCP, its rigid input the
// extrapolated state whose Jacobian carries s_n and s_{n-1} (BDF2's history).
// Trajectories of 10 steps under integrator bdf2 (the first implicit Euler, then nine
// BDF2 steps): forward sensitivities with respect to a random direction of x0, one of v0
// (soft and rigid rows), the rigid body's mass and one inertia component, against central
// differences of whole BDF2 runs; the adjoint of a loss on the final state (soft and
// rigid) against the same sensitivities (the same products in another order: 1e-9
// relative). Scenes: the wedge of test_contact_derivatives.cpp sliding and spinning on a
// plane (three sliding contacts), on the dense and the sparse contact backends; a rigid
// cube pressed onto a soft slab (soft-rigid contact both ways; dense).
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>

#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <string>

using namespace softdiff;

namespace rigid_bdf2_contact_derivatives_test {

constexpr double g0 = 9.81;

using test::rigid_scenes::anchored;

// Tight NCP: the polish solves the mode equations to round-off, so that the finite
// differences see the exact solution of each perturbed problem.
contact::NcpOptions tight() { return test::rigid_scenes::tight_ncp(1e-12); }

// `steps` steps of the model's integrator from s0 (BDF2: the previous state passed).
State run_steps(const Model& model, const State& s0, long steps) {
  Data data(model);
  State a = s0, b, previous;
  for (long k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::time_step(model, data, a, k > 1 ? &previous : nullptr, b, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    previous = a;
    std::swap(a, b);
  }
  return a;
}

State moved_initial(const Model& model, const State& s0, const VecX& dx0, const VecX& dv0, double e) {
  const Eigen::Index n3 = 3L * model.fem.num_nodes;
  State s = s0;
  s.x += e * dx0.head(n3);
  s.v += e * dv0.head(n3);
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const Eigen::Index o = n3 + 6 * static_cast<Eigen::Index>(r);
    rigid::Vec12 d;
    d << dx0.segment<6>(o), dv0.segment<6>(o);
    s.rigid[r] = rigid::retract(s0.rigid[r], d, e);
  }
  return s;
}

void rows_from(const Model& model, const State& base, const State& s, VecX& x_rows, VecX& v_rows) {
  const Eigen::Index n3 = 3L * model.fem.num_nodes, R = static_cast<Eigen::Index>(model.rigid.size());
  x_rows.resize(n3 + 6 * R);
  v_rows.resize(n3 + 6 * R);
  x_rows.head(n3) = s.x - base.x;
  v_rows.head(n3) = s.v - base.v;
  for (Eigen::Index r = 0; r < R; ++r) {
    const rigid::Vec12 t = rigid::tangent_between(base.rigid[static_cast<std::size_t>(r)], s.rigid[static_cast<std::size_t>(r)]);
    x_rows.segment<6>(n3 + 6 * r) = t.head<6>();
    v_rows.segment<6>(n3 + 6 * r) = t.tail<6>();
  }
}

// Columns: x0 (one direction), v0 (one), the body's mass, its inertia component `inertia`.
// eps: the difference's step per column (see each scene; central, or five-point for the
// columns whose bit is set in fourth_order); tol relative to each column's largest entry.
void check_trajectory(const Model& model, long T, unsigned seed, const double (&eps)[4], double tol, int inertia = 3,
                      double soft_x0 = 1.0, unsigned fourth_order = 0) {
  ASSERT_EQ(model.step.integrator, IntegratorKind::bdf2);
  const Eigen::Index n3 = 3L * model.fem.num_nodes, rows = n3 + 6;
  std::mt19937 rng(seed);
  std::normal_distribution<double> N;
  diff::ThetaLayout theta;
  theta.x0 = theta.v0 = true;
  theta.x0_basis = MatX::NullaryExpr(rows, 1, [&] { return N(rng); });
  theta.x0_basis.topRows(n3) *= soft_x0;
  theta.v0_basis = MatX::NullaryExpr(rows, 1, [&] { return N(rng); });
  theta.rigid_parameters = {{0, 0}, {0, inertia}};
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, T, theta, final, dx, dv).ok());
  ASSERT_EQ(dx.cols(), 4);
  EXPECT_GT(data.contact.contacts.size(), 0);
  const VecX zero = VecX::Zero(rows);
  for (int c = 0; c < 4; ++c) {
    const double scale = c < 2 ? 1.0 : c == 2 ? model.rigid[0].mass : model.rigid[0].inertia.trace() / 3;
    // The final state's rows (x, then v; rigid rows in the tangent at `final`) of the run
    // with column c's input moved by e (x0, v0: along the direction; a parameter: by e
    // times its scale).
    auto moved = [&](double e) {
      State s;
      if (c < 2) {
        const VecX d0 = c == 0 ? VecX(theta.x0_basis.col(0)) : zero, e0 = c == 1 ? VecX(theta.v0_basis.col(0)) : zero;
        s = run_steps(model, moved_initial(model, model.initial, d0, e0, e), T);
      } else {
        const int index = c == 2 ? 0 : inertia;
        Model m = model;
        rigid::set_parameter(m.rigid[0], index, rigid::get_parameter(model.rigid[0], index) + e * scale);
        s = run_steps(m, model.initial, T);
      }
      VecX xr, vr, out(2 * rows);
      rows_from(model, final, s, xr, vr);
      out << xr, vr;
      return out;
    };
    // The central difference (f(e) - f(-e)) / 2e (truncation e^2 f^(3) / 6), or for the
    // columns in fourth_order (bit c) the five-point one
    // (8 (f(e) - f(-e)) - (f(2e) - f(-2e))) / 12e (truncation e^4 f^(5) / 30; its
    // difference noise 1.5 delta / e against the central one's delta / e, delta the final
    // state's noise).
    const double e = eps[c];
    VecX fd = (moved(e) - moved(-e)) / (2 * e);
    if (fourth_order & (1u << c)) fd = (8 * (2 * e) * fd - (moved(2 * e) - moved(-2 * e))) / (12 * e);
    VecX an(2 * rows);
    an << dx.col(c) * scale, dv.col(c) * scale;
    const double err = (an - fd).cwiseAbs().maxCoeff(), mag = fd.cwiseAbs().maxCoeff();
    std::cout << "column " << c << ": max |sensitivity - FD| " << err << " of " << mag << "\n";
    EXPECT_LT(err, tol * mag) << "column " << c;
    // The rigid rows alone, relative to their own scale.
    VecX fd_r(12), an_r(12);
    fd_r << fd.segment<6>(n3), fd.tail<6>();
    an_r << an.segment<6>(n3), an.tail<6>();
    EXPECT_LT((an_r - fd_r).cwiseAbs().maxCoeff(), tol * fd_r.cwiseAbs().maxCoeff()) << "rigid rows, column " << c;
  }
  test::rigid_scenes::expect_adjoint_matches_forward(model, T, theta, dx, dv, rng, N);
}

class RigidBdf2ContactTrajectoryDerivatives : public ::testing::TestWithParam<bool> {};

// The wedge sliding at 0.5 m/s and spinning at 0.8 rad/s on a plane with mu = 0.3: three
// sliding contacts all along. eps as test_contact_derivatives.cpp's wedge trajectory:
// 1e-8 for x0 (its direction moves and tilts the 5 cm wedge by O(1) per unit: eps^2
// truncation measured 1.8e-7 relative there at 1e-8), 1e-6 for the others (truncation
// ~1e-12, round-off ~1e-10 relative). tol 1e-5 relative to each column's largest entry.
TEST_P(RigidBdf2ContactTrajectoryDerivatives, SlidingWedge) {
  Model model = anchored(1e-3);
  test::rigid_scenes::add_sliding_wedge(model);
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0, "floor")}, {{"wedge", "floor", 0.3}}, 1e-3, tight());
  model.contact.ncp.backend = GetParam() ? contact::NcpBackend::sparse : contact::NcpBackend::dense;
  model.step.integrator = IntegratorKind::bdf2;
  model.initial = run_steps(model, model.initial, 3);
  check_trajectory(model, 10, 3, {1e-8, 1e-6, 1e-6, 1e-6}, 1e-5);
}

// The wedge dropped 1 mm onto the plane (2026-12-04, rbimp; the impact restart,
// integrator/bdf2.cpp rigid_impact): sliding at 0.5 m/s and spinning, it lands flat on
// its three base corners during step 8 (h = 2 ms) at 0.137 m/s; the landing step and the
// one after restart as implicit Euler contact steps (the branch is recorded in
// data.history_weight and recomputed from the same states by the derivatives), then BDF2
// resumes. 14 steps: step 1 implicit Euler (no previous), 2-7 BDF2 (falling), 8-9 the
// restart, 10-14 BDF2 sliding. The branches are counted first (11 BDF2 steps), then the
// forward sensitivities (x0, v0, mass, inertia) against central differences of whole runs
// and the adjoint against them (1e-9), as the sliding wedge above; eps as there (the
// drop moves no branch: the landing is 9 um above the plane at the end of step 7 and
// closes at 0.137 m/s, far from the 5 mm/s threshold and from a step boundary under a
// perturbation of 1e-6). tol 1e-5.
TEST_P(RigidBdf2ContactTrajectoryDerivatives, WedgeDroppedOntoThePlane) {
  Model model = anchored(2e-3);
  test::rigid_scenes::add_sliding_wedge(model);
  model.initial.rigid[0].position.z() += 1e-3;
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0, "floor")}, {{"wedge", "floor", 0.3}}, 1e-3, tight());
  model.contact.ncp.backend = GetParam() ? contact::NcpBackend::sparse : contact::NcpBackend::dense;
  model.step.integrator = IntegratorKind::bdf2;
  const long T = 14;
  {
    Data data(model);
    State a = model.initial, b, previous;
    long bdf2_steps = 0, landing = 0;
    for (long k = 1; k <= T; ++k) {
      ASSERT_TRUE(integrator::time_step(model, data, a, k > 1 ? &previous : nullptr, b, k).ok());
      bdf2_steps += data.history_weight != 0;
      if (!landing && data.contact.lambda.size() && data.contact.lambda.maxCoeff() > 0) landing = k;
      previous = a;
      std::swap(a, b);
    }
    std::cout << "wedge dropped 1 mm, " << T << " steps: " << bdf2_steps << " BDF2, landing at step " << landing
              << ", v_z " << a.rigid[0].velocity.z() << "\n";
    EXPECT_EQ(landing, 8);
    EXPECT_EQ(bdf2_steps, T - 3);
    EXPECT_LT(std::abs(a.rigid[0].velocity.z()), 1e-9);
  }
  check_trajectory(model, T, 5, {1e-8, 1e-6, 1e-6, 1e-6}, 1e-5);
}

INSTANTIATE_TEST_SUITE_P(, RigidBdf2ContactTrajectoryDerivatives, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& p) { return p.param ? "sparse" : "dense"; });

// A rigid cube (0.02 m, 500 kg/m^3) landing at 0.3 m/s on a soft slab (4 x 4 x 1 boxes of
// tets, bottom fixed), as test_contact_derivatives.cpp's CubeOnASoftSlab: the slab's top
// vertices against the cube's bottom faces and its corners against the slab's top faces,
// from 0.3 mm above the slab, sliding at 0.05 m/s (mu 0.5). With the restart of soft-rigid
// impacts (2026-12-04, rsrb; integrator/bdf2.cpp impact) the cube lands and stays: step 1
// implicit Euler (no previous state), steps 2 and 3 the restart (rule (b): step 1 stopped
// the closing contacts), steps 4-10 BDF2 with the cube resting and partly sticking on the
// slab (without the restart it bounced off within 10 steps, and the test ran 4 steps).
// 10 steps: the restart and seven BDF2 steps from its record (the rigid body's BDF2
// history after a restart). The soft part of the x0 direction is scaled by 1e-3 (a unit
// soft direction deforms every element: its curvature needed eps = 5e-9 in one step).
// The differences: five-point, (8 (f(e) - f(-e)) - (f(2e) - f(-2e))) / 12e, every column.
// The final state's noise delta (the mode system's round-off, amplified in the cube's
// angular velocity by its small inertia, 2.7e-7 kg m^2) is ~1e-13 (measured, the same
// with the NCP tolerance at 1e-12, 1e-14 or 1e-15), and the inertia column is small (the
// resting cube's state barely depends on its inertia: 1.4e-6 of the column per unit of
// trace/3 at step 10, 1.6e-6 at step 4), so its difference needs a step of a few percent
// and the central difference's truncation e^2 f^(3) / 6 (5e-10 at e = 0.1) would be too
// large there. eps: 1e-6 for x0 (five-point error 5e-8 relative; at 1e-5 the difference
// straddles a kink, a contact changing mode: 4e-4), 3e-6 for v0, 3e-3 for the mass, 5e-2
// for the inertia (measured worst over the three variants and steps 4, 5, 6, 10: 3.5e-6
// relative, the noise 1.5 delta / e; central differences at the former eps 1e-7, 1e-7,
// 1e-4, 1e-3 gave 5e-7, 1e-7, 3e-7 and 9e-5). tol 1e-5 relative as before.
// Why 10 steps and not 4: at step 4 the inertia column passes near zero (per unit inertia
// the cube's angular velocity moves by 280 at step 3, 6 at step 4, 68 at step 5), so the
// loss's inertia gradient in the adjoint check is a sum of terms 50 times larger than
// itself and the two orders of the products differ by their round-off, 0.5-1.8e-9 of the
// largest gradient (random in sign under 1e-13 moves of the initial state), against 1e-9;
// at steps 5, 6, 10: 4e-11 at most.
// newton: newton_iterations 20 at tolerance 1e-12 (rnewtd: BDF2's Newton stage with rigid
// contact, its implicit-function derivative at the converged stage), the same eps and tol.
void check_cube_on_a_soft_slab(bool newton, contact::NcpBackend backend) {
  test::BodySpec spec;
  spec.young = 5e4;
  spec.poisson = 0.4;
  spec.density = 1000;
  spec.rayleigh_mass = 20;
  spec.rayleigh_stiffness = 0.01;
  spec.fixed = [](const Vec3& p) { return p.z() < 1e-9; };
  const mesh::TetMesh m = test::box_mesh(4, 4, 1, 0.06, 0.06, 0.01);
  Model model = test::make_model(m, spec, Vec3(0, 0, -g0), 2e-3);
  rigid::RigidState s;
  s.position = Vec3(0.0375, 0.0375, 0.01 + 0.01 + 3e-4);
  s.velocity = Vec3(0.05, 0, -0.3);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Vec3::UnitZ()));
  test::add_rigid_body(model, "cube", test::box_shape(Vec3(0.01, 0.01, 0.01)), 500, s);
  test::enable_rigid_contact(model, {}, {{"body", "cube", 0.5}}, 1e-3, tight());
  model.contact.ncp.backend = backend;
  model.step.integrator = IntegratorKind::bdf2;
  if (newton) {
    model.step.newton_iterations = 20;
    model.step.newton_tolerance = 1e-12;
  }
  const long T = 10;
  {  // the branches: steps 2 and 3 restarted, 4-10 BDF2, the cube on the slab at the end
    Data data(model);
    State a = model.initial, b, previous;
    std::string branches;
    for (long k = 1; k <= T; ++k) {
      ASSERT_TRUE(integrator::time_step(model, data, a, k > 1 ? &previous : nullptr, b, k).ok());
      branches += data.history_weight != 0 ? 'B' : 'E';
      previous = a;
      std::swap(a, b);
    }
    std::cout << "cube on the soft slab, " << T << " steps (E implicit Euler, B BDF2): " << branches << ", cube v_z "
              << a.rigid[0].velocity.z() << " m/s, force on it " << test::rigid_scenes::contact_force_on(data, 1).z()
              << " N\n";
    EXPECT_EQ(branches, "EEEBBBBBBB");
    EXPECT_GT(test::rigid_scenes::contact_force_on(data, 1).z(), 0);
  }
  check_trajectory(model, T, 7, {1e-6, 3e-6, 3e-3, 5e-2}, 1e-5, 3, 1e-3, 0b1111);
}

TEST(RigidBdf2ContactTrajectory, CubeOnASoftSlab) { check_cube_on_a_soft_slab(false, contact::NcpBackend::dense); }

TEST(RigidBdf2ContactTrajectory, NewtonCubeOnASoftSlabDense) {
  check_cube_on_a_soft_slab(true, contact::NcpBackend::dense);
}

TEST(RigidBdf2ContactTrajectory, NewtonCubeOnASoftSlabSparse) {
  check_cube_on_a_soft_slab(true, contact::NcpBackend::sparse);
}

// BDF2 with a limited joint in contact (rbdlim; integrator/bdf2.cpp): the bar of
// rigid_scenes.hpp bar_onto_its_limit_beside_a_wedge turning under gravity onto its upper
// limit 0.02 (from rest at angle 0 it lands on step 24) beside the wedge sliding on the
// floor. The step's branch is its record (data.history_weight): BDF2 (the extrapolated
// states, their Jacobian carrying s_n and s_{n-1}) or the restart, the implicit Euler
// contact step from s_n (no dependence on s_{n-1}, the limit rows in the NCP). Forward
// sensitivities (x0, v0: random directions of every row, soft and both bodies; the bar's
// mass and inertia.yy, its hinge axis's) against central differences of whole runs, and
// the adjoint against them (1e-9). `start`: the steps run before (the initial state of
// the differentiated run); each run's branches are printed and checked against `bdf2`,
// the expected number of BDF2 steps. eps: 1e-7 for x0 (its direction turns the bar and
// the wedge by O(1) rad per unit: eps^2 truncation ~1e-14 relative; the landing step's
// BDF2 free end passes the limit by ~1e-4 rad, far beyond any perturbed run's shift, so
// every run takes the same branches), 1e-6 for v0 and relative 1e-6 for mass and inertia
// (round-off 1e-16 / 1e-6 ~1e-10, the NCP's tolerance 1e-12 below that). tol 1e-5 relative
// to each column's largest entry, plus an absolute floor 1e-9 for the difference's
// round-off: a run's coordinates are O(1) (the wedge at 0.5 m), so each differs from the
// exact one by ~1e-16, and the quotient by 2 eps = 2e-6 by ~1e-10 (measured 4e-11 to 9e-11
// on the columns that are exactly zero: the mass and inertia of a bar held by its limit
// move nothing).
constexpr double kFloor = 1e-9;
void check_limited_bar(long start, long T, long bdf2) {
  Model model = test::rigid_scenes::bar_onto_its_limit_beside_a_wedge(1e-3, 0.0, 0.02, tight());
  model.contact.ncp.backend = contact::NcpBackend::dense;
  model.initial = run_steps(model, model.initial, start);
  {
    // The branches of the differentiated run (its first step implicit Euler: no previous).
    Data data(model);
    State a = model.initial, b, previous;
    long bdf2_steps = 0, landing = 0;
    for (long k = 1; k <= T; ++k) {
      ASSERT_TRUE(integrator::time_step(model, data, a, k > 1 ? &previous : nullptr, b, k).ok());
      bdf2_steps += data.history_weight != 0;
      if (!landing && data.rigid[0].at_limit) landing = k;
      previous = a;
      std::swap(a, b);
    }
    std::cout << "bar from step " << start << ", " << T << " steps: " << bdf2_steps << " BDF2, landing at step "
              << landing << " (0: none), angle " << rigid::joint_coordinate(model.rigid[0], a.rigid[0]) << "\n";
    EXPECT_EQ(bdf2_steps, bdf2);
  }
  const Eigen::Index n3 = 3L * model.fem.num_nodes, rows = n3 + 12;
  std::mt19937 rng(11);
  std::normal_distribution<double> N;
  diff::ThetaLayout theta;
  theta.x0 = theta.v0 = true;
  theta.x0_basis = MatX::NullaryExpr(rows, 1, [&] { return N(rng); });
  theta.v0_basis = MatX::NullaryExpr(rows, 1, [&] { return N(rng); });
  theta.rigid_parameters = {{0, 0}, {0, 2}};
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, T, theta, final, dx, dv).ok());
  ASSERT_EQ(dx.cols(), 4);
  const double eps[4] = {1e-7, 1e-6, 1e-6, 1e-6};
  const VecX zero = VecX::Zero(rows);
  for (int c = 0; c < 4; ++c) {
    double scale = 1;
    State sp, sm;
    if (c < 2) {
      const VecX d0 = c == 0 ? VecX(theta.x0_basis.col(0)) : zero, e0 = c == 1 ? VecX(theta.v0_basis.col(0)) : zero;
      sp = run_steps(model, moved_initial(model, model.initial, d0, e0, eps[c]), T);
      sm = run_steps(model, moved_initial(model, model.initial, d0, e0, -eps[c]), T);
    } else {
      const int index = c == 2 ? 0 : 2;
      scale = rigid::get_parameter(model.rigid[0], index);
      Model mpl = model, mmi = model;
      rigid::set_parameter(mpl.rigid[0], index, scale * (1 + eps[c]));
      rigid::set_parameter(mmi.rigid[0], index, scale * (1 - eps[c]));
      sp = run_steps(mpl, model.initial, T);
      sm = run_steps(mmi, model.initial, T);
    }
    VecX xp, vp, xm, vm;
    rows_from(model, final, sp, xp, vp);
    rows_from(model, final, sm, xm, vm);
    VecX fd(2 * rows), an(2 * rows);
    fd << (xp - xm) / (2 * eps[c]), (vp - vm) / (2 * eps[c]);
    an << dx.col(c) * scale, dv.col(c) * scale;
    const double err = (an - fd).cwiseAbs().maxCoeff(), mag = fd.cwiseAbs().maxCoeff();
    std::cout << "column " << c << ": max |sensitivity - FD| " << err << " of " << mag << "\n";
    EXPECT_LT(err, 1e-5 * mag + kFloor) << "column " << c;
    // The bar's rows alone (x then v), relative to their own scale: the mass and inertia
    // columns are zero elsewhere.
    VecX fd_r(12), an_r(12);
    fd_r << fd.segment<6>(n3), fd.segment<6>(rows + n3);
    an_r << an.segment<6>(n3), an.segment<6>(rows + n3);
    EXPECT_LE((an_r - fd_r).cwiseAbs().maxCoeff(), 1e-5 * fd_r.cwiseAbs().maxCoeff() + kFloor) << "bar rows, column " << c;
  }
  test::rigid_scenes::expect_adjoint_matches_forward(model, T, theta, dx, dv, rng, N);
}

// One BDF2 step in free fall: steps 1 (implicit Euler: no previous) and 2 (BDF2) from
// step 10 of the fall: the BDF2 branch, the limit rows out of the NCP or inactive.
TEST(RigidBdf2ContactLimits, OneBdf2StepBeforeTheLimit) { check_limited_bar(10, 2, 1); }
// One restart on the limit: from step 30 (resting on it since step 24) two steps, both the
// implicit Euler branch (the first has no previous, the second restarts), the upper limit
// row active.
TEST(RigidBdf2ContactLimits, OneRestartOnTheLimit) { check_limited_bar(30, 2, 0); }
// 16 steps from step 14: BDF2 steps (15 to 23, the first of the run implicit Euler), the
// landing (step 24: the BDF2 free end passes the limit, the step is redone as implicit
// Euler) and 6 steps resting on the limit (restarts).
TEST(RigidBdf2ContactLimits, TrajectoryThroughTheLanding) { check_limited_bar(14, 16, 8); }

}  // namespace rigid_bdf2_contact_derivatives_test
