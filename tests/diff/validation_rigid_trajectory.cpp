// Trajectory derivatives with rigid bodies (issue 21, item 4, without contact): the
// forward sensitivities' rigid rows (output.md: per rigid body its position and the
// rotation vector of the orientation change in world axes; velocities: velocity and
// angular velocity) against central differences of whole simulations, for a free body
// spinning about a non-principal axis (gyroscopic term), a hinge pendulum and a slider
// that reaches its limit and rests on it, beside a small clamped soft beam; with respect
// to the rigid initial states (x0, v0 restricted to rigid directions) and the rigid
// bodies' mass and inertia; and the adjoint against the forward mode. Soft parameters have zero rigid rows and rigid parameters
// zero soft rows (no contact couples them).
//
// Both integrators (value-parametrized): implicit Euler, and BDF2 (rigid/rigid_bdf2_derivatives.hpp),
// whose forward sensitivities carry the rigid bodies' previous states as BDF2's history
// (the extrapolation's Jacobian chained with the implicit Euler step of 2h/3; implicit
// Euler of h at the slider's limit and after it: the restarts) and whose adjoint returns
// the history's cotangent one step later.
//
// Steps: 1e-6 on initial states of size ~1 (m, rad, m/s, rad/s) and 1e-6 times a
// parameter's scale (the mass; the inertia's trace / 3): the truncation error (eps^2,
// ~1e-12) is far below the round-off carried over 20 steps (the rotational Newton stops
// within 1e-14 of the momentum: 1e-14 / 1e-6 = 1e-8 relative per step). Tolerance 1e-6
// per column relative to max(|column|, 1), 100 times that.
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;

namespace rigid_trajectory_test {

constexpr long kSteps = 20;

rigid::RigidBody rigid_box(const std::string& name, rigid::Joint::Kind kind) {
  rigid::RigidBody b;
  b.name = name;
  b.shape.kind = rigid::Shape::Kind::box;
  b.shape.half_extents = Vec3(0.05, 0.03, 0.02);
  b.mass = 0.8;
  b.inertia << 0.0011, 0.0001, -0.00005, 0.0001, 0.0008, 0.00007, -0.00005, 0.00007, 0.0006;
  b.joint.kind = kind;
  return b;
}

Model scene(IntegratorKind integrator) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.rayleigh_mass = 0.5;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  Model model = test::make_model(test::box_mesh(2, 1, 1, 0.1, 0.02, 0.02), spec, Vec3(0, 0, -9.81), 0.01, kSteps);
  auto add = [&](rigid::RigidBody b, rigid::RigidState s) {
    rigid::initialize(b, s);
    model.initial.rigid.push_back(b.reference);
    model.rigid.push_back(std::move(b));
  };
  rigid::RigidState s;
  s.position = Vec3(0.3, 0, 0);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Vec3(1, -1, 2).normalized()));
  s.velocity = Vec3(0.1, 0.2, 1.0);
  s.angular_velocity = Vec3(2, -3, 8);
  add(rigid_box("spinner", rigid::Joint::Kind::free), s);
  auto pendulum = rigid_box("pendulum", rigid::Joint::Kind::hinge);
  pendulum.joint.anchor = Vec3(0.5, 0.0, 0.1);
  pendulum.joint.axis = Vec3(1, 0.2, 0).normalized();
  s.position = Vec3(0.5, 0.05, 0.0);
  s.orientation = Eigen::Quaterniond::Identity();
  s.velocity.setZero();
  s.angular_velocity = 1.5 * pendulum.joint.axis;
  add(pendulum, s);
  auto slider = rigid_box("slider", rigid::Joint::Kind::slider);
  slider.joint.anchor = Vec3(0.7, 0, 0);
  slider.joint.axis = Vec3(0.3, 0, -1).normalized();
  slider.joint.limits = std::make_pair(-0.01, 0.004);  // reached after ~4 steps, then rests on it
  s.position = Vec3(0.7, 0, 0);
  s.angular_velocity.setZero();
  add(slider, s);
  model.step.integrator = integrator;
  return model;
}

