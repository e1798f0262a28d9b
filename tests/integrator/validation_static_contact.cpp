// Validation: the static solver with contact (docs/method.md "Static equilibrium",
// "Contact") against analytic answers:
//  - a cube resting on a plane: the normal forces sum to the weight, nothing penetrates;
//  - a beam on two supports (frictionless and mu = 0.3): the reactions sum to the
//    weight, each support carries a share, and the moment balance holds;
//  - a block under a tilted load on a plane with friction mu: below mu N it sticks (the
//    tangential force equals the applied tangential load, no slip), above it slides (the
//    tangential force is mu N, the block moves and there is no equilibrium: the solver
//    stops with not_converged);
//  - configs/beam_supports_static.yaml against the settled state of configs/beam_supports.yaml.
// The contact solution of the last Newton iteration is checked independently
// (support/contact_checks.hpp, h = 1: G = H A^{-1} H^T with the last factorization), and
// the equilibrium residual f_int + P + sum of the contact forces is recomputed from the
// contacts' frames and weights, not from the solver's H_c.
#include <softdiff/data.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <support/contact.hpp>
#include <support/contact_checks.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <numbers>
#include <string>

using namespace softdiff;

namespace static_contact_validation {

constexpr double kG = 9.81;
constexpr double kDeg = std::numbers::pi / 180;

// World contact force on the nodes (first side: C_i lambda_i spread with the weights),
// from the contacts' frames and weights (as cmd_simulate writes /bodies/<b>/contact_force).
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

// The equilibrium residual at the solution, independently of the solver: returns
// ||Pi (f_int + P + f_c)|| / max(||P||, ||f_c||) and the total contact force.
double residual(const Model& model, const Data& data, const State& s, Vec3* total_contact_force) {
  fem::FemData d;
  d.resize(model.fem);
  EXPECT_TRUE(fem::evaluate(model.fem, s.x, {false, true, false}, d));
  const VecX fc = nodal_contact_force(model, data);
  VecX r = d.f_int + model.fem.gravity_force + fc;
  for (int k = 0; k < r.size(); ++k)
    if (model.fem.fixed[k]) r[k] = 0;
  *total_contact_force = Vec3::Zero();
  for (int i = 0; i < model.fem.num_nodes; ++i) *total_contact_force += fc.segment<3>(3 * i);
  return r.norm() / std::max(model.fem.gravity_force.norm(), fc.norm());
}

double body_weight(const Model& model) {
  double w = 0;
  for (int k = 2; k < model.fem.gravity_force.size(); k += 3) w -= model.fem.gravity_force[k];
  return w;
}

// The bound on |sum_i r_i| from the solver's stopping rule ||r|| <= tol * reference (the
// reference is at most this test's max(||P||, ||f_c||) times 2, counting ||f_int||):
// |sum| <= sqrt(#dofs) ||r||. Rounding of the sums: far below.
double sum_bound(const Model& model, double reference) {
  return 2 * std::sqrt(3.0 * model.fem.num_nodes) * model.step.static_tolerance * reference;
}

// A 0.1 m cube (3 x 3 x 3 boxes) resting on the plane z = 0 with no fixed node, gravity
// g (tilted for the friction tests), Coulomb mu.
struct CubeOnPlane {
  Model model;
  explicit CubeOnPlane(const Vec3& g, double mu) {
    test::BodySpec spec;
    spec.young = 1e6;
    spec.poisson = 0.3;
    spec.density = 1000;
    model = test::make_model(test::box_mesh(3, 3, 3, 0.1, 0.1, 0.1), spec, g);
    model.step.integrator = IntegratorKind::static_equilibrium;
    model.step.static_tolerance = 1e-10;
    test::ContactSpec cs;
    cs.mu = mu;
    cs.ncp.tolerance = 1e-10;
    cs.ncp.max_iterations = 5000;
    test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  }
};

TEST(StaticContactValidation, CubeRestsOnPlane) {
  CubeOnPlane c(Vec3(0, 0, -kG), 0.5);
  const Model& model = c.model;
  Data data(model);
  State out;
  const StepStatus st = integrator::solve_static(model, data, model.initial, out);
  ASSERT_TRUE(st.ok()) << describe(model, st);
  test::expect_valid_contact_solution(data, model.contact.ncp.tolerance, "cube", 1.0);
  // The 16 bottom nodes are the contacts.
  EXPECT_EQ(data.contact.contacts.size(), 16);
  Vec3 total;
  const double rel = residual(model, data, out, &total);
  EXPECT_LE(rel, 2 * model.step.static_tolerance);
  const double W = body_weight(model);
  EXPECT_NEAR(total.z(), W, sum_bound(model, W)) << "weight " << W;
  EXPECT_NEAR(total.x(), 0, sum_bound(model, W));
  EXPECT_NEAR(total.y(), 0, sum_bound(model, W));
  // No penetration beyond what the NCP's stopping rule allows: its last solve bounds
  // the linearized normal gap after the increment by -tolerance * |g|_inf (the dual
  // residual's scale), and the plane's gap is linear in x, so that is the gap of the
  // solution. (Measured: about -1e-17 m, the polish's rounding.)
  const double allowed = model.contact.ncp.tolerance * data.contact.g.cwiseAbs().maxCoeff();
  double zmin = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) zmin = std::min(zmin, out.x[3 * i + 2]);
  EXPECT_GE(zmin, -allowed);
  EXPECT_LT(allowed, 1e-9);  // the bound itself is physically negligible (1e-8 of the cube)
}

