// Validation of the shipped Trunk scene (configs/trunk.yaml): cable actuation bends
// the trunk towards the pulled cable, monotonically in the tension; two exactly
// opposite cables pulled equally keep the tip on the axis.
//
// Equilibria come from dynamic relaxation (support/relax.hpp) with the scene's
// dt = 0.01 s, gravity off (it bends the horizontal trunk by ~16 cm, would hide the
// cable's effect and break the symmetry of (b)), and damping overridden to
// rayleigh_mass 10, rayleigh_stiffness 0. The equilibrium does not depend on damping;
// with the scene's upstream damping (0.1 / 0.1) the trunk does not come to rest under
// a constant tension, and the static solver does not converge on this scene (both
// explained in configs/trunk.yaml). Tensions stay at or below 0.05 N, where dt = 0.01
// settles (it does not from ~0.2 N on).
#include <softdiff/data.hpp>
#include <softdiff/io/gmsh_msh.hpp>
#include <support/cli.hpp>
#include <support/relax.hpp>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <gtest/gtest.h>
#include <map>
#include <numbers>
#include <sstream>

using namespace softdiff;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kScene = kRoot / "configs/trunk.yaml";
constexpr double kVTol = 1e-6;    // m/s: at rest
constexpr long kMaxSteps = 3000;  // 30 s of simulated time
constexpr double kResidualTol = 1e-6;

std::string num(double v) {
  std::ostringstream s;
  s.precision(17);
  s << v;
  return s.str();
}

// Gravity off, damping for a fast relaxation, the scene's schedule on cableL0
// replaced by constant tensions (every cable 0 unless given).
std::vector<std::string> relaxation(const std::vector<std::pair<std::string, double>>& tensions,
                                    std::vector<std::string> more = {}) {
  std::vector<std::string> o = {"simulation.gravity=[0,0,0]", "bodies.trunk.damping.rayleigh_mass=10",
                                "bodies.trunk.damping.rayleigh_stiffness=0",
                                "bodies.trunk.actuators.cableL0.schedule=null"};
  for (const auto& [cable, value] : tensions) o.push_back("bodies.trunk.actuators." + cable + ".force=" + num(value));
  o.insert(o.end(), more.begin(), more.end());
  return o;
}

State at_rest(const Model& model) {
  State s = model.initial;
  s.v.setZero();
  return s;
}

struct Equilibrium {
  Vec3 tip_displacement = Vec3::Zero();
  double cable_length = 0;
  State state;
};

// Relaxes `model` from `start` and checks that it reached a static equilibrium.
Equilibrium equilibrium(const Model& model, const State& start, const std::string& cable = "cableL0") {
  const test::Rest r = test::relax(model, start, kVTol, kResidualTol, kMaxSteps);
  EXPECT_TRUE(r.ok) << "no equilibrium after " << r.steps << " steps: max |v| = " << r.max_v
                    << " m/s, relative residual " << r.residual;
  const double residual = r.residual;
  Equilibrium e;
  e.state = r.state;
  e.tip_displacement = test::effector(model, r.state, "tip") - test::effector(model, model.initial, "tip");
  for (const auto& a : model.actuation.actuators)
    if (a.name == cable) e.cable_length = a.measure(r.state.x);
  std::printf("    %ld steps, residual %.2e, tip displacement [%.6g, %.6g, %.6g] mm, %s length %.6g mm\n", r.steps,
              residual, 1e3 * e.tip_displacement.x(), 1e3 * e.tip_displacement.y(), 1e3 * e.tip_displacement.z(),
              cable.c_str(), 1e3 * e.cable_length);
  return e;
}

// Radial direction of cable i of the upstream formula (rotation by 1.57 i about z of
// the +y direction of cableL0): the side the trunk bends to.
Vec3 radial(int i) { return Vec3(-std::sin(1.57 * i), std::cos(1.57 * i), 0); }

}  // namespace

TEST(TrunkScene, MassIsTheUpstreamTotalMass) {
  // density 1034.28 kg/m^3 = totalMass 0.042 kg (SoftRobots trunk.py) / the volume of
  // meshes/trunk.msh (40607.9 mm^3, `softdiff info meshes/trunk.msh`).
  const Model model = test::load_model(kScene, {});
  EXPECT_NEAR(model.fem.total_mass, 0.042, 0.042 * 1e-5);
}

