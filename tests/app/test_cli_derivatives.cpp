// simulate --jacobian (docs/cli.md, docs/output.md /jacobians/*): the datasets exist with
// the contract's shape and attributes, and their values are the central differences
// of two runs with --set (end to end: scene parsing, parameters, actuators, output).
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <Eigen/Core>

#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_derivatives";

// The shipped beam, clamped, with a translation servo on its tip, 10 steps.
std::string scene() {
  return "softdiff: 1\n"
         "simulation: {dt: 0.01, steps: 10}\n"
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
         "        force: 0.02\n";
}

// The final frame's positions (node-major), from /bodies/beam/x (T, n, 3).
Eigen::VectorXd final_x(const fs::path& file) { return h5_final_frame(file.string(), "/bodies/beam/x"); }

TEST(CliDerivatives, JacobianDatasetsMatchDifferencesOfRuns) {
  const auto dir = fresh_dir(kWork, "jacobian");
  write_text(dir / "scene.yaml", scene());
  const CliRun r = run_cli("simulate scene.yaml -o out.h5 --jacobian young,actuation,rayleigh_mass", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto x_dims = h5_shape(f, "/bodies/beam/x");
  const hsize_t n3 = 3 * x_dims[1];
  for (const char* name : {"young", "actuation", "rayleigh_mass"}) {
    const auto d = h5_shape(f, std::string("/jacobians/") + name);
    ASSERT_EQ(d.size(), 2u) << name;
    EXPECT_EQ(d[0], n3) << name;
    EXPECT_EQ(d[1], 1u) << name;
    EXPECT_EQ(h5_number_attribute(f, std::string("/jacobians/") + name, "frame"), 10.0) << name;
  }
  EXPECT_EQ(h5_string_attribute(f, "/jacobians/young", "theta"), "young[beam]");
  EXPECT_EQ(h5_string_attribute(f, "/jacobians/actuation", "theta"), "actuation[pull]");
  const std::vector<double> dyoung = h5_read(f, "/jacobians/young"), dact = h5_read(f, "/jacobians/actuation");
  H5Fclose(f);
  // Central differences of two runs each; steps 1e-5 of the values (see
  // tests/integrator/test_step_derivatives.cpp), tolerance 1e-6 relative.
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
  EXPECT_NE(r.err.find("derivatives"), std::string::npos) << r.err;  // the summary's split
}

}  // namespace

