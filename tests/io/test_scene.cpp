// load_scene(): a full scene, defaults, one test per kind of error (exact
// FILE:LINE:COL: PATH: message), and --set overrides.
#include <softdiff/core/error.hpp>
#include <softdiff/io/scene.hpp>

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>
#include <vector>

namespace {

namespace fs = std::filesystem;
using softdiff::InputError;
using softdiff::Vec3;
using namespace softdiff::io;

const fs::path kDir = fs::path(SOFTDIFF_TEST_DATA_DIR) / "scene_tests";

void write_file(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

// Lines: 1 softdiff, 2 simulation, 3 dt, 4 steps, 5 bodies, 6 name, 7 mesh,
// 8 material, 9 young, 10 poisson, 11 density. Body keys at column 5, material keys at 7.
const std::string kBase = R"(softdiff: 1
simulation:
  dt: 0.01
  steps: 10
bodies:
  - name: beam
    mesh: meshes/beam.msh
    material:
      young: 1.0e5
      poisson: 0.45
      density: 1000
)";

// kBase with the first occurrence of `from` replaced by `to`.
std::string edit(const std::string& from, const std::string& to, std::string text = kBase) {
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

class Scene : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {  // (ctest may run these tests as parallel processes)
    std::error_code ec;
    fs::create_directories(kDir / "meshes", ec);
    if (!fs::exists(kDir / "meshes" / "beam.msh"))
      write_file(kDir / "meshes" / "beam.msh", "not a real mesh: load_scene only checks that it exists\n");
  }

  // A scene file named after the running test.
  fs::path write_scene(const std::string& text) {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    const fs::path path = kDir / (std::string(info->name()) + ".yaml");
    write_file(path, text);
    return path;
  }

  SceneDesc load(const std::string& text, const std::vector<std::string>& overrides = {}) {
    return load_scene(write_scene(text), overrides);
  }

  // The message of the InputError that loading `text` throws.
  std::string error(const std::string& text, const std::vector<std::string>& overrides = {}) {
    const fs::path path = write_scene(text);
    try {
      load_scene(path, overrides);
    } catch (const InputError& e) {
      return e.what();
    }
    ADD_FAILURE() << "no InputError";
    return {};
  }

  // The error must be "<scene file><suffix>", e.g. suffix ":10:7: bodies[0]...: ...".
  void expect_error(const std::string& text, const std::string& suffix, const std::vector<std::string>& overrides = {}) {
    const std::string message = error(text, overrides);
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    EXPECT_EQ(message, (kDir / (std::string(info->name()) + ".yaml")).string() + suffix);
  }
};

// ---------------------------------------------------------------------------
// Valid scenes

TEST_F(Scene, FullSceneParsesEveryField) {
  const std::string text = R"(softdiff: 1
name: cantilever beam
simulation:
  integrator: implicit_euler
  dt: 0.005
  duration: 0.3
  gravity: [0, -9.8, 0.5]
  newton_iterations: 3
  newton_tolerance: 1.0e-8
  static:
    max_iterations: 20
    tolerance: 1.0e-6
    load_steps: 4
linear_solver: {type: cg, tolerance: 1.0e-9, max_iterations: 500}
bodies:
  - name: beam
    type: soft
    mesh: meshes/../meshes/beam.msh
    mesh_scale: 0.001
    translate: [1, 2, 3]
    rotate_deg: [0, 90, 45]
    material:
      law: neo_hookean
      young: 2.5e5
      poisson: 0.3
      density: 1100
    mass: consistent
    damping:
      rayleigh_mass: 0.1
      rayleigh_stiffness: 0.02
    psd_projection: true
    fixed:
      - box: [-1, -1, -1, 0, 1, 1.5]
      - group: clamp
      - nodes: [0, 17, 42]
      - {group: sym_x0, axes: [x, z]}
    initial_velocity: [0.5, 0, -1]
    actuators: []
    effectors: []
  - name: second-2
    mesh: meshes/beam.msh
    material: {young: 1e6, poisson: 0, density: 500}
obstacles: []
contact:
  enabled: false
  friction: 0.3
output:
  file: out/result.h5
  every: 5
  fields: [x, v]
  jacobians: []
)";
  const SceneDesc s = load(text);
  EXPECT_EQ(s.file, kDir / "FullSceneParsesEveryField.yaml");
  EXPECT_EQ(s.text, text);
  EXPECT_EQ(s.name, "cantilever beam");

  EXPECT_EQ(s.simulation.integrator, Integrator::implicit_euler);
  EXPECT_DOUBLE_EQ(s.simulation.dt, 0.005);
  EXPECT_EQ(s.simulation.steps, 60);
  EXPECT_EQ(s.simulation.gravity, Vec3(0, -9.8, 0.5));
  EXPECT_EQ(s.simulation.newton_iterations, 3);
  EXPECT_DOUBLE_EQ(s.simulation.newton_tolerance, 1e-8);
  EXPECT_EQ(s.simulation.static_max_iterations, 20);
  EXPECT_DOUBLE_EQ(s.simulation.static_tolerance, 1e-6);
  EXPECT_EQ(s.simulation.static_load_steps, 4);

  EXPECT_EQ(s.linear_solver.kind, LinearSolverKind::cg);
  EXPECT_DOUBLE_EQ(s.linear_solver.cg_tolerance, 1e-9);
  EXPECT_EQ(s.linear_solver.cg_max_iterations, 500);

  ASSERT_EQ(s.bodies.size(), 2u);
  const BodyDesc& b = s.bodies[0];
  EXPECT_EQ(b.name, "beam");
  EXPECT_EQ(b.mesh, kDir / "meshes" / "beam.msh");
  EXPECT_DOUBLE_EQ(b.mesh_scale, 0.001);
  EXPECT_EQ(b.translate, Vec3(1, 2, 3));
  EXPECT_EQ(b.rotate_deg, Vec3(0, 90, 45));
  EXPECT_EQ(b.material.law, softdiff::material::Law::neo_hookean);
  EXPECT_DOUBLE_EQ(b.material.young, 2.5e5);
  EXPECT_DOUBLE_EQ(b.material.poisson, 0.3);
  EXPECT_DOUBLE_EQ(b.material.density, 1100);
  EXPECT_EQ(b.mass, MassKind::consistent);
  EXPECT_DOUBLE_EQ(b.rayleigh_mass, 0.1);
  EXPECT_DOUBLE_EQ(b.rayleigh_stiffness, 0.02);
  EXPECT_TRUE(b.psd_projection);
  EXPECT_EQ(b.initial_velocity, Vec3(0.5, 0, -1));
  ASSERT_EQ(b.fixed.size(), 4u);
  EXPECT_EQ(b.fixed[0].kind, FixedDesc::Kind::box);
  EXPECT_EQ(b.fixed[0].box, (std::array<double, 6>{-1, -1, -1, 0, 1, 1.5}));
  EXPECT_EQ(b.fixed[0].axes, (std::array<bool, 3>{true, true, true}));
  EXPECT_EQ(b.fixed[1].kind, FixedDesc::Kind::group);
  EXPECT_EQ(b.fixed[1].group, "clamp");
  EXPECT_EQ(b.fixed[2].kind, FixedDesc::Kind::nodes);
  EXPECT_EQ(b.fixed[2].nodes, (std::vector<long>{0, 17, 42}));
  EXPECT_EQ(b.fixed[3].group, "sym_x0");
  EXPECT_EQ(b.fixed[3].axes, (std::array<bool, 3>{true, false, true}));

  // Marks kept for build_model's errors.
  const std::string file = s.file.string();
  EXPECT_EQ(b.where.str(), file + ":16:5: bodies[0]");
  EXPECT_EQ(b.material.where.str(), file + ":22:5: bodies[0].material");
  EXPECT_EQ(b.fixed[0].where.str(), file + ":33:9: bodies[0].fixed[0].box");
  EXPECT_EQ(b.fixed[1].where.str(), file + ":34:9: bodies[0].fixed[1].group");
  EXPECT_EQ(b.fixed[3].where.str(), file + ":36:10: bodies[0].fixed[3].group");

  const BodyDesc& b2 = s.bodies[1];
  EXPECT_EQ(b2.name, "second-2");
  EXPECT_DOUBLE_EQ(b2.material.young, 1e6);
  EXPECT_DOUBLE_EQ(b2.material.poisson, 0);
  EXPECT_EQ(b2.material.law, softdiff::material::Law::corotational);

  EXPECT_EQ(s.output.file, kDir / "out" / "result.h5");
  EXPECT_EQ(s.output.every, 5);
  EXPECT_TRUE(s.output.v);
  EXPECT_FALSE(s.output.contact || s.output.actuation || s.output.effectors);
  EXPECT_TRUE(s.output.jacobians.empty());
}

