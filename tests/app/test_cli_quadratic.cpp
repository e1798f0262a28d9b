// Quadratic elements through the CLI: `info` prints the element order; an invalid
// curved element is exit 2 naming its gmsh tag; `elements: quadratic` on a linear mesh
// and its bad uses; a cable, a pressure cavity and an effector on the quadratic beam
// (simulate, check-grad, --jacobian); `simulate` of configs/beam_cantilever_p2.yaml writes (m, 10) tets
// and (k, 6) surface triangles, and meshio reads its XDMF (Tetrahedron_10); check-grad
// passes on it.
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <Eigen/Core>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

namespace cli_quadratic_test {

using namespace softdiff::test;
namespace fs = std::filesystem;

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;

fs::path dir_for(const std::string& name) { return fresh_dir(fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_quadratic", name); }

std::string beam_scene(const std::string& mesh, const std::string& extra_body = "", const std::string& extra = "") {
  return "softdiff: 1\nsimulation:\n  dt: 0.01\n  steps: 2\n  gravity: [0, 0, -9.81]\n"
         "bodies:\n  - name: beam\n    mesh: " + mesh + "\n" + extra_body +
         "    material: {law: corotational, young: 1.0e6, poisson: 0.45, density: 1070}\n"
         "    fixed:\n      - group: clamp\n" + extra;
}

TEST(CliQuadratic, InfoPrintsTheElementOrder) {
  const fs::path dir = dir_for("info");
  auto r = run_cli("info '" + (kRoot / "meshes/beam_o2.msh").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("elements    quadratic (10-node tetrahedra, gmsh type 11)"), std::string::npos) << r.out;
  r = run_cli("info '" + (kRoot / "meshes/beam.msh").string() + "' --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"elements\":\"linear\""), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("\"nodes_per_tet\":4"), std::string::npos) << r.out;
  r = run_cli("info '" + (kRoot / "configs/beam_cantilever_p2.yaml").string() + "'", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("480 tets (quadratic)"), std::string::npos) << r.out;
}

TEST(CliQuadratic, ElementsQuadraticOnALinearMesh) {
  const fs::path dir = dir_for("elevate");
  write_text(dir / "scene.yaml", beam_scene((kRoot / "meshes/beam.msh").string(), "    elements: quadratic\n"));
  auto r = run_cli("info scene.yaml --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"elements\":\"quadratic\""), std::string::npos) << r.out;
  // beam.msh: 4 x 4 x 40 boxes, 6 tets each; vertices 5 x 5 x 41 = 1025.
  r = run_cli("simulate scene.yaml -o out.h5 --quiet", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto tets = h5_shape(f, "/bodies/beam/tets");
  const auto rest = h5_shape(f, "/bodies/beam/rest");
  H5Fclose(f);
  ASSERT_EQ(tets.size(), 2u);
  EXPECT_EQ(tets[0], 3840u);
  EXPECT_EQ(tets[1], 10u);
  // Euler's formula for the tet mesh of a box (no holes): V - E + F - T = 1, and the
  // boundary (a sphere) has V_b - E_b + F_b = 2 with 3 F_b = 2 E_b; with 4 T = 2 F - F_b:
  // E = V + F - T - 1 = V + (4 T + F_b) / 2 - T - 1. beam.msh: V = 1025, F_b = 2 (2 * 4 * 4
  // + 4 * 4 * 40) = 1344 (2 triangles per boundary square). One node per edge is added.
  const long V = 1025, T = 3840, Fb = 1344;
  const long E = V + (4 * T + Fb) / 2 - T - 1;
  ASSERT_EQ(rest.size(), 2u);
  EXPECT_EQ(static_cast<long>(rest[0]), V + E);
}

TEST(CliQuadratic, BadUsesAreExitTwoWithoutOutput) {
  const fs::path dir = dir_for("bad");
  // An invalid curved element (mid-edge node 5 pushed across the tet).
  write_text(dir / "bad.msh",
             "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n10\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1.1 0.9 0.9\n"
             "6 0.5 0.5 0\n7 0 0.5 0\n8 0 0 0.5\n9 0 0.5 0.5\n10 0.5 0 0.5\n$EndNodes\n$Elements\n1\n"
             "17 11 2 1 1 1 2 3 4 5 6 7 8 9 10\n$EndElements\n");
  auto r = run_cli("info bad.msh", dir);
  EXPECT_EQ(r.code, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("bad.msh:19: 1 invalid quadratic tetrahedra"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("element 17 (line 19"), std::string::npos) << r.err;

  write_text(dir / "linear_on_p2.yaml",
             beam_scene((kRoot / "meshes/beam_o2.msh").string(), "    elements: linear\n"));
  r = run_cli("simulate linear_on_p2.yaml -o out.h5 --quiet", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("linear_on_p2.yaml:9:5: bodies[0].elements: linear elements on the quadratic mesh"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));

  write_text(dir / "typo.yaml", beam_scene((kRoot / "meshes/beam.msh").string(), "    elements: cubic\n"));
  r = run_cli("simulate typo.yaml -o out.h5 --quiet", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("bodies[0].elements"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));

  // A cable point off the quadratic body is still an input error (exit 2, no output).
  write_text(dir / "cable.yaml",
             beam_scene((kRoot / "meshes/beam_o2.msh").string(), "",
                        "    actuators:\n      - {name: c, type: cable, points: [[0.19, 0.01, 0.01], [0.1, 0.01, 0.05]], "
                        "pull_point: [-0.01, 0.01, 0.01], force: 0.1}\n"));
  r = run_cli("simulate cable.yaml -o out.h5 --quiet", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("bodies[0].actuators[0].points[1]: cable point 1 lies 30 mm outside body 'beam'"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));
}

// The quadratic beam (meshes/beam_o2.msh, 10-node tets, 6-node triangles), 5 implicit
// Euler steps, with a cable along its top, a pressure on its tip face (an open cavity of
// 6-node triangles) and an effector at the tip face's centre (a vertex of the mesh: the
// effector is that node). Dynamic: the static solver does not differentiate pressure
// actuators (docs/cli.md).
std::string actuated_scene() {
  return "softdiff: 1\nsimulation:\n  dt: 0.01\n  steps: 5\n  gravity: [0, 0, -9.81]\n"
         "bodies:\n  - name: beam\n    mesh: " + (kRoot / "meshes/beam_o2.msh").string() + "\n"
         "    material: {law: neo_hookean, young: 2.0e5, poisson: 0.45, density: 1000}\n"
         "    fixed:\n      - group: clamp\n"
         "    effectors:\n      - {name: tip, point: [0.2, 0.01, 0.01]}\n"
         "    actuators:\n"
         "      - {name: cable, type: cable, points: [[0.19, 0.01, 0.017], [0.1, 0.013, 0.016], [0.01, 0.01, 0.017]], "
         "force: 0.05}\n"
         "      - {name: push, type: pressure, surface: tip, pressure: 500}\n";
}

TEST(CliQuadratic, CablePressureAndEffectorOnTheQuadraticBeam) {
  const fs::path dir = dir_for("actuated");
  write_text(dir / "scene.yaml", actuated_scene());
  auto r = run_cli("simulate scene.yaml -o out.h5 --quiet", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const Eigen::VectorXd x = h5_final_frame((dir / "out.h5").string(), "/bodies/beam/x");
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const std::vector<double> tips = h5_read(f, "/bodies/beam/effectors/tip");  // (T, 3)
  const std::vector<double> rest = h5_read(f, "/bodies/beam/rest");           // (n, 3)
  EXPECT_EQ(h5_shape(f, "/actuators/cable/length").size(), 1u);  // the cable's length is written
  H5Fclose(f);
  ASSERT_GE(tips.size(), 3u);
  const Eigen::Vector3d tip(tips[tips.size() - 3], tips[tips.size() - 2], tips[tips.size() - 1]);
  int node = -1;
  for (std::size_t i = 0; i < rest.size() / 3; ++i)
    if ((Eigen::Vector3d(rest[3 * i], rest[3 * i + 1], rest[3 * i + 2]) - Eigen::Vector3d(0.2, 0.01, 0.01)).norm() < 1e-12)
      node = static_cast<int>(i);
  ASSERT_GE(node, 0);
  EXPECT_LT((tip - x.segment<3>(3 * node)).norm(), 1e-15) << "the effector is the node at the tip's centre";
  EXPECT_GT((tip - Eigen::Vector3d(0.2, 0.01, 0.01)).norm(), 1e-4) << "the beam bends";
}

// A cable point just outside the quadratic body (1 mm above the top face; half the
// nearest element's longest edge is allowed) is mapped with extrapolated reference
// coordinates, with a warning that says so.
TEST(CliQuadratic, CablePointJustOutsideIsAWarning) {
  const fs::path dir = dir_for("outside");
  write_text(dir / "scene.yaml",
             beam_scene((kRoot / "meshes/beam_o2.msh").string(), "",
                        "    actuators:\n      - {name: c, type: cable, points: [[0.19, 0.01, 0.021], [0.1, 0.01, 0.015]], "
                        "pull_point: [-0.01, 0.01, 0.015], force: 0.01}\n"));
  const auto r = run_cli("simulate scene.yaml -o out.h5 --quiet", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("cable point 0 lies 1 mm outside body 'beam'"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("with extrapolated reference coordinates (quadratic shape functions)"), std::string::npos)
      << r.err;
}

// check-grad with the quadratic cable and pressure, 2 steps: every block (x0, v0,
// young, poisson, density, damping, and the actuation) within check-grad's default
// tolerance 1e-5 (its central differences; the linear beam's blocks measure 1e-8 to
// 4e-7, test_cli_derivatives.cpp).
TEST(CliQuadratic, CheckGradWithCablePressureAndEffector) {
  const fs::path dir = dir_for("actuated_check_grad");
  write_text(dir / "scene.yaml", actuated_scene());
  const auto r = run_cli("check-grad scene.yaml --steps 2", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("actuation"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
}

// simulate --jacobian actuation on the quadratic scene: the columns are the central
// differences of two runs with --set, tolerance 1e-6. Steps 1e-3 of each value (as in
// tests/diff/validation_trajectory.cpp): the runs' positions carry round-off of ~1e-16
// of |x| (0.2 m) per step, and the pressure's column is small (|dx/dp| ~ 2e-10 m/Pa:
// 500 Pa on the 4 cm^2 tip face against the beam's 0.8 N weight), so at 1e-5 of the
// value the quotient's round-off reached 2.7e-6 relative (measured at 50 Pa); the
// response is nearly linear in the actuation, and the truncation error at 1e-3 stays
// far below the tolerance.
TEST(CliQuadratic, JacobianOfTheActuationMatchesDifferencesOfRuns) {
  const fs::path dir = dir_for("actuated_jacobian");
  write_text(dir / "scene.yaml", actuated_scene());
  auto r = run_cli("simulate scene.yaml -o out.h5 --quiet --jacobian actuation", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const std::vector<double> J = h5_read(f, "/jacobians/actuation");
  H5Fclose(f);
  const Eigen::VectorXd x = h5_final_frame((dir / "out.h5").string(), "/bodies/beam/x");
  const Eigen::Index n = x.size();
  ASSERT_EQ(static_cast<Eigen::Index>(J.size()), 2 * n);
  struct Check {
    std::string key;
    double value;
    int column;
  };
  for (const Check& c : {Check{"bodies.beam.actuators.cable.force", 0.05, 0},
                         Check{"bodies.beam.actuators.push.pressure", 500, 1}}) {
    const double e = 1e-3 * c.value;
    char plus[128], minus[128];
    std::snprintf(plus, sizeof plus, "%s=%.17g", c.key.c_str(), c.value + e);
    std::snprintf(minus, sizeof minus, "%s=%.17g", c.key.c_str(), c.value - e);
    ASSERT_EQ(run_cli(std::string("simulate scene.yaml -o p.h5 --force --quiet --set ") + plus, dir).code, 0);
    ASSERT_EQ(run_cli(std::string("simulate scene.yaml -o m.h5 --force --quiet --set ") + minus, dir).code, 0);
    const Eigen::VectorXd fd = (h5_final_frame((dir / "p.h5").string(), "/bodies/beam/x") -
                                h5_final_frame((dir / "m.h5").string(), "/bodies/beam/x")) / (2 * e);
    Eigen::VectorXd analytic(n);
    for (Eigen::Index i = 0; i < n; ++i) analytic[i] = J[static_cast<std::size_t>(i * 2 + c.column)];
    ASSERT_GT(fd.norm(), 0) << c.key;
    EXPECT_LE((analytic - fd).norm(), 1e-6 * fd.norm()) << c.key << ": " << (analytic - fd).norm() / fd.norm();
  }
}

TEST(CliQuadratic, OutputHasTenNodeTetsAndMeshioReadsIt) {
  const fs::path dir = dir_for("output");
  auto r = run_cli("simulate '" + (kRoot / "configs/beam_cantilever_p2.yaml").string() + "' -o out.h5 --quiet", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto tets = h5_shape(f, "/bodies/beam/tets");
  const auto surface = h5_shape(f, "/bodies/beam/surface");
  const auto xdmf_tets = h5_shape(f, "/xdmf/beam/tets");
  H5Fclose(f);
  ASSERT_EQ(tets.size(), 2u);
  EXPECT_EQ(tets[0], 480u);
  EXPECT_EQ(tets[1], 10u);
  ASSERT_EQ(surface.size(), 2u);
  EXPECT_EQ(surface[1], 6u);
  ASSERT_EQ(xdmf_tets.size(), 2u);
  EXPECT_EQ(xdmf_tets[1], 10u);
  EXPECT_NE(read_text(dir / "out.beam.xmf").find("Tetrahedron_10"), std::string::npos);
  const std::string command = "/usr/bin/python3 '" + (kRoot / "tests/app/meshio_read_xdmf.py").string() + "' '" +
                              (dir / "out.h5").string() + "' beam '" + (dir / "out.beam.xmf").string() + "' > '" +
                              (dir / "meshio.txt").string() + "' 2>&1";
  EXPECT_EQ(std::system(command.c_str()), 0) << read_text(dir / "meshio.txt");
  EXPECT_NE(read_text(dir / "meshio.txt").find("ok beam"), std::string::npos) << read_text(dir / "meshio.txt");
}

// The derivatives end to end: check-grad's central differences of whole static solves
// against the analytic Jacobian on the quadratic beam (young, poisson,
// density; its default tolerance 1e-5: measured 8e-9 to 2e-7).
TEST(CliQuadratic, CheckGradPassesOnTheQuadraticBeam) {
  const fs::path dir = dir_for("check_grad");
  const auto r = run_cli("check-grad '" + (kRoot / "configs/beam_cantilever_p2.yaml").string() + "' --quiet", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("young"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
}

// The static solve's line search at round-off (static_solver.cpp: Pi's round-off is
// that of its terms). With OpenBLAS's Haswell kernels (forced here; any AVX2 CPU runs
// them), the quadratic beam with poisson 0.449955 (check-grad's step below 0.45) reaches
// load step 3 at a relative residual of 4e-8, where the strain energy (5.4e-3) and the
// load's work (4.8e-3) cancel to Pi = 6.6e-4: a tolerance relative to Pi took the full
// Newton step's round-off increase (3e-17) for a failure, and Newton stalled at 1.04e-8
// for 50 iterations (exit 1). It converges now, as with the default kernels.
TEST(CliQuadratic, StaticNewtonConvergesWhereTheEnergyCancels) {
  if (!__builtin_cpu_supports("avx2")) GTEST_SKIP() << "OpenBLAS's Haswell kernels need AVX2";
  const fs::path dir = dir_for("energy_cancels");
  const std::string cmd = "cd '" + dir.string() + "' && OPENBLAS_CORETYPE=Haswell '" SOFTDIFF_CLI "' simulate '" +
                          (kRoot / "configs/beam_cantilever_p2.yaml").string() +
                          "' -o out.h5 --quiet --set bodies.beam.material.poisson=0.449955 >out.txt 2>err.txt";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << read_text(dir / "err.txt");
  EXPECT_TRUE(fs::exists(dir / "out.h5"));
}

// Calibration on the quadratic beam works unchanged: young recovered from markers at
// four nodes (vertices or mid-edge nodes of the 10-node tets: their quadratic
// embedding is that node alone, where the 4-vertex embedding would give the
// average of the edge's vertices), as the linear test (test_cli_calibrate.cpp):
// a target simulated with young = 2e5, recovered from 5e4 to 1e-6.
std::string calibration_scene() {
  return "softdiff: 1\nsimulation: {dt: 0.01, steps: 5}\nbodies:\n  - name: beam\n    mesh: " +
         (kRoot / "meshes/beam_o2.msh").string() +
         "\n    material: {law: corotational, young: 2.0e5, poisson: 0.45, density: 1070}\n"
         "    fixed:\n      - group: clamp\n";
}

TEST(CliQuadratic, CalibrationRecoversYoungFromMarkers) {
  const fs::path dir = dir_for("calibrate");
  write_text(dir / "scene.yaml", calibration_scene());
  ASSERT_EQ(run_cli("simulate scene.yaml -o target.h5 --quiet", dir).code, 0);
  const hid_t f = H5Fopen((dir / "target.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto dims = h5_shape(f, "/bodies/beam/x");
  const std::vector<double> x = h5_read(f, "/bodies/beam/x"), time = h5_read(f, "/time");
  H5Fclose(f);
  const std::size_t n = dims[1];
  ASSERT_GT(n, 1000u);
  std::string csv = "time,marker,x,y,z\n";
  const int nodes[4] = {100, 400, 700, 1000};
  for (std::size_t k = 0; k < time.size(); ++k)
    for (int m = 0; m < 4; ++m) {
      const double* p = x.data() + (k * n + static_cast<std::size_t>(nodes[m])) * 3;
      char line[160];
      std::snprintf(line, sizeof line, "%.17g,m%d,%.17g,%.17g,%.17g\n", time[k], m, p[0], p[1], p[2]);
      csv += line;
    }
  write_text(dir / "markers.csv", csv);
  const auto r = run_cli("calibrate scene.yaml --param young --init 5e4 --markers markers.csv -o cal.h5 --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto k = r.out.find("\"young\":");
  ASSERT_NE(k, std::string::npos) << r.out;
  EXPECT_NEAR(std::strtod(r.out.c_str() + k + 8, nullptr) / 2e5, 1.0, 1e-6) << r.out;
  EXPECT_NE(r.out.find("\"converged\":true"), std::string::npos) << r.out;
}

// Control on the quadratic beam works unchanged: a translation servo on the tip and
// an effector there; a goal the servo can reach (where 0.02 N leaves the tip) is
// reached to 0.1 mm from a start 1 mm or more away, within the limits, as the linear
// test (test_cli_control.cpp).
TEST(CliQuadratic, ControlReachesAGoalTheServoCanReach) {
  const fs::path dir = dir_for("control");
  write_text(dir / "scene.yaml",
             "softdiff: 1\nsimulation: {dt: 0.01, steps: 40, gravity: [0, 0, 0]}\nbodies:\n  - name: beam\n"
             "    mesh: " + (kRoot / "meshes/beam_o2.msh").string() + "\n"
             "    material: {law: corotational, young: 2.0e5, poisson: 0.4, density: 1000}\n"
             "    damping: {rayleigh_mass: 5}\n    fixed:\n      - group: clamp\n    actuators:\n"
             "      - {name: pull, type: servo, nodes: {box: [0.19, -1, -1, 1, 1, 1]}, direction: [0, 1, 0], force: 0, "
             "limits: [-0.05, 0.05]}\n"
             "    effectors:\n      - {name: tip, point: [0.2, 0.01, 0.01]}\n");
  ASSERT_EQ(run_cli("simulate scene.yaml -o goal.h5 --quiet --set bodies.beam.actuators.pull.force=0.02 --steps 100", dir).code, 0);
  hid_t f = H5Fopen((dir / "goal.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const std::vector<double> g = h5_read(f, "/bodies/beam/effectors/tip");
  H5Fclose(f);
  char target[128];
  std::snprintf(target, sizeof target, "%.17g,%.17g,%.17g", g[g.size() - 3], g[g.size() - 2], g[g.size() - 1]);
  const auto r = run_cli(std::string("control scene.yaml --target=") + target + " -o c.h5 --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"within_limits\":true"), std::string::npos) << r.out;
  f = H5Fopen((dir / "c.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const std::vector<double> d = h5_read(f, "/control/distance"), a = h5_read(f, "/control/actuation");
  H5Fclose(f);
  ASSERT_FALSE(d.empty());
  EXPECT_GT(d.front(), 1e-3);
  EXPECT_LT(d.back(), 1e-4) << "from " << d.front();
  for (double v : a) EXPECT_TRUE(v >= -0.05 && v <= 0.05) << v;
}

}  // namespace cli_quadratic_test
