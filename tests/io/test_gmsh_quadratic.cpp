// Quadratic meshes in the Gmsh reader (lib/softdiff/io/gmsh_msh.cpp) and the
// elevation of linear meshes (mesh::elevate_to_quadratic): 10-node tetrahedra (type
// 11) and 6-node triangles (type 9) in MSH 2.2 and 4.1, ASCII and binary, written by
// the real gmsh (`-order 2`); gmsh's node order; curved edges; validity by the sign of
// det J at the quadrature points; bad inputs.
#include <softdiff/core/error.hpp>
#include <softdiff/fem/tet10.hpp>
#include <softdiff/io/gmsh_msh.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

namespace gmsh_quadratic_test {

namespace fs = std::filesystem;
using softdiff::InputError;
using softdiff::Vec3;
using softdiff::io::read_gmsh;
using softdiff::mesh::PhysicalGroup;
using softdiff::mesh::TetMesh;

fs::path scratch() {
  static const fs::path dir = [] {
    const fs::path d = fs::path(SOFTDIFF_TEST_DATA_DIR) / ("gmsh_quadratic_" + std::to_string(::getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
  }();
  return dir;
}

fs::path write_file(const std::string& name, const std::string& content) {
  const fs::path p = scratch() / name;
  std::ofstream(p, std::ios::binary) << content;
  return p;
}

std::string error_of(const fs::path& p) {
  try {
    read_gmsh(p);
  } catch (const InputError& e) {
    return e.what();
  }
  ADD_FAILURE() << p << " was read without error";
  return "";
}

// gmsh ARGS -o OUT; "" on success, else the command and its log.
std::string run_gmsh(const std::string& args, const fs::path& out) {
  const fs::path log = scratch() / "gmsh.log";
  const std::string cmd = std::string("\"") + GMSH_EXECUTABLE + "\" " + args + " -o \"" + out.string() + "\" > \"" +
                          log.string() + "\" 2>&1";
  if (std::system(cmd.c_str()) != 0 || !fs::exists(out)) {
    std::ifstream in(log);
    return "command failed: " + cmd + "\n" + std::string(std::istreambuf_iterator<char>(in), {});
  }
  return "";
}

// The test .geo files set Mesh.ElementOrder = 1, which overrides gmsh's `-order 2`:
// a copy in the scratch folder that sets 2.
fs::path order2_copy(const fs::path& geo) {
  std::ifstream in(geo);
  std::string text(std::istreambuf_iterator<char>(in), {});
  const std::string from = "Mesh.ElementOrder = 1;";
  const auto at = text.find(from);
  if (at != std::string::npos) text.replace(at, from.size(), "Mesh.ElementOrder = 2;");
  const fs::path out = scratch() / (geo.stem().string() + "_o2.geo");
  std::ofstream(out) << text;
  return out;
}

struct CubeFiles {
  fs::path linear, a41, b41, a22, b22;
  std::string failure;
};

// tests/data/cube_groups.geo meshed linear, and at order 2 (gmsh meshes at order 1,
// then adds the mid-edge nodes: the same vertices and tets), saved in the four encodings.
const CubeFiles& cube_files() {
  static const CubeFiles files = [] {
    CubeFiles f;
    const fs::path geo1 = fs::path(SOFTDIFF_SOURCE_DIR) / "tests/data/cube_groups.geo";
    const fs::path geo = order2_copy(geo1);
    f.linear = scratch() / "cube_o1.msh";
    f.a41 = scratch() / "cube_o2_a41.msh";
    f.b41 = scratch() / "cube_o2_b41.msh";
    f.a22 = scratch() / "cube_o2_a22.msh";
    f.b22 = scratch() / "cube_o2_b22.msh";
    for (const auto& [args, out] : std::vector<std::pair<std::string, fs::path>>{
             {"-3 \"" + geo1.string() + "\" -format msh41", f.linear},
             {"-3 \"" + geo.string() + "\" -format msh41", f.a41},
             {"\"" + f.a41.string() + "\" -save -format msh41 -bin", f.b41},
             {"\"" + f.a41.string() + "\" -save -format msh22", f.a22},
             {"\"" + f.a41.string() + "\" -save -format msh22 -bin", f.b22}}) {
      f.failure = run_gmsh(args, out);
      if (!f.failure.empty()) break;
    }
    return f;
  }();
  return files;
}

#define REQUIRE_CUBE() \
  if (!cube_files().failure.empty()) FAIL() << cube_files().failure

// Every mid-edge node of every tet is at the midpoint of its edge (straight edges),
// with the edges in gmsh's order (mesh::kTet10Edge).
double worst_midpoint_offset(const TetMesh& m) {
  double worst = 0;
  for (int t = 0; t < m.num_tets(); ++t)
    for (int k = 0; k < 6; ++k) {
      const Vec3 mid = 0.5 * (m.X.col(m.tets10(softdiff::mesh::kTet10Edge[k][0], t)) +
                              m.X.col(m.tets10(softdiff::mesh::kTet10Edge[k][1], t)));
      worst = std::max(worst, (m.X.col(m.tets10(4 + k, t)) - mid).norm());
    }
  return worst;
}

TEST(GmshQuadratic, FourEncodingsGiveTheSameTenNodeMesh) {
  REQUIRE_CUBE();
  const CubeFiles& f = cube_files();
  const TetMesh a41 = read_gmsh(f.a41);
  EXPECT_EQ(a41.order, 2);
  EXPECT_EQ(a41.nodes_per_tet(), 10);
  ASSERT_GT(a41.num_tets(), 100);
  ASSERT_EQ(a41.tets10.cols(), a41.tets.cols());
  EXPECT_TRUE(a41.tets10.topRows(4) == a41.tets);
  for (const fs::path& p : {f.b41, f.a22, f.b22}) {
    SCOPED_TRACE(p.string());
    const TetMesh m = read_gmsh(p);
    EXPECT_EQ(m.order, 2);
    EXPECT_TRUE(m.X == a41.X);
    EXPECT_TRUE(m.tets10 == a41.tets10);
    EXPECT_TRUE(m.triangles == a41.triangles);
    ASSERT_EQ(m.groups.size(), a41.groups.size());
    for (std::size_t g = 0; g < m.groups.size(); ++g) EXPECT_EQ(m.groups[g].nodes, a41.groups[g].nodes);
  }
}

TEST(GmshQuadratic, GmshNodeOrderGroupsAndValidity) {
  REQUIRE_CUBE();
  const TetMesh m = read_gmsh(cube_files().a41);
  const TetMesh lin = read_gmsh(cube_files().linear);
  // The box's edges are straight: gmsh puts every mid-edge node at the midpoint. A
  // wrong edge table (e.g. VTK's order, 8 <-> 9) would be off by a whole edge.
  EXPECT_LT(worst_midpoint_offset(m), 1e-12);
  EXPECT_EQ(m.num_tets(), lin.num_tets());
  EXPECT_EQ(m.reoriented_tets, 0);
  // det J = 6 V at every point of a straight element.
  for (int t = 0; t < m.num_tets(); ++t) {
    Eigen::Matrix<double, 3, 10> X_e;
    for (int a = 0; a < 10; ++a) X_e.col(a) = m.X.col(m.tets10(a, t));
    Eigen::Matrix3d D;
    for (int k = 0; k < 3; ++k) D.col(k) = X_e.col(k + 1) - X_e.col(0);
    EXPECT_NEAR(softdiff::fem::tet10::min_det_jacobian(X_e), D.determinant(), 1e-12 * D.determinant());
  }
  // Groups include the mid-edge nodes of their triangles (type 9) and tets.
  const PhysicalGroup* clamp = m.find_group("clamp");
  const PhysicalGroup* solid = m.find_group("solid");
  const PhysicalGroup* lin_clamp = lin.find_group("clamp");
  ASSERT_TRUE(clamp && solid && lin_clamp);
  for (int i : clamp->nodes) EXPECT_EQ(m.X(0, i), 0.0);
  long on_face = 0;
  for (int i = 0; i < m.num_nodes(); ++i) on_face += m.X(0, i) == 0.0 ? 1 : 0;
  EXPECT_EQ(static_cast<long>(clamp->nodes.size()), on_face) << "every node on x = 0, mid-edge ones included";
  EXPECT_GT(clamp->nodes.size(), 2 * lin_clamp->nodes.size());
  EXPECT_EQ(solid->nodes.size(), static_cast<std::size_t>(m.num_nodes()));
  // The edge group (type 8, 3-node lines) keeps its mid nodes too.
  const PhysicalGroup* edge = m.find_group("edge");
  ASSERT_TRUE(edge);
  EXPECT_EQ(edge->nodes.size(), 2 * lin.find_group("edge")->nodes.size() - 1);
}

// softdiff's straight mid-edge nodes on the linear mesh give the same mesh as gmsh's
// -order 2 (same vertices, same tets): the same node positions for every tet's 10
// nodes, in gmsh's order; the added nodes follow the file's.
TEST(GmshQuadratic, ElevatedLinearMeshEqualsGmshOrderTwo) {
  REQUIRE_CUBE();
  const TetMesh gm = read_gmsh(cube_files().a41);
  TetMesh el = read_gmsh(cube_files().linear);
  const int file_nodes = el.num_nodes();
  softdiff::mesh::elevate_to_quadratic(el);
  EXPECT_EQ(el.order, 2);
  EXPECT_EQ(el.num_nodes(), gm.num_nodes());
  EXPECT_EQ(el.added_nodes, gm.num_nodes() - file_nodes);
  for (int i = file_nodes; i < el.num_nodes(); ++i) {
    EXPECT_EQ(el.file_index[i], -1);
    EXPECT_EQ(el.file_tag[i], -1);
  }
  ASSERT_EQ(el.num_tets(), gm.num_tets());
  for (int t = 0; t < el.num_tets(); ++t)
    for (int a = 0; a < 10; ++a)
      ASSERT_LT((el.X.col(el.tets10(a, t)) - gm.X.col(gm.tets10(a, t))).norm(), 1e-12) << "tet " << t << " node " << a;
  for (std::size_t g = 0; g < el.groups.size(); ++g) {
    if (el.groups[g].dim < 2) continue;  // points and lines keep their own nodes
    EXPECT_EQ(el.groups[g].nodes.size(), gm.groups[g].nodes.size()) << el.groups[g].name;
  }
  EXPECT_LT(worst_midpoint_offset(el), 1e-15);
}

// Curved edges: the hollow sphere octant at order 2 puts mid-edge nodes on the
// spheres. The isoparametric volume (4-point rule, sum of w det J) is much closer to
// the exact pi (b^3 - a^3) / 6 than the straight-sided one.
TEST(GmshQuadratic, CurvedEdgesOnASphere) {
  const fs::path geo = order2_copy(fs::path(SOFTDIFF_SOURCE_DIR) / "tests/data/hollow_sphere_octant.geo");
  const fs::path out = scratch() / "sphere_o2.msh";
  const std::string failure = run_gmsh("-3 \"" + geo.string() + "\" -setnumber h 0.005 -format msh41", out);
  ASSERT_TRUE(failure.empty()) << failure;
  const TetMesh m = read_gmsh(out);
  ASSERT_EQ(m.order, 2);
  EXPECT_GT(worst_midpoint_offset(m), 1e-6) << "some edges are curved";
  double curved = 0;
  for (int t = 0; t < m.num_tets(); ++t) {
    Eigen::Matrix<double, 3, 10> X_e;
    for (int a = 0; a < 10; ++a) X_e.col(a) = m.X.col(m.tets10(a, t));
    for (const auto& q : softdiff::fem::tet10::kMassRule)
      curved += q.weight * softdiff::fem::tet10::jacobian(X_e, softdiff::fem::tet10::shape_gradients_ref(q.u, q.v, q.w))
                               .determinant();
  }
  const double straight = softdiff::mesh::quality(m.X, m.tets).total_volume;
  const double exact = std::numbers::pi * (0.02 * 0.02 * 0.02 - 0.01 * 0.01 * 0.01) / 6;
  std::printf("octant volume: straight %.3e relative error, curved %.3e\n", std::abs(straight / exact - 1),
              std::abs(curved / exact - 1));
  EXPECT_LT(std::abs(curved / exact - 1), 0.1 * std::abs(straight / exact - 1));
}

// ---------------------------------------------------------------------------
// Hand-made files: one 10-node tet (vertices 1-4, mid-edge nodes 5-10 in gmsh order).

const std::string kFormat22 = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n";

// The nodes of the unit tet's 10 nodes, node 5 + k at the midpoint of edge k plus
// `offset` on node `moved` (1-based tag).
std::string nodes22(int moved = 0, const Vec3& offset = Vec3::Zero()) {
  const Vec3 v[4] = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)};
  std::string s = "$Nodes\n10\n";
  for (int a = 0; a < 10; ++a) {
    Vec3 p = a < 4 ? v[a]
                   : 0.5 * (v[softdiff::mesh::kTet10Edge[a - 4][0]] + v[softdiff::mesh::kTet10Edge[a - 4][1]]);
    if (a + 1 == moved) p += offset;
    s += std::to_string(a + 1) + " " + std::to_string(p.x()) + " " + std::to_string(p.y()) + " " +
         std::to_string(p.z()) + "\n";
  }
  return s + "$EndNodes\n";  // lines 4-16; $Elements 17, count 18, the first element 19
}

TEST(GmshQuadraticHandMade, NegativeTetIsReorientedWithItsMidEdgeNodes) {
  // Vertices 1 3 2 4 (negative), mid-edge nodes in gmsh's order for that vertex order:
  // edges (1,3) (3,2) (2,1) (4,1) (4,2) (4,3) -> tags 7 6 5 8 10 9.
  const TetMesh m = read_gmsh(write_file(
      "negative.msh", kFormat22 + nodes22() + "$Elements\n1\n1 11 2 1 1 1 3 2 4 7 6 5 8 10 9\n$EndElements\n"));
  EXPECT_EQ(m.reoriented_tets, 1);
  EXPECT_LT(worst_midpoint_offset(m), 1e-15);
  Eigen::Matrix3d D;
  for (int k = 0; k < 3; ++k) D.col(k) = m.X.col(m.tets(k + 1, 0)) - m.X.col(m.tets(0, 0));
  EXPECT_GT(D.determinant(), 0);
}

TEST(GmshQuadraticHandMade, InvalidCurvedElementIsReportedWithItsTag) {
  // Mid-edge node 5 (edge 01) pushed across the element: det J < 0 near vertex 1.
  const fs::path p = write_file("inverted_mid.msh", kFormat22 + nodes22(5, Vec3(0.6, 0.9, 0.9)) +
                                                        "$Elements\n1\n17 11 2 1 1 1 2 3 4 5 6 7 8 9 10\n$EndElements\n");
  const std::string msg = error_of(p);
  EXPECT_EQ(msg.rfind(p.string() + ":19: ", 0), 0u) << msg;
  EXPECT_NE(msg.find("1 invalid quadratic tetrahedra"), std::string::npos) << msg;
  EXPECT_NE(msg.find("element 17 (line 19"), std::string::npos) << msg;
  EXPECT_NE(msg.find("det J <= 0"), std::string::npos) << msg;
  // A small offset is valid.
  EXPECT_EQ(read_gmsh(write_file("curved_ok.msh", kFormat22 + nodes22(5, Vec3(0, -0.1, 0)) +
                                                      "$Elements\n1\n17 11 2 1 1 1 2 3 4 5 6 7 8 9 10\n$EndElements\n"))
                .order,
            2);
}

TEST(GmshQuadraticHandMade, MixedOrdersAreAnError) {
  const fs::path p = write_file(
      "mixed.msh", kFormat22 + nodes22() +
                       "$Elements\n2\n1 11 2 1 1 1 2 3 4 5 6 7 8 9 10\n2 4 2 1 1 1 2 3 4\n$EndElements\n");
  const std::string msg = error_of(p);
  EXPECT_EQ(msg.rfind(p.string() + ":20: ", 0), 0u) << msg;
  EXPECT_NE(msg.find("element 2 is a type 4 (4-node tetrahedron)"), std::string::npos) << msg;
  EXPECT_NE(msg.find("(line 19) is a type 11 (10-node tetrahedron)"), std::string::npos) << msg;
  EXPECT_NE(msg.find("one element order"), std::string::npos) << msg;
}

TEST(GmshQuadraticHandMade, SixNodeTriangleGroupAndMsh41) {
  // MSH 4.1 with $Entities: a 6-node triangle in surface group 7 on the face x = 0,
  // vertices (1, 3, 4); its mid-edge nodes are the tet's: edge 1-3 tag 7, 3-4 tag 9,
  // 4-1 tag 8.
  std::string nodes = "$Nodes\n1 10 1 10\n3 1 0 10\n";
  const Vec3 v[4] = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)};
  std::string coords;
  for (int a = 0; a < 10; ++a) {
    nodes += std::to_string(a + 1) + "\n";
    const Vec3 p = a < 4 ? v[a]
                         : 0.5 * (v[softdiff::mesh::kTet10Edge[a - 4][0]] + v[softdiff::mesh::kTet10Edge[a - 4][1]]);
    coords += std::to_string(p.x()) + " " + std::to_string(p.y()) + " " + std::to_string(p.z()) + "\n";
  }
  nodes += coords + "$EndNodes\n";
  const std::string entities =
      "$Entities\n0 0 1 1\n1 0 0 0 0 1 1 1 7 0\n1 0 0 0 1 1 1 1 21 0\n$EndEntities\n";
  const std::string elements =
      "$Elements\n2 2 1 2\n2 1 9 1\n2 1 3 4 7 9 8\n3 1 11 1\n1 1 2 3 4 5 6 7 8 9 10\n$EndElements\n";
  const std::string names = "$PhysicalNames\n2\n2 7 \"face\"\n3 21 \"solid\"\n$EndPhysicalNames\n";
  const TetMesh m = read_gmsh(
      write_file("tri6.msh", "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n" + names + entities + nodes + elements));
  EXPECT_EQ(m.order, 2);
  const PhysicalGroup* face = m.find_group("face");
  ASSERT_TRUE(face);
  EXPECT_EQ(face->triangles.size(), 1u);
  EXPECT_EQ(face->nodes.size(), 6u);
  for (int i : face->nodes) EXPECT_EQ(m.X(0, i), 0.0);
  const auto tri6 = softdiff::mesh::quadratic_triangles(m, m.triangles);
  for (int k = 0; k < 3; ++k)
    EXPECT_LT((m.X.col(tri6(3 + k, 0)) - 0.5 * (m.X.col(tri6(k, 0)) + m.X.col(tri6((k + 1) % 3, 0)))).norm(), 1e-15);
}

TEST(GmshQuadraticHandMade, OtherHigherOrderTetsAreStillAnError) {
  std::string nodes = "$Nodes\n20\n";
  for (int a = 1; a <= 20; ++a) nodes += std::to_string(a) + " " + std::to_string(a % 2) + " " + std::to_string(a % 3) + " " + std::to_string(a % 5) + "\n";
  nodes += "$EndNodes\n";
  std::string el = "1 29 2 1 1";
  for (int a = 1; a <= 20; ++a) el += " " + std::to_string(a);
  const fs::path p = write_file("tet20.msh", kFormat22 + nodes + "$Elements\n1\n" + el + "\n$EndElements\n");
  const std::string msg = error_of(p);
  EXPECT_NE(msg.find("only linear and quadratic tetrahedra are supported"), std::string::npos) << msg;
  EXPECT_NE(msg.find("type 29 (20-node tetrahedron)"), std::string::npos) << msg;
}

}  // namespace gmsh_quadratic_test
