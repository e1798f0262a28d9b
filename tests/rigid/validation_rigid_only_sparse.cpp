// Scenes of rigid bodies only on the sparse backend (issue 21, rmend item 5; docs/method.md
// "Scenes of rigid bodies only"): the contact operator with the rigid rows alone (no soft
// dof, so no factor and no solve: SparseDelassus's soft part is empty, G = h Kt^T Kt),
// against the closed forms of validation_rigid_only.cpp and against the dense backend's
// run of the same scene (run build/tests/validation_rigid --gtest_filter='RigidOnlySparse*').
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <iomanip>
#include <iostream>

using namespace softdiff;

namespace rigid_only_sparse_validation {

constexpr double g0 = 9.81;

// validation_rigid_only.cpp's StackedBoxesCarryTheWeightAbove: a 0.2 x 0.2 x 0.1 m base on
// a plane and a 0.08 x 0.08 x 0.06 m box released 0.1 mm above it, off-centre; and, with
// `limited`, a bar on a limited hinge beside them (test_rigid_contact.cpp's kind: its
// lower limit is a row of the NCP, a column of the operator's rigid rows without soft dof).
Model stack(contact::NcpBackend backend, bool limited, double h = 2e-3) {
  Model model = test::rigid_scenes::rigid_only_model(h, g0);
  rigid::RigidState s;
  s.position = Vec3(0, 0, 0.05);
  test::add_rigid_body(model, "base", test::box_shape(Vec3(0.1, 0.1, 0.05)), 500, s, 0.2);
  s.position = Vec3(0.02, -0.01, 0.1 + 0.03 + 1e-4);
  test::add_rigid_body(model, "top", test::box_shape(Vec3(0.04, 0.04, 0.03)), 500, s, 0.2);
  std::vector<test::NamedPair> pairs{{"base", "floor", 0.5}, {"base", "top", 0.5}};
  if (limited) {
    // A bar (0.2 x 0.04 x 0.02 m) hinged about y at its left end, 0.5 m away, released
    // level: gravity turns it about +y (its free end down) onto its upper limit 0.05 rad.
    rigid::RigidState bar;
    bar.position = Vec3(0.6, 0, 0.3);
    test::add_rigid_body(model, "bar", test::box_shape(Vec3(0.1, 0.02, 0.01)), 800, bar, 0.05,
                         rigid::Joint::Kind::hinge);
    auto& b = model.rigid.back();
    b.joint.anchor = Vec3(0.5, 0, 0.3);
    b.joint.axis = Vec3::UnitY();
    b.joint.limits = std::make_pair(-0.05, 0.05);
    rigid::initialize(b, bar);
    model.initial.rigid.back() = b.reference;
  }
  auto ncp = test::rigid_scenes::tight_ncp(1e-10);
  ncp.backend = backend;
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0)}, pairs, 1e-3, ncp);
  return model;
}

State run(const Model& model, Data& data, long steps, bool sparse) {
  State a = model.initial, b;
  for (long n = 1; n <= steps; ++n) {
    const StepStatus st = integrator::time_step(model, data, a, nullptr, b, n);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    if (!st.ok()) break;
    EXPECT_TRUE(data.contact.result.converged) << "step " << n;
    if (data.contact.contacts.size() > 0) {
      EXPECT_EQ(data.contact.result.sparse, sparse) << "step " << n;
    }
    std::swap(a, b);
  }
  return a;
}

