// Bad actuator input on the command line (issue "Actuators"): each case is a clear
// error naming the scene location and the cause, exit code 2, and no output file,
// for `simulate` and for `info` (which validates a scene completely).
//
// Cases: a cable point far outside the body; a cavity group without triangles, and a
// missing one; cavities whose triangles are not on the body's boundary (an interior
// face shared by two tetrahedra, from a hand-written MSH 2.2 file and from a real gmsh
// mesh of two fused boxes with their internal face tagged; a triangle that is no face
// of any tetrahedron); servo node sets that select nothing (a box outside the body, a
// missing group) and a torque servo whose nodes all lie on its axis.
#include <support/cli.hpp>

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_actuators";

fs::path fresh_dir(const std::string& name) { return softdiff::test::fresh_dir(kWork, name); }

// The shipped beam (0.2 x 0.02 x 0.02 m, groups clamp, tip, beam), with `actuators`
// (YAML list items, indented for the body) and the mesh replaceable.
std::string scene(const std::string& actuators, const std::string& mesh = (kRoot / "meshes/beam.msh").string(),
                  const std::string& fixed = "      - group: clamp\n") {
  return "softdiff: 1\n"
         "simulation:\n"
         "  dt: 0.01\n"
         "  steps: 3\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " +
         mesh +
         "\n"
         "    material: {law: corotational, young: 1.0e6, poisson: 0.45, density: 1070}\n" +
         (fixed.empty() ? std::string() : "    fixed:\n" + fixed) + "    actuators:\n" + actuators;
}

// Two tetrahedra sharing the face (1, 2, 3) (z = 0), on either side of it. Group
// "inner" is that shared face; "floating" is the triangle (1, 4, 5), whose nodes are
// on the mesh but which is no face of either tetrahedron; "bottom" is a boundary
// face of the lower tetrahedron (a valid, open cavity).
const char* kTwoTets =
    "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n"
    "$PhysicalNames\n4\n2 1 \"inner\"\n2 2 \"floating\"\n2 4 \"bottom\"\n3 3 \"solid\"\n$EndPhysicalNames\n"
    "$Nodes\n5\n"
    "1 0 0 0\n2 0.01 0 0\n3 0 0.01 0\n4 0 0 0.01\n5 0.004 0.004 -0.01\n"
    "$EndNodes\n"
    "$Elements\n5\n"
    "1 2 2 1 1 1 2 3\n"
    "2 2 2 2 2 1 4 5\n"
    "3 2 2 4 3 1 2 5\n"
    "4 4 2 3 1 1 2 3 4\n"
    "5 4 2 3 1 1 3 2 5\n"
    "$EndElements\n";

// The gmsh mesh of tests/data/two_boxes_interface.geo, made once per test process.
struct GmshMesh {
  fs::path file;
  std::string failure;
};
const GmshMesh& two_boxes() {
  static const GmshMesh mesh = [] {
    GmshMesh m;
    const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / ("cli_actuators_gmsh_" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    m.file = dir / "two_boxes.msh";
    const std::string cmd = std::string("\"") + GMSH_EXECUTABLE + "\" -3 \"" +
                            (kRoot / "tests/data/two_boxes_interface.geo").string() + "\" -format msh41 -o \"" +
                            m.file.string() + "\" > \"" + (dir / "gmsh.log").string() + "\" 2>&1";
    if (std::system(cmd.c_str()) != 0 || !fs::exists(m.file)) m.failure = "command failed: " + cmd + "\n" + read_text(dir / "gmsh.log");
    return m;
  }();
  return mesh;
}
struct RemoveGmshDir {
  ~RemoveGmshDir() {
    std::error_code ec;
    fs::remove_all(fs::path(SOFTDIFF_TEST_DATA_DIR) / ("cli_actuators_gmsh_" + std::to_string(::getpid())), ec);
  }
} remove_gmsh_dir;

constexpr const char* kTwoTetsFile = "@TWO_TETS@";    // replaced by the hand-written mesh's path
constexpr const char* kTwoBoxesFile = "@TWO_BOXES@";  // replaced by the gmsh mesh's path

struct BadActuator {
  std::string name;
  std::string scene;
  std::vector<std::string> expect;  // substrings of stderr (location and cause)
};

void PrintTo(const BadActuator& b, std::ostream* os) { *os << b.name; }

std::string replace_all(std::string s, const std::string& from, const std::string& to) {
  for (size_t k = s.find(from); k != std::string::npos; k = s.find(from, k + to.size())) s.replace(k, from.size(), to);
  return s;
}

// Writes the case's scene (and meshes) into a fresh folder; "" if gmsh failed.
fs::path prepare(const BadActuator& p, const std::string& tag) {
  const auto dir = fresh_dir(p.name + "_" + tag);
  std::string text = replace_all(p.scene, kTwoTetsFile, (dir / "two_tets.msh").string());
  if (text.find(kTwoBoxesFile) != std::string::npos) {
    if (!two_boxes().failure.empty()) return {};
    text = replace_all(text, kTwoBoxesFile, two_boxes().file.string());
  }
  write_text(dir / "two_tets.msh", kTwoTets);
  write_text(dir / "scene.yaml", text);
  return dir;
}

void expect_no_output(const fs::path& dir) {
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    const auto ext = entry.path().extension();
    EXPECT_TRUE(ext != ".h5" && ext != ".xmf" && ext != ".partial") << "left behind: " << entry.path();
  }
}

class CliActuatorBadInput : public ::testing::TestWithParam<BadActuator> {};