// The same cube with the sparse backend (contact::SparseDelassus bound with h = 1 on the
// Newton iteration's factorization) and with the load ramped over 4 load steps (the
// forces carried from one load step to the next as warm start): each load step's
// normal forces carry s / 4 of the weight, and the final forces equal the dense,
// one-step solve's to the NCP's tolerance (the equilibrium of a frictionless cube on a
// plane under its weight is unique: mu = 0 here, so no path dependence).
TEST(StaticContactValidation, CubeSparseBackendAndLoadSteps) {
  VecX reference_lambda;
  for (int variant = 0; variant < 2; ++variant) {
    SCOPED_TRACE(variant == 0 ? "dense, 1 load step" : "sparse, 4 load steps");
    CubeOnPlane c(Vec3(0, 0, -kG), 0.0);
    Model& model = c.model;
    if (variant == 1) {
      model.contact.ncp.backend = contact::NcpBackend::sparse;
      model.step.static_load_steps = 4;
    }
    Data data(model);
    State out;
    const double W = body_weight(model);
    long steps_seen = 0;
    const StepStatus st = integrator::solve_static(model, data, model.initial, out, [&](long s, const State& state) {
      ++steps_seen;
      Vec3 total;
      const double factor = static_cast<double>(s) / model.step.static_load_steps;
      (void)residual(model, data, state, &total);
      EXPECT_NEAR(total.z(), factor * W, sum_bound(model, W)) << "load step " << s;
    });
    ASSERT_TRUE(st.ok()) << describe(model, st);
    EXPECT_EQ(steps_seen, model.step.static_load_steps);
    EXPECT_EQ(data.contact.result.sparse, variant == 1);
    test::expect_valid_contact_solution(data, model.contact.ncp.tolerance, "cube", 1.0);
    if (variant == 0) {
      reference_lambda = data.contact.lambda;
    } else {
      // The same 16 contacts in the same order (detection order of the bottom nodes).
      ASSERT_EQ(data.contact.lambda.size(), reference_lambda.size());
      // The normal forces of a frictionless cube on a plane: K's response to the same
      // load on the same contact set; both solves meet 1e-10 on the residual, which
      // bounds the difference of the forces by ~1e-10 of their sum times the condition
      // of the round trip through K^-1 and G^-1 (measured difference: 4e-12 W); 1e-7 W
      // allows a condition up to 1e3.
      EXPECT_LE((data.contact.lambda - reference_lambda).cwiseAbs().maxCoeff(), 1e-7 * W);
    }
  }
}

