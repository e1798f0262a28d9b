// Inverse dynamics with a rigid body in contact (issue 21; optim/control.hpp, docs/method.md
// "Control"): the controller's actuation Jacobian J_a (the effector's rows of dx_f/dlambda)
// and its contact-force Jacobian J_c (the effector's body's nodal contact forces over the
// contacts with other sides, here the rigid block) against central differences of
// integrator::time_step itself, on both contact backends.
//
// The scene: the clamped beam (meshes/beam.msh, 0.2 x 0.02 x 0.02 m, E = 1 MPa, no gravity)
// whose tip a translation servo pushes down (-z) onto a free rigid block (12 g) 0.5 mm
// below it; the block stands on a frictionless floor (mu 0.5 between beam and block).
// After 30 steps at 0.02 N the tip rests on the block (the beam's bottom vertices at its
// end against the block's top face: vertex-face pairs, soft on rigid, all sticking) and
// the block on the floor (its 4 bottom corners), sliding under the tip's tangential push.
// The floor is frictionless on purpose: with friction there, the 4 corners' friction
// forces are statically indeterminate and the forward solve's split put two corners
// exactly on the cone (|t| = mu n, zero slip) while the block sticks; the mode-fixed
// derivative then treats them as sliding and lets the block slip: J_a was 5x off the
// central differences (measured 2026-12-03; docs/method.md "Control", rigid bodies).
// The normal split of the 4 corners stays indeterminate but moves nothing (min-norm).
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/control.hpp>
#include <support/cli.hpp>

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

using namespace softdiff;

