// Derivatives of scenes of rigid bodies only (issue 21; docs/method.md "Scenes of rigid
// bodies only"): a model without any soft node, whose step skips the soft stage
// (integrator/bdf2.cpp time_step_rigid_only) and whose derivative has no soft system
// either (implicit_euler_derivatives.cpp: an empty system, the mode-fixed contact system
// on the rigid rows alone). Forward sensitivities (diff::forward_sensitivities) with
// respect to every input at once (x0, v0: the identity over each body's 6 + 6 rows; every
// mass and inertia component) against central differences of whole runs of
// integrator::time_step, over one step and over a trajectory, and the adjoint against
// the forward sensitivities (to round-off). Scenes: a free box tumbling (no contact), a
// limited hinge resting on its limit beside a sliding wedge (the limit a row of the NCP),
// the wedge sliding on a plane, and a two-body stack (the wedge sliding on a prism that
// stands on the plane: rigid-rigid contact, both bodies' rows). Implicit Euler and BDF2,
// the dense and the sparse contact backends.
// (Determinate contacts only: the wedge's and the prism's three base vertices. A box's
// four corners on a plane share their normal forces indeterminately, and with friction
// the split, which the solver picks, moves the friction torque: no derivative of one
// piece; test_contact_derivatives.cpp's note.)
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>
#include <support/rigid_contact.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <string>

using namespace softdiff;