TEST_F(Scene, Defaults) {
  const SceneDesc s = load(kBase);
  EXPECT_EQ(s.name, "");
  EXPECT_EQ(s.simulation.integrator, Integrator::implicit_euler);
  EXPECT_DOUBLE_EQ(s.simulation.dt, 0.01);
  EXPECT_EQ(s.simulation.steps, 10);
  EXPECT_EQ(s.simulation.gravity, Vec3(0, 0, -9.81));
  EXPECT_EQ(s.simulation.newton_iterations, 1);
  EXPECT_DOUBLE_EQ(s.simulation.newton_tolerance, 1e-10);
  EXPECT_EQ(s.simulation.static_max_iterations, 50);
  EXPECT_DOUBLE_EQ(s.simulation.static_tolerance, 1e-10);
  EXPECT_EQ(s.simulation.static_load_steps, 1);
  EXPECT_EQ(s.linear_solver.kind, LinearSolverKind::cholmod);
  EXPECT_DOUBLE_EQ(s.linear_solver.cg_tolerance, 1e-10);
  EXPECT_EQ(s.linear_solver.cg_max_iterations, 10000);
  ASSERT_EQ(s.bodies.size(), 1u);
  const BodyDesc& b = s.bodies[0];
  EXPECT_DOUBLE_EQ(b.mesh_scale, 1.0);
  EXPECT_EQ(b.translate, Vec3::Zero());
  EXPECT_EQ(b.rotate_deg, Vec3::Zero());
  EXPECT_EQ(b.material.law, softdiff::material::Law::corotational);
  EXPECT_EQ(b.mass, MassKind::lumped);
  EXPECT_EQ(b.rayleigh_mass, 0);
  EXPECT_EQ(b.rayleigh_stiffness, 0);
  EXPECT_FALSE(b.psd_projection);
  EXPECT_TRUE(b.fixed.empty());
  EXPECT_EQ(b.initial_velocity, Vec3::Zero());
  EXPECT_TRUE(s.output.file.empty());
  EXPECT_EQ(s.output.every, 1);
  EXPECT_FALSE(s.output.v || s.output.contact || s.output.actuation || s.output.effectors);
  EXPECT_EQ(s.output.gzip_level, 0);
}

// output.compression: none | gzip (level 6) | gzip:LEVEL, LEVEL 1..9 (docs/scene.md).
TEST_F(Scene, OutputCompression) {
  EXPECT_EQ(load(kBase + "output: {compression: none}\n").output.gzip_level, 0);
  EXPECT_EQ(load(kBase + "output: {compression: gzip}\n").output.gzip_level, 6);
  EXPECT_EQ(load(kBase + "output: {compression: 'gzip:1'}\n").output.gzip_level, 1);
  EXPECT_EQ(load(kBase + "output:\n  compression: gzip:9\n").output.gzip_level, 9);
  EXPECT_EQ(load(kBase, {"output.compression=gzip:3"}).output.gzip_level, 3);
  const std::string message = "output.compression: must be none, gzip or gzip:LEVEL with LEVEL in 1..9; got ";
  expect_error(kBase + "output:\n  compression: gzip:10\n", ":13:3: " + message + "'gzip:10'");
  expect_error(kBase + "output:\n  compression: zstd\n", ":13:3: " + message + "'zstd'");
  expect_error(kBase + "output:\n  compression: gzip:0\n", ":13:3: " + message + "'gzip:0'");
  expect_error(kBase + "output:\n  compression: GZIP\n", ":13:3: " + message + "'GZIP'");
  expect_error(kBase + "output:\n  compression: 6\n", ":13:3: " + message + "'6'");
}

TEST_F(Scene, StaticIntegratorNeedsNoTimeStep) {
  const SceneDesc s = load(edit("  dt: 0.01\n  steps: 10\n", "  integrator: static\n  static: {load_steps: 3}\n"));
  EXPECT_EQ(s.simulation.integrator, Integrator::static_equilibrium);
  EXPECT_EQ(s.simulation.steps, 0);
  EXPECT_EQ(s.simulation.static_load_steps, 3);
}

// static.convergence (extension, method.md "Static equilibrium"): residual by default;
// answer with its two tolerances (defaults 1e-4, 1e-3); those keys need `answer`.
TEST_F(Scene, StaticConvergenceCriterion) {
  const auto base = [](const std::string& static_section) {
    return edit("  dt: 0.01\n  steps: 10\n", "  integrator: static\n" + static_section);
  };
  const SceneDesc plain = load(base(""));
  EXPECT_FALSE(plain.simulation.static_answer_criterion);
  const SceneDesc answer = load(base("  static: {convergence: answer}\n"));
  EXPECT_TRUE(answer.simulation.static_answer_criterion);
  EXPECT_DOUBLE_EQ(answer.simulation.static_displacement_tolerance, 1e-4);
  EXPECT_DOUBLE_EQ(answer.simulation.static_residual_tolerance, 1e-3);
  const SceneDesc set = load(base("  static: {convergence: answer, displacement_tolerance: 1.0e-6, residual_tolerance: 1.0e-5}\n"));
  EXPECT_DOUBLE_EQ(set.simulation.static_displacement_tolerance, 1e-6);
  EXPECT_DOUBLE_EQ(set.simulation.static_residual_tolerance, 1e-5);
  const std::string message = error(base("  static: {displacement_tolerance: 1.0e-6}\n"));
  EXPECT_NE(message.find("simulation.static.displacement_tolerance: applies to convergence: answer"), std::string::npos)
      << message;
  EXPECT_NE(error(base("  static: {convergence: newton}\n")).find("convergence"), std::string::npos);
  EXPECT_NE(error(base("  static: {convergence: answer, residual_tolerance: 0.5}\n")).find("residual_tolerance"),
            std::string::npos);
}

// static.friction (extension, method.md "Static equilibrium with contact",
// *Load-step-anchored friction*; 2026-12-04, branch sfric): iterate by default, load_step
// on request (and into the model's StepSettings), anything else refused naming the choices.
TEST_F(Scene, StaticFriction) {
  const auto base = [](const std::string& static_section) {
    return edit("  dt: 0.01\n  steps: 10\n", "  integrator: static\n" + static_section);
  };
  EXPECT_FALSE(load(base("")).simulation.static_friction_load_step);
  EXPECT_FALSE(load(base("  static: {friction: iterate}\n")).simulation.static_friction_load_step);
  EXPECT_TRUE(load(base("  static: {friction: load_step}\n")).simulation.static_friction_load_step);
  const std::string message = error(base("  static: {friction: sticky}\n"));
  EXPECT_NE(message.find("simulation.static.friction"), std::string::npos) << message;
  EXPECT_NE(message.find("iterate, load_step"), std::string::npos) << message;
}

TEST_F(Scene, LinearSolverAsString) {
  EXPECT_EQ(load(kBase + "linear_solver: ldlt\n").linear_solver.kind, LinearSolverKind::ldlt);
  EXPECT_EQ(load(kBase + "linear_solver: cg\n").linear_solver.kind, LinearSolverKind::cg);
}

TEST_F(Scene, DurationGivesSteps) {
  EXPECT_EQ(load(edit("steps: 10", "duration: 0.3")).simulation.steps, 30);
  EXPECT_EQ(load(edit("steps: 10", "duration: 1")).simulation.steps, 100);
}

TEST_F(Scene, ContactDisabledIsAccepted) {
  EXPECT_NO_THROW(load(kBase + "contact: {enabled: false}\n"));
  EXPECT_NO_THROW(load(kBase + "contact:\n"));
}

// ---------------------------------------------------------------------------
// Errors: reading and YAML

TEST_F(Scene, MissingFile) {
  const fs::path path = kDir / "no_such_scene.yaml";
  try {
    load_scene(path);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), path.string() + ": cannot read scene file: No such file or directory");
  }
}

TEST_F(Scene, YamlSyntaxError) {
  expect_error(edit("  steps: 10\n", "  steps: 10\n   bad: [1, 2\n"), ":5:7: YAML syntax error: illegal map value");
  expect_error("softdiff: 1\nsimulation:\n  dt: 0.01: 2\n", ":3:11: YAML syntax error: illegal map value");
}

// Inputs found by the fuzz target (tests/fuzz/fuzz_scene.cpp), minimized; the seed
// corpus keeps them too. yaml-cpp 0.7 loops forever, allocating, on a stray comma
// where a block node is expected (io/yaml_tree.cpp): a syntax error at the comma.
// alarm(): should the loop come back, the test process ends in 20 s instead of
// hanging until ctest's timeout.
TEST_F(Scene, FuzzRegressionStrayCommaDoesNotHang) {
  alarm(20);
  expect_error("\n  , ne:", ":2:3: YAML syntax error: unexpected ','");
  expect_error(",", ":1:1: YAML syntax error: unexpected ','");
  expect_error("softdiff: 1\nsimulation:\n  , dt: 0.01\n", ":3:3: YAML syntax error: end of map not found");
  alarm(0);
}

TEST_F(Scene, SeveralDocuments) {
  expect_error(kBase + "---\nsoftdiff: 1\n", ":" + std::to_string(std::count(kBase.begin(), kBase.end(), '\n') + 1) +
                                              ":1: expected one YAML document, found 2 (separated by '---')");
}

TEST_F(Scene, DuplicateKey) {
  expect_error(edit("  steps: 10\n", "  steps: 10\n  dt: 0.02\n"), ":5:3: simulation.dt: duplicate key (first given at line 3)");
  expect_error(edit("density: 1000", "density: 1000\n      young: 3"), ":12:7: bodies[0].material.young: duplicate key (first given at line 9)");
}