namespace control_rigid_test {

namespace fs = std::filesystem;

std::string pad_on_block_scene() {
  return std::string("softdiff: 1\n"
                     "simulation: {dt: 0.01, steps: 40, gravity: [0, 0, 0]}\n"
                     "bodies:\n"
                     "  - name: beam\n"
                     "    mesh: ") +
         (fs::path(SOFTDIFF_SOURCE_DIR) / "meshes/beam.msh").string() +
         "\n"
         "    material: {law: corotational, young: 1.0e6, poisson: 0.4, density: 1000}\n"
         "    damping: {rayleigh_mass: 5}\n"
         "    fixed: [{group: clamp}]\n"
         "    actuators:\n"
         "      - {name: press, type: servo, nodes: {box: [0.19, -1, -1, 1, 1, 1]}, direction: [0, 0, -1], "
         "force: 0.02, limits: [0, 0.05]}\n"
         "    effectors:\n"
         "      - {name: tip, point: [0.2, 0.01, 0.01]}\n"
         "  - name: block\n"
         "    type: rigid\n"
         "    shape: {type: box, half_extents: [0.015, 0.02, 0.005]}\n"
         "    density: 1000\n"
         "    position: [0.19, 0.01, -0.0055]\n"
         "obstacles: [{name: floor, type: plane, normal: [0, 0, 1], offset: -0.0105}]\n"
         "contact:\n"
         "  friction: 0.5\n"
         "  pairs: [[beam, block, 0.5], [block, floor, 0]]\n";
}

// J_a and J_c against central differences. The linearized step with its contact modes
// fixed (every contact sticks here) is affine in the actuation: b gains h H_a^T lambda
// and the NCP's sticking solution is linear in g. So the difference quotient has no
// truncation error; eps = 1e-3 N (5% of the 0.02 N push, far from breaking a contact:
// the tip presses with ~0.015 N) divides only the NCP's residual (tolerance 1e-12,
// tightened for this test: the scene's default 1e-8 would give errors ~1e-8 / 2e-3)
// and round-off by 2 eps. Tolerance 1e-5 relative to each column (measured below: printed).

TEST(ControlRigid, ActuationAndContactForceJacobiansMatchCentralDifferences) {
  const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / "control_rigid";
  test::write_text(dir / "scene.yaml", pad_on_block_scene());
  struct Case {
    std::string name, block;
  };
  // free: the block on the frictionless floor (it slides under the tip's tangential
  // push); fixed: the block on a fixed joint (an immovable rigid side).
  const std::vector<Case> cases = {{"free", ""},
                                   {"fixed", "bodies.block.joint={type: fixed, anchor: [0.19, 0.01, -0.0055]}"}};
  for (const Case& c : cases)
  for (const std::string backend : {"dense", "sparse"}) {
    SCOPED_TRACE(c.name + " " + backend);
    std::vector<std::string> overrides = {"contact.backend=" + backend, "contact.tolerance=1e-12",
                                          "contact.max_iterations=20000"};
    if (!c.block.empty()) overrides.push_back(c.block);
    const Model model = io::build_model(io::load_scene(dir / "scene.yaml", overrides));
    ASSERT_TRUE(model.contact.with_rigid());
    const VecX push = VecX::Constant(1, 0.02);
    Data data(model);
    State s = model.initial, next;
    const long warm = 30;
    for (long k = 1; k <= warm; ++k) {
      const StepStatus st = integrator::time_step(model, data, s, nullptr, next, k, &push);
      ASSERT_TRUE(st.ok()) << describe(model, st);
      std::swap(s, next);
    }
    optim::ControlOptions options;
    options.alpha = 1;
    options.beta = 10;
    optim::InverseDynamics id(model, options);
    const Vec3 goal = model.actuation.effectors[0].effector.position(s.x) - Vec3(0, 0, 1e-3);
    VecX lambda;
    optim::ControlStep info;
    const StepStatus st = id.compute(model, s, warm + 1, goal, push, lambda, info);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    // The tip pushes on the block: contacts with the rigid side, a nonzero force on the beam.
    int with_block = 0;
    const auto& contacts = id.data().contact.contacts.contacts;
    const int block_side = 1;  // contact names: beam, block, floor
    for (const auto& k : contacts) with_block += (k.side_a == block_side) != (k.side_b == block_side) &&
                                                 (k.side_a == 0 || k.side_b == 0);
    ASSERT_GT(with_block, 0);
    ASSERT_EQ(info.Ja.cols(), 1);
    ASSERT_GT(info.F.norm(), 1e-3);
    ASSERT_EQ(info.Jc.rows(), info.F.size());
    const double eps = 1e-3;
    Vec3 Ja_fd;
    VecX F_fd;
    {
      Data plus(model), minus(model);
      State sp, sm;
      const VecX lp = push + VecX::Constant(1, eps), lm = push - VecX::Constant(1, eps);
      ASSERT_TRUE(integrator::time_step(model, plus, s, nullptr, sp, warm + 1, &lp).ok());
      ASSERT_TRUE(integrator::time_step(model, minus, s, nullptr, sm, warm + 1, &lm).ok());
      ASSERT_EQ(plus.contact.contacts.size(), id.data().contact.contacts.size());
      ASSERT_EQ(minus.contact.contacts.size(), id.data().contact.contacts.size());
      const auto& e = model.actuation.effectors[0].effector;
      Ja_fd = (e.position(sp.x) - e.position(sm.x)) / (2 * eps);
      F_fd = (id.nodal_contact_forces(plus, plus.contact.lambda) - id.nodal_contact_forces(minus, minus.contact.lambda)) /
             (2 * eps);
    }
    const Vec3 Ja = info.Ja.col(0);
    const VecX Jc = info.Jc.col(0);
    const double ea = (Ja - Ja_fd).norm() / Ja_fd.norm(), ec = (Jc - F_fd).norm() / F_fd.norm();
    std::printf("%s %s: %d contacts beam-block, |F| %.4e N, |J_a| %.4e m/N (rel. error %.2e), |J_c| %.4e (rel. error %.2e)\n",
                c.name.c_str(), backend.c_str(), with_block, info.F.norm(), Ja_fd.norm(), ea, F_fd.norm(), ec);
    EXPECT_GT(Ja_fd.norm(), 0);
    EXPECT_GT(F_fd.norm(), 0);
    EXPECT_LE(ea, 1e-5);
    EXPECT_LE(ec, 1e-5);
    // The rigid block is another side: its forces on the beam are in F (the floor does
    // not touch the beam), so F's resultant is the push the block takes (vertical here).
    Vec3 resultant = Vec3::Zero();
    for (Eigen::Index i = 0; i < info.F.size() / 3; ++i) resultant += info.F.segment<3>(3 * i);
    EXPECT_GT(resultant.z(), 0.5 * 0.02) << "the block pushes the beam up";
  }
}

}  // namespace control_rigid_test
