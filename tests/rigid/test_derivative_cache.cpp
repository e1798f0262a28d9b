// The rigid contact maps of a step's derivative are prepared once per step (issue 21
// review, rmend item 2): contact::RigidContactDerivative::prepare (with a limited joint in
// the NCP, prepare_limits, which rebuilds the extended dense G) runs on the first jvp or
// vjp of a step and is reused by every further column of that step
// (integrator::StepDerivatives::prepare_rigid's cache key: the contact record's serial
// number ContactData::serial, a new one each time the contact stage writes the record;
// an O(1) test, 2026-12-03 review mend), and runs again for the next step. The reused
// maps give the same columns to the bit.
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;

namespace rigid_derivative_cache_test {

// The slider block of test_cli_rigid_derivatives.cpp's CheckGradThroughAJointLimitInContact
// (0.04 x 0.04 x 0.02 m, 1000 kg/m^3, limits [-0.01, 0.05] along z) beside the fixed soft
// anchor: it falls onto its lower limit 0.2 mm above the floor (within the 1 mm margin), so
// that the NCP holds the floor's contacts and the limit's row.
Model slider_over_floor() {
  Model model = test::rigid_scenes::anchored(0.01);
  rigid::RigidState s;
  s.position = Vec3(0.5, 0.3, 0);
  test::add_rigid_body(model, "block", test::box_shape(Vec3(0.02, 0.02, 0.01)), 1000, s, 0.01,
                       rigid::Joint::Kind::slider);
  model.rigid[0].joint.anchor = s.position;
  model.rigid[0].joint.axis = Vec3::UnitZ();
  model.rigid[0].joint.limits = std::make_pair(-0.01, 0.05);
  rigid::initialize(model.rigid[0], s);
  model.initial.rigid[0] = model.rigid[0].reference;
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), -0.0202)}, {{"block", "floor", 0.3}}, 1e-3,
                             test::rigid_scenes::tight_ncp(1e-12));
  model.contact.ncp.backend = contact::NcpBackend::dense;
  return model;
}

integrator::StepTangent random_tangent(const Model& model, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> N;
  const Eigen::Index n3 = 3L * model.fem.num_nodes;
  integrator::StepTangent t;
  t.x = VecX::NullaryExpr(n3, [&] { return N(rng); });
  t.v = VecX::NullaryExpr(n3, [&] { return N(rng); });
  t.rigid = VecX::NullaryExpr(12, [&] { return N(rng); });
  t.rigid_p = VecX::NullaryExpr(7, [&] { return N(rng); });
  return t;
}

TEST(RigidContactStepDerivatives, RigidMapsPreparedOncePerStepWithALimitInContact) {
  const Model model = slider_over_floor();
  Data data(model);
  State a = model.initial, b;
  for (long k = 1; k <= 10; ++k) {
    const StepStatus st = integrator::time_step(model, data, a, nullptr, b, k);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    if (k < 10) std::swap(a, b);
  }
  // The step a -> b: floor contacts and the lower limit's row, active, in its NCP.
  ASSERT_GT(data.contact.contacts.size(), 0);
  ASSERT_EQ(data.contact.rigid.limit_lambda.size(), 2);
  ASSERT_GT(data.contact.rigid.limit_lambda[0], 0);

  integrator::StepDerivatives D(model, {});
  EXPECT_EQ(D.rigid_prepare_count(), 0);
  integrator::StateTangent first, other, again;
  ASSERT_TRUE(D.jvp(model, data, a, b, random_tangent(model, 1), first));
  EXPECT_EQ(D.rigid_prepare_count(), 1);
  for (unsigned seed = 2; seed <= 4; ++seed) ASSERT_TRUE(D.jvp(model, data, a, b, random_tangent(model, seed), other));
  integrator::StateTangent bar;
  bar.x = random_tangent(model, 7).x;
  bar.v = random_tangent(model, 8).v;
  bar.rigid = random_tangent(model, 9).rigid;
  integrator::StepCotangent cot;
  ASSERT_TRUE(D.vjp(model, data, a, b, bar, cot));
  ASSERT_TRUE(D.vjp(model, data, a, b, bar, cot));
  EXPECT_EQ(D.rigid_prepare_count(), 1);  // 4 JVP and 2 VJP columns of one step: one prepare
  // The reused maps: the first column again, identical (no stale or half-updated state).
  ASSERT_TRUE(D.jvp(model, data, a, b, random_tangent(model, 1), again));
  EXPECT_EQ(again.x, first.x);
  EXPECT_EQ(again.v, first.v);
  EXPECT_EQ(again.rigid, first.rigid);

  // Another step: prepared again, once (a new record serial; the block is pushed onto its
  // limit at 5 cm/s, so that the maps also differ).
  State c = b;
  c.rigid[0].velocity = Vec3(0, 0, -0.05);
  const StepStatus st = integrator::time_step(model, data, c, nullptr, a, 11);
  ASSERT_TRUE(st.ok()) << describe(model, st);
  ASSERT_GT(data.contact.contacts.size(), 0);
  ASSERT_TRUE(D.jvp(model, data, c, a, random_tangent(model, 1), other));
  ASSERT_TRUE(D.jvp(model, data, c, a, random_tangent(model, 2), other));
  EXPECT_EQ(D.rigid_prepare_count(), 2);
}

}  // namespace rigid_derivative_cache_test