TEST_F(Scene, EmptyOrNotAMap) {
  EXPECT_EQ(error("# nothing\n"), (kDir / "EmptyOrNotAMap.yaml").string() +
                                      ": empty scene file (expected at least 'softdiff: 1', 'simulation' and 'bodies')");
  expect_error("- 1\n- 2\n", ":1:1: expected a map of scene keys (softdiff, simulation, bodies, ...), got a list of 2 items");
}

// ---------------------------------------------------------------------------
// Errors: version, unknown keys

TEST_F(Scene, Version) {
  expect_error(edit("softdiff: 1", "softdiff: 2"), ":1:1: softdiff: unsupported format version '2' (supported: 1)");
  expect_error(edit("softdiff: 1\n", "name: x\n"),
               ":1:1: missing required key 'softdiff' (the format version; this softdiff reads 'softdiff: 1')");
}

TEST_F(Scene, UnknownKeyWithSuggestionAtEveryLevel) {
  expect_error(kBase + "outptu: {}\n", ":12:1: outptu: unknown key; did you mean 'output'?");
  expect_error(edit("  dt: 0.01", "  dtt: 0.01"), ":3:3: simulation.dtt: unknown key; did you mean 'dt'?");
  expect_error(edit("  steps: 10\n", "  steps: 10\n  static: {max_iteration: 3}\n"),
               ":5:12: simulation.static.max_iteration: unknown key; did you mean 'max_iterations'?");
  expect_error(edit("    mesh:", "    mesh_scal: 2\n    mesh:"), ":7:5: bodies[0].mesh_scal: unknown key; did you mean 'mesh_scale'?");
  expect_error(edit("young:", "Young:"), ":9:7: bodies[0].material.Young: unknown key; did you mean 'young'?");
  expect_error(edit("poisson:", "poison:"), ":10:7: bodies[0].material.poison: unknown key; did you mean 'poisson'?");
  expect_error(kBase + "    damping: {rayleigh_mas: 0.1}\n",
               ":12:15: bodies[0].damping.rayleigh_mas: unknown key; did you mean 'rayleigh_mass'?");
  expect_error(kBase + "    fixed:\n      - {group: a, axis: [x]}\n",
               ":13:20: bodies[0].fixed[0].axis: unknown key; did you mean 'axes'?");
  expect_error(kBase + "linear_solver: {type: cg, tolerence: 1e-8}\n",
               ":12:27: linear_solver.tolerence: unknown key; did you mean 'tolerance'?");
  expect_error(kBase + "output:\n  evry: 2\n", ":13:3: output.evry: unknown key; did you mean 'every'?");
  expect_error(kBase + "contact: {enabled: false, frction: 0.3}\n",
               ":12:27: contact.frction: unknown key; did you mean 'friction'?");
}

TEST_F(Scene, UnknownKeyWithoutSuggestionListsValidKeys) {
  expect_error(kBase + "    damping: {alpha: 0.1}\n",
               ":12:15: bodies[0].damping.alpha: unknown key (valid keys: rayleigh_mass, rayleigh_stiffness)");
}

// ---------------------------------------------------------------------------
// Errors: types

TEST_F(Scene, WrongType) {
  expect_error(edit("young: 1.0e5", "young: stiff"), ":9:7: bodies[0].material.young: expected a number, got 'stiff'");
  expect_error(edit("young: 1.0e5", "young: \"1e5\""),
               ":9:7: bodies[0].material.young: expected a number, got \"1e5\" (a quoted string)");
  expect_error(edit("young: 1.0e5", "young: .inf"), ":9:7: bodies[0].material.young: expected a finite number, got '.inf'");
  expect_error(edit("young: 1.0e5", "young: [1]"), ":9:7: bodies[0].material.young: expected a number, got a list of 1 item");
  expect_error(edit("young: 1.0e5", "young:"), ":9:7: bodies[0].material.young: expected a number, got nothing (null)");
  expect_error(edit("steps: 10", "steps: 2.5"), ":4:3: simulation.steps: expected an integer, got '2.5'");
  expect_error(edit("  steps: 10", "  steps: 10\n  gravity: -9.81"),
               ":5:3: simulation.gravity: expected a list of 3 numbers [x, y, z], got '-9.81'");
  expect_error(edit("  steps: 10", "  steps: 10\n  gravity: [0, 0]"),
               ":5:3: simulation.gravity: expected a list of 3 numbers [x, y, z], got a list of 2 items");
  expect_error(edit("  steps: 10", "  steps: 10\n  gravity: [0, g, 0]"), ":5:16: simulation.gravity[1]: expected a number, got 'g'");
  expect_error(kBase + "    psd_projection: yes\n", ":12:5: bodies[0].psd_projection: expected true or false, got 'yes'");
  expect_error(edit("simulation:\n  dt: 0.01\n  steps: 10\n", "simulation: fast\n"), ":2:1: simulation: expected a map, got 'fast'");
  expect_error(kBase + "linear_solver: [cg]\n", ":12:1: linear_solver: expected a map or one of: cholmod, ldlt, cg, got a list of 1 item");
  expect_error("softdiff: 1\nsimulation: {steps: 1}\nbodies: {beam: 1}\n", ":3:1: bodies: expected a list, got a map");
}

TEST_F(Scene, MessagesAreOneLine) {
  expect_error(edit("young: 1.0e5", "young: \"a\\nb\""), ":9:7: bodies[0].material.young: expected a number, got \"a\\nb\" (a quoted string)");
}

TEST_F(Scene, IntegersMayUseExponent) { EXPECT_EQ(load(edit("steps: 10", "steps: 1e3")).simulation.steps, 1000); }

// ---------------------------------------------------------------------------
// Errors: ranges

TEST_F(Scene, OutOfRange) {
  const auto body = [](const std::string& line) { return kBase + "    " + line + "\n"; };
  expect_error(edit("young: 1.0e5", "young: 0"), ":9:7: bodies[0].material.young: must be > 0, got 0");
  expect_error(edit("poisson: 0.45", "poisson: 0.5"), ":10:7: bodies[0].material.poisson: must be in [0, 0.5), got 0.5");
  expect_error(edit("poisson: 0.45", "poisson: -0.1"), ":10:7: bodies[0].material.poisson: must be in [0, 0.5), got -0.1");
  expect_error(edit("density: 1000", "density: -1"), ":11:7: bodies[0].material.density: must be > 0, got -1");
  expect_error(edit("dt: 0.01", "dt: 0"), ":3:3: simulation.dt: must be > 0, got 0");
  expect_error(edit("steps: 10", "steps: 0"), ":4:3: simulation.steps: must be >= 1, got 0");
  expect_error(edit("steps: 10", "duration: 0"), ":4:3: simulation.duration: must be > 0, got 0");
  expect_error(edit("steps: 10", "steps: 99999999999999999999"), ":4:3: simulation.steps: must be <= 9223372036854775807, got 99999999999999999999");
  expect_error(edit("steps: 10", "steps: 10\n  newton_iterations: 0"), ":5:3: simulation.newton_iterations: must be >= 1, got 0");
  expect_error(edit("steps: 10", "steps: 10\n  newton_iterations: 3000000000"),
               ":5:3: simulation.newton_iterations: must be <= 2147483647, got 3000000000");
  expect_error(edit("steps: 10", "steps: 10\n  newton_tolerance: -1e-9"), ":5:3: simulation.newton_tolerance: must be > 0, got -1e-9");
  expect_error(edit("steps: 10", "steps: 10\n  static: {tolerance: 0}"), ":5:12: simulation.static.tolerance: must be > 0, got 0");
  expect_error(edit("steps: 10", "steps: 10\n  static: {max_iterations: 0}"),
               ":5:12: simulation.static.max_iterations: must be >= 1, got 0");
  expect_error(edit("steps: 10", "steps: 10\n  static: {load_steps: 0}"), ":5:12: simulation.static.load_steps: must be >= 1, got 0");
  expect_error(body("mesh_scale: 0"), ":12:5: bodies[0].mesh_scale: must be > 0, got 0");
  expect_error(body("damping: {rayleigh_mass: -0.1}"), ":12:15: bodies[0].damping.rayleigh_mass: must be >= 0, got -0.1");
  expect_error(body("damping: {rayleigh_stiffness: -1}"), ":12:15: bodies[0].damping.rayleigh_stiffness: must be >= 0, got -1");
  expect_error(body("fixed: [{nodes: [0, -1]}]"), ":12:25: bodies[0].fixed[0].nodes[1]: must be >= 0, got -1");
  expect_error(kBase + "output: {every: 0}\n", ":12:10: output.every: must be >= 1, got 0");
  expect_error(kBase + "linear_solver: {type: cg, tolerance: 0}\n", ":12:27: linear_solver.tolerance: must be > 0, got 0");
  expect_error(kBase + "linear_solver: {type: cg, max_iterations: 0}\n", ":12:27: linear_solver.max_iterations: must be >= 1, got 0");
}

