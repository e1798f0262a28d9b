// softdiff control (docs/cli.md, docs/output.md /control): end to end on the shipped
// beam mesh with a translation servo on its tip (limits [-0.05, 0.05] N) and an
// effector there: a goal the servo can reach (made by `simulate` with 0.02 N) is
// reached, with the /control datasets of the contract, the tension within its limits;
// a timed-goals CSV; every kind of bad input exits 2 with a message and no file.
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_control";

std::string scene(const std::string& extra_body = "", const std::string& extra = "") {
  return "softdiff: 1\n"
         "simulation: {dt: 0.01, steps: 40, gravity: [0, 0, 0]}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
         "    material: {law: corotational, young: 2.0e5, poisson: 0.4, density: 1000}\n"
         "    damping: {rayleigh_mass: 5}\n"
         "    fixed:\n"
         "      - group: clamp\n"
         "    actuators:\n"
         "      - {name: pull, type: servo, nodes: {box: [0.19, -1, -1, 1, 1, 1]}, direction: [0, 1, 0], force: 0, "
         "limits: [-0.05, 0.05]}\n"
         "    effectors:\n"
         "      - {name: tip, point: [0.2, 0.01, 0.01]}\n" + extra_body + extra;
}

std::vector<double> final_tip(const fs::path& file) {
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const std::vector<double> p = h5_read(f, "/bodies/beam/effectors/tip");
  H5Fclose(f);
  return {p[p.size() - 3], p[p.size() - 2], p[p.size() - 1]};
}