namespace {

bool no_output_files(const fs::path& dir) {
  for (const auto& entry : fs::directory_iterator(dir)) {
    const auto ext = entry.path().extension();
    if (ext == ".h5" || ext == ".xmf" || ext == ".partial") return false;
  }
  return true;
}

TEST(CliCheckGrad, EveryBlockPassesAndNoFileIsWritten) {
  const auto dir = fresh_dir(kWork, "check_grad");
  write_text(dir / "scene.yaml", scene());
  const CliRun r = run_cli("check-grad scene.yaml --steps 2", dir);
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  for (const char* block : {"young", "poisson", "density", "rayleigh_mass", "rayleigh_stiffness", "actuation", "x0", "v0"})
    EXPECT_NE(r.out.find(std::string("\n") + block + " "), std::string::npos) << block << " missing in:\n" << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  EXPECT_TRUE(no_output_files(dir));
  const CliRun j = run_cli("check-grad scene.yaml --steps 2 --wrt young,x0 --json", dir);
  ASSERT_EQ(j.code, 0) << j.err;
  EXPECT_NE(j.out.find("\"passed\":true"), std::string::npos) << j.out;
  EXPECT_NE(j.out.find("\"theta\":\"x0\""), std::string::npos) << j.out;
}

TEST(CliCheckGrad, ABlockAboveTheToleranceExitsOne) {
  // A tolerance no finite difference can meet: the check must be able to fail.
  const auto dir = fresh_dir(kWork, "check_grad_fail");
  write_text(dir / "scene.yaml", scene());
  const CliRun r = run_cli("check-grad scene.yaml --wrt young --tolerance 1e-300", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  EXPECT_NE(r.err.find("above the tolerance"), std::string::npos) << r.err;
}

TEST(CliCheckGrad, BadInputExitsTwo) {
  const auto dir = fresh_dir(kWork, "check_grad_bad");
  write_text(dir / "scene.yaml", scene());
  struct Case {
    std::string args, expect;
  };
  for (const Case& c : {Case{"check-grad scene.yaml --wrt yung", "unknown name 'yung'"},
                        Case{"check-grad scene.yaml --wrt friction", "'friction' needs contact"},
                        Case{"check-grad scene.yaml --steps 0", "--steps"},
                        Case{"check-grad scene.yaml --eps -1", "--eps"},
                        Case{"check-grad nothere.yaml", "nothere.yaml"},
                        Case{"check-grad scene.yaml --set bodies.beam.material.yung=3", "yung"}}) {
    const CliRun r = run_cli(c.args, dir);
    EXPECT_EQ(r.code, 2) << c.args << ": " << r.err;
    EXPECT_NE(r.err.find(c.expect), std::string::npos) << c.args << ": " << r.err;
  }
  EXPECT_TRUE(no_output_files(dir));
}

}  // namespace

namespace {

// The beam in static equilibrium under gravity, a cable along its top and a servo on
// its tip.
std::string static_scene(const std::string& extra_actuator = "") {
  return "softdiff: 1\n"
         "simulation:\n"
         "  integrator: static\n"
         "  static: {load_steps: 1, tolerance: 1.0e-11}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
         "    material: {law: neo_hookean, young: 2.0e5, poisson: 0.4, density: 1000}\n"
         "    fixed:\n"
         "      - group: clamp\n"
         "    actuators:\n"
         "      - name: cable\n"
         "        type: cable\n"
         "        points: [[0.19, 0.01, 0.017], [0.1, 0.01, 0.017], [0.01, 0.01, 0.017]]\n"
         "        force: 0.05\n"
         "      - name: pull\n"
         "        type: servo\n"
         "        nodes: {box: [0.19, -1, -1, 1, 1, 1]}\n"
         "        direction: [0, 1, 0]\n"
         "        force: 0.01\n" + extra_actuator;
}

TEST(CliCheckGrad, StaticEquilibriumByTheImplicitFunctionTheorem) {
  const auto dir = fresh_dir(kWork, "check_grad_static");
  write_text(dir / "scene.yaml", static_scene());
  const CliRun r = run_cli("check-grad scene.yaml --tolerance 1e-6", dir);
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  for (const char* block : {"young", "poisson", "density", "actuation"})
    EXPECT_NE(r.out.find(std::string("\n") + block + " "), std::string::npos) << block << " missing in:\n" << r.out;
  EXPECT_NE(r.out.find("static equilibrium"), std::string::npos) << r.out;
  // simulate --jacobian writes the same kind of datasets for a static scene.
  const CliRun s = run_cli("simulate scene.yaml -o out.h5 --jacobian young,actuation", dir);
  ASSERT_EQ(s.code, 0) << s.err;
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto d = h5_shape(f, "/jacobians/actuation");
  ASSERT_EQ(d.size(), 2u);
  EXPECT_EQ(d[1], 2u);  // cable and servo
  EXPECT_EQ(h5_string_attribute(f, "/jacobians/young", "method"), "implicit function theorem at the equilibrium");
  EXPECT_EQ(h5_number_attribute(f, "/jacobians/young", "frame"), 1.0);
  H5Fclose(f);
}

TEST(CliCheckGrad, StaticSceneRefusesWhatItDoesNotDifferentiate) {
  const auto dir = fresh_dir(kWork, "check_grad_static_bad");
  write_text(dir / "scene.yaml", static_scene());
  CliRun r = run_cli("check-grad scene.yaml --wrt x0", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("no effect on a static equilibrium"), std::string::npos) << r.err;
  write_text(dir / "scene.yaml", static_scene("      - name: turn\n"
                                              "        type: servo\n"
                                              "        nodes: {box: [0.19, -1, -1, 1, 1, 1]}\n"
                                              "        axis: [1, 0, 0]\n"
                                              "        center: [0.2, 0.01, 0.01]\n"
                                              "        force: 0.001\n"));
  r = run_cli("simulate scene.yaml -o o.h5 --jacobian young", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("actuator 'turn'"), std::string::npos) << r.err;
  EXPECT_TRUE(no_output_files(dir));
}

}  // namespace