State run(const Model& model, const State& initial) {
  Data data(model);
  State s = initial, next, previous;
  const bool bdf2 = model.step.integrator == IntegratorKind::bdf2;
  for (long k = 1; k <= kSteps; ++k) {
    const StepStatus st = integrator::time_step(model, data, s, bdf2 && k > 1 ? &previous : nullptr, next, k);
    EXPECT_TRUE(st.ok()) << st.detail;
    previous = s;
    std::swap(s, next);
  }
  return s;
}

// The rigid rows of a final state relative to `base`: per body 6 position rows, then
// (after all bodies) 6 velocity rows, as dx_dtheta's and dv_dtheta's rigid rows.
void rigid_rows(const State& base, const State& s, VecX& x, VecX& v) {
  const auto nr = static_cast<Eigen::Index>(s.rigid.size());
  x.resize(6 * nr);
  v.resize(6 * nr);
  for (Eigen::Index r = 0; r < nr; ++r) {
    const rigid::Vec12 t = rigid::tangent_between(base.rigid[static_cast<std::size_t>(r)], s.rigid[static_cast<std::size_t>(r)]);
    x.segment<6>(6 * r) = t.head<6>();
    v.segment<6>(6 * r) = t.tail<6>();
  }
}

class RigidTrajectory : public ::testing::TestWithParam<IntegratorKind> {};

TEST_P(RigidTrajectory, JacobianRowsAgainstWholeRuns) {
  const Model model = scene(GetParam());
  const Eigen::Index n3 = 3L * model.fem.num_nodes, nr = static_cast<Eigen::Index>(model.rigid.size());
  diff::ThetaLayout theta;
  theta.parameters.push_back({Parameter::young, 0});
  theta.x0 = theta.v0 = true;
  // Only the rigid directions of x0, v0 (the soft ones are validation_trajectory's).
  theta.x0_basis = MatX::Zero(n3 + 6 * nr, 6 * nr);
  theta.x0_basis.bottomRows(6 * nr).setIdentity();
  theta.v0_basis = theta.x0_basis;
  for (int r = 0; r < nr; ++r)
    for (int k = 0; k < rigid::kRigidParameters; ++k) theta.rigid_parameters.push_back({r, k});
  ASSERT_EQ(theta.size(model), 1 + 12 * nr + 7 * nr);

  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, kSteps, theta, final, dx, dv).ok());
  ASSERT_EQ(dx.rows(), n3 + 6 * nr);
  ASSERT_EQ(dv.rows(), n3 + 6 * nr);
  // The slider rests on its limit at the end.
  EXPECT_TRUE(data.rigid[2].at_limit);

  // Decoupled: young has zero rigid rows; rigid columns have zero soft rows.
  EXPECT_EQ(dx.col(0).tail(6 * nr).norm(), 0.0);
  EXPECT_GT(dx.col(0).head(n3).norm(), 0.0);
  EXPECT_EQ(dx.rightCols(dx.cols() - 1).topRows(n3).norm(), 0.0);
  EXPECT_EQ(dv.rightCols(dv.cols() - 1).topRows(n3).norm(), 0.0);

  const double eps = 1e-6, tol = 1e-6;
  for (Eigen::Index c = 1; c < theta.size(model); ++c) {
    Model mp = model, mm = model;
    State sp = model.initial, sm = model.initial;
    double e = eps;
    std::string what;
    if (c < 1 + 12 * nr) {
      const bool is_x = c < 1 + 6 * nr;
      const Eigen::Index k = (c - 1) % (6 * nr), r = k / 6;
      rigid::Vec12 t = rigid::Vec12::Zero();
      t[(is_x ? 0 : 6) + k % 6] = 1;
      sp.rigid[static_cast<std::size_t>(r)] = rigid::retract(sp.rigid[static_cast<std::size_t>(r)], t, e);
      sm.rigid[static_cast<std::size_t>(r)] = rigid::retract(sm.rigid[static_cast<std::size_t>(r)], t, -e);
      what = std::string(is_x ? "x0" : "v0") + " of " + model.rigid[static_cast<std::size_t>(r)].name + " entry " +
             std::to_string(k % 6);
    } else {
      const auto& p = theta.rigid_parameters[static_cast<std::size_t>(c - 1 - 12 * nr)];
      auto& body = mp.rigid[static_cast<std::size_t>(p.body)];
      const double value = rigid::get_parameter(body, p.index);
      e = eps * (p.index == 0 ? value : body.inertia.trace() / 3);
      rigid::set_parameter(body, p.index, value + e);
      rigid::set_parameter(mm.rigid[static_cast<std::size_t>(p.body)], p.index, value - e);
      what = rigid::rigid_parameter_name(p.index) + " of " + body.name;
    }
    VecX xp, vp, xm, vm;
    rigid_rows(final, run(mp, sp), xp, vp);
    rigid_rows(final, run(mm, sm), xm, vm);
    const VecX fdx = (xp - xm) / (2 * e), fdv = (vp - vm) / (2 * e);
    const VecX ax = dx.col(c).tail(6 * nr), av = dv.col(c).tail(6 * nr);
    const double scale = c < 1 + 12 * nr ? 1.0 : e / eps;  // per unit of the parameter's scale
    EXPECT_LE(scale * (ax - fdx).norm(), tol * std::max(scale * fdx.norm(), 1.0))
        << what << "\nanalytic " << ax.transpose() << "\nfd       " << fdx.transpose();
    EXPECT_LE(scale * (av - fdv).norm(), tol * std::max(scale * fdv.norm(), 1.0))
        << what << "\nanalytic " << av.transpose() << "\nfd       " << fdv.transpose();
  }
}