// Friction: gravity tilted by a in the x-z plane (a plane inclined by a): the tangential
// load is m g sin a, the normal load m g cos a. tan a < mu: stick; tan a > mu: slide.
TEST(StaticContactValidation, BlockSticksBelowMuN) {
  const double a = 25 * kDeg;  // tan 25 = 0.466 < 0.5
  CubeOnPlane c(Vec3(kG * std::sin(a), 0, -kG * std::cos(a)), 0.5);
  const Model& model = c.model;
  Data data(model);
  State out;
  const StepStatus st = integrator::solve_static(model, data, model.initial, out);
  ASSERT_TRUE(st.ok()) << describe(model, st);
  test::expect_valid_contact_solution(data, model.contact.ncp.tolerance, "stick", 1.0);
  Vec3 total;
  EXPECT_LE(residual(model, data, out, &total), 2 * model.step.static_tolerance);
  const double m_g = body_weight(model) / std::cos(a);  // m g
  const double tangential_load = m_g * std::sin(a), normal_load = m_g * std::cos(a);
  EXPECT_NEAR(-total.x(), tangential_load, sum_bound(model, m_g));
  EXPECT_NEAR(total.z(), normal_load, sum_bound(model, m_g));
  // Below the cone: |tangential| < mu N with a margin of (0.5 - tan 25) / 0.5 = 7%.
  EXPECT_LT(std::abs(total.x()), 0.5 * total.z());
  // Stick: every contact that carries load ends in the sticking mode, and the block
  // has not slid: friction acts on each Newton increment (docs/method.md "Static
  // equilibrium"), so contacts near the unloaded edge may slip locally on the way
  // (measured: up to 1.8e-5 m), but the block does not move as a whole. The sliding
  // case below moves by more than 1e-3 m (and on, without equilibrium).
  const auto& cd = data.contact;
  int sticking = 0;
  for (int i = 0; i < cd.contacts.size(); ++i) {
    if (cd.modes[static_cast<std::size_t>(i)] == contact::Mode::breaking) continue;
    EXPECT_EQ(cd.modes[static_cast<std::size_t>(i)], contact::Mode::sticking) << "contact " << i;
    ++sticking;
  }
  EXPECT_GE(sticking, 8);
  double mean_x = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) mean_x += (out.x[3 * i] - model.fem.X(0, i)) / model.fem.num_nodes;
  EXPECT_LT(std::abs(mean_x), 1e-4);
}

TEST(StaticContactValidation, BlockSlidesAboveMuN) {
  const double a = 30 * kDeg;  // tan 30 = 0.577 > 0.5
  CubeOnPlane c(Vec3(kG * std::sin(a), 0, -kG * std::cos(a)), 0.5);
  const Model& model = c.model;
  Data data(model);
  State out;
  const StepStatus st = integrator::solve_static(model, data, model.initial, out);
  // No equilibrium: the block slides until the solver gives up (static.max_iterations,
  // or a move beyond the scene's size in one iteration: both say so).
  ASSERT_EQ(st.code, StepStatus::Code::not_converged) << describe(model, st);
  // The last contact solve: every contact that carries load slides on the cone,
  // |lambda_T| = mu lambda_N (NCP tolerance relative to the largest force), against
  // the motion, and the block moves down the slope (+x).
  const auto& cd = data.contact;
  ASSERT_GT(cd.contacts.size(), 0);
  test::expect_valid_contact_solution(data, model.contact.ncp.tolerance, "slide", 1.0);
  const double scale = cd.lambda.cwiseAbs().maxCoeff();
  double normal = 0, tangential_x = 0;
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const Vec3 l = cd.lambda.segment<3>(3 * i);
    const Vec3 world = cd.contacts.contacts[static_cast<std::size_t>(i)].frame * l;
    normal += world.z();
    tangential_x += world.x();
    if (cd.modes[static_cast<std::size_t>(i)] == contact::Mode::breaking) continue;
    EXPECT_EQ(cd.modes[static_cast<std::size_t>(i)], contact::Mode::sliding) << "contact " << i;
    EXPECT_NEAR(l.head<2>().norm(), 0.5 * l[2], 1e-8 * scale) << "contact " << i;
  }
  // The tangential force is mu N (the sum of per-contact equalities), opposing +x.
  EXPECT_NEAR(-tangential_x, 0.5 * normal, 1e-8 * scale * cd.contacts.size());
  // The block has moved down the slope, and its last increment still does.
  double mean_x = 0, mean_dx = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    mean_x += (out.x[3 * i] - model.fem.X(0, i)) / model.fem.num_nodes;
    mean_dx += data.dv[3 * i] / model.fem.num_nodes;
  }
  EXPECT_GT(mean_x, 1e-3);
  EXPECT_GT(mean_dx, 0);
}