// (a) One long cable: the tip moves towards the cable's side, more with more tension.
TEST(TrunkScene, LongCableBendsTowardsItsSideMonotonically) {
  Model model = test::load_model(kScene, relaxation({}));
  State state = at_rest(model);
  double previous_norm = 0, previous_length = model.actuation.actuators[0].measure(model.initial.x);
  for (double tension : {0.01, 0.02, 0.03, 0.04, 0.05}) {
    SCOPED_TRACE("cableL0 tension " + num(tension) + " N");
    std::printf("  cableL0 %g N:\n", tension);
    model = test::load_model(kScene, relaxation({{"cableL0", tension}}));
    const Equilibrium e = equilibrium(model, state);
    const Vec3 d = e.tip_displacement;
    const Vec3 lateral(d.x(), d.y(), 0);
    // Towards +y (cableL0's side), within 2 degrees: the only asymmetry is the mesh's
    // (0.5 degrees measured).
    EXPECT_GT(lateral.dot(radial(0)), std::cos(2 * std::numbers::pi / 180) * lateral.norm());
    EXPECT_LT(d.z(), 0);  // the bend shortens the trunk's projection on its axis
    EXPECT_GT(d.norm(), previous_norm * 1.2);  // grows with the tension (by >= 20% per 0.01 N step)
    EXPECT_LT(e.cable_length, previous_length);  // the cable shortens
    previous_norm = d.norm();
    previous_length = e.cable_length;
    state = e.state;
  }
}

// (a) Each of the other long cables bends the trunk towards its own side.
TEST(TrunkScene, EachLongCableBendsTowardsItsOwnSide) {
  for (int i = 1; i < 4; ++i) {
    const std::string cable = "cableL" + std::to_string(i);
    SCOPED_TRACE(cable);
    std::printf("  %s 0.05 N:\n", cable.c_str());
    const Model model = test::load_model(kScene, relaxation({{cable, 0.05}}));
    const Vec3 d = equilibrium(model, at_rest(model), cable).tip_displacement;
    const Vec3 lateral(d.x(), d.y(), 0);
    const double angle = std::acos(std::min(1.0, lateral.normalized().dot(radial(i)))) * 180 / std::numbers::pi;
    std::printf("    angle to the cable's radial direction %.3g deg\n", angle);
    EXPECT_LT(angle, 2.0);
    EXPECT_GT(lateral.norm(), 0.01);  // > 10 mm: a real bend, not noise
  }
}

namespace {

// An exactly mirror-symmetric mesh of the Trunk (about the planes x = 0 and y = 0):
// meshes/trunk.geo revolved by pi/2 instead of 2 pi (the quarter x >= 0, y >= 0) is
// meshed by gmsh, its nodes on the cut planes are snapped onto them, and the quarter
// is reflected into the other three (reflected tets reordered to positive
// orientation; nodes on the planes shared). Written as MSH 2.2, in mm like trunk.msh.
// The shipped meshes/trunk.msh is not symmetric (gmsh meshes the whole solid): on it
// the symmetric test below would measure the mesh, not the method.
fs::path symmetric_trunk_mesh() {
  static fs::path cached;
  if (!cached.empty()) return cached;
  const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / "trunk_symmetric";
  fs::create_directories(dir);
  std::string geo = test::read_text(kRoot / "meshes/trunk.geo");
  const std::string revolve = "Extrude {{0, 0, 1}, {0, 0, 0}, 2 * Pi}";
  const auto at = geo.find(revolve);
  if (at == std::string::npos) {
    ADD_FAILURE() << "meshes/trunk.geo no longer contains '" << revolve << "'";
    return {};
  }
  geo.replace(at, revolve.size(), "Extrude {{0, 0, 1}, {0, 0, 0}, Pi / 2}");
  test::write_text(dir / "quarter.geo", geo);
  const std::string cmd = std::string("\"") + GMSH_EXECUTABLE + "\" -3 \"" + (dir / "quarter.geo").string() +
                          "\" -format msh41 -o \"" + (dir / "quarter.msh").string() + "\" >\"" +
                          (dir / "gmsh.log").string() + "\" 2>&1";
  if (std::system(cmd.c_str()) != 0) {
    ADD_FAILURE() << "gmsh failed: " << test::read_text(dir / "gmsh.log");
    return {};
  }
  const mesh::TetMesh q = io::read_gmsh(dir / "quarter.msh");
  std::map<std::array<double, 3>, int> index;
  std::vector<Vec3> nodes;
  std::vector<std::array<int, 4>> tets;
  for (const auto& [sx, sy] : {std::pair{1, 1}, {-1, 1}, {1, -1}, {-1, -1}}) {
    std::vector<int> local(q.num_nodes());
    for (int i = 0; i < q.num_nodes(); ++i) {
      Vec3 p = q.X.col(i);
      for (int c = 0; c < 2; ++c) {
        EXPECT_GT(p[c], -1e-9) << "node " << i << " outside the quarter";
        if (std::abs(p[c]) < 1e-9) p[c] = 0;  // on a cut plane (a revolved plane has |x| ~ 1e-15)
      }
      // + 0.0 turns the -0.0 of a reflected 0 into +0.0: one key per point
      const std::array<double, 3> key{sx * p.x() + 0.0, sy * p.y() + 0.0, p.z()};
      const auto [it, inserted] = index.emplace(key, static_cast<int>(nodes.size()));
      if (inserted) nodes.emplace_back(key[0], key[1], key[2]);
      local[i] = it->second;
    }
    for (int e = 0; e < q.num_tets(); ++e) {
      std::array<int, 4> t;
      for (int a = 0; a < 4; ++a) t[a] = local[q.tets(a, e)];
      if (sx * sy < 0) std::swap(t[2], t[3]);  // one reflection flips the orientation
      tets.push_back(t);
    }
  }
  std::ostringstream s;
  s.precision(17);
  s << "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n" << nodes.size() << "\n";
  for (size_t i = 0; i < nodes.size(); ++i) s << i + 1 << " " << nodes[i].x() << " " << nodes[i].y() << " " << nodes[i].z() << "\n";
  s << "$EndNodes\n$Elements\n" << tets.size() << "\n";
  for (size_t e = 0; e < tets.size(); ++e)
    s << e + 1 << " 4 2 1 1 " << tets[e][0] + 1 << " " << tets[e][1] + 1 << " " << tets[e][2] + 1 << " " << tets[e][3] + 1
      << "\n";
  s << "$EndElements\n";
  test::write_text(dir / "trunk_symmetric.msh", s.str());
  std::printf("  symmetric trunk mesh: %zu nodes, %zu tets (quarter: %d nodes, %d tets)\n", nodes.size(), tets.size(),
              q.num_nodes(), q.num_tets());
  cached = dir / "trunk_symmetric.msh";
  return cached;
}

// cableL0's points reflected about y = 0: the exact opposite of cableL0 (upstream
// cableL2 is cableL0 rotated by 3.14 rad, not pi: 16 micrometres off at r = 10 mm).
std::string mirrored_cableL0() {
  const io::SceneDesc scene = io::load_scene(kScene);
  for (const auto& a : scene.bodies[0].actuators)
    if (a.name == "cableL0") {
      std::ostringstream s;
      s.precision(17);
      s << "[";
      for (size_t k = 0; k < a.points.size(); ++k)
        s << (k ? ", " : "") << "[" << a.points[k].x() << ", " << -a.points[k].y() << ", " << a.points[k].z() << "]";
      s << "]";
      return s.str();
    }
  ADD_FAILURE() << "no cableL0 in " << kScene;
  return "[]";
}

double lateral_over_axial(const Vec3& d) { return std::hypot(d.x(), d.y()) / std::abs(d.z()); }

}  // namespace