TEST_F(Scene, Names) {
  expect_error(edit("name: beam", "name: my beam"),
               ":6:5: bodies[0].name: must be a name of letters, digits, '_' and '-' ([A-Za-z0-9_-]+), got 'my beam'");
  const std::string second = "  - name: beam\n    mesh: meshes/beam.msh\n    material: {young: 1, poisson: 0, density: 1}\n";
  expect_error(kBase + second, ":12:5: bodies[1].name: duplicate body name 'beam' (also bodies[0])");
}

TEST_F(Scene, Fixed) {
  const auto fixed = [](const std::string& entry) { return kBase + "    fixed:\n      - " + entry + "\n"; };
  expect_error(fixed("{box: [0, 0, 0, 1, 1]}"),
               ":13:10: bodies[0].fixed[0].box: expected a list of 6 numbers [xmin, ymin, zmin, xmax, ymax, zmax], got a list of 5 items");
  expect_error(fixed("{box: [0, 1, 0, 1, 0, 1]}"), ":13:10: bodies[0].fixed[0].box: min must not exceed max, got ymin 1 > ymax 0");
  expect_error(fixed("{axes: [x]}"), ":13:9: bodies[0].fixed[0]: needs one of 'box', 'group', 'nodes'");
  expect_error(fixed("{box: [0, 0, 0, 1, 1, 1], group: clamp}"),
               ":13:35: bodies[0].fixed[0].group: give only one of 'box', 'group', 'nodes' per entry (this one also has 'box')");
  expect_error(fixed("{group: clamp, axes: []}"), ":13:24: bodies[0].fixed[0].axes: must not be empty");
  expect_error(fixed("{group: clamp, axes: [x, y, x]}"), ":13:37: bodies[0].fixed[0].axes[2]: duplicate entry 'x' (also at index 0)");
  expect_error(fixed("{group: clamp, axes: [w]}"),
               ":13:31: bodies[0].fixed[0].axes[0]: must be one of: x, y, z; got 'w'");
  expect_error(fixed("{nodes: []}"), ":13:10: bodies[0].fixed[0].nodes: must not be empty");
  expect_error(fixed("{group: \"\"}"), ":13:10: bodies[0].fixed[0].group: must not be empty");
}

// ---------------------------------------------------------------------------
// Errors: required keys, exclusive keys

TEST_F(Scene, MissingRequiredKey) {
  expect_error(edit("      young: 1.0e5\n", ""), ":8:5: bodies[0].material: missing required key 'young'");
  expect_error(edit("    mesh: meshes/beam.msh\n", ""), ":6:5: bodies[0]: missing required key 'mesh'");
  expect_error("softdiff: 1\nsimulation: {steps: 1}\n", ":1:1: missing required key 'bodies'");
  expect_error("softdiff: 1\nsimulation: {steps: 1}\nbodies: []\n", ":3:1: bodies: must not be empty");
}

TEST_F(Scene, StepsAndDuration) {
  expect_error(edit("steps: 10", "steps: 10\n  duration: 0.1"), ":5:3: simulation.duration: give either 'steps' or 'duration', not both");
  expect_error(edit("  steps: 10\n", ""), ":2:1: simulation: missing 'steps' or 'duration' (integrators implicit_euler and bdf2 need exactly one)");
  expect_error(edit("steps: 10", "duration: 0.305"),
               ":4:3: simulation.duration: must be a multiple of dt = 0.01 (to 1e-9 relative), got 0.305 = 30.5 dt; use steps or a "
               "multiple of dt");
  expect_error(edit("steps: 10", "duration: 0.001"), ":4:3: simulation.duration: must be at least dt = 0.01, got 0.001");
  expect_error(edit("steps: 10", "integrator: static"), ":3:3: simulation.dt: not used by integrator 'static' (remove it)");
}

// ---------------------------------------------------------------------------
// Errors: enums, files, features not supported yet

TEST_F(Scene, BadEnumListsValidValues) {
  expect_error(edit("      young", "      law: neohookean\n      young"),
               ":9:7: bodies[0].material.law: must be one of: corotational, stvk, neo_hookean, linear; got 'neohookean' (did you mean "
               "'neo_hookean'?)");
  expect_error(edit("  dt", "  integrator: explicit\n  dt"), ":3:3: simulation.integrator: must be one of: implicit_euler, bdf2, static; got 'explicit'");
  expect_error(kBase + "linear_solver: cholesky\n", ":12:1: linear_solver: must be one of: cholmod, ldlt, cg; got 'cholesky'");
  expect_error(kBase + "    mass: lumpd\n", ":12:5: bodies[0].mass: must be one of: lumped, consistent; got 'lumpd' (did you mean 'lumped'?)");
  expect_error(kBase + "    type: rigd\n",
               ":12:5: bodies[0].type: must be one of: soft, rigid; got 'rigd' (did you mean 'rigid'?) (static rigid shapes are "
               "'obstacles')");
}

TEST_F(Scene, MissingMeshFile) {
  expect_error(edit("meshes/beam.msh", "meshes/nope.msh"),
               ":7:5: bodies[0].mesh: mesh file not found: " + (kDir / "meshes" / "nope.msh").string());
}

TEST_F(Scene, CgOptionsNeedCg) {
  expect_error(kBase + "linear_solver: {type: ldlt, tolerance: 1e-8}\n",
               ":12:29: linear_solver.tolerance: only used by type 'cg' (type is 'ldlt')");
}

TEST_F(Scene, FeaturesNotSupportedYet) {
  expect_error(kBase + "output: {jacobians: [young]}\n", ":12:10: output.jacobians: not supported yet (planned: jacobians)");
  expect_error(kBase + "contact: {enabled: no}\n", ":12:11: contact.enabled: expected true or false, got 'no'");
}

// Contact with newton_iterations > 1 is accepted (docs/method.md "Newton iterations with
// contact"); it was an error before the Newton loop solved the contact problem.
TEST_F(Scene, NewtonWithContactIsAccepted) {
  const SceneDesc s = load(edit("  steps: 10", "  steps: 10\n  newton_iterations: 3") + "contact: {friction: 0.3}\n");
  EXPECT_EQ(s.simulation.newton_iterations, 3);
  EXPECT_TRUE(s.contact.enabled);
}

// Contact with integrator static is accepted (docs/method.md "Static equilibrium"); it
// was an error before the static solver supported it.
TEST_F(Scene, StaticWithContactIsAccepted) {
  const SceneDesc s = load(edit("  dt: 0.01\n  steps: 10", "  integrator: static") + "contact: {friction: 0.3}\n");
  EXPECT_EQ(s.simulation.integrator, Integrator::static_equilibrium);
  EXPECT_TRUE(s.contact.enabled);
  EXPECT_EQ(s.contact.friction, 0.3);
}

// ---------------------------------------------------------------------------
// Obstacles and contact

TEST_F(Scene, ObstaclesAndContactParse) {
  write_file(kDir / "meshes" / "key.stl", "solid key\nendsolid key\n");  // load_scene only checks that it exists
  const SceneDesc s = load(kBase + R"(obstacles:
  - {name: floor, type: plane, normal: [0, 0, 2], offset: -0.1}
  - {name: support, type: box, center: [0, 0, 0], half_extents: [0.1, 0.2, 0.3], rotate_deg: [0, 0, 45]}
  - {name: ball, type: sphere, center: [1, 2, 3], radius: 0.01}
  - {name: rod, type: capsule, center: [0, 0, 1], radius: 0.02, half_length: 0.5}
  - {name: can, type: cylinder, center: [0, 1, 0], radius: 0.03, half_length: 0.1, rotate_deg: [90, 0, 0]}
  - {name: key, type: mesh, mesh: meshes/key.stl, mesh_scale: 0.001}
contact:
  friction: 0.4
  pairs: [[beam, floor, 0.5], [beam, beam, 0.1]]
  self_collision: true
  margin: 2.0e-3
  solver: pgs
  tolerance: 1.0e-9
  max_iterations: 77
  polish: false
  smoothing: {samples: 8, sigma: 5.0e-5, seed: 3}
output: {fields: [x, contact]}
)");
  ASSERT_EQ(s.obstacles.size(), 6u);
  using K = ObstacleDesc::Kind;
  EXPECT_EQ(s.obstacles[0].kind, K::plane);
  EXPECT_EQ(s.obstacles[0].normal, Vec3(0, 0, 2));
  EXPECT_EQ(s.obstacles[0].offset, -0.1);
  EXPECT_EQ(s.obstacles[1].kind, K::box);
  EXPECT_EQ(s.obstacles[1].half_extents, Vec3(0.1, 0.2, 0.3));
  EXPECT_EQ(s.obstacles[1].rotate_deg, Vec3(0, 0, 45));
  EXPECT_EQ(s.obstacles[2].kind, K::sphere);
  EXPECT_EQ(s.obstacles[2].radius, 0.01);
  EXPECT_EQ(s.obstacles[3].kind, K::capsule);
  EXPECT_EQ(s.obstacles[3].half_length, 0.5);
  EXPECT_EQ(s.obstacles[4].kind, K::cylinder);
  EXPECT_EQ(s.obstacles[5].kind, K::mesh);
  EXPECT_EQ(s.obstacles[5].mesh, kDir / "meshes" / "key.stl");
  EXPECT_EQ(s.obstacles[5].mesh_scale, 0.001);
  EXPECT_TRUE(s.contact.enabled);
  EXPECT_EQ(s.contact.friction, 0.4);
  ASSERT_EQ(s.contact.pairs.size(), 2u);
  EXPECT_EQ(s.contact.pairs[0].first, "beam");
  EXPECT_EQ(s.contact.pairs[0].second, "floor");
  EXPECT_EQ(s.contact.pairs[0].mu, 0.5);
  EXPECT_EQ(s.contact.pairs[1].second, "beam");
  EXPECT_TRUE(s.contact.self_collision);
  EXPECT_EQ(s.contact.margin, 2e-3);
  EXPECT_EQ(s.contact.solver, ContactDesc::Solver::pgs);
  EXPECT_EQ(s.contact.tolerance, 1e-9);
  EXPECT_EQ(s.contact.max_iterations, 77);
  EXPECT_FALSE(s.contact.polish);
  EXPECT_EQ(s.contact.smoothing_samples, 8);
  EXPECT_EQ(s.contact.smoothing_sigma, 5e-5);
  EXPECT_EQ(s.contact.smoothing_seed, 3);
  EXPECT_TRUE(s.output.contact);
}