// A 0.5 x 0.05 x 0.05 m beam (20 x 2 x 2 boxes) on two box supports under its ends
// (as in tests/contact/validation_contact.cpp), no fixed node.
struct BeamOnSupports {
  Model model;
  explicit BeamOnSupports(double mu) {
    test::BodySpec spec;
    spec.young = 5e5;
    spec.poisson = 0.3;
    spec.density = 1000;
    model = test::make_model(test::box_mesh(20, 2, 2, 0.5, 0.05, 0.05), spec, Vec3(0, 0, -kG));
    model.step.integrator = IntegratorKind::static_equilibrium;
    model.step.static_tolerance = 1e-10;
    test::ContactSpec cs;
    cs.mu = mu;
    cs.ncp.tolerance = 1e-10;
    cs.ncp.max_iterations = 5000;
    test::enable_contact(model,
                         {test::box(Vec3(0.03, 0.025, -0.05), Vec3(0.02, 0.05, 0.05), "left"),
                          test::box(Vec3(0.47, 0.025, -0.05), Vec3(0.02, 0.05, 0.05), "right")},
                         cs);
  }
};

TEST(StaticContactValidation, BeamOnTwoSupportsCarriesItsWeightSymmetrically) {
  for (double mu : {0.0, 0.3}) {
    SCOPED_TRACE("mu " + std::to_string(mu));
    BeamOnSupports b(mu);
    const Model& model = b.model;
    Data data(model);
    State out;
    const StepStatus st = integrator::solve_static(model, data, model.initial, out);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    test::expect_valid_contact_solution(data, model.contact.ncp.tolerance, "beam", 1.0);
    Vec3 total;
    EXPECT_LE(residual(model, data, out, &total), 2 * model.step.static_tolerance);
    const double W = body_weight(model);
    EXPECT_NEAR(total.z(), W, sum_bound(model, W));
    // Left and right reactions.
    const auto& cd = data.contact;
    double left = 0, right = 0;
    for (int i = 0; i < cd.contacts.size(); ++i) {
      const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
      const double fz = (c.frame * cd.lambda.segment<3>(3 * i)).z();
      (c.point.x() < 0.25 ? left : right) += fz;
    }
    // Each support carries a share: the tets' diagonal split makes box_mesh's beam not
    // mirror-symmetric (measured: 47% / 53%), and without friction in x the beam's
    // position along x is not unique. The moment balance about the y axis is exact:
    // f_int has no moment (rotation invariance), so sum_i (x_i f_z,i - z_i f_x,i) of the
    // contact forces plus gravity on the nodes vanishes to |r| max|x| <= the residual's
    // bound times the beam's length 0.5 m.
    EXPECT_GT(left, 0.4 * W);
    EXPECT_GT(right, 0.4 * W);
    const VecX f = nodal_contact_force(model, data) + model.fem.gravity_force;
    double moment = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i) moment += out.x[3 * i] * f[3 * i + 2] - out.x[3 * i + 2] * f[3 * i];
    EXPECT_NEAR(moment, 0, 0.5 * sum_bound(model, W));
    // Nothing sinks into a support (the gaps of the last contacts, to the NCP bound).
    const double allowed = model.contact.ncp.tolerance * cd.g.cwiseAbs().maxCoeff();
    for (int i = 0; i < cd.contacts.size(); ++i) {
      if (cd.modes[static_cast<std::size_t>(i)] != contact::Mode::breaking) {
        EXPECT_GE(cd.contacts.contacts[static_cast<std::size_t>(i)].gap, -allowed - 1e-12) << "contact " << i;
      }
    }
  }
}