// The stack on the operator: at rest after 250 steps with the closed forms of the dense
// test (the top box carries its weight, the base's net contact force is its own weight,
// 1e-8 relative: the NCP's tolerance 1e-10 on forces of ~10 N), nothing factorized, and
// the final poses those of the dense backend's run to 1e-9 m (both solve each step's NCP
// to 1e-10 m/s; h = 2 ms: 2e-13 m per step, and the stack is at rest).
TEST(RigidOnlySparse, StackedBoxesMatchTheClosedFormsAndTheDenseBackend) {
  const Model sparse = stack(contact::NcpBackend::sparse, false), dense = stack(contact::NcpBackend::dense, false);
  Data ds(sparse), dd(dense);
  const State es = run(sparse, ds, 250, true), ed = run(dense, dd, 250, false);
  const double w_base = sparse.rigid[0].mass * g0, w_top = sparse.rigid[1].mass * g0;
  const Vec3 on_top = test::rigid_scenes::contact_force_on(ds, 1), on_base = test::rigid_scenes::contact_force_on(ds, 0);
  std::cout << "[rigid only, sparse] stack: force on top " << on_top.transpose() << " N (weight " << w_top
            << "), on base " << on_base.transpose() << " N (weight " << w_base << "), top at "
            << es.rigid[1].position.transpose() << " (dense: " << ed.rigid[1].position.transpose() << ")\n";
  EXPECT_EQ(ds.factorizations, 0);
  EXPECT_NEAR(on_top.z(), w_top, 1e-8 * w_top);
  EXPECT_LT(on_top.head<2>().norm(), 1e-8 * w_top);
  EXPECT_NEAR(on_base.z(), w_base, 1e-8 * (w_base + w_top));
  for (std::size_t r = 0; r < 2; ++r) {
    EXPECT_LT((es.rigid[r].position - ed.rigid[r].position).norm(), 1e-9) << r;
    EXPECT_LT(es.rigid[r].velocity.norm(), 1e-9) << r;
    EXPECT_LT(es.rigid[r].angular_velocity.norm(), 1e-9) << r;
  }
  EXPECT_NEAR(es.rigid[1].position.z(), 0.13, 1e-11);
}

// The limit's reaction of a hinge resting on its limit, in closed form (issue 21, ronly;
// rbranch; docs/method.md "Scenes of rigid bodies only", "The hinge's limit reaction").
// The free step (rigid::step, limits off) is implicit in the gravity torque
// Q(c) = m g l cos(c): from rest at the limit c_lim it goes on to c_lim + d, d the root of
// I_a d / h^2 = Q(c_lim + d). The limit's row then stops that rate d / h with the joint's
// effective inertia I_a - h^2 Q'(c_lim + d) (W_r = T T^T / (I_a - h^2 Q'), the tangent of
// the implicit step at the free end, rigid_contact.cpp begin_rigid_contact):
// lambda = (I_a - h^2 Q') d / h^2 = Q(c_lim + d) - Q'(c_lim + d) d = Q(c_lim) - Q'' d^2 / 2
// + O(d^3): m g l cos(c_lim) (1 + d^2 / 2) to second order (Q'' = -Q), d ~ h^2 Q / I_a.
// (With W_r = T T^T / I_a, before 2026-12-03 rbranch: Q(c_lim + d), an O(h^2) offset.)
// The free step's overshoot d past the limit.
double overshoot(const rigid::RigidBody& bar, double c_lim, double l, double h) {
  const double I_a = bar.inertia(1, 1) + bar.mass * l * l;  // about y through the anchor (y is a principal axis)
  double d = 0;
  for (int it = 0; it < 50; ++it) d = h * h * bar.mass * g0 * l * std::cos(c_lim + d) / I_a;  // a contraction (1e-5)
  return d;
}
double limit_reaction_closed_form(const rigid::RigidBody& bar, double c_lim, double l, double h) {
  const double d = overshoot(bar, c_lim, l, h);
  return bar.mass * g0 * l * (std::cos(c_lim + d) + std::sin(c_lim + d) * d);
}