// The adjoint (reverse sweep through the rigid bodies' step Jacobians) against the forward
// sensitivities for l = a.x_T + b.v_T + c.(rigid rows of frame T) with random a, b, c,
// every theta column: the same products in another order, so to round-off (1e-9 relative).
TEST_P(RigidTrajectory, AdjointMatchesForward) {
  const Model model = scene(GetParam());
  const Eigen::Index n3 = 3L * model.fem.num_nodes, nr = static_cast<Eigen::Index>(model.rigid.size());
  diff::ThetaLayout theta;
  theta.parameters.push_back({Parameter::young, 0});
  theta.x0 = theta.v0 = true;  // every coordinate, soft and rigid
  for (int r = 0; r < nr; ++r)
    for (int k = 0; k < rigid::kRigidParameters; ++k) theta.rigid_parameters.push_back({r, k});
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, kSteps, theta, final, dx, dv).ok());
  std::mt19937 rng(2112);
  std::normal_distribution<double> nd;
  VecX a(n3), b(n3), c(12 * nr);
  for (auto* v : {&a, &b, &c})
    for (Eigen::Index i = 0; i < v->size(); ++i) (*v)[i] = nd(rng);
  VecX forward = dx.topRows(n3).transpose() * a + dv.topRows(n3).transpose() * b;
  for (Eigen::Index r = 0; r < nr; ++r)
    forward += dx.middleRows(n3 + 6 * r, 6).transpose() * c.segment<6>(12 * r) +
               dv.middleRows(n3 + 6 * r, 6).transpose() * c.segment<6>(12 * r + 6);

  Data data2(model);
  diff::Tape tape;
  ASSERT_TRUE(diff::record(model, data2, model.initial, kSteps, tape).ok());
  diff::AdjointResult result;
  const auto loss = [&](long k, const State&, VecX& bx, VecX& bv) {
    if (k != kSteps) return;
    bx += a;
    bv += b;
  };
  const auto rigid_loss = [&](long k, const State&, VecX& br) {
    if (k == kSteps) br += c;
  };
  ASSERT_TRUE(diff::adjoint(model, data2, tape, theta, loss, result, rigid_loss).ok());
  ASSERT_EQ(result.theta.size(), forward.size());
  ASSERT_EQ(result.rigid0.size(), 12 * nr);
  EXPECT_LE((result.theta - forward).norm(), 1e-9 * forward.norm());
  // The rigid parameters' entries are not zero (the loss sees the rigid states).
  EXPECT_GT(result.theta.tail(7 * nr).norm(), 0.0);
}

INSTANTIATE_TEST_SUITE_P(Integrators, RigidTrajectory,
                         ::testing::Values(IntegratorKind::implicit_euler, IntegratorKind::bdf2),
                         [](const auto& tp) { return tp.param == IntegratorKind::bdf2 ? "bdf2" : "implicit_euler"; });

}  // namespace rigid_trajectory_test