// The shipped static scene against the dynamic one's settled state (the beam of
// configs/beam_supports.yaml, 1 s, at rest from 0.3 s): the midspan sag of the
// underside. Friction makes the rest state path-dependent: the dynamic beam slides
// outwards on the supports' inner edges while it sags and sticks where its motion
// stops; the static solve slides along its Newton iterates instead (friction acts on
// each iteration's increment) and sticks at convergence. Both lie between the sticking
// (1.1 mm) and frictionless (2.1 mm) sags of beam_supports.yaml's header; measured:
// 1.82 mm static, 1.99 mm dynamic. The documented tolerance (docs/method.md "Static
// equilibrium"): 0.25 mm, a quarter of that bracket. The total normal force is the
// weight in both.
double midspan_sag(const Model& model, const State& s) {
  double z = 0;
  int n = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (std::abs(model.fem.X(0, i)) < 1e-9 && model.fem.X(2, i) < 1e-9) {
      z += s.x[3 * i + 2] - model.fem.X(2, i);
      ++n;
    }
  EXPECT_GT(n, 0);
  return -z / n;
}

TEST(StaticContactValidation, ShippedStaticBeamMatchesTheSettledDynamicBeam) {
  const std::string root = SOFTDIFF_SOURCE_DIR;
  const Model stat = io::build_model(io::load_scene(root + "/configs/beam_supports_static.yaml"));
  Data ds(stat);
  State eq;
  const StepStatus st = integrator::solve_static(stat, ds, stat.initial, eq);
  ASSERT_TRUE(st.ok()) << describe(stat, st);
  Vec3 total;
  EXPECT_LE(residual(stat, ds, eq, &total), 2 * stat.step.static_tolerance);
  EXPECT_NEAR(total.z(), body_weight(stat), sum_bound(stat, body_weight(stat)));
  const double sag_static = midspan_sag(stat, eq);

  const Model dyn = io::build_model(io::load_scene(root + "/configs/beam_supports.yaml"));
  Data dd(dyn);
  State s = dyn.initial, next = dyn.initial;
  for (long k = 1; k <= dyn.step.steps; ++k) {
    const StepStatus sd = integrator::implicit_euler_step(dyn, dd, s, next, k);
    ASSERT_TRUE(sd.ok()) << describe(dyn, sd);
    std::swap(s, next);
  }
  const double sag_dynamic = midspan_sag(dyn, s);
  std::cout << "midspan sag: static " << sag_static * 1e3 << " mm, dynamic " << sag_dynamic * 1e3 << " mm\n";
  EXPECT_GT(sag_static, 1.1e-3);
  EXPECT_LT(sag_static, 2.1e-3);
  EXPECT_NEAR(sag_static, sag_dynamic, 0.25e-3);
}