TEST_F(Scene, ContactDefaults) {
  const SceneDesc s = load(kBase + "obstacles: [{name: floor, type: plane, normal: [0, 0, 1], offset: 0}]\ncontact: {}\n");
  EXPECT_TRUE(s.contact.enabled);
  EXPECT_EQ(s.contact.friction, 0.0);
  EXPECT_TRUE(s.contact.pairs.empty());
  EXPECT_FALSE(s.contact.self_collision);
  EXPECT_EQ(s.contact.margin, 1e-3);
  EXPECT_EQ(s.contact.solver, ContactDesc::Solver::admm);
  EXPECT_EQ(s.contact.tolerance, 1e-8);
  EXPECT_EQ(s.contact.max_iterations, 1000);
  EXPECT_TRUE(s.contact.polish);
  EXPECT_EQ(s.contact.smoothing_samples, 16);
  EXPECT_EQ(s.contact.smoothing_sigma, 0);  // resolved to margin / 10 by build_model
  EXPECT_FALSE(load(kBase + "contact: {enabled: false, friction: 0.3}\n").contact.enabled);
  EXPECT_FALSE(load(kBase).contact.enabled);
}

TEST_F(Scene, ObstacleErrors) {
  expect_error(kBase + "obstacles:\n  - {name: floor, type: plane}\n", ":13:5: obstacles[0]: a plane obstacle needs 'normal'");
  expect_error(kBase + "obstacles:\n  - {name: floor, type: plane, normal: [0, 0, 1], offset: 0, radius: 1}\n",
               ":13:62: obstacles[0].radius: not used by a plane obstacle");
  expect_error(kBase + "obstacles:\n  - {name: floor, type: plane, normal: [0, 0, 0], offset: 0}\n",
               ":13:32: obstacles[0].normal: must not be the zero vector");
  expect_error(kBase + "obstacles:\n  - {name: b, type: box, center: [0, 0, 0], half_extents: [1, 0, 1]}\n",
               ":13:45: obstacles[0].half_extents: must be > 0 on every axis, got 0");
  expect_error(kBase + "obstacles:\n  - {name: c, type: cylinder, center: [0, 0, 0], radius: 1}\n",
               ":13:5: obstacles[0]: a cylinder obstacle needs 'half_length'");
  expect_error(kBase + "obstacles:\n  - {name: s, type: sphere, center: [0, 0, 0], radius: -1}\n",
               ":13:48: obstacles[0].radius: must be > 0, got -1");
  expect_error(kBase + "obstacles:\n  - {name: k, type: mesh, mesh: meshes/nokey.stl}\n",
               ":13:27: obstacles[0].mesh: mesh file not found: " + (kDir / "meshes" / "nokey.stl").string());
  expect_error(kBase + "obstacles:\n  - {name: beam, type: sphere, center: [0, 0, 0], radius: 1}\n",
               ":13:6: obstacles[0].name: obstacle name 'beam' is also a body's name (contact pairs refer to either)");
  expect_error(kBase + "obstacles:\n  - {name: s, type: sphere, center: [0, 0, 0], radius: 1}\n"
                       "  - {name: s, type: sphere, center: [0, 0, 0], radius: 1}\n",
               ":14:6: obstacles[1].name: duplicate obstacle name 's' (also obstacles[0])");
  expect_error(kBase + "obstacles:\n  - {name: s, type: cone, center: [0, 0, 0], radius: 1}\n",
               ":13:15: obstacles[0].type: must be one of: plane, box, sphere, capsule, cylinder, mesh; got 'cone'");
}

TEST_F(Scene, ContactErrors) {
  const std::string base = kBase + "obstacles: [{name: floor, type: plane, normal: [0, 0, 1], offset: 0}]\n";
  expect_error(base + "contact: {pairs: [[beam, flor, 0.3]]}\n",
               ":13:26: contact.pairs[0][1]: unknown body or obstacle 'flor'");
  expect_error(base + "contact: {pairs: [[floor, beam, 0.3]]}\n",
               ":13:20: contact.pairs[0][0]: must be a body (put the obstacle 'floor' second)");
  expect_error(base + "contact: {pairs: [[beam, floor, -1]]}\n",
               ":13:33: contact.pairs[0][2]: friction must be a number >= 0, got -1");
  expect_error(base + "contact: {pairs: [[beam, floor, high]]}\n",
               ":13:33: contact.pairs[0][2]: friction must be a number >= 0, got 'high'");
  expect_error(base + "contact: {pairs: [[beam, floor]]}\n",
               ":13:19: contact.pairs[0]: expected a list of 3 [body, obstacle-or-body, mu], got a list of 2 items");
  expect_error(base + "contact: {pairs: [[beam, floor, 0.1], [beam, floor, 0.2]]}\n",
               ":13:39: contact.pairs[1]: duplicate pair [beam, floor] (also contact.pairs[0])");
  expect_error(base + "contact: {friction: -0.1}\n", ":13:11: contact.friction: must be >= 0, got -0.1");
  expect_error(base + "contact: {solver: lcp}\n", ":13:11: contact.solver: must be one of: admm, pgs; got 'lcp'");
  expect_error(base + "contact: {tolerance: 0}\n", ":13:11: contact.tolerance: must be > 0, got 0");
  expect_error(base + "contact: {max_iterations: 0}\n", ":13:11: contact.max_iterations: must be >= 1, got 0");
  expect_error(base + "contact: {smoothing: {samples: -1}}\n", ":13:23: contact.smoothing.samples: must be >= 0, got -1");
  expect_error(base + "contact: {smoothing: {sigma: 0}}\n", ":13:23: contact.smoothing.sigma: must be > 0, got 0");
  expect_error(base + "contact: {smoothing: {seed: 1.5}}\n", ":13:23: contact.smoothing.seed: expected an integer, got '1.5'");
  expect_error(base + "contact: {smoothing: {sample: 4}}\n",
               ":13:23: contact.smoothing.sample: unknown key; did you mean 'samples'?");
}

// ---------------------------------------------------------------------------
// Actuators and effectors

TEST_F(Scene, ActuatorsAndEffectorsParse) {
  const SceneDesc s = load(kBase + R"(    actuators:
      - {name: c1, type: cable, points: [[0, 0, 0], [1, 0, 0]], pull_point: [-1, 0, 0], force: 2.5, limits: [0, 20]}
      - {name: cav, type: pressure, surface: cavity, schedule: [[0, 0], [1, 500]]}
      - {name: s1, type: servo, nodes: {box: [0, 0, 0, 1, 1, 1]}, direction: [0, 0, 2], force: -1}
      - {name: s2, type: servo, nodes: {group: clamp}, axis: [0, 1, 0], center: [0, 0, 0.5]}
    effectors:
      - {name: tip, point: [0.2, 0.01, 0.01]}
output: {fields: [x, actuation, effectors]}
)");
  const auto& a = s.bodies[0].actuators;
  ASSERT_EQ(a.size(), 4u);
  EXPECT_EQ(a[0].kind, ActuatorDesc::Kind::cable);
  EXPECT_EQ(a[0].points.size(), 2u);
  ASSERT_TRUE(a[0].pull_point.has_value());
  EXPECT_EQ(*a[0].pull_point, Vec3(-1, 0, 0));
  EXPECT_DOUBLE_EQ(a[0].value, 2.5);
  ASSERT_TRUE(a[0].limits.has_value());
  EXPECT_DOUBLE_EQ((*a[0].limits)[1], 20);
  EXPECT_EQ(a[1].kind, ActuatorDesc::Kind::pressure);
  EXPECT_EQ(a[1].surface, "cavity");
  ASSERT_EQ(a[1].schedule.size(), 2u);
  EXPECT_DOUBLE_EQ(a[1].schedule[1][1], 500);
  EXPECT_EQ(a[2].kind, ActuatorDesc::Kind::servo);
  EXPECT_FALSE(a[2].rotation);
  EXPECT_EQ(a[2].nodes.kind, FixedDesc::Kind::box);
  EXPECT_TRUE(a[3].rotation);
  EXPECT_EQ(a[3].nodes.group, "clamp");
  EXPECT_EQ(a[3].center, Vec3(0, 0, 0.5));
  ASSERT_EQ(s.bodies[0].effectors.size(), 1u);
  EXPECT_EQ(s.bodies[0].effectors[0].name, "tip");
  EXPECT_TRUE(s.output.actuation);
  EXPECT_TRUE(s.output.effectors);
}

