// Derivatives with rigid bodies on the command line (issue 21, item 4): `check-grad`
// passes on a scene with a free spinning rigid body and a hinge pendulum beside the
// clamped beam (every default block, the rigid ones included), and on a rigid sphere
// resting on the floor through contact;
// under bdf2 too (issue 21, rbd2); `simulate --jacobian` writes /jacobians rows for the rigid states (3 n_total + 6 per
// rigid body) with the column names and units of docs/output.md; `mass`/`inertia`
// without rigid bodies is refused with exit 2.
#include <support/cli.hpp>
#include <support/h5.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <string>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace cli_rigid_derivatives_test {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_rigid_derivatives";

std::string beam() {
  return rigid_scenes::clamped_beam_yaml(3, "    damping: {rayleigh_mass: 0.5, rayleigh_stiffness: 0.001}\n");
}

std::string rigid_scene() {
  return beam() + rigid_scenes::spinner_yaml() +
         "  - name: pendulum\n"
         "    type: rigid\n"
         "    shape: {type: box, half_extents: [0.005, 0.02, 0.005]}\n"
         "    density: 1000\n"
         "    position: [0.3, -0.1, 0]\n"
         "    angular_velocity: [2, 0, 0]\n"
         "    joint: {type: hinge, anchor: [0.3, -0.08, 0], axis: [1, 0, 0], limits: [-1, 1]}\n";
}