// static.friction load_step (docs/method.md "Static equilibrium with contact",
// *Load-step-anchored friction*; 2026-12-04, branch sfric): a 0.1 m soft block (3 x 3 x 3
// boxes, E 1 MPa, nu 0 (with nu 0.3 the pressed bottom's Poisson spreading makes its rim
// slide outwards: measured, 5.4e-5 m), no gravity) on the rigid plane z = 0 (mu 0.5), its top face
// fixed at a prescribed displacement (shift, 0, -1 mm): pressed by 1% and pushed sideways.
// Closed forms of Coulomb's law on the load step's total slip:
//  - shift 0.1 mm (the shear it asks for, ~G A shift / H = 3.8 N, is ~4% of mu N with N
//    ~ E A 1% = 100 N: far inside the cone, the edge nodes' Poisson traction included):
//    every loaded contact sticks and its total slip is zero: each bottom node ends where
//    it started tangentially (to the NCP's accuracy on the slip, 1e-10 relative to |g| ~
//    the 1 mm press: asserted 1e-12 m);
//  - shift 5 mm (~190 N asked, above mu N): every loaded contact slides (the trailing row
//    lifts off), against its own total slip, the magnitudes of the tangential forces sum
//    to mu times the normal load (the sum of per-contact equalities on the cone), their
//    vector sum opposes the push, and the bottom has slid along +x.
// In both the force balance of the whole block holds: the fixed top's reaction balances
// the contact forces (residual checked as the other tests).
struct PressedBlock {
  Model model;
  explicit PressedBlock(double shift, StaticFriction friction) {
    test::BodySpec spec;
    spec.young = 1e6;
    spec.poisson = 0;  // no Poisson spreading of the pressed bottom: the press alone asks no friction
    spec.density = 1000;
    spec.fixed = [](const Vec3& p) { return p.z() > 0.1 - 1e-9; };
    model = test::make_model(test::box_mesh(3, 3, 3, 0.1, 0.1, 0.1), spec, Vec3::Zero());
    model.step.integrator = IntegratorKind::static_equilibrium;
    model.step.static_tolerance = 1e-10;
    model.step.static_max_iterations = 100;
    model.step.static_friction = friction;
    for (int i = 0; i < model.fem.num_nodes; ++i)
      if (model.fem.X(2, i) > 0.1 - 1e-9) model.initial.x.segment<3>(3 * i) += Vec3(shift, 0, -1e-3);
    test::ContactSpec cs;
    cs.mu = 0.5;
    cs.ncp.tolerance = 1e-10;
    cs.ncp.max_iterations = 5000;
    test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  }
};

TEST(StaticContactValidation, LoadStepFrictionPressedBlockSticksWithZeroSlip) {
  for (const auto friction : {StaticFriction::load_step, StaticFriction::iterate}) {
    const bool load_step = friction == StaticFriction::load_step;
    SCOPED_TRACE(load_step ? "load_step" : "iterate");
    PressedBlock b(1e-4, friction);
    const Model& model = b.model;
    Data data(model);
    State out;
    const StepStatus st = integrator::solve_static(model, data, model.initial, out);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    test::expect_valid_contact_solution(data, model.contact.ncp.tolerance, "stick", 1.0);
    const auto& cd = data.contact;
    int sticking = 0;
    double normal = 0, tangential = 0;
    for (int i = 0; i < cd.contacts.size(); ++i) {
      const Vec3 world = cd.contacts.contacts[static_cast<std::size_t>(i)].frame * cd.lambda.segment<3>(3 * i);
      normal += world.z();
      tangential += world.x();
      if (cd.modes[static_cast<std::size_t>(i)] == contact::Mode::breaking) continue;
      EXPECT_EQ(cd.modes[static_cast<std::size_t>(i)], contact::Mode::sticking) << "contact " << i;
      ++sticking;
    }
    EXPECT_EQ(sticking, 16);  // the 4 x 4 bottom nodes
    double slip = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i)
      if (model.fem.X(2, i) < 1e-9)
        slip = std::max(slip, (out.x.segment<2>(3 * i) - model.fem.X.col(i).head<2>()).norm());
    std::cout << "[ pressed block, shift 0.1 mm, " << (load_step ? "load_step" : "iterate") << " ] normal load "
              << normal << " N, tangential " << tangential << " N, largest slip of a bottom node " << slip
              << " m, " << st.iterations << " iterations\n";
    EXPECT_GT(normal, 50.0);
    EXPECT_LT(std::abs(tangential), 0.1 * 0.5 * normal);
    // load_step: zero total slip (the NCP's stick is on it). iterate: measured only.
    if (load_step) {
      EXPECT_LT(slip, 1e-12);
    }
  }
}