TEST_P(CliActuatorBadInput, ExitsTwoWithMessageAndNoOutput) {
  const auto& p = GetParam();
  for (const std::string command : {"simulate scene.yaml -o o.h5", "info scene.yaml"}) {
    SCOPED_TRACE(command);
    const fs::path dir = prepare(p, command.substr(0, command.find(' ')));
    ASSERT_FALSE(dir.empty()) << two_boxes().failure;
    const auto r = run_cli(command, dir);
    EXPECT_EQ(r.code, 2) << r.err;
    for (const auto& e : p.expect) EXPECT_NE(r.err.find(e), std::string::npos) << "expected '" << e << "' in: " << r.err;
    EXPECT_NE(r.err.find("scene.yaml:"), std::string::npos) << "no scene location in: " << r.err;
    expect_no_output(dir);
  }
}

INSTANTIATE_TEST_SUITE_P(
    Cases, CliActuatorBadInput,
    ::testing::Values(
        // The beam spans x in [0, 0.2]: the anchor 0.3 m beyond its tip.
        BadActuator{"cable_point_far_outside",
                    scene("      - {name: c, type: cable, points: [[0.1, 0.01, 0.01], [0.5, 0.01, 0.01]], force: 1}\n"),
                    {"actuators[0].points[1]", "cable point 1 lies 300 mm outside body 'beam'"}},
        // Units slip: the pulled end given in millimetres.
        BadActuator{"cable_point_in_mm",
                    scene("      - {name: c, type: cable, points: [[10, 10, 10], [0.19, 0.01, 0.01]], "
                          "pull_point: [-0.01, 0.01, 0.01], force: 1}\n"),
                    {"actuators[0].points[0]", "cable point 0 lies", "outside body 'beam'"}},
        // `beam` is the volume group: no triangle.
        BadActuator{"cavity_group_without_triangles",
                    scene("      - {name: p, type: pressure, surface: beam, pressure: 1000}\n"),
                    {"actuators[0].surface", "physical group 'beam' has no triangle on the body"}},
        BadActuator{"cavity_group_missing",
                    scene("      - {name: p, type: pressure, surface: cavity, pressure: 1000}\n"),
                    {"actuators[0].surface", "has no physical group 'cavity'", "'clamp'"}},
        BadActuator{"cavity_interior_face_hand_written",
                    scene("      - {name: p, type: pressure, surface: inner, pressure: 1000}\n", kTwoTetsFile, ""),
                    {"actuators[0].surface", "cavity 'inner'",
                     "is an interior face (shared by 2 tetrahedra), not on the boundary"}},
        BadActuator{"cavity_interior_face_gmsh",
                    scene("      - {name: p, type: pressure, surface: interface, pressure: 1000}\n", kTwoBoxesFile, ""),
                    {"actuators[0].surface", "cavity 'interface'",
                     "is an interior face (shared by 2 tetrahedra), not on the boundary"}},
        BadActuator{"cavity_triangle_not_a_face",
                    scene("      - {name: p, type: pressure, surface: floating, pressure: 1000}\n", kTwoTetsFile, ""),
                    {"actuators[0].surface", "cavity 'floating'", "is not a face of any tetrahedron of the body"}},
        BadActuator{"servo_box_outside",
                    scene("      - {name: s, type: servo, nodes: {box: [0.3, 0, 0, 0.4, 0.02, 0.02]}, "
                          "direction: [1, 0, 0], force: 1}\n"),
                    {"actuators[0].nodes.box", "box selects no node of body 'beam'", "[0, 0, 0] to [0.2, 0.02, 0.02]"}},
        BadActuator{"servo_group_missing",
                    scene("      - {name: s, type: servo, nodes: {group: handle}, axis: [1, 0, 0], center: [0, 0.01, "
                          "0.01], force: 0.1}\n"),
                    {"actuators[0].nodes.group", "has no physical group 'handle'"}},
        // The beam's edge y = z = 0 as the node set, and the same line as the axis.
        BadActuator{"servo_torque_all_nodes_on_axis",
                    scene("      - {name: r, type: servo, nodes: {box: [-1, -0.001, -0.001, 1, 0.001, 0.001]}, "
                          "axis: [1, 0, 0], center: [0, 0, 0], force: 0.1}\n"),
                    {"actuators[0]", "servo 'r'", "every node of the servo lies on its axis"}}),
    [](const auto& p) { return p.param.name; });

// Controls: the same meshes with a boundary group, and a cable inside the beam, are
// accepted by `info` (which builds the model, actuators included): the errors above
// are about the actuator, not the mesh. (`info`, not `simulate`: these 2 g free bodies
// under 1 kPa with dt = 0.01 s stop at step 2 with "not positive definite", correctly:
// the compressed corotational stiffness is indefinite and h^2 K outweighs M; they run
// with dt = 0.001, psd_projection or the linear law.)
TEST(CliActuators, BoundaryCavitiesOfTheSameMeshesAreAccepted) {
  ASSERT_TRUE(two_boxes().failure.empty()) << two_boxes().failure;
  const BadActuator ok[] = {
      {"ok_hand_written", scene("      - {name: p, type: pressure, surface: bottom, pressure: 1000}\n", kTwoTetsFile, ""),
       {}},
      {"ok_gmsh", scene("      - {name: p, type: pressure, surface: end, pressure: 1000}\n", kTwoBoxesFile, ""), {}},
      {"ok_cable", scene("      - {name: c, type: cable, points: [[0.1, 0.01, 0.01], [0.19, 0.01, 0.01]], force: 1}\n"),
       {}}};
  for (const auto& p : ok) {
    SCOPED_TRACE(p.name);
    const fs::path dir = prepare(p, "info");
    const auto r = run_cli("info scene.yaml", dir);
    EXPECT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("(valid)"), std::string::npos) << r.out;
  }
}

}  // namespace