// (b) Two exactly opposite long cables, equal tensions: the tip stays on the axis.
// Gravity is off (it is transverse to the trunk and would bend it). On the symmetric
// mesh the tip's lateral displacement is round-off; the same run with one cable, or
// with the upstream pair cableL0 + cableL2 (3.14 rad apart), shows what the ratio
// measures.
TEST(TrunkScene, OppositeCablesKeepTheTipOnTheAxis) {
  const fs::path mesh = symmetric_trunk_mesh();
  ASSERT_FALSE(mesh.empty());
  const double tension = 0.05;
  const std::string on_mesh = "bodies.trunk.mesh=" + mesh.string();
  const std::string mirrored = "bodies.trunk.actuators.cableL2.points=" + mirrored_cableL0();

  std::printf("  symmetric mesh, cableL0 + its mirror image, %g N each:\n", tension);
  Model model = test::load_model(kScene, relaxation({{"cableL0", tension}, {"cableL2", tension}}, {on_mesh, mirrored}));
  const Vec3 d = equilibrium(model, at_rest(model)).tip_displacement;
  std::printf("    lateral / axial = %.3g\n", lateral_over_axial(d));
  EXPECT_LT(d.z(), -1e-4);  // compressed by > 0.1 mm: an axial displacement to compare with
  EXPECT_LT(lateral_over_axial(d), 1e-6);

  std::printf("  symmetric mesh, upstream cableL0 + cableL2, %g N each:\n", tension);
  model = test::load_model(kScene, relaxation({{"cableL0", tension}, {"cableL2", tension}}, {on_mesh}));
  const double upstream_pair = lateral_over_axial(equilibrium(model, at_rest(model)).tip_displacement);
  std::printf("    lateral / axial = %.3g\n", upstream_pair);
  EXPECT_GT(upstream_pair, 1e-4);

  std::printf("  symmetric mesh, cableL0 alone, %g N:\n", tension);
  model = test::load_model(kScene, relaxation({{"cableL0", tension}}, {on_mesh}));
  const double one_cable = lateral_over_axial(equilibrium(model, at_rest(model)).tip_displacement);
  std::printf("    lateral / axial = %.3g\n", one_cable);
  EXPECT_GT(one_cable, 1);

  std::printf("  shipped mesh, cableL0 + its mirror image, %g N each:\n", tension);
  model = test::load_model(kScene, relaxation({{"cableL0", tension}, {"cableL2", tension}}, {mirrored}));
  const double shipped = lateral_over_axial(equilibrium(model, at_rest(model)).tip_displacement);
  std::printf("    lateral / axial = %.3g (mesh asymmetry)\n", shipped);
  EXPECT_GT(shipped, 1e-3);  // why the symmetric mesh: the shipped one cannot show 1e-6
}
