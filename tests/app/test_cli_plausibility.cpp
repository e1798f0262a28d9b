// Plausibility checks (docs/scene.md "Plausibility checks", io/plausibility.hpp) end to
// end: a beam meshed in millimetres (200 x 20 x 20 mm) and read without mesh_scale is
// a 200 m, 85,600 t body: `info` warns and suggests mesh_scale: 0.001, prints each
// body's size and mass with their units; --strict (info, simulate) makes it bad input
// (exit 2, no output file); with mesh_scale: 0.001 nothing is said. A metre mesh
// scaled by 0.001 (0.2 mm) warns. A free body under gravity that nothing holds warns;
// one on a floor (contact), fixed along gravity, held by a servo, or without gravity
// does not.
#include <support/cli.hpp>
#include <support/meshes.hpp>

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <string>

using namespace softdiff::test;

// (A named namespace: this file shares a unity translation unit with test_cli.cpp.)
namespace plausibility_cli {
namespace {

namespace fs = std::filesystem;

const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_plausibility";

// A box of 8 x 2 x 2 cells of size (lx, ly, lz) in the file's units, as MSH 2.2.
std::string box_msh(double lx, double ly, double lz) {
  const auto m = box_mesh(8, 2, 2, lx, ly, lz);
  std::string s = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n" + std::to_string(m.X.cols()) + "\n";
  char buf[128];
  for (int i = 0; i < m.X.cols(); ++i) {
    std::snprintf(buf, sizeof buf, "%d %.17g %.17g %.17g\n", i + 1, m.X(0, i), m.X(1, i), m.X(2, i));
    s += buf;
  }
  s += "$EndNodes\n$Elements\n" + std::to_string(m.tets.cols()) + "\n";
  for (int e = 0; e < m.tets.cols(); ++e) {
    std::snprintf(buf, sizeof buf, "%d 4 2 1 1 %d %d %d %d\n", e + 1, m.tets(0, e) + 1, m.tets(1, e) + 1,
                  m.tets(2, e) + 1, m.tets(3, e) + 1);
    s += buf;
  }
  return s + "$EndElements\n";
}

// A scene on beam.msh; `body_extra` is appended to the body (indented 4 spaces),
// `extra` to the scene.
std::string scene(const std::string& body_extra, const std::string& extra = "") {
  return "softdiff: 1\n"
         "simulation: {dt: 0.01, steps: 1}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: beam.msh\n"
         "    material: {law: corotational, young: 1.0e6, poisson: 0.45, density: 1070}\n" +
         body_extra + extra;
}

fs::path folder(const std::string& name, double size, const std::string& scene_text) {
  const auto dir = fresh_dir(kWork, name);
  write_text(dir / "beam.msh", box_msh(size, 0.1 * size, 0.1 * size));
  write_text(dir / "scene.yaml", scene_text);
  return dir;
}

bool has(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(CliPlausibility, AMillimetreMeshWithoutMeshScaleWarnsAndSuggestsTheScale) {
  const auto dir = folder("mm", 200, scene("    fixed:\n      - box: [-1, -1, -1, 1, 30, 30]\n"));
  const CliRun r = run_cli("info scene.yaml", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(has(r.err, "scene.yaml:4:5: bodies[0]: body 'beam' is 200 x 20 x 20 m (bounding box) and 8.56e+07 kg: "
                         "implausible for a soft robot (its largest extent is above 5 m and its mass is above 1000 kg)"))
      << r.err;
  EXPECT_TRUE(has(r.err, "set mesh_scale: 0.001")) << r.err;
  EXPECT_TRUE(has(r.out, "size 200 x 20 x 20 m, mass 8.56e+07 kg")) << r.out;
  EXPECT_TRUE(has(r.out, "warnings    1 (on stderr)")) << r.out;
  const CliRun j = run_cli("info scene.yaml --json", dir);
  EXPECT_EQ(j.code, 0) << j.err;
  EXPECT_TRUE(has(j.out, "\"size\":[200,20,20]")) << j.out;
}

TEST(CliPlausibility, StrictMakesAnImplausibleBodyBadInputWithoutOutput) {
  const auto dir = folder("mm_strict", 200, scene("    fixed:\n      - box: [-1, -1, -1, 1, 30, 30]\n"));
  CliRun r = run_cli("info scene.yaml --strict", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_TRUE(has(r.err, "body 'beam' is 200 x 20 x 20 m")) << r.err;
  EXPECT_TRUE(has(r.err, "--strict")) << r.err;
  r = run_cli("simulate scene.yaml -o out.h5 --strict", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_TRUE(has(r.err, "set mesh_scale: 0.001")) << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));
  // Without --strict it runs (a warning only).
  r = run_cli("simulate scene.yaml -o out.h5 --quiet", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(has(r.err, "implausible for a soft robot")) << r.err;
  EXPECT_TRUE(fs::exists(dir / "out.h5"));
}

TEST(CliPlausibility, TheSameMeshWithMeshScaleIsQuiet) {
  const auto dir = folder("mm_scaled", 200,
                          scene("    mesh_scale: 0.001\n    fixed:\n      - box: [-0.001, -1, -1, 0.001, 1, 1]\n"));
  const CliRun r = run_cli("info scene.yaml --strict", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_TRUE(has(r.out, "size 0.2 x 0.02 x 0.02 m, mass 0.0856 kg")) << r.out;
  EXPECT_FALSE(has(r.out, "warnings")) << r.out;
}

TEST(CliPlausibility, AMetreMeshScaledByAThousandthIsTooSmall) {
  const auto dir = folder("tiny", 0.2, scene("    mesh_scale: 0.001\n    fixed:\n      - box: [-1, -1, -1, 1e-6, 1, 1]\n"));
  const CliRun r = run_cli("info scene.yaml", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(has(r.err, "its largest extent is below 1 mm")) << r.err;
  EXPECT_TRUE(has(r.err, "is the mesh already in metres?")) << r.err;
}

TEST(CliPlausibility, ABodyHeldByNothingFallsAndSaysSo) {
  const auto dir = folder("free", 0.2, scene(""));
  const CliRun r = run_cli("info scene.yaml", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(has(r.err, "body 'beam' is held by nothing")) << r.err;
  EXPECT_TRUE(has(r.err, "falls freely under gravity (9.81 m/s^2)")) << r.err;
  // simulate says it too; --strict does not make it an error (a drop can be intended).
  const CliRun s = run_cli("simulate scene.yaml -o out.h5 --quiet --strict", dir);
  EXPECT_EQ(s.code, 0) << s.err;
  EXPECT_TRUE(has(s.err, "is held by nothing")) << s.err;
}

TEST(CliPlausibility, ABodyHeldBySomethingDoesNotWarn) {
  const std::string holders[][2] = {
      {"on_floor", "obstacles:\n  - {name: floor, type: plane, normal: [0, 0, 1], offset: -0.001}\ncontact: {friction: 0.3}\n"},
      {"fixed_z", ""},
      {"servo", ""},
      {"no_gravity", "simulation: {dt: 0.01, steps: 1, gravity: [0, 0, 0]}\n"},
  };
  for (const auto& h : holders) {
    const std::string name = h[0];
    std::string body, extra = h[1];
    if (name == "fixed_z") body = "    fixed:\n      - {box: [-1, -1, -1, 0.001, 1, 1], axes: [z]}\n";
    if (name == "servo")
      body = "    actuators:\n      - {name: s, type: servo, nodes: {box: [-1, -1, -1, 0.001, 1, 1]}, direction: [0, 0, 1], "
             "force: 0}\n";
    std::string text = scene(body, extra);
    if (name == "no_gravity") {  // its own simulation section
      const std::string plain = scene(body);
      text = "softdiff: 1\n" + extra + plain.substr(plain.find("bodies:"));
    }
    const auto dir = folder("held_" + name, 0.2, text);
    const CliRun r = run_cli("info scene.yaml", dir);
    EXPECT_EQ(r.code, 0) << name << ": " << r.err;
    EXPECT_FALSE(has(r.err, "held by nothing")) << name << ": " << r.err;
  }
  // Fixed along x only (gravity along z): still falls.
  const auto dir = folder("held_x_only", 0.2, scene("    fixed:\n      - {box: [-1, -1, -1, 0.001, 1, 1], axes: [x]}\n"));
  const CliRun r = run_cli("info scene.yaml", dir);
  EXPECT_TRUE(has(r.err, "held by nothing")) << r.err;
}

}  // namespace
}  // namespace plausibility_cli