TEST(CliRigidDerivatives, CheckGradPasses) {
  const fs::path dir = fresh_dir(kWork, "check_grad");
  write_text(dir / "scene.yaml", rigid_scene());
  const auto r = run_cli("check-grad scene.yaml --quiet", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  // Every block is listed, the rigid ones included.
  for (const char* block : {"young", "x0", "v0", "mass", "inertia"}) EXPECT_NE(r.out.find(block), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
}

// configs/hinged_key.yaml after 50 steps: the key rests on its lower limit (reached after
// ~30 steps), so its state does not depend on its mass or inertia: the analytic blocks are
// zero (the clamped coordinate has zero derivative) and so are the differences (to their
// round-off), which check-grad counts as a match (relative error printed as 0).
TEST(CliRigidDerivatives, CheckGradOnTheHingedKeyAtItsLimit) {
  const fs::path dir = fresh_dir(kWork, "hinged_key_limit");
  const auto r = run_cli("check-grad '" + (kRoot / "configs/hinged_key.yaml").string() +
                             "' --quiet --steps 50 --wrt mass,inertia",
                         dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  for (const char* block : {"mass", "inertia"}) {
    const auto at = r.out.find(std::string("\n") + block);
    ASSERT_NE(at, std::string::npos) << r.out;
    EXPECT_NE(r.out.substr(at, 80).find("0.000e+00"), std::string::npos) << r.out;
  }
}

TEST(CliRigidDerivatives, JacobianRowsForRigidStates) {
  const fs::path dir = fresh_dir(kWork, "jacobian");
  write_text(dir / "scene.yaml", rigid_scene());
  const auto r = run_cli("simulate scene.yaml -o out.h5 --quiet --steps 1 --jacobian young,mass,inertia,v0", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const hid_t f = H5Fopen((dir / "out.h5").string().c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto x = h5_shape(f, "/bodies/beam/x");  // (T, n, 3)
  ASSERT_EQ(x.size(), 3u);
  const hsize_t rows = 3 * x[1] + 6 * 2;         // output.md: 3 n_total, then 6 per rigid body
  auto expect_shape = [&](const std::string& name, hsize_t cols) {
    const auto s = h5_shape(f, "/jacobians/" + name);
    ASSERT_EQ(s.size(), 2u) << name;
    EXPECT_EQ(s[0], rows) << name;
    EXPECT_EQ(s[1], cols) << name;
  };
  expect_shape("young", 1);
  expect_shape("mass", 2);
  expect_shape("inertia", 12);
  expect_shape("v0", rows);
  EXPECT_EQ(h5_string_attribute(f, "/jacobians/mass", "theta"), "mass[spinner],mass[pendulum]");
  EXPECT_NE(h5_string_attribute(f, "/jacobians/inertia", "theta").find("inertia[pendulum].yz"), std::string::npos);
  EXPECT_EQ(h5_string_attribute(f, "/jacobians/mass", "units"), "m/kg");
  // Row-major (rows x cols): young moves the beam, not the rigid bodies; the pendulum's
  // rows depend on its mass (its inertia about the pin is not m r^2 alone), not the spinner's.
  const auto young = h5_read(f, "/jacobians/young");
  double soft = 0, rigid = 0;
  for (hsize_t i = 0; i < rows; ++i) (i < rows - 12 ? soft : rigid) += young[i] * young[i];
  EXPECT_GT(soft, 0.0);
  EXPECT_EQ(rigid, 0.0);
  const auto mass = h5_read(f, "/jacobians/mass");
  double pendulum = 0, soft_mass = 0;
  for (hsize_t i = 0; i < rows; ++i) {
    if (i < rows - 12) soft_mass += std::abs(mass[2 * i]) + std::abs(mass[2 * i + 1]);
    if (i >= rows - 6) pendulum += std::abs(mass[2 * i + 1]);
  }
  EXPECT_EQ(soft_mass, 0.0);
  EXPECT_GT(pendulum, 0.0);
  H5Fclose(f);
}

// Through contact (issue 21, item 4's last part): a rigid sphere on its pole on the floor
// beside the clamped beam, launched at (0.2, 0.05, 0) m/s with friction 0.3: one sliding
// contact that spins it up over the 3 steps checked (a box flat on four corners would
// have indeterminate normal forces: four on a plane, rank 3). Every default block passes,
// the friction coefficient's, mass and inertia included (measured: 1.6e-7 relative at
// worst, x0). check-grad passes on every default block, the contact's included;
// simulate --jacobian runs (it was refused with contact and rigid bodies).
std::string sphere_on_floor() {
  return beam() +
         "  - name: ball\n"
         "    type: rigid\n"
         "    shape: {type: sphere, radius: 0.01}\n"
         "    density: 1000\n"
         "    position: [0.1, 0.1, 0]\n"
         "    velocity: [0.2, 0.05, 0]\n"
         "obstacles: [{name: floor, type: plane, normal: [0, 0, 1], offset: -0.01}]\n"
         "contact: {friction: 0.3, pairs: [[ball, floor, 0.3]]}\n";
}

TEST(CliRigidDerivatives, CheckGradThroughContact) {
  const fs::path dir = fresh_dir(kWork, "check_grad_contact");
  write_text(dir / "scene.yaml", sphere_on_floor());
  const auto r = run_cli("check-grad scene.yaml --quiet --steps 3", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  for (const char* block : {"young", "friction", "x0", "v0", "mass", "inertia"})
    EXPECT_NE(r.out.find(block), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  const auto j = run_cli("simulate scene.yaml -o out.h5 --jacobian mass,v0", dir);
  EXPECT_EQ(j.code, 0) << j.err;
  EXPECT_TRUE(fs::exists(dir / "out.h5"));
}

// The same on the sparse contact backend and on the operator (issue 21: the derivative's
// G_AA there lacked the rigid part h Kt^T Kt, so the friction, mass and inertia blocks
// were wrong; docs/method.md "Through contact with rigid bodies", Backends). Measured:
// the same errors as on the dense backend (1.6e-7 relative at worst, x0).
TEST(CliRigidDerivatives, CheckGradThroughContactOnTheSparseBackends) {
  const fs::path dir = fresh_dir(kWork, "check_grad_contact_sparse");
  write_text(dir / "scene.yaml", sphere_on_floor());
  for (const std::string set :
       {"--set contact.backend=sparse", "--set contact.backend=sparse --set contact.dense_max_contacts=0 --set "
                                        "contact.derivative_dense_max_active=0 --set "
                                        "contact.derivative_mixed_dense_max_active=0"}) {
    const auto r = run_cli("check-grad scene.yaml --quiet --steps 3 " + set, dir);
    EXPECT_EQ(r.code, 0) << set << "\n" << r.out << r.err;
    for (const char* block : {"friction", "x0", "v0", "mass", "inertia"})
      EXPECT_NE(r.out.find(block), std::string::npos) << set << "\n" << r.out;
    EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << set << "\n" << r.out;
  }
}

// Newton with rigid bodies in contact (rnewtd; it was refused, exit 2): the sphere sliding
// on the floor beside the clamped beam with newton_iterations 8 (the beam's own Newton
// needs 5-8 at this dt), on the dense and the sparse contact backends: check-grad passes
// on every default block, and simulate --jacobian runs (mass and friction: v0's 3n + 6
// columns are a forward sensitivity each, minutes on the loaded machine).
TEST(CliRigidDerivatives, CheckGradThroughContactWithNewton) {
  const fs::path dir = fresh_dir(kWork, "check_grad_contact_newton");
  write_text(dir / "scene.yaml", sphere_on_floor());
  for (const std::string set : {"", " --set contact.backend=sparse"}) {
    const std::string newton = " --set simulation.newton_iterations=8" + set;
    const auto r = run_cli("check-grad scene.yaml --quiet --steps 3" + newton, dir);
    EXPECT_EQ(r.code, 0) << newton << "\n" << r.out << r.err;
    for (const char* block : {"young", "friction", "x0", "v0", "mass", "inertia"})
      EXPECT_NE(r.out.find(block), std::string::npos) << newton << "\n" << r.out;
    EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << newton << "\n" << r.out;
    fs::remove(dir / "out.h5");
    const auto j = run_cli("simulate scene.yaml -o out.h5 --quiet --force --jacobian mass,friction" + newton, dir);
    EXPECT_EQ(j.code, 0) << newton << "\n" << j.err;
    EXPECT_TRUE(fs::exists(dir / "out.h5")) << newton;
  }
}

// BDF2 with rigid bodies (issue 21, "rbd2"; it was refused, exit 2): the spinner and the
// pendulum beside the beam, and the sphere sliding on the floor through contact, under
// integrator bdf2 over 5 steps (four BDF2 steps after the implicit Euler start, so that
// the history carries the rigid states): check-grad passes on every default block, and
// simulate --jacobian writes the rigid rows. On the dense contact backend (the
// derivative's default for this one contact) and on the sparse one.
TEST(CliRigidDerivatives, CheckGradUnderBdf2) {
  const fs::path dir = fresh_dir(kWork, "check_grad_bdf2");
  write_text(dir / "scene.yaml", rigid_scene());
  write_text(dir / "contact.yaml", sphere_on_floor());
  for (const std::string args :
       {"scene.yaml", "contact.yaml", "contact.yaml --set contact.backend=sparse"}) {
    const auto r = run_cli("check-grad " + args + " --quiet --steps 5 --set simulation.integrator=bdf2", dir);
    EXPECT_EQ(r.code, 0) << args << "\n" << r.out << r.err;
    for (const char* block : {"young", "x0", "v0", "mass", "inertia"})
      EXPECT_NE(r.out.find(block), std::string::npos) << args << "\n" << r.out;
    EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << args << "\n" << r.out;
  }
  const auto j = run_cli("simulate scene.yaml -o out.h5 --quiet --steps 5 --set simulation.integrator=bdf2 "
                         "--jacobian mass,inertia,v0", dir);
  ASSERT_EQ(j.code, 0) << j.err;
  const hid_t f = H5Fopen((dir / "out.h5").string().c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto x = h5_shape(f, "/bodies/beam/x");
  ASSERT_EQ(x.size(), 3u);
  const auto s = h5_shape(f, "/jacobians/mass");
  ASSERT_EQ(s.size(), 2u);
  EXPECT_EQ(s[0], 3 * x[1] + 12);
  EXPECT_EQ(s[1], 2u);
  // The pendulum's rows depend on its mass (not zero), the beam's do not.
  const auto mass = h5_read(f, "/jacobians/mass");
  double pendulum = 0, soft = 0;
  for (hsize_t i = 0; i < s[0]; ++i) {
    if (i < s[0] - 12) soft += std::abs(mass[2 * i]) + std::abs(mass[2 * i + 1]);
    if (i >= s[0] - 6) pendulum += std::abs(mass[2 * i + 1]);
  }
  EXPECT_EQ(soft, 0.0);
  EXPECT_GT(pendulum, 0.0);
  H5Fclose(f);
}

// A scene of rigid bodies only (issue 21, ronly; docs/method.md "Scenes of rigid bodies
// only"; its derivatives were refused, exit 2): the sphere sliding on the floor of
// CheckGradThroughContact and a pendulum on a limited hinge, no soft body. check-grad
// passes on every default block (friction, x0, v0, mass, inertia; no soft parameter is
// listed; measured: v0 2.8e-6, the others 2e-8 or less relative); under bdf2 and on the
// sparse backend without the limits (bdf2 with a limited joint in contact is refused by
// the scene reader, and the sparse backend's limit rows are not differentiated: rbdlim,
// rpsp); on configs/rigid_stack.yaml over 5 steps with the contact solve at 1e-13
// (before the upper boxes land: their four corners would share the load indeterminately,
// test_rigid_only_derivatives.cpp). simulate --jacobian writes 6 rows per rigid body; a
// soft parameter is refused (exit 2, no file).
std::string rigid_only(bool limits) {
  return std::string("softdiff: 1\nsimulation: {dt: 0.01, steps: 3}\nbodies:\n") +
         "  - name: ball\n"
         "    type: rigid\n"
         "    shape: {type: sphere, radius: 0.01}\n"
         "    density: 1000\n"
         "    position: [0.1, 0.1, 0]\n"
         "    velocity: [0.2, 0.05, 0]\n"
         "  - name: pendulum\n"
         "    type: rigid\n"
         "    shape: {type: box, half_extents: [0.005, 0.02, 0.005]}\n"
         "    density: 1000\n"
         "    position: [0.3, -0.1, 0]\n"
         "    angular_velocity: [2, 0, 0]\n"
         "    joint: {type: hinge, anchor: [0.3, -0.08, 0], axis: [1, 0, 0]" +
         (limits ? ", limits: [-1, 1]" : "") +
         "}\n"
         "obstacles: [{name: floor, type: plane, normal: [0, 0, 1], offset: -0.01}]\n"
         "contact: {friction: 0.3, pairs: [[ball, floor, 0.3]]}\n";
}

TEST(CliRigidDerivatives, RigidOnlyCheckGradAndJacobian) {
  const fs::path dir = fresh_dir(kWork, "rigid_only");
  write_text(dir / "limits.yaml", rigid_only(true));
  write_text(dir / "free.yaml", rigid_only(false));
  const std::string stack = "'" + (kRoot / "configs/rigid_stack.yaml").string() + "'";
  for (const std::string& args :
       {std::string("limits.yaml --steps 3"), std::string("free.yaml --steps 5 --set simulation.integrator=bdf2"),
        std::string("free.yaml --steps 3 --set contact.backend=sparse"),
        stack + " --steps 5 --set contact.tolerance=1e-13 --set contact.max_iterations=5000"}) {
    const auto r = run_cli("check-grad " + args + " --quiet", dir);
    EXPECT_EQ(r.code, 0) << args << "\n" << r.out << r.err;
    for (const char* block : {"friction", "x0", "v0", "mass", "inertia"})
      EXPECT_NE(r.out.find(block), std::string::npos) << args << "\n" << r.out;
    EXPECT_EQ(r.out.find("young"), std::string::npos) << args << "\n" << r.out;
    EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << args << "\n" << r.out;
  }
  const auto j = run_cli("simulate limits.yaml -o out.h5 --quiet --jacobian mass,x0", dir);
  ASSERT_EQ(j.code, 0) << j.err;
  const hid_t f = H5Fopen((dir / "out.h5").string().c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto m = h5_shape(f, "/jacobians/mass"), x0 = h5_shape(f, "/jacobians/x0");
  ASSERT_EQ(m.size(), 2u);
  EXPECT_EQ(m[0], 12u);  // 6 per rigid body, no soft row
  EXPECT_EQ(m[1], 2u);
  ASSERT_EQ(x0.size(), 2u);
  EXPECT_EQ(x0[0], 12u);
  EXPECT_EQ(x0[1], 12u);
  EXPECT_EQ(h5_string_attribute(f, "/jacobians/mass", "theta"), "mass[ball],mass[pendulum]");
  H5Fclose(f);
  const auto y = run_cli("simulate limits.yaml -o young.h5 --quiet --jacobian young", dir);
  EXPECT_EQ(y.code, 2) << y.err;
  EXPECT_NE(y.err.find("--jacobian: 'young' needs soft bodies, and this scene has none"), std::string::npos) << y.err;
  EXPECT_FALSE(fs::exists(dir / "young.h5"));
}

// configs/rigid_stack.yaml over 20 steps (rstack, 2026-12-03): the middle box lands at
// step 7, the top one at step 10, each on its four corners, and the stack rests.
// check-grad passes on every default block, on both contact backends, with the scene's
// own contact tolerance (1e-8; since rstk, 2026-12-04: before, the test set 1e-13).
// The zero blocks, friction, mass and inertia, are compared with the differences'
// round-off: the differences of the top box's angular velocity are 1.7e-13 rad/s (one
// ulp of a corner's height over h, over its lever arm), whatever the contact tolerance
// (the polish solves the modes to 1e-16), and the round-off bound of check-grad now
// scales the angular velocity rows so (docs/cli.md "check-grad"). Before, it failed
// at the landings (v[middle].wz at step 7: analytic -4.2e-3 against 0): the face's
// triangulation diagonal crossing the landing box's bottom edges gave edge-edge contacts
// whose normals (the edges' cross product) tilt away from the face's under a
// perturbation, so the sticking rows were inconsistent and the mode-fixed least-squares
// solve turned the box (contact_step.cpp drop_planar_rigid_edges; docs/method.md
// "Scenes of rigid bodies only").
TEST(CliRigidDerivatives, RigidStackCheckGradOverTheLandings) {
  const fs::path dir = fresh_dir(kWork, "rigid_stack_landings");
  const std::string stack = "'" + (kRoot / "configs/rigid_stack.yaml").string() + "'";
  for (const std::string backend : {"dense", "sparse"}) {
    const std::string args = stack + " --steps 20 --set contact.backend=" + backend;
    const auto r = run_cli("check-grad " + args + " --quiet --threads 1", dir);
    EXPECT_EQ(r.code, 0) << args << "\n" << r.out << r.err;
    for (const char* block : {"friction", "x0", "v0", "mass", "inertia"})
      EXPECT_NE(r.out.find(block), std::string::npos) << args << "\n" << r.out;
    EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << args << "\n" << r.out;
  }
}

// The table's line of a block (empty if absent) and its relative error.
std::string block_line(const std::string& out, const std::string& block) {
  const auto at = out.find("\n" + block + " ");
  if (at == std::string::npos) return "";
  return out.substr(at + 1, out.find('\n', at + 1) - at - 1);
}
double block_error(const std::string& line) {
  std::istringstream in(line);
  std::string name;
  long columns = 0;
  double rel = -1;
  in >> name >> columns >> rel;
  return rel;
}

// check-grad on the shipped rigid_stack as a user runs it (issue 21, rstk 2026-12-04):
// its default options (one step, eps 1e-4, tolerance 1e-5, the scene's contact
// tolerance 1e-8), and over the scene's whole duration (250 steps), on both backends.
// The stack rests from step 10 on, so friction, mass and inertia have zero analytic
// blocks and differences at their round-off: they are matched as zero within the
// printed round-off bound (measured at 100 steps: the differences' worst entries
// 1.8e-9, 8.0e-9 and 3.6e-5 against bounds 1.3e-6, 3.4e-6 and 1.4e-2 of the blocks'
// norms: the bound is conservative, by 1e-14 a row, see docs/cli.md). x0 and v0 are real comparisons:
// measured at most 2.4e-8 and 3.3e-8 over 1..250 steps (since x0/v0's steps use the
// boxes' radius of gyration; with the 1 m length before, v0 was 2.4e-6 dense and
// 7.1e-6 sparse, the landings' truncation), asserted 1e-6.
TEST(CliRigidDerivatives, RigidStackCheckGradWithItsDefaults) {
  const fs::path dir = fresh_dir(kWork, "rigid_stack_defaults");
  const std::string stack = "'" + (kRoot / "configs/rigid_stack.yaml").string() + "'";
  for (const std::string& args : {std::string(""), std::string(" --steps 250"),
                                 std::string(" --steps 250 --set contact.backend=sparse")}) {
    const auto r = run_cli("check-grad " + stack + args + " --quiet", dir);
    EXPECT_EQ(r.code, 0) << args << "\n" << r.out << r.err;
    EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << args << "\n" << r.out;
    for (const char* block : {"friction", "mass", "inertia"})
      EXPECT_NE(block_line(r.out, block).find("(zero: both within the round-off"), std::string::npos)
          << block << args << "\n" << r.out;
    for (const char* block : {"x0", "v0"}) {
      const std::string line = block_line(r.out, block);
      EXPECT_EQ(line.find("(zero"), std::string::npos) << block << args << "\n" << r.out;
      EXPECT_GE(block_error(line), 0.0) << block << args << "\n" << r.out;
      EXPECT_LE(block_error(line), 1e-6) << block << args << "\n" << r.out;
    }
  }
}

// check-grad still fails where the derivative is wrong (the round-off bound must not
// hide it): SOFTDIFF_CHECK_GRAD_FAULT (docs/cli.md, tests only) multiplies one analytic
// block. On rigid_stack over 20 steps: v0 zeroed (an analytic zero against resolved
// differences: relative error 1, ABOVE TOLERANCE, exit 1), x0 off by 1e-3 (relative
// error 1.000e-03, exit 1); on the spinner and pendulum beside the beam, inertia zeroed
// (a zero block where the differences are not zero); a malformed value is bad input.
TEST(CliRigidDerivatives, CheckGradReportsAWrongDerivative) {
  const fs::path dir = fresh_dir(kWork, "wrong_derivative");
  write_text(dir / "scene.yaml", rigid_scene());
  const std::string stack = "'" + (kRoot / "configs/rigid_stack.yaml").string() + "' --steps 20 --quiet";
  struct Case {
    std::string fault, args, block, error;
  };
  for (const Case& c : {Case{"v0:0", stack, "v0", "1.000e+00"}, Case{"x0:1.001", stack + " --wrt x0", "x0", "1.000e-03"},
                        Case{"inertia:0", "scene.yaml --quiet --wrt inertia", "inertia", "1.000e+00"}}) {
    ::setenv("SOFTDIFF_CHECK_GRAD_FAULT", c.fault.c_str(), 1);
    const auto r = run_cli("check-grad " + c.args, dir);
    ::unsetenv("SOFTDIFF_CHECK_GRAD_FAULT");
    EXPECT_EQ(r.code, 1) << c.fault << "\n" << r.out << r.err;
    const std::string line = block_line(r.out, c.block);
    EXPECT_NE(line.find("ABOVE TOLERANCE"), std::string::npos) << c.fault << "\n" << r.out;
    EXPECT_NE(line.find(c.error), std::string::npos) << c.fault << "\n" << r.out;
    EXPECT_EQ(line.find("(zero"), std::string::npos) << c.fault << "\n" << r.out;
    EXPECT_NE(r.err.find("a fault injected for the tests"), std::string::npos) << r.err;
    if (c.block == "v0") {  // the other blocks still pass
      for (const char* other : {"friction", "x0", "mass", "inertia"}) {
        EXPECT_EQ(block_line(r.out, other).find("ABOVE TOLERANCE"), std::string::npos) << other << "\n" << r.out;
      }
    }
  }
  ::setenv("SOFTDIFF_CHECK_GRAD_FAULT", "x0", 1);
  const auto bad = run_cli("check-grad " + stack, dir);
  ::unsetenv("SOFTDIFF_CHECK_GRAD_FAULT");
  EXPECT_EQ(bad.code, 2) << bad.err;
  EXPECT_NE(bad.err.find("SOFTDIFF_CHECK_GRAD_FAULT: 'x0' is not THETA:FACTOR"), std::string::npos) << bad.err;
}

// check-grad says when the analytic run used smoothed contact derivatives (issue 21,
// 2026-12-04, rgrip). The scene of the rsph report (test_contact_derivatives.cpp
// sphere_beam_scene): a rigid sphere's pole 0.28 mm from the diagonal of the beam's
// top-face triangle, margin 1e-3 m, so with the default smoothing (16 samples, sigma =
// margin / 10) the pole's contact takes the smoothed estimate and x0 fails by design
// (measured 9.1e-2, docs/method.md "A rigid sphere on the soft beam"): the JSON says
// `smoothed_contact_derivatives: true` with the count, stderr points at
// contact.smoothing.samples=0; with it the block passes (1.8e-8) and the field is false.
// Without contact the field is false too.
long json_long(const std::string& json, const std::string& key) {
  const auto at = json.find("\"" + key + "\":");
  if (at == std::string::npos) return -2;
  return std::stol(json.substr(at + key.size() + 3));
}

TEST(CliRigidDerivatives, CheckGradSaysWhenContactDerivativesWereSmoothed) {
  const fs::path dir = fresh_dir(kWork, "smoothed_contacts");
  write_text(dir / "scene.yaml", rigid_scenes::clamped_beam_yaml(1) +
                                     "  - name: ball\n    type: rigid\n    shape: {type: sphere, radius: 0.008}\n"
                                     "    density: 1000\n    position: [0.1013, 0.0117, 0.0282]\n"
                                     "    velocity: [0.05, 0.0, -0.1]\n"
                                     "contact:\n  pairs: [[beam, ball, 0.4]]\n  margin: 1.0e-3\n"
                                     "  tolerance: 1.0e-12\n  max_iterations: 5000\n  backend: dense\n");
  const std::string args = "check-grad scene.yaml --wrt x0 --quiet";
  const auto smoothed = run_cli(args + " --json", dir);
  EXPECT_EQ(smoothed.code, 1) << smoothed.out << smoothed.err;
  EXPECT_NE(smoothed.out.find("\"smoothed_contact_derivatives\":true"), std::string::npos) << smoothed.out;
  EXPECT_EQ(json_long(smoothed.out, "samples"), 16) << smoothed.out;
  EXPECT_GT(json_long(smoothed.out, "smoothed_contacts"), 0) << smoothed.out;
  EXPECT_NE(smoothed.err.find("smoothed contact derivatives"), std::string::npos) << smoothed.err;
  EXPECT_NE(smoothed.err.find("--set contact.smoothing.samples=0"), std::string::npos) << smoothed.err;
  const auto text = run_cli(args, dir);
  EXPECT_EQ(text.code, 1) << text.out << text.err;
  EXPECT_NE(text.out.find("contact derivatives: randomized smoothing"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("smoothed contact(s) over the analytic run's steps"), std::string::npos) << text.out;

  const auto exact = run_cli(args + " --json --set contact.smoothing.samples=0", dir);
  EXPECT_EQ(exact.code, 0) << exact.out << exact.err;
  EXPECT_NE(exact.out.find("\"smoothed_contact_derivatives\":false"), std::string::npos) << exact.out;
  EXPECT_EQ(json_long(exact.out, "smoothed_contacts"), 0) << exact.out;
  EXPECT_EQ(exact.err.find("smoothed contact derivatives"), std::string::npos) << exact.err;
  const auto exact_text = run_cli(args + " --set contact.smoothing.samples=0", dir);
  EXPECT_NE(exact_text.out.find("contact derivatives: exact (contact.smoothing off)"), std::string::npos)
      << exact_text.out;

  write_text(dir / "no_contact.yaml", beam());
  const auto none = run_cli("check-grad no_contact.yaml --wrt young --quiet --json", dir);
  EXPECT_EQ(none.code, 0) << none.out << none.err;
  EXPECT_NE(none.out.find("\"smoothed_contact_derivatives\":false"), std::string::npos) << none.out;
}

// rigid_stack under `integrator: bdf2` (issue 21, rstk; revised after rbimp). Before
// rigid impacts restarted BDF2 (rbimp, docs/method.md "BDF2", *Impacts: BDF2 restarts*)
// the middle box bounced off the base (v_z -0.137 m/s at step 7, +0.057, +0.108), the top
// box landed on a moving box and the run was not smooth beyond step 9 (docs/method.md
// "Scenes of rigid bodies only", *rigid_stack under BDF2*): this test then ran 12 steps
// at eps 1e-7. With the restart the landings are inelastic and the run over 9 and 12
// steps is smooth at check-grad's defaults: measured 2026-12-04 over 12 steps, x0 1.5e-8
// and v0 2.5e-8 at eps 1e-4 (2.3e-10, 3.2e-10 at 1e-5); friction, mass and inertia zero
// within the round-off. At eps 1e-7 the differences are round-off (check-grad's
// round-off column 3.5e-3 for x0, against the 1.6e-5 error it then shows). The landings
// over 20 steps: RigidStackCheckGradOverTheLandingsUnderBdf2 (rbimp).
TEST(CliRigidDerivatives, RigidStackCheckGradUnderBdf2AtSmoothPoints) {
  const fs::path dir = fresh_dir(kWork, "rigid_stack_bdf2");
  const std::string stack =
      "'" + (kRoot / "configs/rigid_stack.yaml").string() + "' --quiet --set simulation.integrator=bdf2";
  for (const std::string& args : {std::string(" --steps 9"), std::string(" --steps 12")}) {
    const auto r = run_cli("check-grad " + stack + args, dir);
    EXPECT_EQ(r.code, 0) << args << "\n" << r.out << r.err;
    EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << args << "\n" << r.out;
  }
}

TEST(CliRigidDerivatives, RigidParametersNeedRigidBodies) {
  const fs::path dir = fresh_dir(kWork, "no_rigid");
  write_text(dir / "scene.yaml", beam());
  const auto r = run_cli("simulate scene.yaml -o out.h5 --jacobian young,mass", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("--jacobian: 'mass' needs rigid bodies, and this scene has none"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));
}

// Through a joint limit in contact (issue 21, "rlim"; it was refused, exit 2): the
// slider block of test_cli_rigid.cpp's SliderBlockLandsOnItsLimitAboveTheFloor falls onto
// its lower limit (by step 5 of 10) 0.2 mm above a floor, within the contact margin, so
// that the NCP has the floor's contacts (inactive) and the limit's row (active) from then
// on. check-grad --steps 10 passes (measured: young 6.8e-9, x0 4.7e-7, v0 1.6e-7
// relative; mass 0: held by its limit, the block's state does not depend on its mass),
// and simulate --jacobian runs.
TEST(CliRigidDerivatives, CheckGradThroughAJointLimitInContact) {
  const fs::path dir = fresh_dir(kWork, "check_grad_limit_contact");
  write_text(dir / "scene.yaml",
             beam() +
                 "  - name: block\n"
                 "    type: rigid\n"
                 "    shape: {type: box, half_extents: [0.02, 0.02, 0.01]}\n"
                 "    density: 1000\n"
                 "    position: [0.5, 0.3, 0]\n"
                 "    joint: {type: slider, anchor: [0.5, 0.3, 0], axis: [0, 0, 1], limits: [-0.01, 0.05]}\n"
                 "obstacles: [{name: floor, type: plane, normal: [0, 0, 1], offset: -0.0202}]\n"
                 "contact: {friction: 0.3, margin: 1.0e-3, pairs: [[block, floor, 0.3]]}\n");
  const auto r = run_cli("check-grad scene.yaml --quiet --steps 10 --wrt young,x0,v0,mass --directions 2", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  for (const char* block : {"young", "x0", "v0", "mass"}) EXPECT_NE(r.out.find(block), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  const auto j = run_cli("simulate scene.yaml -o out.h5 --steps 10 --jacobian mass", dir);
  EXPECT_EQ(j.code, 0) << j.err;
  EXPECT_TRUE(fs::exists(dir / "out.h5"));
  // The sparse backend (rpsp; it was refused, exit 2): the limit rows' derivative on the
  // extended rigid rows Kt (no dense G), as a dense G_AA and on the operator (the
  // derivative's crossovers 0); the same check-grad, and --jacobian runs.
  for (const std::string set :
       {"--set contact.backend=sparse", "--set contact.backend=sparse --set contact.derivative_dense_max_active=0 "
                                        "--set contact.derivative_mixed_dense_max_active=0"}) {
    const auto s = run_cli("check-grad scene.yaml --quiet --steps 10 --wrt young,x0,v0,mass --directions 2 " + set, dir);
    EXPECT_EQ(s.code, 0) << set << "\n" << s.out << s.err;
    for (const char* block : {"young", "x0", "v0", "mass"})
      EXPECT_NE(s.out.find(block), std::string::npos) << set << "\n" << s.out;
    EXPECT_EQ(s.out.find("ABOVE TOLERANCE"), std::string::npos) << set << "\n" << s.out;
  }
  const auto s =
      run_cli("simulate scene.yaml -o out_sparse.h5 --steps 10 --jacobian mass --set contact.backend=sparse", dir);
  EXPECT_EQ(s.code, 0) << s.err;
  EXPECT_TRUE(fs::exists(dir / "out_sparse.h5"));
}

// The same scene under bdf2 (issue 21, rbdlim; refused before, exit 2): the block falls
// by BDF2 steps, its landing step and the steps resting on the limit are the implicit
// Euler contact step from s_n (integrator/bdf2.cpp), and the derivatives follow each
// step's branch. check-grad --steps 10 passes on the dense backend, and simulate under
// bdf2 rests on the limit (-0.01 m to the NCP's tolerance, never beyond).
TEST(CliRigidDerivatives, CheckGradThroughAJointLimitInContactUnderBdf2) {
  const fs::path dir = fresh_dir(kWork, "check_grad_limit_contact_bdf2");
  write_text(dir / "scene.yaml",
             beam() +
                 "  - name: block\n"
                 "    type: rigid\n"
                 "    shape: {type: box, half_extents: [0.02, 0.02, 0.01]}\n"
                 "    density: 1000\n"
                 "    position: [0.5, 0.3, 0]\n"
                 "    joint: {type: slider, anchor: [0.5, 0.3, 0], axis: [0, 0, 1], limits: [-0.01, 0.05]}\n"
                 "obstacles: [{name: floor, type: plane, normal: [0, 0, 1], offset: -0.0202}]\n"
                 "contact: {friction: 0.3, margin: 1.0e-3, pairs: [[block, floor, 0.3]]}\n");
  const std::string bdf2 = " --set simulation.integrator=bdf2";
  const auto r = run_cli("check-grad scene.yaml --steps 10 --wrt young,x0,v0,mass --directions 2" + bdf2, dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  std::cout << r.out;
  for (const char* block : {"young", "x0", "v0", "mass"}) EXPECT_NE(r.out.find(block), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  const auto j = run_cli("simulate scene.yaml -o out.h5 --steps 10 --jacobian mass" + bdf2, dir);
  EXPECT_EQ(j.code, 0) << j.err;
  EXPECT_TRUE(fs::exists(dir / "out.h5"));
}

}  // namespace cli_rigid_derivatives_test

namespace cli_rigid_derivatives_test {

// configs/rigid_stack.yaml under bdf2 over its landings (2026-12-04, rbimp; before, BDF2
// bounced there and check-grad failed: x0 2.1, v0 2.5 relative): the middle box lands at
// step 8, the top one at step 10; steps 8-12 are restarted as implicit Euler contact
// steps (integrator/bdf2.cpp rigid_impact), the others BDF2.
// check-grad --steps 20 passes on x0 and v0 with eps 1e-5 (measured: x0 8.2e-7, v0
// 1.8e-6 relative). Not at the default eps 1e-4: a v0 direction of 1e-4 (and of 2e-5,
// 5e-5) of its scale moves one perturbed run across a kink of the landing (a corner's
// contact mode: the difference is exactly half the analytic value, v[middle].wy 3.48
// against 6.95 after 8 steps; at 1e-5 they agree to 2.5e-8, at 1e-6 to 9e-11). The mass
// and inertia blocks are analytically zero at rest (the boxes' positions do not depend on
// them) and their differences are the contact solve's noise; the derivatives through the
// restart with mass and inertia columns are test_rigid's WedgeDroppedOntoThePlane.
TEST(CliRigidDerivatives, RigidStackCheckGradOverTheLandingsUnderBdf2) {
  const fs::path dir = fresh_dir(kWork, "rigid_stack_landings_bdf2");
  const std::string stack = "'" + (kRoot / "configs/rigid_stack.yaml").string() + "'";
  const auto r = run_cli("check-grad " + stack +
                             " --steps 20 --set contact.tolerance=1e-13 --set contact.max_iterations=5000"
                             " --set simulation.integrator=bdf2 --wrt x0,v0 --eps 1e-5 --quiet --threads 1",
                         dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  for (const char* block : {"x0", "v0"}) EXPECT_NE(r.out.find(block), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
}

}  // namespace cli_rigid_derivatives_test
