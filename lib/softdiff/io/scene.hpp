#pragma once
// The scene file (spec: docs/scene.md), parsed and validated into plain data.
// load_scene() checks everything that can be checked without the mesh: keys,
// types, ranges, exclusive options, that files exist. Checks that need the mesh
// (a physical group that the mesh lacks, a box that selects no node) are done by
// build_model(), which uses the `where` marks kept here to report
// `FILE:LINE:COL: KEY.PATH: message`.
#include <softdiff/core/types.hpp>
#include <softdiff/material/material.hpp>

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace softdiff::io {

// Where a value came from: "scene.yaml:12:7: bodies[0].material.poisson".
struct Where {
  std::string file;
  int line = 0;    // 1-based; 0 if unknown (e.g. a value given by --set)
  int column = 0;  // 1-based
  std::string path;  // bodies[0].fixed[1].group
  std::string str() const;  // "FILE:LINE:COL: PATH" (omits LINE:COL when unknown)
};

struct FixedDesc {
  enum class Kind { box, group, nodes } kind = Kind::box;
  std::array<double, 6> box{};        // xmin ymin zmin xmax ymax zmax (world, after transform)
  std::string group;                  // physical group name
  std::vector<long> nodes;            // 0-based indices in file node order
  std::array<bool, 3> axes{true, true, true};  // which world components are fixed
  Where where;
};

// An actuator (scene.md `actuators`). Coordinates are world coordinates (after the
// body's mesh_scale/rotate_deg/translate), in metres, like fixed boxes.
struct ActuatorDesc {
  enum class Kind { cable, pressure, servo } kind = Kind::cable;
  std::string name;
  std::vector<Vec3> points;            // cable: from the pulled end to the anchored end
  std::optional<Vec3> pull_point;      // cable
  std::string surface;                 // pressure: physical group of boundary triangles
  FixedDesc nodes;                     // servo: {box} or {group} (axes unused)
  bool rotation = false;               // servo: axis + center (torque) instead of direction
  Vec3 direction = Vec3::Zero();       // servo translation direction, or rotation axis
  Vec3 center = Vec3::Zero();          // servo rotation center
  double value = 0;                    // force (N), pressure (Pa) or torque (N m)
  std::vector<std::array<double, 2>> schedule;  // extension: (t, value), t increasing
  std::optional<std::array<double, 2>> limits;  // [min, max], used by control
  Where where;
};

// A rigidified part of a soft body (scene.md `rigidify`, issue 21 item 2): the nodes
// of `nodes` ({group} or {box}) move as one rigid body; attach is "free", "fixed" or
// the name of one of the body's servo actuators.
struct RigidifyDesc {
  FixedDesc nodes;                     // box or group (axes unused)
  std::string attach = "free";
  Where where, attach_where;
};

struct EffectorDesc {
  std::string name;
  Vec3 point = Vec3::Zero();           // world coordinates
  Where where;
};

struct MaterialDesc {
  material::Law law = material::Law::corotational;
  double young = 0, poisson = 0, density = 0;
  Where where;
};

enum class MassKind { lumped, consistent };
// `elements`: the mesh's own order (default), or linear / quadratic.
enum class ElementOrder { mesh, linear, quadratic };

struct BodyDesc {
  std::string name;
  std::filesystem::path mesh;   // resolved against the scene file's folder
  double mesh_scale = 1.0;
  Vec3 translate = Vec3::Zero();
  Vec3 rotate_deg = Vec3::Zero();  // XYZ Euler angles: R = Rz * Ry * Rx, applied after scale
  MaterialDesc material;
  MassKind mass = MassKind::lumped;
  ElementOrder elements = ElementOrder::mesh;
  Where elements_where;           // where `elements` is (or the body), for messages
  double rayleigh_mass = 0, rayleigh_stiffness = 0;
  bool psd_projection = false;
  std::vector<FixedDesc> fixed;
  Vec3 initial_velocity = Vec3::Zero();
  std::vector<ActuatorDesc> actuators;
  std::vector<EffectorDesc> effectors;
  std::vector<RigidifyDesc> rigidify;
  Where where;
};

// A rigid body (scene.md `type: rigid`, additions of 2026-12): a 6-DoF body, free or
// on a joint with the world. Plain data; io::build_model turns it into a
// rigid::RigidBody (mass properties, tessellation, joint).
struct RigidShapeDesc {
  enum class Kind { box, sphere, capsule, cylinder, mesh } kind = Kind::box;
  Vec3 half_extents = Vec3::Zero();  // box
  double radius = 0;                 // sphere, capsule, cylinder
  double length = 0;                 // capsule (its segment), cylinder: along the body z axis
  std::filesystem::path mesh;        // mesh: .msh (triangles), resolved against the scene folder
  double mesh_scale = 1.0;           // mesh
  Where where;                       // the `shape` key
  Where mesh_where;                  // the `mesh` key (mesh shapes)
};

struct JointDesc {
  enum class Kind { fixed, hinge, slider } kind = Kind::fixed;
  Vec3 anchor = Vec3::Zero();        // world, at t = 0 (default: the body's position)
  Vec3 axis = Vec3::UnitZ();         // world, unit (normalized here): hinge, slider
  std::optional<std::array<double, 2>> limits;  // rad (hinge) or m (slider), lo <= hi
  Where where;
};

struct RigidBodyDesc {
  std::string name;
  RigidShapeDesc shape;
  std::optional<double> density;     // kg/m^3; else mass and inertia are given
  double mass = 0;                   // kg (given)
  Mat3 inertia = Mat3::Zero();       // kg m^2 about the centre of mass, body axes (given), SPD
  Vec3 position = Vec3::Zero();      // centre of mass, world
  std::array<double, 4> orientation{1, 0, 0, 0};  // w, x, y, z; unit (normalized here)
  Vec3 velocity = Vec3::Zero();
  Vec3 angular_velocity = Vec3::Zero();  // world, rad/s
  std::optional<JointDesc> joint;    // absent: a free body
  Where where;
};

// A static rigid obstacle (scene.md `obstacles`), world coordinates.
struct ObstacleDesc {
  enum class Kind { plane, box, sphere, capsule, cylinder, mesh } kind = Kind::plane;
  std::string name;
  Vec3 normal{0, 0, 1};          // plane (not yet normalized)
  double offset = 0;             // plane
  std::vector<std::array<double, 2>> offset_schedule;  // plane (extension): offset: [[t, offset], ...]
  Vec3 center = Vec3::Zero();    // box, sphere, capsule, cylinder
  Vec3 half_extents = Vec3::Zero();  // box
  Vec3 rotate_deg = Vec3::Zero();    // box, capsule, cylinder (XYZ Euler, R = Rz Ry Rx)
  double radius = 0;             // sphere, capsule, cylinder
  double half_length = 0;        // capsule, cylinder (extension): along the local z axis
  std::filesystem::path mesh;    // mesh: .stl or .msh, resolved against the scene folder
  double mesh_scale = 1.0;       // mesh
  Where where;
};

// One `contact.pairs` entry: [body, obstacle-or-body, mu].
struct ContactPairDesc {
  std::string first, second;
  double mu = 0;
  Where where;
};

struct ContactDesc {
  bool enabled = false;
  double friction = 0;           // default Coulomb mu
  std::vector<ContactPairDesc> pairs;  // empty: every soft body vs every obstacle
  bool self_collision = false;
  double margin = 1e-3;
  enum class Solver { admm, pgs } solver = Solver::admm;
  double tolerance = 1e-8;
  int max_iterations = 1000;
  bool polish = true;            // extension
  bool polish_at_scale_always = false;  // extension: polish_at_scale: always (default: stalled)
  enum class Backend { automatic, dense, sparse } backend = Backend::automatic;  // extension
  int dense_max_contacts = 400;  // extension: the automatic backend's crossover
  // extension: the derivative's crossovers (dense G_AA / operator) and its scale's power
  // iteration cap (contact::NcpOptions; -1: NcpOptions' default)
  int derivative_dense_max_active = -1, derivative_mixed_dense_max_active = -1, derivative_scale_iterations = -1;
  // extension: randomized smoothing of the collision-detection derivatives
  int smoothing_samples = 16;
  double smoothing_sigma = 0;    // 0: margin / 10
  long long smoothing_seed = 0;
  Where where;
};

enum class Integrator { implicit_euler, static_equilibrium, bdf2 };
enum class LinearSolverKind { cholmod, ldlt, cg };

struct SimulationDesc {
  Integrator integrator = Integrator::implicit_euler;
  double dt = 0.01;
  long steps = 0;              // from `steps`, or round(duration / dt) (duration must be a multiple of dt to 1e-9)
  Vec3 gravity{0, 0, -9.81};
  int newton_iterations = 1;
  double newton_tolerance = 1e-10;   // extension: relative velocity-increment tolerance for newton_iterations > 1
  int static_max_iterations = 50;
  double static_tolerance = 1e-10;
  int static_load_steps = 1;
  // extension (method.md "Static equilibrium"): `static.convergence` residual (the
  // default: `tolerance`) or answer (`displacement_tolerance`, `residual_tolerance`).
  bool static_answer_criterion = false;
  double static_displacement_tolerance = 1e-4;  // `static.displacement_tolerance`
  double static_residual_tolerance = 1e-3;      // `static.residual_tolerance`
  // extension (method.md "Static equilibrium with contact", *Load-step-anchored
  // friction*): `static.friction` iterate (the default) or load_step.
  bool static_friction_load_step = false;
};

struct LinearSolverDesc {
  LinearSolverKind kind = LinearSolverKind::cholmod;
  double cg_tolerance = 1e-10;     // extension (cg only): relative residual
  int cg_max_iterations = 10000;   // extension (cg only)
  // extension (cholmod only, docs/method.md "Reusing the factor"): factor_reuse: pcg
  bool factor_reuse = false;
  double pcg_tolerance = 1e-10;    // `tolerance` with factor_reuse: relative residual of PCG
  int pcg_max_iterations = 40;     // `max_iterations` with factor_reuse: then factorize and solve directly
  int refactor_iterations = 8;     // a solve needing more iterations: the next step factorizes
};

struct OutputDesc {
  std::filesystem::path file;   // resolved against the scene file's folder; empty if absent (the CLI then uses -o or "<scene stem>.h5" in the current directory)
  long every = 1;
  bool v = false, contact = false, actuation = false, effectors = false;  // x is always written
  int gzip_level = 0;           // output.compression: 0 none (default), 1..9 gzip level of the per-frame datasets
  std::vector<std::string> jacobians;
};

struct SceneDesc {
  std::filesystem::path file;   // the scene file
  std::string text;             // the YAML text as read (written to the output's attributes)
  std::string name;
  SimulationDesc simulation;
  LinearSolverDesc linear_solver;
  std::vector<BodyDesc> bodies;              // the soft bodies (type: soft), in scene order
  std::vector<RigidBodyDesc> rigid_bodies;   // the rigid bodies (type: rigid), in scene order
  std::vector<ObstacleDesc> obstacles;
  ContactDesc contact;
  OutputDesc output;
};

// Parse and validate. `overrides` are --set KEY=VALUE strings, applied to the YAML
// tree before validation (KEY: dotted path; list items by index or, for bodies and
// named items, by name, e.g. bodies.beam.material.young=2e5; VALUE is parsed as YAML).
// Throws InputError with a one-line message `FILE:LINE:COL: PATH: message`.
SceneDesc load_scene(const std::filesystem::path& file, const std::vector<std::string>& overrides = {});

}  // namespace softdiff::io
