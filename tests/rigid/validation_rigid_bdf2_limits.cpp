// BDF2 with a limited joint in contact (issue 21, rbdlim; integrator/bdf2.cpp
// time_step_rigid_contact_limits; docs/method.md "BDF2 with rigid bodies", *Limits in
// contact*): a step after a step that ended at a limit, a step whose BDF2 free end reaches
// a limit and a BDF2 step whose contact solve has an active limit row are the implicit
// Euler contact step of size h from s_n. Run build/tests/validation_rigid
// --gtest_filter='RigidBdf2Limits*' (dense and sparse backends):
//  - validation_rigid_contact.cpp's limits carrying contact loads under BDF2: a soft pad on
//    a bar held by its upper limit (moment balance about the hinge) and a pad on a block
//    resting on its slider's lower limit ((m_block + m_pad) g); every step after the first
//    restarts, so the BDF2 run is the implicit Euler run (compared state by state);
//  - a bar turning under gravity onto its limit beside a wedge sliding on a plane (the
//    NCP runs all along): its angle, step by step, is the no-contact BDF2 run's (the
//    restart of rigid/rigid_bdf2.hpp), it lands at the same step and stays on the limit:
//    no spurious bounce; the same scene without its soft anchor (rigid bodies only) too;
//  - a box on a centre-hinged bar (rigid bodies only): on the limit, a BDF2 step whose
//    free end stays short of the limit has an active limit row (the box pushes) and is
//    redone as implicit Euler (equal to the implicit Euler step); landings driven by the
//    box alone rest on the limit with the reaction equal to the box's moment.
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

using namespace softdiff;