TEST_F(Scene, ActuatorErrors) {
  const std::string head = kBase + "    actuators:\n";
  expect_error(head + "      - {name: c, type: cable}\n", ":13:9: bodies[0].actuators[0]: a cable actuator needs 'points'");
  expect_error(head + "      - {name: c, type: cable, points: [[0, 0, 0]]}\n",
               ":13:32: bodies[0].actuators[0].points: a cable needs at least 2 points, or 1 point and a pull_point");
  expect_error(head + "      - {name: c, type: cable, points: [[0, 0, 0], [1, 0, 0]], surface: s}\n",
               ":13:64: bodies[0].actuators[0].surface: not used by a cable actuator");
  expect_error(head + "      - {name: p, type: pressure}\n", ":13:9: bodies[0].actuators[0]: a pressure actuator needs 'surface'");
  expect_error(head + "      - {name: p, type: pressure, surface: s, force: 1}\n",
               ":13:47: bodies[0].actuators[0].force: not used by a pressure actuator");
  expect_error(head + "      - {name: s, type: servo, nodes: {group: g}, direction: [1, 0, 0], axis: [0, 0, 1]}\n",
               ":13:51: bodies[0].actuators[0].direction: give either 'direction' (translation servo) or 'axis' and "
               "'center' (rotation servo), not both");
  expect_error(head + "      - {name: s, type: servo, nodes: {group: g}, direction: [0, 0, 0]}\n",
               ":13:51: bodies[0].actuators[0].direction: must be a non-zero vector");
  expect_error(head + "      - {name: s, type: servo, nodes: {group: g}}\n",
               ":13:9: bodies[0].actuators[0]: a servo needs 'direction' (translation) or both 'axis' and 'center' (rotation)");
  expect_error(head + "      - {name: p, type: pressure, surface: s, schedule: [[0, 1], [0, 2]]}\n",
               ":13:66: bodies[0].actuators[0].schedule[1]: times must be >= 0 and increasing, got 0");
  expect_error(head + "      - {name: p, type: pressure, surface: s, pressure: 1, schedule: [[0, 1]]}\n",
               ":13:60: bodies[0].actuators[0].schedule: give either 'pressure' (constant) or 'schedule', not both");
  expect_error(head + "      - {name: p, type: pressure, surface: s, limits: [2, 1]}\n",
               ":13:47: bodies[0].actuators[0].limits: min must not exceed max, got [2, 1]");
  expect_error(head + "      - {name: p, type: pressure, surface: s}\n      - {name: p, type: pressure, surface: t}\n",
               ":14:9: bodies[0].actuators[1].name: duplicate actuator name 'p' (also bodies[0].actuators[0])");
}

// ---------------------------------------------------------------------------
// --set

TEST_F(Scene, SetNumbersByNameAndIndex) {
  const SceneDesc s = load(kBase, {"bodies.beam.material.young=2e5", "bodies.0.material.poisson=0.25",
                                   "bodies[0].material.density=1200", "simulation.dt=0.02"});
  EXPECT_DOUBLE_EQ(s.bodies[0].material.young, 2e5);
  EXPECT_DOUBLE_EQ(s.bodies[0].material.poisson, 0.25);
  EXPECT_DOUBLE_EQ(s.bodies[0].material.density, 1200);
  EXPECT_DOUBLE_EQ(s.simulation.dt, 0.02);
}

TEST_F(Scene, SetListsAndNewKeys) {
  const SceneDesc s = load(kBase, {"simulation.gravity=[0, 0, -1]", "bodies.beam.fixed=[{group: clamp, axes: [z]}]",
                                   "bodies.beam.damping.rayleigh_mass=0.5", "output.fields=[x, v]", "name=sweep 3"});
  EXPECT_EQ(s.simulation.gravity, Vec3(0, 0, -1));
  ASSERT_EQ(s.bodies[0].fixed.size(), 1u);
  EXPECT_EQ(s.bodies[0].fixed[0].group, "clamp");
  EXPECT_EQ(s.bodies[0].fixed[0].axes, (std::array<bool, 3>{false, false, true}));
  EXPECT_EQ(s.bodies[0].fixed[0].where.str(), "--set: bodies[0].fixed[0].group");
  EXPECT_DOUBLE_EQ(s.bodies[0].rayleigh_mass, 0.5);
  EXPECT_TRUE(s.output.v);
  EXPECT_EQ(s.name, "sweep 3");
  const std::string with_gravity = edit("  steps: 10\n", "  steps: 10\n  gravity: [0, 0, -9]\n");
  EXPECT_EQ(load(with_gravity, {"simulation.gravity.2=-3"}).simulation.gravity, Vec3(0, 0, -3));
}

TEST_F(Scene, SetStepsReplacesDurationAndBack) {
  const std::string with_duration = edit("steps: 10", "duration: 0.3");
  EXPECT_EQ(load(with_duration, {"simulation.steps=7"}).simulation.steps, 7);
  EXPECT_EQ(load(kBase, {"simulation.duration=0.5"}).simulation.steps, 50);
  EXPECT_EQ(load(with_duration, {"simulation.dt=0.1"}).simulation.steps, 3);
}

TEST_F(Scene, SetActuatorForceReplacesScheduleAndBack) {
  const std::string scene = kBase + R"(    actuators:
      - {name: c, type: cable, points: [[0, 0, 0], [1, 0, 0]], schedule: [[0, 0], [1, 2]]}
      - {name: p, type: pressure, surface: s, pressure: 5}
)";
  SceneDesc s = load(scene, {"bodies.beam.actuators.c.force=0.5"});
  EXPECT_TRUE(s.bodies[0].actuators[0].schedule.empty());
  EXPECT_DOUBLE_EQ(s.bodies[0].actuators[0].value, 0.5);
  s = load(scene, {"bodies.beam.actuators.c.force=0.5", "bodies.beam.actuators.c.schedule=[[0, 1], [2, 3]]"});
  ASSERT_EQ(s.bodies[0].actuators[0].schedule.size(), 2u);
  EXPECT_DOUBLE_EQ(s.bodies[0].actuators[0].value, 0);
  // schedule removes `force` only (one exclusion per key): a constant pressure stays, an error.
  EXPECT_EQ(error(scene, {"bodies.beam.actuators.p.schedule=[[0, 1]]"}),
            "--set: bodies[0].actuators[1].schedule: give either 'pressure' (constant) or 'schedule', not both");
}

TEST_F(Scene, SetNullRemovesAKey) {
  const SceneDesc s = load(kBase, {"simulation.integrator=static", "simulation.dt=null", "simulation.steps=~"});
  EXPECT_EQ(s.simulation.integrator, Integrator::static_equilibrium);
}

TEST_F(Scene, SetIntoLinearSolverShorthand) {
  const SceneDesc s = load(kBase + "linear_solver: cg\n", {"linear_solver.max_iterations=50"});
  EXPECT_EQ(s.linear_solver.kind, LinearSolverKind::cg);
  EXPECT_EQ(s.linear_solver.cg_max_iterations, 50);
}

TEST_F(Scene, SetErrors) {
  EXPECT_EQ(error(kBase, {"bodies.beam.material.yung=2e5"}), "--set bodies.beam.material.yung: unknown key 'yung'; did you mean 'young'?");
  EXPECT_EQ(error(kBase, {"simulaton.dt=1"}), "--set simulaton.dt: unknown key 'simulaton'; did you mean 'simulation'?");
  EXPECT_EQ(error(kBase, {"bodies.beam.damping.alpha=1"}),
            "--set bodies.beam.damping.alpha: unknown key 'alpha' (valid keys of 'bodies.beam.damping': rayleigh_mass, "
            "rayleigh_stiffness)");
  EXPECT_EQ(error(kBase, {"bodies.bam.material.young=2e5"}), "--set bodies.bam.material.young: no body named 'bam' (bodies: beam)");
  EXPECT_EQ(error(kBase, {"bodies.3.mesh=x.msh"}), "--set bodies.3.mesh: index 3 out of range ('bodies' has 1 item)");
  EXPECT_EQ(error(kBase, {"simulation.dt.x=1"}), "--set simulation.dt.x: cannot set 'x': 'simulation.dt' is a number, not a map or a list");
  EXPECT_EQ(error(kBase, {"simulation.gravity=[0, 0, -1]", "simulation.gravity.z=1"}),
            "--set simulation.gravity.z: 'z' is not an index into 'simulation.gravity' (a list)");
  EXPECT_EQ(error(kBase, {"simulation.gravity.2=-3"}),
            "--set simulation.gravity.2: 'simulation.gravity' is not in the scene; set the whole list (simulation.gravity=[...])");
  EXPECT_EQ(error(kBase, {"simulation.dt"}), "--set simulation.dt: expected KEY=VALUE (e.g. bodies.beam.material.young=2e5)");
  EXPECT_EQ(error(kBase, {"simulation.gravity=[0, 0"}),
            "--set simulation.gravity: invalid YAML value '[0, 0': YAML syntax error: end of sequence flow not found");
  // Values given by --set are validated like the file's, with "--set" as their place.
  EXPECT_EQ(error(kBase, {"bodies.beam.material.young=-1"}), "--set: bodies[0].material.young: must be > 0, got -1");
  EXPECT_EQ(error(kBase, {"simulation.gravity=[0, 0]"}),
            "--set: simulation.gravity: expected a list of 3 numbers [x, y, z], got a list of 2 items");
  EXPECT_EQ(error(kBase, {"bodies.beam.material.law=neohookean"}),
            "--set: bodies[0].material.law: must be one of: corotational, stvk, neo_hookean, linear; got 'neohookean' (did you mean "
            "'neo_hookean'?)");
  EXPECT_EQ(error(kBase, {"contact.solver=lcp"}), "--set: contact.solver: must be one of: admm, pgs; got 'lcp'");
  EXPECT_EQ(error(kBase, {"softdiff=2"}), "--set: softdiff: unsupported format version '2' (supported: 1)");
}