// With a limited hinge beside the stack: the bar falls onto its upper limit (a row of the
// operator without soft dof) and rests there; the limit's reaction is the same as on the
// dense backend (1e-8 relative) and is the closed form above (1e-9 relative: the NCP's
// tolerance 1e-10 on a row of ~0.1 N m, polished to round-off).
TEST(RigidOnlySparse, LimitedHingeRestsOnItsLimit) {
  const Model sparse = stack(contact::NcpBackend::sparse, true), dense = stack(contact::NcpBackend::dense, true);
  Data ds(sparse), dd(dense);
  const State es = run(sparse, ds, 400, true), ed = run(dense, dd, 400, false);
  const auto& bar = sparse.rigid[2];
  const double angle = rigid::joint_coordinate(bar, es.rigid[2]);
  const double torque = bar.mass * g0 * 0.1 * std::cos(0.05);
  ASSERT_EQ(ds.contact.rigid.limit_lambda.size(), 2);
  std::cout << "[rigid only, sparse] hinge: angle " << angle << " rad (dense "
            << rigid::joint_coordinate(bar, ed.rigid[2]) << "), limit reaction " << ds.contact.rigid.limit_lambda[1]
            << " N m (m g l cos: " << torque << "; dense " << dd.contact.rigid.limit_lambda[1] << ")\n";
  EXPECT_NEAR(angle, 0.05, 1e-9);
  // The operator against the dense backend: the same limit reaction to 1e-8. Both are
  // the closed form above, O(d^2) from m g l cos(0.05) (before rbranch 1.5e-5 relative below it).
  EXPECT_NEAR(ds.contact.rigid.limit_lambda[1], dd.contact.rigid.limit_lambda[1], 1e-8 * torque);
  const double closed = limit_reaction_closed_form(bar, 0.05, 0.1, sparse.step.dt);
  EXPECT_NEAR(ds.contact.rigid.limit_lambda[1], closed, 1e-9 * torque);
  EXPECT_NEAR(dd.contact.rigid.limit_lambda[1], closed, 1e-9 * torque);
  EXPECT_EQ(ds.contact.rigid.limit_lambda[0], 0);
  EXPECT_EQ(ds.factorizations, 0);
}

// The reaction's offset from m g l cos(c_lim) at h = 2 ms and 1 ms (dense backend): the
// closed form to 1e-9 relative at each, and the offset O(h^4): d^2 / 2 with d the free
// step's overshoot (about 4.3e-8 and 2.7e-9 relative here), their ratio 16; both to 1e-2
// relative (the next order, -Q''' d^3 / 3 = -tan(c_lim) d^3 / 3 relative, adds
// -2 tan(c_lim) d / 3 = 1e-5 of the offset at 2 ms). Before W_r took the gravity
// torque's tangent (rbranch) the offset was -tan(c_lim) d: -1.47e-5 and -3.67e-6.
TEST(RigidOnlySparse, LimitReactionOffsetIsSecondOrderInTheOvershoot) {
  double offset[2];
  for (int k = 0; k < 2; ++k) {
    const double h = k == 0 ? 2e-3 : 1e-3;
    const Model model = stack(contact::NcpBackend::dense, true, h);
    Data data(model);
    const State end = run(model, data, k == 0 ? 400 : 800, false);
    const auto& bar = model.rigid[2];
    ASSERT_NEAR(rigid::joint_coordinate(bar, end.rigid[2]), 0.05, 1e-9);
    ASSERT_EQ(data.contact.rigid.limit_lambda.size(), 2);
    const double lambda = data.contact.rigid.limit_lambda[1], torque = bar.mass * g0 * 0.1 * std::cos(0.05);
    const double closed = limit_reaction_closed_form(bar, 0.05, 0.1, h), d = overshoot(bar, 0.05, 0.1, h);
    offset[k] = (lambda - torque) / torque;
    std::cout << "[rigid only] hinge on its limit, h " << h << ": reaction " << std::setprecision(12) << lambda
              << " N m, m g l cos " << torque << ", closed form " << closed << std::setprecision(6) << "; offset "
              << offset[k] << " relative (d^2 / 2 = " << d * d / 2 << ", d = " << d << " rad)\n";
    EXPECT_NEAR(lambda, closed, 1e-9 * torque);
    EXPECT_NEAR(offset[k], d * d / 2, 1e-2 * std::abs(offset[k]));
  }
  EXPECT_NEAR(offset[0] / offset[1], 16.0, 16e-2);
}

}  // namespace rigid_only_sparse_validation