TEST(CliControl, ReachesAGoalTheServoCanReach) {
  const auto dir = fresh_dir(kWork, "reach");
  write_text(dir / "scene.yaml", scene());
  // The goal: where 0.02 N leaves the tip after the run (simulate with --set).
  ASSERT_EQ(run_cli("simulate scene.yaml -o goal.h5 --quiet --set bodies.beam.actuators.pull.force=0.02 --steps 100", dir).code, 0);
  const auto g = final_tip(dir / "goal.h5");
  char target[128];
  std::snprintf(target, sizeof target, "%.17g,%.17g,%.17g", g[0], g[1], g[2]);
  const CliRun r = run_cli(std::string("control scene.yaml --target=") + target + " -o c.h5 --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"within_limits\":true"), std::string::npos) << r.out;
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen((dir / "c.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto T = h5_shape(f, "/time")[0];
  EXPECT_EQ(T, 41u);
  EXPECT_EQ(h5_shape(f, "/control/goal"), (std::vector<hsize_t>{T, 3}));
  EXPECT_EQ(h5_shape(f, "/control/distance"), (std::vector<hsize_t>{T}));
  EXPECT_EQ(h5_shape(f, "/control/actuation"), (std::vector<hsize_t>{T, 1}));
  EXPECT_TRUE(h5_shape(f, "/control/contact_force_norm").empty());  // no contact in this scene
  const std::vector<double> d = h5_read(f, "/control/distance"), a = h5_read(f, "/control/actuation");
  const std::vector<double> kkt = h5_read(f, "/control/kkt_residual");
  H5Fclose(f);
  EXPECT_GT(d.front(), 1e-3);
  EXPECT_LT(d.back(), 1e-4) << "from " << d.front();
  for (double v : a) EXPECT_TRUE(v >= -0.05 && v <= 0.05) << v;
  for (double v : kkt) EXPECT_LE(v, 1e-8);
}

TEST(CliControl, FollowsTimedGoals) {
  const auto dir = fresh_dir(kWork, "timed");
  write_text(dir / "scene.yaml", scene());
  write_text(dir / "goals.csv", "time,x,y,z\n0,0.2,0.01,0.01\n0.4,0.2,0.015,0.01\n");
  const CliRun r = run_cli("control scene.yaml --target goals.csv -o c.h5", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const hid_t f = H5Fopen((dir / "c.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const std::vector<double> goal = h5_read(f, "/control/goal");
  H5Fclose(f);
  // Linear between the two goals: at frame 20 (t = 0.2) y = 0.0125.
  EXPECT_NEAR(goal[3 * 20 + 1], 0.0125, 1e-12);
  EXPECT_NEAR(goal[3 * 40 + 1], 0.015, 1e-12);
}

TEST(CliControl, BadInputExitsTwoWithoutOutput) {
  const auto dir = fresh_dir(kWork, "bad");
  write_text(dir / "scene.yaml", scene());
  write_text(dir / "no_effector.yaml",
             "softdiff: 1\nsimulation: {dt: 0.01, steps: 5}\nbodies:\n  - name: beam\n    mesh: " +
                 (kRoot / "meshes/beam.msh").string() +
                 "\n    material: {law: corotational, young: 2.0e5, poisson: 0.4, density: 1000}\n    fixed:\n"
                 "      - group: clamp\n    actuators:\n      - {name: pull, type: servo, nodes: {box: [0.19, -1, -1, 1, 1, 1]}, "
                 "direction: [0, 1, 0], force: 0}\n");
  write_text(dir / "no_actuator.yaml",
             "softdiff: 1\nsimulation: {dt: 0.01, steps: 5}\nbodies:\n  - name: beam\n    mesh: " +
                 (kRoot / "meshes/beam.msh").string() +
                 "\n    material: {law: corotational, young: 2.0e5, poisson: 0.4, density: 1000}\n    fixed:\n"
                 "      - group: clamp\n    effectors:\n      - {name: tip, point: [0.2, 0.01, 0.01]}\n");
  write_text(dir / "bad_header.csv", "t,x,y,z\n0,0,0,0\n");
  write_text(dir / "bad_line.csv", "time,x,y,z\n0,0,0,0\n0.1,0,nan,0\n");
  write_text(dir / "decreasing.csv", "time,x,y,z\n0.2,0,0,0\n0.1,0,0,0\n");
  write_text(dir / "exists.h5", "x");
  struct Case {
    std::string args, message;
  };
  const Case cases[] = {
      {"scene.yaml --target 1,2", "--target 1,2: expected X,Y,Z"},
      {"scene.yaml --target goals.csv", "--target goals.csv: expected X,Y,Z (three numbers, metres) or a CSV file"},
      {"scene.yaml --target bad_header.csv", "bad_header.csv:1: expected the header line 'time,x,y,z'"},
      {"scene.yaml --target bad_line.csv", "bad_line.csv:3: y: expected a finite number, got 'nan'"},
      {"scene.yaml --target decreasing.csv", "decreasing.csv:3: times must increase"},
      {"scene.yaml --target 0,0,0 --effector toe", "--effector toe: no such effector (the scene has beam.tip)"},
      {"scene.yaml --target 0,0,0 --weights 1", "--weights 1: expected alpha,beta"},
      {"scene.yaml --target 0,0,0 --weights 1,-1", "--weights 1,-1: expected alpha,beta"},
      {"scene.yaml --target 0,0,0 --weights 1,0.5", "the contact-force weight beta needs contact"},
      {"scene.yaml --target 0,0,0 --axes w", "--axes w: expected a subset of xyz"},
      {"scene.yaml --target 0,0,0 --filter 0", "--filter 0: must be in (0, 1]"},
      {"scene.yaml --target 0,0,0 --filter 1.5", "--filter 1.5: must be in (0, 1]"},
      {"no_effector.yaml --target 0,0,0", "the scene has no effectors"},
      {"no_actuator.yaml --target 0,0,0", "the scene has no actuators"},
      {"scene.yaml --target 0,0,0 --set simulation.integrator=static --set simulation.dt=null --set simulation.steps=null",
       "the scene's integrator must be implicit_euler"},
      {"scene.yaml --target 0,0,0 -o exists.h5", "exists.h5"},
  };
  for (const Case& c : cases) {
    const bool to_existing = c.args.find("exists.h5") != std::string::npos;
    const CliRun r = run_cli("control " + c.args + (to_existing ? "" : " -o out.h5"), dir);
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_FALSE(fs::exists(dir / "out.h5")) << c.args;
    EXPECT_FALSE(fs::exists(dir / "out.h5.partial")) << c.args;
    EXPECT_EQ(read_text(dir / "exists.h5"), "x");
  }
}

// A rigid body in contact (issue 21): the servo pulls the tip (+y) against a free rigid
// block (2.7 g, no gravity) standing 0.5 mm beside it; the goal lies 5 mm beyond, so the
// tip pushes the block away. control runs, writes /control as for soft scenes, with the
// contact-force norm of the beam's contacts with the block (another side) > 0 once they
// touch, the servo within its limits, and the block pushed along +y.
std::string block(const std::string& joint = "") {
  return "  - name: block\n"
         "    type: rigid\n"
         "    shape: {type: box, half_extents: [0.015, 0.005, 0.015]}\n"
         "    density: 300\n"
         "    position: [0.19, 0.0255, 0.01]\n" + joint;
}
const std::string kBlockContact = "contact: {friction: 0.3, pairs: [[beam, block, 0.3]]}\n";

// newton: the same with newton_iterations 4 (rnewtd: the Newton step with rigid contact
// is differentiated; it was refused, exit 2), the same assertions.
void pushes_a_free_rigid_block(bool newton) {
  const auto dir = fresh_dir(kWork, newton ? "rigid_block_newton" : "rigid_block");
  write_text(dir / "scene.yaml", scene(block(), kBlockContact));
  const CliRun r = run_cli(std::string("control scene.yaml --target 0.2,0.025,0.01 --axes y --weights 1,1 -o c.h5 --json") +
                               (newton ? " --set simulation.newton_iterations=4" : ""),
                           dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"within_limits\":true"), std::string::npos) << r.out;
  const hid_t f = H5Fopen((dir / "c.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto T = h5_shape(f, "/time")[0];
  EXPECT_EQ(T, 41u);
  EXPECT_EQ(h5_shape(f, "/control/contact_force_norm"), (std::vector<hsize_t>{T}));
  EXPECT_EQ(h5_shape(f, "/control/actuation"), (std::vector<hsize_t>{T, 1}));
  const std::vector<double> force = h5_read(f, "/control/contact_force_norm"), a = h5_read(f, "/control/actuation");
  const std::vector<double> p = h5_read(f, "/bodies/block/position"), kkt = h5_read(f, "/control/kkt_residual");
  H5Fclose(f);
  EXPECT_GT(*std::max_element(force.begin(), force.end()), 1e-4);  // the tip pushed the block
  EXPECT_GT(p[3 * (T - 1) + 1] - p[1], 1e-3);                      // and the block moved along +y
  for (double v : a) EXPECT_TRUE(v >= -0.05 && v <= 0.05) << v;
  for (double v : kkt) EXPECT_LE(v, 1e-8);
}

TEST(CliControl, PushesAFreeRigidBlock) { pushes_a_free_rigid_block(false); }

TEST(CliControl, PushesAFreeRigidBlockWithNewton) { pushes_a_free_rigid_block(true); }

// A limited joint in contact runs on both backends (issue 21's rlim on the dense one; on
// the sparse one since rpsp: it was refused, exit 2), and bdf2 with rigid bodies in
// contact since rbd2.
TEST(CliControl, RigidBodiesWithALimitedJointOrBdf2Run) {
  const auto dir = fresh_dir(kWork, "rigid_refused");
  write_text(dir / "bdf2.yaml", scene(block(), kBlockContact));
  write_text(dir / "limits.yaml",
             scene(block("    joint: {type: slider, anchor: [0.19, 0.0255, 0.01], axis: [0, 1, 0], limits: [-0.01, 0.01]}\n"),
                   kBlockContact));
  const CliRun ok = run_cli("control limits.yaml --target 0,0,0 -o limits.h5", dir);
  EXPECT_EQ(ok.code, 0) << ok.err;
  EXPECT_TRUE(fs::exists(dir / "limits.h5"));
  const CliRun sparse = run_cli("control limits.yaml --target 0,0,0 --set contact.backend=sparse -o limits_sparse.h5", dir);
  EXPECT_EQ(sparse.code, 0) << sparse.err;
  EXPECT_TRUE(fs::exists(dir / "limits_sparse.h5"));
  // bdf2 with rigid bodies in contact runs since issue 21's rbd2 (it was refused).
  const CliRun bdf2 = run_cli("control bdf2.yaml --target 0,0,0 --set simulation.integrator=bdf2 -o bdf2.h5", dir);
  EXPECT_EQ(bdf2.code, 0) << bdf2.err;
  EXPECT_TRUE(fs::exists(dir / "bdf2.h5"));
}

}  // namespace