// ---------------------------------------------------------------------------
// Rigid bodies (scene.md, additions of 2026-12; issue 21)

// kBase plus a rigid key from line 12: body keys at column 5, joint keys at 7.
const std::string kRigid = kBase + R"(  - name: key
    type: rigid
    shape: {type: box, half_extents: [0.011, 0.07, 0.006]}
    density: 1200
    position: [0.1, 0, 0]
    orientation: [0.7071, 0.7071, 0, 0]
    joint:
      type: hinge
      anchor: [0.1, -0.06, -0.006]
      axis: [2, 0, 0]
      limits: [-0.1, 0.2]
)";

std::string rigid_edit(const std::string& from, const std::string& to) { return edit(from, to, kRigid); }

TEST_F(Scene, RigidBodyParsesEveryField) {
  const SceneDesc s = load(kRigid);
  ASSERT_EQ(s.bodies.size(), 1u);  // the soft beam
  ASSERT_EQ(s.rigid_bodies.size(), 1u);
  const RigidBodyDesc& r = s.rigid_bodies[0];
  EXPECT_EQ(r.name, "key");
  EXPECT_EQ(r.where.path, "bodies[1]");
  EXPECT_EQ(r.shape.kind, RigidShapeDesc::Kind::box);
  EXPECT_EQ(r.shape.half_extents, Vec3(0.011, 0.07, 0.006));
  ASSERT_TRUE(r.density.has_value());
  EXPECT_EQ(*r.density, 1200);
  EXPECT_EQ(r.position, Vec3(0.1, 0, 0));
  // Normalized: [0.7071, 0.7071, 0, 0] has norm 0.99999 (within the 1e-3 accepted).
  EXPECT_NEAR(r.orientation[0], std::sqrt(0.5), 1e-15);
  EXPECT_NEAR(r.orientation[1], std::sqrt(0.5), 1e-15);
  EXPECT_EQ(r.velocity, Vec3::Zero());
  EXPECT_EQ(r.angular_velocity, Vec3::Zero());
  ASSERT_TRUE(r.joint.has_value());
  EXPECT_EQ(r.joint->kind, JointDesc::Kind::hinge);
  EXPECT_EQ(r.joint->anchor, Vec3(0.1, -0.06, -0.006));
  EXPECT_EQ(r.joint->axis, Vec3(1, 0, 0));  // normalized
  ASSERT_TRUE(r.joint->limits.has_value());
  EXPECT_EQ((*r.joint->limits)[0], -0.1);
  EXPECT_EQ((*r.joint->limits)[1], 0.2);
}

TEST_F(Scene, RigidBodyDefaultsAndGivenInertia) {
  const SceneDesc s = load(kBase + "  - {name: ball, type: rigid, shape: {type: sphere, radius: 0.01}, mass: 0.2, "
                                   "inertia: [3, 4, 5, 0.5, 0.25, -0.125]}\n"
                                   "  - {name: rod, type: rigid, shape: {type: capsule, radius: 0.01, length: 0.1}, "
                                   "mass: 0.1, inertia: [2, 2, 1], joint: {type: slider, axis: [0, 0, -3]}}\n");
  ASSERT_EQ(s.rigid_bodies.size(), 2u);
  const RigidBodyDesc& ball = s.rigid_bodies[0];
  EXPECT_FALSE(ball.density.has_value());
  EXPECT_EQ(ball.mass, 0.2);
  softdiff::Mat3 I;
  I << 3, 0.5, 0.25, 0.5, 4, -0.125, 0.25, -0.125, 5;  // [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]
  EXPECT_EQ(ball.inertia, I);
  EXPECT_EQ(ball.position, Vec3::Zero());
  EXPECT_EQ(ball.orientation, (std::array<double, 4>{1, 0, 0, 0}));
  EXPECT_FALSE(ball.joint.has_value());
  const RigidBodyDesc& rod = s.rigid_bodies[1];
  EXPECT_EQ(rod.shape.kind, RigidShapeDesc::Kind::capsule);
  EXPECT_EQ(rod.shape.length, 0.1);
  EXPECT_EQ(rod.inertia, Vec3(2, 2, 1).asDiagonal().toDenseMatrix());
  ASSERT_TRUE(rod.joint.has_value());
  EXPECT_EQ(rod.joint->kind, JointDesc::Kind::slider);
  EXPECT_EQ(rod.joint->axis, Vec3(0, 0, -1));
  EXPECT_EQ(rod.joint->anchor, Vec3::Zero());  // default: the body's position
  EXPECT_FALSE(rod.joint->limits.has_value());
}

TEST_F(Scene, RigidBodySetAddressesItsKeys) {
  const SceneDesc s = load(kRigid, {"bodies.key.shape.half_extents=[0.01, 0.05, 0.005]", "bodies.key.joint.limits=[-0.2, 0]"});
  EXPECT_EQ(s.rigid_bodies[0].shape.half_extents, Vec3(0.01, 0.05, 0.005));
  EXPECT_EQ((*s.rigid_bodies[0].joint->limits)[0], -0.2);
  EXPECT_EQ(error(kRigid, {"bodies.key.desnity=3"}), "--set bodies.key.desnity: unknown key 'desnity'; did you mean 'density'?");
}

TEST_F(Scene, RigidBodyErrors) {
  // unknown shape type, a key of another shape type, a missing one
  expect_error(rigid_edit("{type: box,", "{type: cone,"),
               ":14:13: bodies[1].shape.type: must be one of: box, sphere, capsule, cylinder, mesh; got 'cone'");
  expect_error(rigid_edit("half_extents: [0.011, 0.07, 0.006]", "half_extents: [0.011, 0.07, 0.006], radius: 1"),
               ":14:60: bodies[1].shape.radius: not used by a box shape");
  expect_error(rigid_edit("{type: box, half_extents: [0.011, 0.07, 0.006]}", "{type: cylinder, radius: 0.01}"),
               ":14:5: bodies[1].shape: a cylinder shape needs 'length'");
  // density and mass, neither, mass without inertia
  expect_error(rigid_edit("    density: 1200\n", "    density: 1200\n    mass: 1\n"),
               ":16:5: bodies[1].mass: give either 'density' or 'mass' and 'inertia', not both");
  expect_error(rigid_edit("    density: 1200\n", ""), ":12:5: bodies[1]: a rigid body needs 'density', or 'mass' and 'inertia'");
  expect_error(rigid_edit("    density: 1200\n", "    mass: 1\n"), ":15:5: bodies[1].mass: needs 'inertia' too (or 'density' alone)");
  // inertia: not positive definite, 4 entries
  expect_error(rigid_edit("    density: 1200\n", "    mass: 1\n    inertia: [1, 1, 1, 2, 0, 0]\n"),
               ":16:5: bodies[1].inertia: must be positive definite (principal moments -1, 1, 3 kg m^2)");
  expect_error(rigid_edit("    density: 1200\n", "    mass: 1\n    inertia: [1, 1, 1, 0]\n"),
               ":16:5: bodies[1].inertia: expected a list of 3 numbers [Ixx, Iyy, Izz] or 6 [Ixx, Iyy, Izz, Ixy, Ixz, Iyz], got 4");
  // orientation far from unit, zero
  expect_error(rigid_edit("[0.7071, 0.7071, 0, 0]", "[1, 1, 0, 0]"),
               ":17:5: bodies[1].orientation: must be a unit quaternion [w, x, y, z] (norm within 0.001 of 1), got norm 1.41421356237");
  expect_error(rigid_edit("[0.7071, 0.7071, 0, 0]", "[0, 0, 0, 0]"),
               ":17:5: bodies[1].orientation: must be a unit quaternion [w, x, y, z] (norm within 0.001 of 1), got norm 0");
  // joint: zero axis, limits reversed or not around the initial state, keys of another type
  expect_error(rigid_edit("axis: [2, 0, 0]", "axis: [0, 0, 0]"), ":21:7: bodies[1].joint.axis: must be a non-zero vector");
  expect_error(rigid_edit("limits: [-0.1, 0.2]", "limits: [0.2, -0.1]"),
               ":22:7: bodies[1].joint.limits: lo must not exceed hi, got [0.2, -0.1]");
  expect_error(rigid_edit("limits: [-0.1, 0.2]", "limits: [0.1, 0.2]"),
               ":22:7: bodies[1].joint.limits: must contain 0 (the angle is measured from the initial state), got [0.1, 0.2]");
  expect_error(rigid_edit("      axis: [2, 0, 0]\n", ""), ":18:5: bodies[1].joint: a hinge joint needs 'axis'");
  expect_error(rigid_edit("type: hinge", "type: fixed"), ":21:7: bodies[1].joint.axis: not used by a fixed joint");
  expect_error(rigid_edit("type: hinge", "type: ball"), ":19:7: bodies[1].joint.type: must be one of: fixed, hinge, slider; got 'ball'");
  // unknown keys: of a rigid body (with the closest), and a soft body's key
  expect_error(rigid_edit("    density: 1200\n", "    density: 1200\n    angular_velocty: [0, 0, 1]\n"),
               ":16:5: bodies[1].angular_velocty: unknown key; did you mean 'angular_velocity'?");
  expect_error(rigid_edit("    density: 1200\n", "    density: 1200\n    material: {young: 1}\n"), ":16:5: bodies[1].material: unknown key (valid keys: name, type, shape, density, mass, inertia, position, "
               "orientation, velocity, angular_velocity, joint)");
  // a mesh shape: the file must exist, .msh or .stl
  expect_error(rigid_edit("{type: box, half_extents: [0.011, 0.07, 0.006]}", "{type: mesh, mesh: meshes/nope.msh}"),
               ":14:25: bodies[1].shape.mesh: mesh file not found: " + (kDir / "meshes" / "nope.msh").string());
  write_file(kDir / "meshes" / "part.obj", "not read: only its extension is checked\n");
  expect_error(rigid_edit("{type: box, half_extents: [0.011, 0.07, 0.006]}", "{type: mesh, mesh: meshes/part.obj}"),
               ":14:25: bodies[1].shape.mesh: expected a closed triangle surface (.msh or .stl), got 'part.obj'");
  // names are shared with soft bodies and obstacles
  expect_error(rigid_edit("name: key", "name: beam"), ":12:5: bodies[1].name: duplicate body name 'beam' (also bodies[0])");
}

