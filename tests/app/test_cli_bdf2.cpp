// `integrator: bdf2` end to end through the command line (docs/scene.md, docs/method.md
// "BDF2"): simulate --jacobian against central differences of whole runs; check-grad
// with and without contact (its blocks are central differences of BDF2 runs);
// calibrate recovers young from a BDF2 target; control reaches a goal with BDF2; info
// names the integrator; a misspelt integrator exits 2 with the valid names and no file.
// Steps and tolerances as in test_cli_derivatives.cpp (1e-5 of the values; 1e-6
// relative: the central differences' error is ~1e-8 there).
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <Eigen/Core>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace cli_bdf2 {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_bdf2";

// The shipped beam, clamped, with a translation servo on its tip, BDF2, 10 steps.
std::string beam_scene() {
  return "softdiff: 1\n"
         "simulation: {integrator: bdf2, dt: 0.01, steps: 10}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
         "    material: {law: neo_hookean, young: 2.0e5, poisson: 0.4, density: 1000}\n"
         "    damping: {rayleigh_mass: 0.5}\n"
         "    fixed:\n"
         "      - group: clamp\n"
         "    actuators:\n"
         "      - name: pull\n"
         "        type: servo\n"
         "        nodes: {box: [0.19, -1, -1, 1, 1, 1]}\n"
         "        direction: [0, 1, 0]\n"
         "        force: 0.02\n"
         "    effectors:\n"
         "      - {name: tip, point: [0.2, 0.01, 0.01]}\n";
}

// The final frame's positions (node-major), from /bodies/beam/x (T, n, 3).
Eigen::VectorXd final_x(const fs::path& file) { return h5_final_frame(file.string(), "/bodies/beam/x"); }

double json_number(const std::string& json, const std::string& key) {
  const auto k = json.find("\"" + key + "\":");
  if (k == std::string::npos) return std::nan("");
  return std::strtod(json.c_str() + k + key.size() + 3, nullptr);
}


TEST(CliBdf2, JacobianMatchesDifferencesOfRuns) {
  const auto dir = fresh_dir(kWork, "jacobian");
  write_text(dir / "scene.yaml", beam_scene());
  const CliRun r = run_cli("simulate scene.yaml -o out.h5 --jacobian young,actuation", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const std::vector<double> dyoung = h5_read(f, "/jacobians/young"), dact = h5_read(f, "/jacobians/actuation");
  H5Fclose(f);
  struct Check {
    std::string key;
    double value;
    const std::vector<double>* column;
  };
  for (const Check& c : {Check{"bodies.beam.material.young", 2.0e5, &dyoung},
                         Check{"bodies.beam.actuators.pull.force", 0.02, &dact}}) {
    const double e = 1e-5 * c.value;
    char plus[128], minus[128];
    std::snprintf(plus, sizeof plus, "%s=%.17g", c.key.c_str(), c.value + e);
    std::snprintf(minus, sizeof minus, "%s=%.17g", c.key.c_str(), c.value - e);
    ASSERT_EQ(run_cli(std::string("simulate scene.yaml -o p.h5 --force --set ") + plus, dir).code, 0);
    ASSERT_EQ(run_cli(std::string("simulate scene.yaml -o m.h5 --force --set ") + minus, dir).code, 0);
    const Eigen::VectorXd fd = (final_x(dir / "p.h5") - final_x(dir / "m.h5")) / (2 * e);
    const Eigen::Map<const Eigen::VectorXd> analytic(c.column->data(), static_cast<Eigen::Index>(c.column->size()));
    ASSERT_GT(fd.norm(), 0) << c.key;
    EXPECT_LE((analytic - fd).norm(), 1e-6 * fd.norm()) << c.key << ": " << (analytic - fd).norm() / fd.norm();
  }
  // The BDF2 run differs from the implicit Euler one (the integrator is used).
  ASSERT_EQ(run_cli("simulate scene.yaml -o euler.h5 --set simulation.integrator=implicit_euler", dir).code, 0);
  EXPECT_GT((final_x(dir / "euler.h5") - final_x(dir / "out.h5")).norm(), 0);
}

TEST(CliBdf2, CheckGradEveryBlockPasses) {
  const auto dir = fresh_dir(kWork, "check_grad");
  write_text(dir / "scene.yaml", beam_scene());
  const CliRun r = run_cli("check-grad scene.yaml --steps 3", dir);
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  for (const char* block : {"young", "poisson", "density", "rayleigh_mass", "rayleigh_stiffness", "actuation", "x0", "v0"})
    EXPECT_NE(r.out.find(std::string("\n") + block + " "), std::string::npos) << block << " missing in:\n" << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
}

// The beam pressed 0.1 mm into a plane, resting and sticking (mu = 0.5), 3 BDF2 steps
// (test_cli_contact.cpp's case with the second and third steps BDF2). --eps 1e-5: at
// check-grad's default 1e-4 the x0 block's central differences carry a truncation
// error of 5.7e-5 relative (measured; 5.9e-7 at 1e-5, the h^2 scaling of truncation):
// the extrapolation x^ = 4/3 x_n - 1/3 x_{n-1} moves the contact points further per
// unit of x0 than implicit Euler's x_i, so the runs are more curved in x0.
std::string bdf2_contact_scene(const std::string& simulation_extra) {
  return "softdiff: 1\n"
         "simulation: {integrator: bdf2, dt: 0.005, steps: 3" + simulation_extra + "}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
         "    translate: [0, 0, -0.0001]\n"
         "    material: {law: corotational, young: 1.0e5, poisson: 0.3, density: 1000}\n"
         "obstacles:\n"
         "  - {name: floor, type: plane, normal: [0, 0, 1], offset: 0}\n"
         "contact:\n"
         "  friction: 0.5\n"
         "  tolerance: 1.0e-13\n"
         "  max_iterations: 20000\n";
}

// The same with Newton (docs/method.md "Newton iterations with contact"): the implicit
// function theorem at each converged BDF2 stage (converged to 1e-12, 30 iterations at
// most, so that the differences see the converged map). young and x0 at --eps 1e-5 (as
// above); friction at the default 1e-4: the first step's Newton stops at a relative
// residual of ~1.6e-11 (it does not reach 1e-14 in 30 iterations), noise that the
// friction block's differences at 1e-5 divide into 1.2e-5 relative (measured), at 1e-4
// into 1.2e-6.
TEST(CliBdf2, CheckGradThroughContactWithNewton) {
  const auto dir = fresh_dir(kWork, "check_grad_contact_newton");
  write_text(dir / "scene.yaml", bdf2_contact_scene(", newton_iterations: 30, newton_tolerance: 1.0e-12"));
  for (const std::string args : {"--wrt young,x0 --directions 2 --eps 1e-5", "--wrt friction"}) {
    const CliRun r = run_cli("check-grad scene.yaml --steps 3 " + args, dir);
    EXPECT_EQ(r.code, 0) << r.out << r.err;
    EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  }
}

TEST(CliBdf2, CheckGradThroughContact) {
  const auto dir = fresh_dir(kWork, "check_grad_contact");
  write_text(dir / "scene.yaml",
             "softdiff: 1\n"
             "simulation: {integrator: bdf2, dt: 0.005, steps: 3}\n"
             "bodies:\n"
             "  - name: beam\n"
             "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
             "    translate: [0, 0, -0.0001]\n"
             "    material: {law: corotational, young: 1.0e5, poisson: 0.3, density: 1000}\n"
             "obstacles:\n"
             "  - {name: floor, type: plane, normal: [0, 0, 1], offset: 0}\n"
             "contact:\n"
             "  friction: 0.5\n"
             "  tolerance: 1.0e-13\n"
             "  max_iterations: 20000\n");
  const CliRun r = run_cli("check-grad scene.yaml --steps 3 --wrt young,friction,x0 --directions 2 --eps 1e-5", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  for (const char* block : {"young", "friction", "x0"})
    EXPECT_NE(r.out.find(std::string("\n") + block + " "), std::string::npos) << r.out;
}

TEST(CliBdf2, CalibrateRecoversYoung) {
  const auto dir = fresh_dir(kWork, "calibrate");
  write_text(dir / "scene.yaml", beam_scene());
  ASSERT_EQ(run_cli("simulate scene.yaml -o target.h5 --quiet --steps 5", dir).code, 0);
  const CliRun r =
      run_cli("calibrate scene.yaml --param young --init 1e5 --target target.h5 -o cal.h5 --json --set simulation.steps=5", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NEAR(json_number(r.out, "young") / 2e5, 1.0, 1e-6) << r.out;
  EXPECT_NE(r.out.find("\"converged\":true"), std::string::npos) << r.out;
}

// test_cli_control.cpp's goal with BDF2, and damping rayleigh_mass 20 over 60 steps
// (there 5 over 40): the one-step-ahead controller saturates its servo (bang-bang at
// the limits) and, without implicit Euler's numerical damping, the tip then oscillates
// about the goal by up to 2 mm with damping 5 (measured); with 20 it settles within
// 1e-4 m.
TEST(CliBdf2, ControlReachesAGoal) {
  const auto dir = fresh_dir(kWork, "control");
  write_text(dir / "scene.yaml",
             "softdiff: 1\n"
             "simulation: {integrator: bdf2, dt: 0.01, steps: 60, gravity: [0, 0, 0]}\n"
             "bodies:\n"
             "  - name: beam\n"
             "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
             "    material: {law: corotational, young: 2.0e5, poisson: 0.4, density: 1000}\n"
             "    damping: {rayleigh_mass: 20}\n"
             "    fixed:\n"
             "      - group: clamp\n"
             "    actuators:\n"
             "      - {name: pull, type: servo, nodes: {box: [0.19, -1, -1, 1, 1, 1]}, direction: [0, 1, 0], force: 0, "
             "limits: [-0.05, 0.05]}\n"
             "    effectors:\n"
             "      - {name: tip, point: [0.2, 0.01, 0.01]}\n");
  ASSERT_EQ(run_cli("simulate scene.yaml -o goal.h5 --quiet --set bodies.beam.actuators.pull.force=0.02 --steps 100", dir).code, 0);
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  hid_t f = H5Fopen((dir / "goal.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const std::vector<double> p = h5_read(f, "/bodies/beam/effectors/tip");
  H5Fclose(f);
  char target[128];
  std::snprintf(target, sizeof target, "%.17g,%.17g,%.17g", p[p.size() - 3], p[p.size() - 2], p[p.size() - 1]);
  const CliRun r = run_cli(std::string("control scene.yaml --target=") + target + " -o c.h5 --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  f = H5Fopen((dir / "c.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const std::vector<double> d = h5_read(f, "/control/distance");
  H5Fclose(f);
  EXPECT_GT(d.front(), 1e-3);
  EXPECT_LT(d.back(), 1e-4) << "from " << d.front();
}

TEST(CliBdf2, InfoNamesItAndABadNameExitsTwo) {
  const auto dir = fresh_dir(kWork, "info");
  write_text(dir / "scene.yaml", beam_scene());
  const CliRun i = run_cli("info scene.yaml", dir);
  ASSERT_EQ(i.code, 0) << i.err;
  EXPECT_NE(i.out.find("integrator  bdf2, dt 0.01 s"), std::string::npos) << i.out;
  const CliRun r = run_cli("simulate scene.yaml -o out.h5 --set simulation.integrator=bdf3", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("bdf2"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));
}

}  // namespace cli_bdf2
