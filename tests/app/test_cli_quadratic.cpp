// Quadratic elements through the CLI: `info` prints the element order; an invalid
// curved element is exit 2 naming its gmsh tag; `elements: quadratic` on a linear mesh
// and its bad uses; `simulate` of configs/beam_cantilever_p2.yaml writes (m, 10) tets
// and (k, 6) surface triangles, and meshio reads its XDMF (Tetrahedron_10); check-grad
// passes on it.
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <filesystem>
#include <string>

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

  write_text(dir / "cable.yaml",
             beam_scene((kRoot / "meshes/beam_o2.msh").string(), "",
                        "    actuators:\n      - {name: c, type: cable, points: [[0.19, 0.01, 0.01], [0.1, 0.01, 0.01]], "
                        "pull_point: [-0.01, 0.01, 0.01], force: 0.1}\n"));
  r = run_cli("simulate cable.yaml -o out.h5 --quiet", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("cable and pressure actuators on quadratic elements are not supported yet"), std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));
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

}  // namespace cli_quadratic_test