TEST_F(Scene, RigidBodiesRefuseWhatIsNotSupportedYet) {
  // Contact with rigid bodies (docs/method.md "Rigid bodies in contact"): newton_iterations
  // > 1 with bdf2 and a rigid self-pair are refused. A joint with limits is accepted on either
  // backend (issue 21: the limit is a row of the contact NCP, on the operator columns of
  // its rigid rows; the sparse backend refused it before).
  const SceneDesc limited = load(kRigid + "contact: {friction: 0.5}\n");
  ASSERT_EQ(limited.rigid_bodies.size(), 1u);
  ASSERT_TRUE(limited.rigid_bodies[0].joint && limited.rigid_bodies[0].joint->limits);
  EXPECT_TRUE(limited.contact.enabled);
  const SceneDesc limited_sparse = load(kRigid + "contact: {friction: 0.5, backend: sparse}\n");
  EXPECT_EQ(limited_sparse.contact.backend, ContactDesc::Backend::sparse);
  ASSERT_TRUE(limited_sparse.rigid_bodies[0].joint && limited_sparse.rigid_bodies[0].joint->limits);
  const std::string free_key = rigid_edit(
      "    joint:\n      type: hinge\n      anchor: [0.1, -0.06, -0.006]\n      axis: [2, 0, 0]\n      limits: [-0.1, 0.2]\n",
      "");
  auto expect_message = [&](const std::string& text, const std::string& part) {
    const std::string message = error(text, {});
    EXPECT_NE(message.find(part), std::string::npos) << message;
  };
  // newton_iterations > 1: accepted with implicit Euler (docs/method.md "Newton with rigid
  // contact") and with bdf2 (its stage from the extrapolated states; refused until
  // 2026-12-03, rnewtd).
  EXPECT_EQ(load(edit("  dt: 0.01\n", "  dt: 0.01\n  newton_iterations: 2\n", free_key) + "contact: {friction: 0.5}\n")
                .simulation.newton_iterations,
            2);
  {
    const SceneDesc bdf2_newton = load(edit("  dt: 0.01\n", "  dt: 0.01\n  newton_iterations: 2\n  integrator: bdf2\n",
                                            free_key) + "contact: {friction: 0.5}\n");
    EXPECT_EQ(bdf2_newton.simulation.integrator, Integrator::bdf2);
    EXPECT_EQ(bdf2_newton.simulation.newton_iterations, 2);
    EXPECT_TRUE(bdf2_newton.contact.enabled);
  }
  // The sparse backend takes rigid bodies (SparseDelassus::set_rigid): accepted.
  EXPECT_EQ(load(free_key + "contact: {friction: 0.5, backend: sparse}\n").contact.backend, ContactDesc::Backend::sparse);
  expect_message(free_key + "contact: {pairs: [[key, key, 0.5]]}\n", "a rigid body has no self-contact ('key')");
  // Accepted: a free rigid body in contact, named on either side of a pair.
  const SceneDesc ok = load(free_key + "contact: {pairs: [[key, beam, 0.4]]}\n");
  ASSERT_EQ(ok.contact.pairs.size(), 1u);
  EXPECT_EQ(ok.contact.pairs[0].first, "key");
  EXPECT_EQ(load(free_key + "contact: {pairs: [[beam, key, 0.4]]}\n").contact.pairs[0].second, "key");
  // BDF2 with rigid bodies (rigid/rigid_bdf2.hpp): accepted, with and without contact;
  // in contact, a joint with limits too (a limit restarts the step as implicit Euler,
  // integrator/bdf2.cpp; refused until 2026-12-03 rbdlim).
  EXPECT_EQ(load(rigid_edit("  dt: 0.01\n", "  integrator: bdf2\n  dt: 0.01\n")).simulation.integrator, Integrator::bdf2);
  EXPECT_EQ(load(edit("  dt: 0.01\n", "  integrator: bdf2\n  dt: 0.01\n", free_key) + "contact: {friction: 0.5}\n")
                .simulation.integrator,
            Integrator::bdf2);
  {
    const SceneDesc bdf2_limited = load(edit("  dt: 0.01\n", "  integrator: bdf2\n  dt: 0.01\n", kRigid) + "contact: {friction: 0.5}\n");
    EXPECT_EQ(bdf2_limited.simulation.integrator, Integrator::bdf2);
    ASSERT_EQ(bdf2_limited.rigid_bodies.size(), 1u);
    ASSERT_TRUE(bdf2_limited.rigid_bodies[0].joint.has_value());
    EXPECT_TRUE(bdf2_limited.rigid_bodies[0].joint->limits.has_value());
    EXPECT_TRUE(bdf2_limited.contact.enabled);
  }
  // static with rigid bodies (integrator/static_rigid.hpp): a body with dofs needs
  // contact; a fixed one, or one in contact, is accepted, a joint with limits too
  // (rstat2: the limits are rows of the static contact solve).
  expect_message(rigid_edit("  dt: 0.01\n  steps: 10\n", "  integrator: static\n"),
                 "simulation.integrator: a static scene needs contact for a rigid body that is not fixed: bodies[1] "
                 "('key') has no equilibrium under gravity without a support");
  EXPECT_EQ(load(rigid_edit("  dt: 0.01\n  steps: 10\n", "  integrator: static\n") + "contact: {friction: 0.5}\n")
                .simulation.integrator,
            Integrator::static_equilibrium);
  const std::string static_free = edit("  dt: 0.01\n  steps: 10\n", "  integrator: static\n", free_key);
  expect_message(static_free, "simulation.integrator: a static scene needs contact for a rigid body that is not fixed: "
                              "bodies[1] ('key') has no equilibrium under gravity without a support");
  EXPECT_EQ(load(static_free + "contact: {friction: 0.5}\n").simulation.integrator, Integrator::static_equilibrium);
  EXPECT_NO_THROW(load(kRigid + "contact: {enabled: false}\n"));
  // rigidify (issue 21 item 2): read here, its nodes resolved by build_model.
  const SceneDesc r = load(edit("    material:", "    rigidify: [{group: hub, attach: free}, {box: [0, 0, 0, 1, 1, 1]}]\n    material:"));
  ASSERT_EQ(r.bodies[0].rigidify.size(), 2u);
  EXPECT_EQ(r.bodies[0].rigidify[0].nodes.group, "hub");
  EXPECT_EQ(r.bodies[0].rigidify[0].attach, "free");
  EXPECT_EQ(r.bodies[0].rigidify[1].attach, "free");  // the default
  EXPECT_EQ(r.bodies[0].rigidify[1].nodes.kind, FixedDesc::Kind::box);
}

}  // namespace