namespace rigid_bdf2_limits_validation {

constexpr double g0 = 9.81;

class RigidBdf2Limits : public ::testing::TestWithParam<contact::NcpBackend> {
 protected:
  const char* backend() const { return GetParam() == contact::NcpBackend::sparse ? "sparse" : "dense"; }
};

// Steps from model.initial with the model's integrator (BDF2: the previous state passed),
// asserting every step ok and every contact solve converged; `each(n, data, state)` after
// every step.
template <class Each>
State run(const Model& model, Data& data, long steps, Each each) {
  State previous, a = model.initial, b;
  for (long n = 1; n <= steps; ++n) {
    const StepStatus st = integrator::time_step(model, data, a, n == 1 ? nullptr : &previous, b, n);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    if (!st.ok()) break;
    if (data.contact.contacts.size() > 0) {
      EXPECT_TRUE(data.contact.result.converged) << "step " << n;
    }
    previous = a;
    std::swap(a, b);
    each(n, data, a);
  }
  return a;
}

// The scene of validation_rigid_contact.cpp's LimitsCarryContactLoadsExactly (upper 0, the
// pads on the bar and on the block), on `backend`, with `integrator`.
Model pads_on_limits(contact::NcpBackend backend, IntegratorKind integrator) {
  const double h = 1e-3;
  test::BodySpec spec;
  spec.young = 1e5;
  spec.density = 1000;
  spec.rayleigh_mass = 20;
  spec.rayleigh_stiffness = 0.005;
  mesh::TetMesh pad_a = test::box_mesh(2, 2, 1, 0.04, 0.04, 0.02), pad_b = pad_a;
  for (Eigen::Index i = 0; i < pad_a.X.cols(); ++i) {
    pad_a.X.col(i) += Vec3(0.13, -0.02, 0.02);  // on the bar's top (z = 0.02), centre x = 0.15
    pad_b.X.col(i) += Vec3(0.98, -0.02, 0.04);  // on the slider block's top (z = 0.04)
  }
  Model model = test::make_model({{pad_a, spec, "pad_a"}, {pad_b, spec, "pad_b"}}, Vec3(0, 0, -g0), h);
  test::rigid_scenes::add_limited_bar_and_block(model, 0.0, 0.01);
  contact::NcpOptions ncp;  // the default tolerance 1e-8, as the implicit Euler test
  ncp.backend = backend;
  test::enable_rigid_contact(model, {}, {{"pad_b", "block", 0.5}, {"pad_a", "bar", 0.5}}, 1e-3, ncp);
  model.step.integrator = integrator;
  return model;
}

// Closed forms as the implicit Euler test's (validation_rigid_contact.cpp): at rest the
// upper limit's reaction of the bar (N m about y) is m_bar g 0.1 cos(angle) plus the pad's
// contact moments about the hinge, the slider's lower limit carries (m_block + m_pad) g,
// the pad on the bar weighs on it. Tolerances: the NCP tolerance 1e-8 (scaled) on forces
// of ~0.3 N; the pads at rest to their damping's decay after 0.4 s. Then the BDF2 run is
// the implicit Euler run: every step after the first restarts (both bodies rest on a
// limit), and the restart is the implicit Euler contact step itself, so the states agree
// to round-off (measured: 0; asserted 1e-14 of the 2 cm pads' coordinates and velocities).
TEST_P(RigidBdf2Limits, LimitsCarryContactLoadsAndAgreeWithImplicitEuler) {
  const long steps = 400;
  const Model model = pads_on_limits(GetParam(), IntegratorKind::bdf2);
  const Model euler = pads_on_limits(GetParam(), IntegratorKind::implicit_euler);
  Data data(model), data_e(euler);
  long bdf2_steps = 0;
  const State end = run(model, data, steps, [&](long, const Data& d, const State&) { bdf2_steps += d.history_weight != 0; });
  const State end_e = run(euler, data_e, steps, [](long, const Data&, const State&) {});
  EXPECT_EQ(bdf2_steps, 0);  // every step restarted (the bodies rest on their limits)
  const double pad_mass = model.fem.mass_diagonal.sum() / 6.0;  // two equal pads, 3 dofs a node
  const int bar_side = 2, block_side = 3;  // names: pad_a, pad_b, bar, block
  double moment = 0, on_bar = 0, on_block = 0;
  for (int i = 0; i < data.contact.contacts.size(); ++i) {
    const auto& c = data.contact.contacts.contacts[static_cast<std::size_t>(i)];
    Vec3 f = c.frame * data.contact.lambda.segment<3>(3 * i);  // on side a
    int side = c.side_a;
    if (c.side_b == bar_side || c.side_b == block_side) f = -f, side = c.side_b;
    if (side == bar_side) {
      moment += (c.point - model.rigid[0].joint.anchor).cross(f).y();
      on_bar += f.z();
    } else if (side == block_side) {
      on_block += f.z();
    }
  }
  const auto& rd = data.contact.rigid;
  ASSERT_EQ(rd.limit_lambda.size(), 4);
  const double m_bar = model.rigid[0].mass, m_block = model.rigid[1].mass;
  const double angle = rigid::joint_coordinate(model.rigid[0], end.rigid[0]);
  const double q_bar = m_bar * g0 * 0.1 * std::cos(angle) + moment;
  const double dx = (end.x - end_e.x).cwiseAbs().maxCoeff(), dv = (end.v - end_e.v).cwiseAbs().maxCoeff();
  double drigid = 0;
  for (int r = 0; r < 2; ++r)
    drigid = std::max(drigid, rigid::tangent_between(end_e.rigid[r], end.rigid[r]).cwiseAbs().maxCoeff());
  std::cout << backend() << ": bdf2, limits in contact: bar limit reaction " << rd.limit_lambda[1] << " N m (moments "
            << q_bar << "), slider limit " << rd.limit_lambda[2] << " N ((m_block + m_pad) g = "
            << (m_block + pad_mass) * g0 << "); BDF2 - implicit Euler: x " << dx << ", v " << dv << ", rigid " << drigid
            << "\n";
  EXPECT_NEAR(-on_bar, pad_mass * g0, 1e-5 * pad_mass * g0);
  EXPECT_NEAR(rd.limit_lambda[1], q_bar, 1e-5 * q_bar);
  EXPECT_NEAR(rd.limit_lambda[0], 0, 1e-12);
  EXPECT_NEAR(angle, 0.0, 1e-9);
  EXPECT_LT(end.rigid[0].angular_velocity.norm(), 1e-8);
  EXPECT_NEAR(-on_block, pad_mass * g0, 1e-5 * pad_mass * g0);
  EXPECT_NEAR(rd.limit_lambda[2], (m_block + pad_mass) * g0, 1e-5 * (m_block + pad_mass) * g0);
  EXPECT_NEAR(rd.limit_lambda[3], 0, 1e-12);
  EXPECT_LT(std::abs(rigid::joint_coordinate(model.rigid[1], end.rigid[1])), 1e-9);
  EXPECT_LE(dx, 1e-14 * 0.02);
  EXPECT_LE(dv, 1e-14);
  EXPECT_LE(drigid, 1e-14);
}

// The bar (rigid_scenes.hpp bar_onto_its_limit_beside_a_wedge) turns from rest at angle 0
// under gravity onto its upper limit 0.02 (in ~23 steps of 1 ms) while the wedge slides
// on the floor (three contacts: the NCP runs every step, the limit rows join it near the
// limit). Reference: the same bar without contact (contact disabled: rigid::bdf2_step
// with its restart). Before the landing both are BDF2 steps (the limit rows inactive), the
// landing step and the steps resting on the limit implicit Euler: the angles agree to the
// NCP's tolerance (1e-12 scaled; measured below 1e-15 rad), and after the landing the bar
// stays on the limit (1e-12 rad) with rate 0 (1e-9 rad/s): no bounce. Without the restart
// the BDF2 velocity at the landing, (limit - c^) / h', points away from the limit when the
// bar arrives early in the step (docs/method.md "BDF2 with rigid bodies"). The scene of
// rigid bodies only (no soft anchor) gives the same angles and branches.
TEST_P(RigidBdf2Limits, BarArrivingAtItsLimitInContactDoesNotBounce) {
  const long steps = 60;
  const double upper = 0.02;
  contact::NcpOptions ncp = test::rigid_scenes::tight_ncp(1e-12);
  ncp.backend = GetParam();
  const Model model = test::rigid_scenes::bar_onto_its_limit_beside_a_wedge(1e-3, 0.0, upper, ncp);
  Model alone = model;
  alone.contact.enabled = false;
  // The same scene without the soft anchor: a scene of rigid bodies only takes the same
  // path (bdf2.cpp time_step_rigid_only in the restart's attempts).
  const Model rigid_only = test::rigid_scenes::bar_onto_its_limit_beside_a_wedge(1e-3, 0.0, upper, ncp, true);
  ASSERT_EQ(rigid_only.fem.num_nodes, 0);
  Data data(model), data_a(alone), data_r(rigid_only);
  std::vector<double> angle, rate, angle_a, angle_r;
  long bdf2_r = 0;
  run(rigid_only, data_r, steps, [&](long, const Data& d, const State& s) {
    angle_r.push_back(rigid::joint_coordinate(rigid_only.rigid[0], s.rigid[0]));
    bdf2_r += d.history_weight != 0;
  });
  std::vector<char> bdf2;
  run(model, data, steps, [&](long, const Data& d, const State& s) {
    angle.push_back(rigid::joint_coordinate(model.rigid[0], s.rigid[0]));
    rate.push_back(model.rigid[0].joint.axis.dot(s.rigid[0].angular_velocity));
    bdf2.push_back(d.history_weight != 0);
    EXPECT_GT(d.contact.contacts.size(), 0);
  });
  run(alone, data_a, steps, [&](long, const Data&, const State& s) {
    angle_a.push_back(rigid::joint_coordinate(alone.rigid[0], s.rigid[0]));
  });
  ASSERT_EQ(angle.size(), static_cast<std::size_t>(steps));
  ASSERT_EQ(angle_a.size(), static_cast<std::size_t>(steps));
  ASSERT_EQ(angle_r.size(), static_cast<std::size_t>(steps));
  long landing = -1, bdf2_before = 0, bdf2_after = 0;
  double diff = 0, off_limit = 0, moving = 0;
  for (long n = 0; n < steps; ++n) {
    const auto k = static_cast<std::size_t>(n);
    diff = std::max({diff, std::abs(angle[k] - angle_a[k]), std::abs(angle_r[k] - angle_a[k])});
    if (landing < 0 && angle[k] >= upper - 1e-12) landing = n;
    if (landing < 0) bdf2_before += bdf2[k];
    if (landing >= 0) {
      bdf2_after += bdf2[k];
      off_limit = std::max(off_limit, upper - angle[k]);
      if (n > landing) moving = std::max(moving, std::abs(rate[k]));
    }
  }
  std::cout << backend() << ": bar onto its limit in contact: lands at step " << landing + 1 << " (" << bdf2_before
            << " BDF2 steps before, " << bdf2_after << " after), |angle - no-contact angle| <= " << diff
            << " rad, off the limit after landing " << off_limit << " rad, rate after landing " << moving
            << " rad/s\n";
  ASSERT_GT(landing, 5);
  EXPECT_LT(landing, steps - 20);
  EXPECT_EQ(bdf2_before, landing - 1);  // the first step implicit Euler, then BDF2 until the landing step
  EXPECT_EQ(bdf2_after, 0);             // the landing and the rest restart
  EXPECT_EQ(bdf2_r, bdf2_before);       // the scene of rigid bodies only: the same branches
  EXPECT_LT(diff, 1e-12);
  EXPECT_LT(off_limit, 1e-12);
  EXPECT_LT(moving, 1e-9);
}

// A bar (0.2 x 0.04 x 0.02 m, 800 kg/m^3) hinged about y at its centre (gravity has no
// moment about the hinge), limits [-0.1, 0], from rest at angle `start` <= 0 (its right
// end raised), and a free box (20 mm, 500 kg/m^3) resting on its right half (centre
// 0.05 m from the hinge, tilted with the bar), mu 0.5; rigid bodies only, dense NCP at
// 1e-10. Bodies: 0 the bar, 1 the box.
Model bar_and_box(double start, IntegratorKind integrator) {
  Model model = test::rigid_scenes::rigid_only_model(1e-3, g0);
  rigid::RigidState bar;
  bar.position = Vec3(0.1, 0, 0.01);
  test::add_rigid_body(model, "bar", test::box_shape(Vec3(0.1, 0.02, 0.01)), 800, bar, 0.06, rigid::Joint::Kind::hinge);
  model.rigid[0].joint.anchor = bar.position;
  model.rigid[0].joint.axis = Vec3::UnitY();
  model.rigid[0].joint.limits = std::make_pair(-0.1, 0.0);
  rigid::initialize(model.rigid[0], bar);
  rigid::move_along_joint(model.rigid[0], model.rigid[0].reference, start, 1.0, model.initial.rigid[0]);
  model.initial.rigid[0].velocity.setZero();
  model.initial.rigid[0].angular_velocity.setZero();
  const Eigen::Quaterniond tilt(Eigen::AngleAxisd(start, Vec3::UnitY()));
  rigid::RigidState box;
  box.orientation = tilt;
  box.position = bar.position + tilt * Vec3(0.05, 0, 0.01 + 0.01);
  test::add_rigid_body(model, "box", test::box_shape(Vec3(0.01, 0.01, 0.01)), 500, box);
  test::enable_rigid_contact(model, {}, {{"box", "bar", 0.5}}, 1e-3, test::rigid_scenes::tight_ncp(1e-10));
  model.step.integrator = integrator;
  return model;
}

// The third branch: a limit row made active by a contact while the body's own BDF2 free
// end stays short of the limit. The bar on its limit (start 0) under the box, at rest, a
// BDF2 step with previous = in and no restart flag (a fresh Data): the bar's free step
// (no torque, rate 0) stays at the limit without passing it (rigid::step's clamp is strict),
// the box's weight pushes the bar onto it through the contacts: the BDF2 attempt's limit
// row is active, so the step is redone as the implicit Euler contact step from s_n. Its
// record says so (history_weight 0, h), its end is the implicit Euler model's step from
// the same state (to the NCP's tolerance 1e-10 on forces ~0.04 N: the redo warm-starts
// from the attempt's forces, the implicit Euler step from zero; 1e-12 asserted on the
// states, whose velocities are ~h g = 1e-2), and the limit carries the box's moment.
TEST(RigidBdf2LimitsActiveRow, ContactPushesTheBarOntoItsLimit) {
  const Model model = bar_and_box(0.0, IntegratorKind::bdf2), euler = bar_and_box(0.0, IntegratorKind::implicit_euler);
  const State in = model.initial;
  rigid::RigidState hat, free;
  double h_used = 0;
  rigid::bdf2_step(model.rigid[0], in.rigid[0], &in.rigid[0], 1e-3, model.step.gravity, Vec3::Zero(), Vec3::Zero(), hat,
                   free, true, false, &h_used);
  EXPECT_LT(h_used, 1e-3);  // the bar's BDF2 free end does not reach past the limit
  Data data(model), data_e(euler);
  State out, out_e;
  ASSERT_TRUE(integrator::time_step(model, data, in, &in, out, 2).ok());
  ASSERT_TRUE(integrator::time_step(euler, data_e, in, nullptr, out_e, 1).ok());
  EXPECT_EQ(data.history_weight, 0.0);
  EXPECT_EQ(data.h, 1e-3);
  EXPECT_TRUE(data.rigid[0].at_limit);
  double d = 0;
  for (int r = 0; r < 2; ++r) d = std::max(d, rigid::tangent_between(out_e.rigid[r], out.rigid[r]).cwiseAbs().maxCoeff());
  std::cout << "active limit row: limit force " << data.contact.rigid.limit_lambda[1] << " N m, BDF2 step - implicit Euler step "
            << d << "\n";
  EXPECT_GT(data.contact.rigid.limit_lambda[1], 0);
  EXPECT_LE(d, 1e-12);
}

// Landings driven by the contacts alone: the bar of bar_and_box from 12 starts, -4 to
// -48 urad (landing by step 2 to 6), BDF2. For every start: at rest after 300 steps
// (1 ms) the bar on its limit (1e-9 rad, the NCP's tolerance 1e-10 scaled), its limit
// reaction the box's contact moment about the hinge (1e-6 relative), the box's contact
// forces its weight (1e-6), the last 100 steps all restarts; never past the limit.
TEST(RigidBdf2LimitsActiveRow, BarTurnedOntoItsLimitByABox) {
  for (int k = 0; k < 12; ++k) {
    const double start = -4e-6 * (k + 1);
    SCOPED_TRACE("start " + std::to_string(start));
    const Model model = bar_and_box(start, IntegratorKind::bdf2);
    Data data(model);
    const rigid::RigidBody& b = model.rigid[0];
    const long steps = 300;
    long bdf2_last = 0;
    double past = 0;
    State previous, a = model.initial, out;
    for (long n = 1; n <= steps; ++n) {
      const StepStatus st = integrator::time_step(model, data, a, n == 1 ? nullptr : &previous, out, n);
      ASSERT_TRUE(st.ok()) << describe(model, st);
      ASSERT_TRUE(data.contact.result.converged) << "step " << n;
      if (n > steps - 100) bdf2_last += data.history_weight != 0;
      previous = a;
      std::swap(a, out);
      past = std::max(past, rigid::joint_coordinate(b, a.rigid[0]));
    }
    double moment = 0, on_box = 0;
    for (int i = 0; i < data.contact.contacts.size(); ++i) {
      const auto& c = data.contact.contacts.contacts[static_cast<std::size_t>(i)];
      Vec3 f = c.frame * data.contact.lambda.segment<3>(3 * i);  // on side a
      if (c.side_a != 0) f = -f;                                 // on the bar (names: bar 0, box 1)
      moment += (c.point - b.joint.anchor).cross(f).y();
      on_box -= f.z();
    }
    const double reaction = data.contact.rigid.limit_lambda[1], weight = model.rigid[1].mass * g0;
    std::cout << "start " << start << ": angle " << rigid::joint_coordinate(b, a.rigid[0]) << ", limit reaction "
              << reaction << " N m (box moment " << moment << "), box support " << on_box << " N (weight " << weight
              << ")\n";
    EXPECT_NEAR(rigid::joint_coordinate(b, a.rigid[0]), 0.0, 1e-9);
    EXPECT_LT(past, 1e-9);
    EXPECT_NEAR(reaction, moment, 1e-6 * std::abs(moment));
    EXPECT_NEAR(on_box, weight, 1e-6 * weight);
    EXPECT_EQ(bdf2_last, 0);
  }
}

INSTANTIATE_TEST_SUITE_P(, RigidBdf2Limits, ::testing::Values(contact::NcpBackend::dense, contact::NcpBackend::sparse),
                         [](const ::testing::TestParamInfo<contact::NcpBackend>& p) {
                           return p.param == contact::NcpBackend::sparse ? "sparse" : "dense";
                         });

}  // namespace rigid_bdf2_limits_validation