namespace rigid_only_derivatives_test {

constexpr double g0 = 9.81;

enum class Scene { free_box, limited_hinge, wedge, stack };
std::string scene_name(Scene s) {
  return s == Scene::free_box ? "free_box" : s == Scene::limited_hinge ? "limited_hinge" : s == Scene::wedge ? "wedge" : "stack";
}

// A triangular prism (base triangle (-0.05, -0.05), (0.25, -0.05), (-0.05, 0.2) m, 0.05 m
// high) as a closed mesh, its triangles oriented outward.
rigid::Shape prism_shape() {
  rigid::Shape s;
  s.kind = rigid::Shape::Kind::mesh;
  s.mesh_vertices.resize(3, 6);
  s.mesh_vertices << -0.05, 0.25, -0.05, -0.05, 0.25, -0.05,  //
      -0.05, -0.05, 0.2, -0.05, -0.05, 0.2,                    //
      0, 0, 0, 0.05, 0.05, 0.05;
  const int tri[8][3] = {{0, 1, 2}, {3, 4, 5}, {0, 1, 4}, {0, 4, 3}, {1, 2, 5}, {1, 5, 4}, {2, 0, 3}, {2, 3, 5}};
  s.mesh_triangles.resize(3, 8);
  const Vec3 centre = s.mesh_vertices.rowwise().mean();
  for (int t = 0; t < 8; ++t) {
    const Vec3 a = s.mesh_vertices.col(tri[t][0]), b = s.mesh_vertices.col(tri[t][1]), c = s.mesh_vertices.col(tri[t][2]);
    const bool outward = (b - a).cross(c - a).dot((a + b + c) / 3 - centre) > 0;
    s.mesh_triangles.col(t) << tri[t][0], outward ? tri[t][1] : tri[t][2], outward ? tri[t][2] : tri[t][1];
  }
  return s;
}

// The scenes, h = 1 ms, warmed up a few steps (model.initial: the state the runs start
// from), on the given backend and integrator.
Model make_scene(Scene scene, bool bdf2, contact::NcpBackend backend) {
  Model model = test::rigid_scenes::rigid_only_model(1e-3, g0);
  if (bdf2) model.step.integrator = IntegratorKind::bdf2;
  std::vector<collision::Obstacle> obstacles{test::plane(Vec3::UnitZ(), 0, "floor")};
  std::vector<test::NamedPair> pairs;
  if (scene == Scene::free_box) {
    // A 1.3 kg box (0.1 x 0.2 x 0.3 m) tumbling: off the origin, turned, moving and
    // spinning mostly about z (the gyroscopic term); no contact.
    test::add_rigid_body(model, "box", test::box_shape(Vec3(0.05, 0.1, 0.15)), 1000, test::rigid_scenes::generic_state());
  } else if (scene == Scene::limited_hinge || scene == Scene::wedge) {
    test::rigid_scenes::add_sliding_wedge(model);
    pairs.push_back({"wedge", "floor", 0.3});
    if (scene == Scene::limited_hinge) {
      // validation_rigid_only_sparse.cpp's bar: hinged about y at its left end, released
      // level; gravity turns it onto its upper limit 0.05 rad (in ~37 steps), where it
      // rests (a limit row of the NCP, active, reaction ~0.1254 N m).
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
  } else {
    // The prism (500 kg/m^3) standing on the plane (mu 0.8: it sticks), the wedge on its
    // top face (z = 0.05), sliding at 0.5 m/s and spinning (mu 0.3): three vertex-face
    // contacts each, the wedge's against the prism's top triangle, well inside it.
    rigid::RigidState p;
    const rigid::MassProperties mp = rigid::mass_properties(prism_shape(), 500);
    p.position = mp.centre;
    test::add_rigid_body(model, "prism", prism_shape(), 500, p);
    test::rigid_scenes::add_sliding_wedge(model);
    model.initial.rigid.back().position.z() += 0.05;
    pairs = {{"prism", "floor", 0.8}, {"prism", "wedge", 0.3}};
  }
  if (!pairs.empty()) {
    auto ncp = test::rigid_scenes::tight_ncp(1e-12);
    ncp.backend = backend;
    test::enable_rigid_contact(model, obstacles, pairs, 1e-3, ncp);
  }
  return model;
}

// `steps` steps from s0 (BDF2 from its second step), asserting each.
State run(const Model& model, const State& s0, long steps) {
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

// The final state's rows as the sensitivities have them: per rigid body (position,
// rotation vector) as tangents from `base`, then (velocity, angular velocity).
void rows_from(const State& base, const State& s, VecX& x_rows, VecX& v_rows) {
  const auto R = static_cast<Eigen::Index>(s.rigid.size());
  x_rows.resize(6 * R);
  v_rows.resize(6 * R);
  for (Eigen::Index r = 0; r < R; ++r) {
    const rigid::Vec12 t = rigid::tangent_between(base.rigid[static_cast<std::size_t>(r)], s.rigid[static_cast<std::size_t>(r)]);
    x_rows.segment<6>(6 * r) = t.head<6>();
    v_rows.segment<6>(6 * r) = t.tail<6>();
  }
}

struct Case {
  Scene scene;
  bool bdf2;
  contact::NcpBackend backend;
  long warm, T;          // warm-up steps (model.initial), steps differentiated
  double eps_x0 = 1e-7;  // the x0 columns' step (see the test)
};
std::string case_name(const Case& c) {
  return scene_name(c.scene) + (c.bdf2 ? "_bdf2" : "_euler") +
         (c.backend == contact::NcpBackend::sparse ? "_sparse" : "_dense") + "_T" + std::to_string(c.T);
}

class RigidOnlyDerivatives : public ::testing::TestWithParam<Case> {};

// Every column of theta (x0: 6 per body, v0: 6 per body, mass and the six inertia
// components per body) against central differences of whole runs. eps: 1e-6 for v0 (m/s,
// rad/s) and the parameters (relative to their own scale: the mass, the inertia's trace /
// 3); x0 (m, rad) 1e-7, where the error is eps^2 truncation (the gap term phi / h; the
// wedge over two steps, its height's column: 1.1e-2, 1.2e-3, 1.1e-4 at eps 3e-6, 1e-6,
// 3e-7, against entries of 1.44), but 1e-6 on the stack, whose x0 columns are noise / eps
// instead (one step: 1.5e-3 at 1e-6, 4.4e-3, 0.44, 44 at 1e-7, 1e-8, 1e-9 against
// entries of ~1e3). The contact modes do not change under these steps (the wedge slides
// at 0.5 m/s, the prism sticks with a margin, the hinge's limit carries ~0.125 N m).
// The hinge over 10 steps: x0 3e-8 (its truncation 8.9e-4, 8.9e-6 at 1e-6, 1e-7 against
// 0.575). tol: 1e-5 relative to the column's largest difference, plus 1e-14 / eps
// absolute, the outputs' noise (the contact solve at 1e-12, polished to round-off, over
// the steps) over the step, which a column of zeros shows (e.g. the mass of a body held
// by its limit; the wedge's inertia xx over 12 steps: differences 3.4e-9 against 0 at eps
// 1e-6, the outputs' noise ~7e-15).
// The stack over 2 and 10 steps: before 2026-12-03 (rstack) its tilt columns (the prism's
// and the wedge's x0 rotations x, y; rows: the wedge's angular velocity x, y) did not
// converge as eps shrank (45, 576 at eps 1e-7, 3e-8, two steps): a perturbed run's wedge
// contacts have gaps of ~1e-12 m after the first step, and the vertex-triangle normal was
// d / |d|, tilted by round-off / gap (1e-5 rad), which times the wedge's 0.5 m/s sliding
// put ~1e-6 m/s into the normal rows; the normal is now the face's (contact_step.cpp
// rigid_face_normals; docs/method.md "Scenes of rigid bodies only"). These columns now give
// 1.78, 0.714 (prism) and 2.43, 2.56 (wedge) at every eps from 1e-6 to 3e-8. Their x0
// step is the default 1e-7: at 1e-6 the wedge's height column has the eps^2 truncation
// above (1.2e-3 against 1.41, two steps).
TEST_P(RigidOnlyDerivatives, SensitivitiesAgainstCentralDifferencesAndAdjoint) {
  const Case c = GetParam();
  Model model = make_scene(c.scene, c.bdf2, c.backend);
  ASSERT_EQ(model.fem.num_nodes, 0);
  model.initial = run(model, model.initial, c.warm);
  const auto R = static_cast<Eigen::Index>(model.rigid.size());
  diff::ThetaLayout theta;
  theta.x0 = theta.v0 = true;
  for (int r = 0; r < R; ++r)
    for (int k = 0; k < rigid::kRigidParameters; ++k) theta.rigid_parameters.push_back({r, k});
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, c.T, theta, final, dx, dv).ok());
  EXPECT_EQ(data.factorizations, 0);
  const Eigen::Index cols = 12 * R + 7 * R;
  ASSERT_EQ(dx.cols(), cols);
  ASSERT_EQ(dx.rows(), 6 * R);
  if (c.scene != Scene::free_box) {
    ASSERT_GT(data.contact.contacts.size(), 0);
  }
  if (c.scene == Scene::limited_hinge) {
    ASSERT_EQ(data.contact.rigid.limit_lambda.size(), 2);
    EXPECT_GT(data.contact.rigid.limit_lambda[1], 0.1);  // resting on its upper limit
  }
  MatX fd(12 * R, cols), an(12 * R, cols);
  VecX floor(cols);
  for (Eigen::Index col = 0; col < cols; ++col) {
    Model mp = model, mm = model;
    State sp = model.initial, sm = model.initial;
    double eps = 0, scale = 1;
    if (col < 12 * R) {
      const bool x = col < 6 * R;
      const Eigen::Index k = x ? col : col - 6 * R;
      eps = x ? c.eps_x0 : 1e-6;
      rigid::Vec12 d = rigid::Vec12::Zero();
      d[(x ? 0 : 6) + k % 6] = 1;
      sp.rigid[static_cast<std::size_t>(k / 6)] = rigid::retract(model.initial.rigid[static_cast<std::size_t>(k / 6)], d, eps);
      sm.rigid[static_cast<std::size_t>(k / 6)] = rigid::retract(model.initial.rigid[static_cast<std::size_t>(k / 6)], d, -eps);
    } else {
      const auto& p = theta.rigid_parameters[static_cast<std::size_t>(col - 12 * R)];
      const auto& b = model.rigid[static_cast<std::size_t>(p.body)];
      eps = 1e-6;
      scale = p.index == 0 ? b.mass : b.inertia.trace() / 3;
      const double v = rigid::get_parameter(b, p.index);
      rigid::set_parameter(mp.rigid[static_cast<std::size_t>(p.body)], p.index, v + eps * scale);
      rigid::set_parameter(mm.rigid[static_cast<std::size_t>(p.body)], p.index, v - eps * scale);
    }
    VecX xp, vp, xm, vm;
    rows_from(final, run(mp, sp, c.T), xp, vp);
    rows_from(final, run(mm, sm, c.T), xm, vm);
    fd.col(col) << (xp - xm) / (2 * eps), (vp - vm) / (2 * eps);
    floor[col] = 1e-14 / eps;
    an.col(col) << dx.col(col) * scale, dv.col(col) * scale;
  }
  const double whole = fd.cwiseAbs().maxCoeff();
  double worst = 0;
  for (Eigen::Index col = 0; col < cols; ++col) {
    const double err = (an.col(col) - fd.col(col)).cwiseAbs().maxCoeff();
    const double mag = fd.col(col).cwiseAbs().maxCoeff();
    worst = std::max(worst, err / (mag + 1e-4));
    EXPECT_LT(err, 1e-5 * mag + floor[col]) << "column " << col << " (x0: 6 per body, v0: 6 per body, then 7 parameters "
                                         "per body): |FD| " << mag;
  }
  std::cout << "[rigid only derivatives] " << case_name(c) << ": " << cols << " columns, contacts "
            << data.contact.contacts.size() << ", worst |sensitivity - FD| / (column's largest + 1e-4) " << worst
            << " (largest entry " << whole << ")\n";
  std::mt19937 rng(7);
  std::normal_distribution<double> N;
  test::rigid_scenes::expect_adjoint_matches_forward(model, c.T, theta, dx, dv, rng, N);
}

using B = contact::NcpBackend;
INSTANTIATE_TEST_SUITE_P(
    , RigidOnlyDerivatives,
    ::testing::Values(
        // One step (BDF2: two, its first is implicit Euler's).
        Case{Scene::free_box, false, B::dense, 0, 1}, Case{Scene::free_box, true, B::dense, 0, 2},
        Case{Scene::limited_hinge, false, B::dense, 60, 1}, Case{Scene::wedge, false, B::dense, 3, 1},
        Case{Scene::wedge, true, B::dense, 3, 2}, Case{Scene::wedge, false, B::sparse, 3, 1},
        Case{Scene::stack, false, B::dense, 5, 1, 1e-6}, Case{Scene::stack, false, B::sparse, 5, 1, 1e-6},
        // Trajectories.
        Case{Scene::free_box, true, B::dense, 0, 20}, Case{Scene::limited_hinge, false, B::dense, 60, 10, 3e-8},
        Case{Scene::wedge, false, B::dense, 3, 12}, Case{Scene::wedge, true, B::sparse, 3, 12},
        Case{Scene::stack, false, B::dense, 5, 2}, Case{Scene::stack, false, B::dense, 5, 10},
        Case{Scene::stack, false, B::sparse, 5, 10}, Case{Scene::stack, true, B::dense, 5, 10}),
    [](const ::testing::TestParamInfo<Case>& p) { return case_name(p.param); });

}  // namespace rigid_only_derivatives_test