TEST(StaticContactValidation, LoadStepFrictionPressedBlockSlidesWithMuN) {
  PressedBlock b(5e-3, StaticFriction::load_step);
  const Model& model = b.model;
  Data data(model);
  State out;
  const StepStatus st = integrator::solve_static(model, data, model.initial, out);
  ASSERT_TRUE(st.ok()) << describe(model, st);
  test::expect_valid_contact_solution(data, model.contact.ncp.tolerance, "slide", 1.0);
  Vec3 total;
  EXPECT_LE(residual(model, data, out, &total), 2 * model.step.static_tolerance);
  const auto& cd = data.contact;
  const double scale = cd.lambda.cwiseAbs().maxCoeff();
  double normal = 0, tangential_x = 0, tangential_y = 0, tangential_magnitude = 0, worst_alignment = 1;
  int sliding = 0;
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
    const Vec3 l = cd.lambda.segment<3>(3 * i);
    const Vec3 world = c.frame * l;
    normal += world.z();
    tangential_x += world.x();
    tangential_y += world.y();
    tangential_magnitude += l.head<2>().norm();
    if (cd.modes[static_cast<std::size_t>(i)] == contact::Mode::breaking) continue;
    EXPECT_EQ(cd.modes[static_cast<std::size_t>(i)], contact::Mode::sliding) << "contact " << i;
    EXPECT_NEAR(l.head<2>().norm(), 0.5 * l[2], 1e-8 * scale) << "contact " << i;
    // The force opposes the node's total slip over the load step (from its start, the
    // initial state here: one load step): cos(lambda_T, -slip) = 1.
    ASSERT_EQ(c.count, 1);
    const Vec3 moved = out.x.segment<3>(3 * c.nodes[0]) - model.initial.x.segment<3>(3 * c.nodes[0]);
    const Eigen::Vector2d slip(c.frame.col(0).dot(moved), c.frame.col(1).dot(moved));
    worst_alignment = std::min(worst_alignment, -l.head<2>().dot(slip) / (l.head<2>().norm() * slip.norm()));
    ++sliding;
  }
  // The bottom's trailing row lifts off under the push's moment (4 breaking, measured).
  EXPECT_GE(sliding, 8);
  double mean_x = 0;
  int bottom = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (model.fem.X(2, i) < 1e-9) {
      mean_x += out.x[3 * i] - model.fem.X(0, i);
      ++bottom;
    }
  mean_x /= bottom;
  std::cout << "[ pressed block, shift 5 mm, load_step ] normal load " << normal << " N, tangential (" << tangential_x
            << ", " << tangential_y << ") N, mu N " << 0.5 * normal << " N; bottom slid by " << mean_x << " m, "
            << st.iterations << " iterations\n";
  std::cout << "  sum |lambda_T| " << tangential_magnitude << " N; worst cos(lambda_T, -total slip) "
            << worst_alignment << "\n";
  // Coulomb on the cone: the tangential forces' magnitudes sum to mu N (the sum of the
  // per-contact equalities), each against its total slip (to the NCP's accuracy:
  // 1e-8 asserted on the cosine); their vector sum is at most mu N, along -x up to the
  // slips' spread about x (the mesh's tetrahedra are not symmetric in y: measured
  // (-50.7496, -0.3648) N against mu N 50.7509 N).
  EXPECT_NEAR(tangential_magnitude, 0.5 * normal, 1e-8 * scale * cd.contacts.size());
  EXPECT_GT(worst_alignment, 1 - 1e-8);
  EXPECT_LE(std::hypot(tangential_x, tangential_y), 0.5 * normal * (1 + 1e-8));
  EXPECT_GT(-tangential_x, 0.99 * 0.5 * normal);
  EXPECT_GT(mean_x, 1e-3);
}

}  // namespace static_contact_validation
