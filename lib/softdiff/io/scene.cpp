// load_scene(): read, --set, validate, and turn the scene file into a SceneDesc.
//
// The format is scene.md (version 1); its keys are listed, with types and ranges,
// in scene_schema.cpp. Validation order: YAML syntax and duplicate keys (while
// converting yaml-cpp's tree, yaml_tree.cpp), the format version, the --set
// overrides, the schema (yaml_validate.cpp: unknown keys, types, ranges, enums,
// required keys, features not supported yet), then the checks below that relate
// several keys or the file system. The first error is thrown as an InputError
// with one line:
//   FILE:LINE:COL: PATH: message       e.g. scene.yaml:12:7: bodies[0].material.poisson: must be in [0, 0.5), got 0.5
//   FILE: cannot read scene file: <reason>
//   --set: PATH: message               a value given by --set (no line)
//   --set KEY: message                 a --set key that does not fit the schema
// LINE:COL point at the key for a map value, at the item for a list item.
//
// Extensions to scene.md (all optional; scenes written to the spec are unaffected):
//   simulation.newton_tolerance: 1e-10    > 0; relative residual of the implicit Euler
//                                         equations that ends Newton early when
//                                         newton_iterations > 1 (docs/method.md)
//   bodies[].material.law: linear         small-strain elasticity (constant stiffness:
//                                         one factorization per run)
//   linear_solver: {type: cg, tolerance: 1e-10, max_iterations: 10000}
//                                         the map form of linear_solver (`linear_solver: cg`
//                                         is {type: cg}); type defaults to cholmod;
//                                         tolerance (> 0, relative residual) and
//                                         max_iterations (>= 1) are CG options, an
//                                         error with another type
//   linear_solver: {type: cholmod, factor_reuse: pcg, tolerance: 1e-10,
//                   refactor_iterations: 8, max_iterations: 40}
//                                         reuse the previous step's factor as PCG's
//                                         preconditioner (docs/method.md "Reusing the
//                                         factor"); tolerance, max_iterations are then
//                                         PCG's; not with contact, newton_iterations > 1
//                                         or integrator: static
//   --set KEY=null (or ~, or empty)       removes KEY (back to its default); giving
//                                         simulation.steps removes duration and vice versa
// Interpretation of scene.md where it is silent:
//   - `softdiff`, `bodies` (non-empty), and per body `name`, `mesh`, `material` with
//     `young`, `poisson`, `density` are required; material.law defaults to corotational,
//     body type to soft; damping values are >= 0.
//   - implicit_euler and bdf2 need exactly one of steps/duration; with integrator static,
//     dt, steps and duration are errors (they mean nothing there).
//   - Empty actuators/effectors/obstacles/jacobians lists are accepted. A `contact`
//     section is enabled unless it says `enabled: false`; `contact: {enabled: false}`
//     or no section: no collision detection at all.
//   - Obstacle keys are per type: plane {normal, offset}; box {center, half_extents,
//     rotate_deg}; sphere {center, radius}; capsule and cylinder {center, radius,
//     half_length (extension), rotate_deg} (axis: local z); mesh {mesh, mesh_scale}.
//     A key of another type is an error. Obstacle names share one namespace with
//     body names (contact pairs refer to either).
//   - contact.pairs [a, b, mu]: a is a body; b an obstacle, another body (soft-soft
//     contact) or a itself (self-contact for that body only). Without pairs: every
//     body vs every obstacle with `friction`. self_collision: true adds every body
//     against itself with `friction`.
//   - Contact with newton_iterations > 1 is solved per Newton iteration on the contacts
//     of the step's start (docs/method.md "Newton iterations with contact"). Contact with integrator static is solved per Newton iteration (docs/method.md
//     "Static equilibrium"); a body without fixed nodes is then allowed if it is in a
//     contact pair (build_model).
//   - Numbers are plain YAML numbers: a quoted "1e5" is a string, not a number.
//     Integers may be written 1e3. Booleans are true/false.
//   - A map key given with no value (`damping:`) is an empty map; an empty list key
//     (`fixed:`) an empty list.
#include <softdiff/io/scene.hpp>

#include <softdiff/io/input_error.hpp>
#include <softdiff/io/scene_schema.hpp>
#include <softdiff/io/yaml_tree.hpp>
#include <softdiff/io/yaml_validate.hpp>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <system_error>

namespace softdiff::io {

std::string Where::str() const {
  // (appends, not `":" + std::to_string(...)`: GCC 12 gives a false -Wrestrict on that)
  std::string s = file;
  if (line > 0) {
    s += ':';
    s += std::to_string(line);
    s += ':';
    s += std::to_string(column);
  }
  if (!path.empty()) {
    s += ": ";
    s += path;
  }
  return s;
}

namespace {

namespace fs = std::filesystem;
using yaml::Entry;
using yaml::Node;

constexpr long supported_version = 1;

std::string read_scene_text(const fs::path& file) {
  const std::string label = file.string();
  std::error_code ec;
  if (fs::is_directory(file, ec)) throw InputError(label + ": cannot read scene file: is a directory");
  std::FILE* f = std::fopen(label.c_str(), "rb");
  if (!f) throw InputError(label + ": cannot read scene file: " + std::strerror(errno));
  std::string text;
  char buffer[65536];
  std::size_t n = 0;
  while ((n = std::fread(buffer, 1, sizeof buffer, f)) > 0) text.append(buffer, n);
  const bool failed = std::ferror(f) != 0;
  const int error = errno;
  std::fclose(f);
  if (failed) throw InputError(label + ": cannot read scene file: " + std::strerror(error));
  return text;
}

// Reads the validated tree into a SceneDesc, with the checks that relate keys.
class Reader {
 public:
  Reader(const schema::Context& ctx, const fs::path& folder) : ctx_(ctx), folder_(folder) {}

  void read(const Node& root, SceneDesc& scene) const {
    if (const Node* n = root.get("name")) scene.name = n->scalar;
    read_simulation(root, scene.simulation);
    read_linear_solver(root, scene.linear_solver);
    const Entry* bodies = root.find("bodies");
    for (std::size_t i = 0; i < bodies->value.items.size(); ++i) {
      const Node& body = bodies->value.items[i];
      const std::string body_path = yaml::index_path("bodies", i);
      const std::string body_name = get(body, "name")->scalar;
      const auto same_name = [&](const Where& other) {
        ctx_.fail(body.find("name")->key_mark, body_path + ".name",
                  "duplicate body name '" + body_name + "' (also " + other.path + ")");
      };
      for (const auto& b : scene.bodies)
        if (b.name == body_name) same_name(b.where);
      for (const auto& r : scene.rigid_bodies)
        if (r.name == body_name) same_name(r.where);
      const Node* type = get(body, "type");
      if (type && type->scalar == "rigid") {
        scene.rigid_bodies.push_back(read_rigid_body(body, body_path));
        continue;
      }
      BodyDesc desc = read_body(body, body_path);
      // Actuator names are global (output: /actuators/<name>).
      for (const auto& a : desc.actuators)
        for (const auto& other : scene.bodies)
          for (const auto& b : other.actuators)
            if (a.name == b.name)
              throw InputError(a.where.str() + ".name: duplicate actuator name '" + a.name + "' (also " + b.where.path + ")");
      for (std::size_t p = 0; p < desc.actuators.size(); ++p)
        for (std::size_t q = 0; q < p; ++q)
          if (desc.actuators[p].name == desc.actuators[q].name)
            throw InputError(desc.actuators[p].where.str() + ".name: duplicate actuator name '" + desc.actuators[p].name +
                             "' (also " + desc.actuators[q].where.path + ")");
      scene.bodies.push_back(std::move(desc));
    }
    read_obstacles(root, scene);
    read_contact(root, scene);
    check_rigid_support(root, scene);  // (after read_contact: static needs contact)
    check_rigid_contact(scene);
    check_rigidify_support(root, scene);  // (after read_contact: it reads the backend)
    read_output(root, scene.output);
    check_factor_reuse(root, scene);
  }

 private:
  static const Node* get(const Node* map, std::string_view key) { return map && map->is_map() ? map->get(key) : nullptr; }
  static const Node* get(const Node& map, std::string_view key) { return get(&map, key); }
  static double number(const Node* n, double fallback) { return n ? *yaml::to_number(*n) : fallback; }
  static long long integer(const Node* n, long long fallback) { return n ? *yaml::to_integer(*n) : fallback; }
  static bool boolean(const Node* n, bool fallback) { return n ? *yaml::to_bool(*n) : fallback; }
  static Vec3 vec3(const Node* n, const Vec3& fallback) {
    if (!n) return fallback;
    return {*yaml::to_number(n->items[0]), *yaml::to_number(n->items[1]), *yaml::to_number(n->items[2])};
  }

  Where where(const Entry& e, const std::string& path) const { return ctx_.where(e.key_mark, path); }

  void read_simulation(const Node& root, SimulationDesc& sim) const {
    const Entry* section = root.find("simulation");
    const Node* s = section ? &section->value : nullptr;
    const yaml::Mark at = section ? section->key_mark : root.mark;
    if (const Node* n = get(s, "integrator"))
      sim.integrator = n->scalar == "static" ? Integrator::static_equilibrium
                       : n->scalar == "bdf2" ? Integrator::bdf2
                                             : Integrator::implicit_euler;
    sim.gravity = vec3(get(s, "gravity"), sim.gravity);
    sim.newton_iterations = static_cast<int>(integer(get(s, "newton_iterations"), sim.newton_iterations));
    sim.newton_tolerance = number(get(s, "newton_tolerance"), sim.newton_tolerance);
    const Node* st = get(s, "static");
    sim.static_max_iterations = static_cast<int>(integer(get(st, "max_iterations"), sim.static_max_iterations));
    sim.static_tolerance = number(get(st, "tolerance"), sim.static_tolerance);
    sim.static_load_steps = static_cast<int>(integer(get(st, "load_steps"), sim.static_load_steps));
    sim.static_displacement_tolerance =
        number(get(st, "displacement_tolerance"), sim.static_displacement_tolerance);
    sim.static_residual_tolerance = number(get(st, "residual_tolerance"), sim.static_residual_tolerance);
    if (const Node* n = get(st, "friction")) sim.static_friction_load_step = n->scalar == "load_step";
    if (st && st->is_map()) {
      const Entry* convergence = st->find("convergence");
      const Entry* answer_tolerance = st->find("displacement_tolerance");
      if (!answer_tolerance) answer_tolerance = st->find("residual_tolerance");
      sim.static_answer_criterion = convergence && convergence->value.scalar == "answer";
      if (!sim.static_answer_criterion && answer_tolerance)
        ctx_.fail(answer_tolerance->key_mark, "simulation.static." + answer_tolerance->key,
                  "applies to convergence: answer (add 'convergence: answer'; the residual criterion uses "
                  "tolerance)");
    }

    const Entry* dt = s && s->is_map() ? s->find("dt") : nullptr;
    const Entry* steps = s && s->is_map() ? s->find("steps") : nullptr;
    const Entry* duration = s && s->is_map() ? s->find("duration") : nullptr;
    if (sim.integrator == Integrator::static_equilibrium) {
      for (const Entry* e : {dt, steps, duration})
        if (e) ctx_.fail(e->key_mark, "simulation." + e->key, "not used by integrator 'static' (remove it)");
      sim.steps = 0;
      return;
    }
    sim.dt = number(dt ? &dt->value : nullptr, sim.dt);
    if (steps && duration) {
      const Entry* second = steps->key_mark.line > duration->key_mark.line ? steps : duration;
      ctx_.fail(second->key_mark, "simulation." + second->key, "give either 'steps' or 'duration', not both");
    }
    if (!steps && !duration)
      ctx_.fail(at, "simulation", "missing 'steps' or 'duration' (integrators implicit_euler and bdf2 need exactly one)");
    if (steps) {
      sim.steps = static_cast<long>(*yaml::to_integer(steps->value));
      return;
    }
    const double T = *yaml::to_number(duration->value);
    const double ratio = T / sim.dt;
    const std::string path = "simulation.duration";
    if (!(ratio < 1e15)) ctx_.fail(duration->key_mark, path, "too many steps: duration / dt = " + format_number(ratio));
    const double n = std::round(ratio);
    if (n < 1)
      ctx_.fail(duration->key_mark, path, "must be at least dt = " + format_number(sim.dt) + ", got " + duration->value.scalar);
    if (std::abs(n * sim.dt - T) > 1e-9 * T)
      ctx_.fail(duration->key_mark, path,
                "must be a multiple of dt = " + format_number(sim.dt) + " (to 1e-9 relative), got " + duration->value.scalar +
                    " = " + format_number(ratio) + " dt; use steps or a multiple of dt");
    sim.steps = static_cast<long>(n);
  }

  void read_linear_solver(const Node& root, LinearSolverDesc& ls) const {
    const Node* n = root.get("linear_solver");
    if (!n) return;
    const Node* type = n->is_scalar() ? n : get(n, "type");
    const std::string kind = type ? type->scalar : "cholmod";
    ls.kind = kind == "cg" ? LinearSolverKind::cg : kind == "ldlt" ? LinearSolverKind::ldlt : LinearSolverKind::cholmod;
    if (!n->is_map()) return;
    if (const Node* reuse = get(n, "factor_reuse")) {
      if (ls.kind != LinearSolverKind::cholmod)
        ctx_.fail(n->find("factor_reuse")->key_mark, "linear_solver.factor_reuse",
                  "only used by type 'cholmod' (type is '" + kind + "')");
      ls.factor_reuse = reuse->scalar == "pcg";
    }
    for (const Entry& e : n->entries) {
      if (e.key == "type" || e.key == "factor_reuse") continue;
      if (ls.factor_reuse) {
        if (e.key == "tolerance" || e.key == "max_iterations" || e.key == "refactor_iterations") continue;
      } else if (ls.kind == LinearSolverKind::cg && e.key != "refactor_iterations") {
        continue;
      }
      ctx_.fail(e.key_mark, "linear_solver." + e.key,
                e.key == "refactor_iterations"
                    ? std::string("only used with factor_reuse: pcg")
                    : std::string("only used by type 'cg'") +
                          (ls.kind == LinearSolverKind::cholmod ? " or with factor_reuse: pcg" : "") + " (type is '" +
                          kind + "')");
    }
    if (ls.factor_reuse) {
      ls.pcg_tolerance = number(get(n, "tolerance"), ls.pcg_tolerance);
      ls.pcg_max_iterations = static_cast<int>(integer(get(n, "max_iterations"), ls.pcg_max_iterations));
      ls.refactor_iterations = static_cast<int>(integer(get(n, "refactor_iterations"), ls.refactor_iterations));
      return;
    }
    ls.cg_tolerance = number(get(n, "tolerance"), ls.cg_tolerance);
    ls.cg_max_iterations = static_cast<int>(integer(get(n, "max_iterations"), ls.cg_max_iterations));
  }

  // factor_reuse: pcg serves the linearized dynamic step and its derivatives; the
  // solves that need A's own factor or another matrix per solve are refused
  // (docs/method.md "Reusing the factor").
  void check_factor_reuse(const Node& root, const SceneDesc& scene) const {
    if (!scene.linear_solver.factor_reuse) return;
    const Entry* key = root.get("linear_solver")->find("factor_reuse");
    const std::string path = "linear_solver.factor_reuse";
    if (scene.simulation.integrator == Integrator::static_equilibrium)
      ctx_.fail(key->key_mark, path, "pcg is not available with simulation.integrator: static (use factor_reuse: off)");
    if (scene.simulation.newton_iterations > 1)
      ctx_.fail(key->key_mark, path,
                "pcg is not available with simulation.newton_iterations > 1 (got " +
                    std::to_string(scene.simulation.newton_iterations) + "; use factor_reuse: off or newton_iterations: 1)");
    if (scene.contact.enabled)
      ctx_.fail(key->key_mark, path, "pcg is not available with contact (use factor_reuse: off or contact.enabled: false)");
  }

  // Rigid bodies (issue 21): stepped by implicit Euler or BDF2 (rigid/rigid_bdf2.hpp),
  // with or without contact; static (integrator/static_rigid.hpp) beside a soft body or
  // alone (solve_static_rigid_only), every rigid body with dofs held by contact (a fixed one needs nothing); joint limits
  // are rows of its contact solve (static_rigid.hpp). The rest of static is refused.
  void check_rigid_support(const Node& root, const SceneDesc& scene) const {
    if (scene.rigid_bodies.empty()) return;
    if (scene.simulation.integrator != Integrator::static_equilibrium) return;
    const Entry* integrator = root.get("simulation")->find("integrator");
    for (const auto& rb : scene.rigid_bodies) {
      const bool fixed = rb.joint && rb.joint->kind == JointDesc::Kind::fixed;
      if (!fixed && !scene.contact.enabled)
        ctx_.fail(integrator->key_mark, "simulation.integrator",
                  "a static scene needs contact for a rigid body that is not fixed: " + rb.where.path + " ('" + rb.name +
                      "') has no equilibrium under gravity without a support (enable contact and rest it on one, or "
                      "give it joint: {type: fixed})");
    }
  }

  // Rigid bodies in contact (docs/method.md "Rigid bodies in contact"): free, fixed,
  // hinge and slider bodies (limits: rows of the NCP, on either backend), implicit
  // Euler or BDF2 (Newton too), either NCP backend. The rest is refused (issue 21).
  void check_rigid_contact(const SceneDesc& scene) const {
    if (scene.rigid_bodies.empty() || !scene.contact.enabled) return;
    // Newton (newton_iterations > 1) with rigid bodies in contact: implicit Euler and BDF2
    // (docs/method.md "Newton with rigid contact"); bdf2 with a limited joint in contact is
    // refused below either way.
    // A scene of rigid bodies only runs on either backend: the operator with the rigid
    // rows alone (docs/method.md "Scenes of rigid bodies only").
    // BDF2 in contact with a limited joint: the whole step restarts as implicit Euler at a
    // limit (integrator/bdf2.cpp time_step_rigid_contact_limits; docs/method.md "BDF2
    // with rigid bodies", *Limits in contact*).
    for (const auto& p : scene.contact.pairs)
      if (p.first == p.second &&
          std::any_of(scene.rigid_bodies.begin(), scene.rigid_bodies.end(), [&](const auto& rb) { return rb.name == p.first; }))
        throw InputError(p.where.str() + ": a rigid body has no self-contact ('" + p.first + "')");
  }

  // Rigidified parts (issue 21 item 2): implicit Euler (Newton too), BDF2 and static
  // (the reduced Newton, integrator/static_rigid.hpp), contact on either backend, factor
  // reuse where it is available at all (check_factor_reuse: no contact, no Newton, not
  // static; the reduced PCG, integrator/rigidify_pcg.hpp); derivatives are refused by the
  // commands where not supported. attach: fixed parts are fixed nodes (io::build_model):
  // nothing to check for them.
  void check_rigidify_support(const Node& /*root*/, const SceneDesc& /*scene*/) const {}

  RigidBodyDesc read_rigid_body(const Node& body, const std::string& path) const {
    RigidBodyDesc d;
    d.where = ctx_.where(body.mark, path);
    d.name = get(body, "name")->scalar;

    // shape: the keys of its type, and nothing it ignores
    const Entry* shape = body.find("shape");
    const Node& sh = shape->value;
    const std::string spath = path + ".shape";
    RigidShapeDesc& s = d.shape;
    s.where = where(*shape, spath);
    const std::string type = get(sh, "type")->scalar;
    using K = RigidShapeDesc::Kind;
    std::vector<std::string> needed, allowed = {"type"};
    if (type == "box") { s.kind = K::box; needed = {"half_extents"}; }
    else if (type == "sphere") { s.kind = K::sphere; needed = {"radius"}; }
    else if (type == "capsule") { s.kind = K::capsule; needed = {"radius", "length"}; }
    else if (type == "cylinder") { s.kind = K::cylinder; needed = {"radius", "length"}; }
    else { s.kind = K::mesh; needed = {"mesh"}; allowed.push_back("mesh_scale"); }
    allowed.insert(allowed.end(), needed.begin(), needed.end());
    for (const Entry& e : sh.entries)
      if (std::find(allowed.begin(), allowed.end(), e.key) == allowed.end())
        ctx_.fail(e.key_mark, spath + "." + e.key, "not used by a " + type + " shape");
    for (const std::string& k : needed)
      if (!sh.find(k)) ctx_.fail(shape->key_mark, spath, "a " + type + " shape needs '" + k + "'");
    s.half_extents = vec3(get(sh, "half_extents"), s.half_extents);
    s.radius = number(get(sh, "radius"), s.radius);
    s.length = number(get(sh, "length"), s.length);
    s.mesh_scale = number(get(sh, "mesh_scale"), s.mesh_scale);
    if (s.kind == K::box)
      for (int k = 0; k < 3; ++k)
        if (!(s.half_extents[k] > 0))
          ctx_.fail(sh.find("half_extents")->key_mark, spath + ".half_extents",
                    "must be > 0 on every axis, got " + format_number(s.half_extents[k]));
    if (s.kind == K::mesh) {
      const Entry* mesh = sh.find("mesh");
      s.mesh = (folder_ / fs::path(mesh->value.scalar)).lexically_normal();
      s.mesh_where = where(*mesh, spath + ".mesh");
      std::error_code ec;
      const fs::file_status status = fs::status(s.mesh, ec);
      if (!fs::exists(status)) ctx_.fail(mesh->key_mark, spath + ".mesh", "mesh file not found: " + s.mesh.string());
      if (fs::is_directory(status))
        ctx_.fail(mesh->key_mark, spath + ".mesh", "is a directory, not a mesh file: " + s.mesh.string());
      std::string ext = s.mesh.extension().string();
      for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      if (ext != ".msh" && ext != ".stl")
        ctx_.fail(mesh->key_mark, spath + ".mesh",
                  "expected a closed triangle surface (.msh or .stl), got '" + s.mesh.filename().string() + "'");
    }

    // density, or mass and inertia
    const Entry* density = body.find("density");
    const Entry* mass = body.find("mass");
    const Entry* inertia = body.find("inertia");
    if (density && (mass || inertia)) {
      const Entry* second = mass ? mass : inertia;
      ctx_.fail(second->key_mark, path + "." + second->key,
                "give either 'density' or 'mass' and 'inertia', not both");
    }
    if (!density && !mass && !inertia)
      ctx_.fail(body.mark, path, "a rigid body needs 'density', or 'mass' and 'inertia'");
    if (!density && !(mass && inertia))
      ctx_.fail((mass ? mass : inertia)->key_mark, path + "." + (mass ? "mass" : "inertia"),
                std::string("needs '") + (mass ? "inertia" : "mass") + "' too (or 'density' alone)");
    if (density) d.density = *yaml::to_number(density->value);
    if (mass) {
      d.mass = *yaml::to_number(mass->value);
      const auto& items = inertia->value.items;
      const std::string ipath = path + ".inertia";
      if (items.size() != 3 && items.size() != 6)
        ctx_.fail(inertia->key_mark, ipath,
                  "expected a list of 3 numbers [Ixx, Iyy, Izz] or 6 [Ixx, Iyy, Izz, Ixy, Ixz, Iyz], got " +
                      std::to_string(items.size()));
      double I[6] = {0, 0, 0, 0, 0, 0};
      for (std::size_t k = 0; k < items.size(); ++k) I[k] = *yaml::to_number(items[k]);
      d.inertia << I[0], I[3], I[4], I[3], I[1], I[5], I[4], I[5], I[2];
      // positive definite: the smallest eigenvalue > 0, relative to the largest (a
      // tensor with a zero or negative principal moment has no finite rotation)
      const Eigen::SelfAdjointEigenSolver<Mat3> eig(d.inertia, Eigen::EigenvaluesOnly);
      const Vec3 moments = eig.eigenvalues();
      if (!(moments[0] > 1e-12 * std::abs(moments[2])) || !(moments[2] > 0))
        ctx_.fail(inertia->key_mark, ipath,
                  "must be positive definite (principal moments " + format_number(moments[0]) + ", " +
                      format_number(moments[1]) + ", " + format_number(moments[2]) + " kg m^2)");
    }

    // the initial state
    d.position = vec3(get(body, "position"), d.position);
    d.velocity = vec3(get(body, "velocity"), d.velocity);
    d.angular_velocity = vec3(get(body, "angular_velocity"), d.angular_velocity);
    if (const Entry* q = body.find("orientation")) {
      double norm2 = 0;
      for (int k = 0; k < 4; ++k) {
        d.orientation[static_cast<std::size_t>(k)] = *yaml::to_number(q->value.items[static_cast<std::size_t>(k)]);
        norm2 += d.orientation[static_cast<std::size_t>(k)] * d.orientation[static_cast<std::size_t>(k)];
      }
      const double norm = std::sqrt(norm2);
      // Normalized; written with a few digits (0.7071) a quaternion is off by ~1e-5.
      if (!(std::abs(norm - 1) <= kQuaternionTolerance))
        ctx_.fail(q->key_mark, path + ".orientation",
                  "must be a unit quaternion [w, x, y, z] (norm within " + format_number(kQuaternionTolerance) +
                      " of 1), got norm " + format_number(norm));
      for (double& c : d.orientation) c /= norm;
    }

    // joint: the keys of its type
    if (const Entry* joint = body.find("joint")) {
      const Node& j = joint->value;
      const std::string jpath = path + ".joint";
      JointDesc jd;
      jd.where = where(*joint, jpath);
      const std::string jtype = get(j, "type")->scalar;
      jd.kind = jtype == "hinge" ? JointDesc::Kind::hinge : jtype == "slider" ? JointDesc::Kind::slider
                                                                             : JointDesc::Kind::fixed;
      if (jd.kind == JointDesc::Kind::fixed)
        for (const Entry& e : j.entries)
          if (e.key != "type" && e.key != "anchor") ctx_.fail(e.key_mark, jpath + "." + e.key, "not used by a fixed joint");
      jd.anchor = vec3(get(j, "anchor"), d.position);
      if (jd.kind != JointDesc::Kind::fixed) {
        const Entry* axis = j.find("axis");
        if (!axis) ctx_.fail(joint->key_mark, jpath, "a " + jtype + " joint needs 'axis'");
        const Vec3 a = vec3(&axis->value, Vec3::Zero());
        if (!(a.norm() > 0)) ctx_.fail(axis->key_mark, jpath + ".axis", "must be a non-zero vector");
        jd.axis = a.normalized();
        if (const Entry* limits = j.find("limits")) {
          const double lo = *yaml::to_number(limits->value.items[0]), hi = *yaml::to_number(limits->value.items[1]);
          if (!(lo <= hi))
            ctx_.fail(limits->key_mark, jpath + ".limits",
                      "lo must not exceed hi, got [" + limits->value.items[0].scalar + ", " +
                          limits->value.items[1].scalar + "]");
          if (!(lo <= 0 && 0 <= hi))
            ctx_.fail(limits->key_mark, jpath + ".limits",
                      std::string("must contain 0 (the ") + (jd.kind == JointDesc::Kind::hinge ? "angle" : "travel") +
                          " is measured from the initial state), got [" + limits->value.items[0].scalar + ", " +
                          limits->value.items[1].scalar + "]");
          jd.limits = std::array<double, 2>{lo, hi};
        }
      }
      d.joint = jd;
    }
    return d;
  }

  static constexpr double kQuaternionTolerance = 1e-3;

  BodyDesc read_body(const Node& body, const std::string& path) const {
    BodyDesc d;
    d.where = ctx_.where(body.mark, path);
    d.name = get(body, "name")->scalar;

    const Entry* mesh = body.find("mesh");
    d.mesh = (folder_ / fs::path(mesh->value.scalar)).lexically_normal();
    std::error_code ec;
    const fs::file_status status = fs::status(d.mesh, ec);
    if (!fs::exists(status)) ctx_.fail(mesh->key_mark, path + ".mesh", "mesh file not found: " + d.mesh.string());
    if (fs::is_directory(status)) ctx_.fail(mesh->key_mark, path + ".mesh", "is a directory, not a mesh file: " + d.mesh.string());

    d.mesh_scale = number(get(body, "mesh_scale"), d.mesh_scale);
    d.translate = vec3(get(body, "translate"), d.translate);
    d.rotate_deg = vec3(get(body, "rotate_deg"), d.rotate_deg);

    const Entry* material = body.find("material");
    MaterialDesc& m = d.material;
    m.where = where(*material, path + ".material");
    if (const Node* law = get(material->value, "law"))
      m.law = law->scalar == "stvk"          ? material::Law::stvk
              : law->scalar == "neo_hookean" ? material::Law::neo_hookean
              : law->scalar == "linear"      ? material::Law::linear
                                             : material::Law::corotational;
    m.young = number(get(material->value, "young"), 0);
    m.poisson = number(get(material->value, "poisson"), 0);
    m.density = number(get(material->value, "density"), 0);

    d.elements_where = d.where;
    if (const Entry* elements = body.find("elements")) {
      d.elements = elements->value.scalar == "quadratic" ? ElementOrder::quadratic : ElementOrder::linear;
      d.elements_where = where(*elements, path + ".elements");
    }
    if (const Node* mass = get(body, "mass")) d.mass = mass->scalar == "consistent" ? MassKind::consistent : MassKind::lumped;
    const Node* damping = get(body, "damping");
    d.rayleigh_mass = number(get(damping, "rayleigh_mass"), d.rayleigh_mass);
    d.rayleigh_stiffness = number(get(damping, "rayleigh_stiffness"), d.rayleigh_stiffness);
    d.psd_projection = boolean(get(body, "psd_projection"), d.psd_projection);
    d.initial_velocity = vec3(get(body, "initial_velocity"), d.initial_velocity);

    if (const Node* fixed = get(body, "fixed"))
      for (std::size_t i = 0; i < fixed->items.size(); ++i)
        d.fixed.push_back(read_fixed(fixed->items[i], yaml::index_path(path + ".fixed", i)));
    if (const Node* actuators = get(body, "actuators"))
      for (std::size_t i = 0; i < actuators->items.size(); ++i)
        d.actuators.push_back(read_actuator(actuators->items[i], yaml::index_path(path + ".actuators", i)));
    if (const Node* rigidify = get(body, "rigidify"))
      for (std::size_t i = 0; i < rigidify->items.size(); ++i)
        d.rigidify.push_back(read_rigidify(rigidify->items[i], yaml::index_path(path + ".rigidify", i)));
    if (const Node* effectors = get(body, "effectors"))
      for (std::size_t i = 0; i < effectors->items.size(); ++i) {
        const Node& e = effectors->items[i];
        const std::string epath = yaml::index_path(path + ".effectors", i);
        EffectorDesc ed;
        ed.where = ctx_.where(e.mark, epath);
        ed.name = get(e, "name")->scalar;
        ed.point = vec3(get(e, "point"), ed.point);
        for (const auto& other : d.effectors)
          if (other.name == ed.name) ctx_.fail(e.mark, epath + ".name", "duplicate effector name '" + ed.name + "'");
        d.effectors.push_back(ed);
      }
    return d;
  }

  // Type-specific keys of an actuator: what each type needs, and nothing it ignores.
  ActuatorDesc read_actuator(const Node& item, const std::string& path) const {
    ActuatorDesc a;
    a.where = ctx_.where(item.mark, path);
    a.name = get(item, "name")->scalar;
    const std::string type = get(item, "type")->scalar;
    a.kind = type == "pressure" ? ActuatorDesc::Kind::pressure
             : type == "servo"  ? ActuatorDesc::Kind::servo
                                : ActuatorDesc::Kind::cable;
    const char* value_key = a.kind == ActuatorDesc::Kind::pressure ? "pressure" : "force";
    std::vector<std::string> allowed = {"name", "type", "limits", "schedule", value_key};
    auto require = [&](const char* key) {
      if (!item.find(key)) ctx_.fail(item.mark, path, "a " + type + " actuator needs '" + key + "'");
    };
    switch (a.kind) {
      case ActuatorDesc::Kind::cable: {
        allowed.insert(allowed.end(), {"points", "pull_point"});
        require("points");
        for (const Node& p : get(item, "points")->items) a.points.push_back(vec3(&p, Vec3::Zero()));
        if (const Node* pp = get(item, "pull_point")) a.pull_point = vec3(pp, Vec3::Zero());
        if (a.points.size() < 2 && !a.pull_point)
          ctx_.fail(item.find("points")->key_mark, path + ".points",
                    "a cable needs at least 2 points, or 1 point and a pull_point");
        break;
      }
      case ActuatorDesc::Kind::pressure:
        allowed.push_back("surface");
        require("surface");
        a.surface = get(item, "surface")->scalar;
        break;
      case ActuatorDesc::Kind::servo: {
        allowed.insert(allowed.end(), {"nodes", "direction", "axis", "center"});
        require("nodes");
        const Entry* nodes = item.find("nodes");
        const Entry* chosen = nullptr;
        for (const char* key : {"box", "group"})
          if (const Entry* e = nodes->value.find(key)) {
            if (chosen) ctx_.fail(e->key_mark, path + ".nodes." + e->key, "give only one of 'box', 'group'");
            chosen = e;
          }
        if (!chosen) ctx_.fail(nodes->key_mark, path + ".nodes", "needs one of 'box', 'group'");
        a.nodes.where = where(*chosen, path + ".nodes." + chosen->key);
        if (chosen->key == "box") {
          a.nodes.kind = FixedDesc::Kind::box;
          for (int k = 0; k < 6; ++k) a.nodes.box[k] = *yaml::to_number(chosen->value.items[k]);
        } else {
          a.nodes.kind = FixedDesc::Kind::group;
          a.nodes.group = chosen->value.scalar;
        }
        const Entry* direction = item.find("direction");
        const Entry* axis = item.find("axis");
        const Entry* center = item.find("center");
        if (direction && (axis || center))
          ctx_.fail(direction->key_mark, path + ".direction",
                    "give either 'direction' (translation servo) or 'axis' and 'center' (rotation servo), not both");
        if (!direction && !(axis && center))
          ctx_.fail(item.mark, path,
                    "a servo needs 'direction' (translation) or both 'axis' and 'center' (rotation)");
        a.rotation = !direction;
        a.direction = vec3(&(direction ? direction : axis)->value, Vec3::Zero());
        if (center) a.center = vec3(&center->value, Vec3::Zero());
        if (!(a.direction.norm() > 0))
          ctx_.fail((direction ? direction : axis)->key_mark, path + "." + (direction ? "direction" : "axis"),
                    "must be a non-zero vector");
        break;
      }
    }
    for (const Entry& e : item.entries)
      if (std::find(allowed.begin(), allowed.end(), e.key) == allowed.end())
        ctx_.fail(e.key_mark, path + "." + e.key, "not used by a " + type + " actuator");
    const Entry* value = item.find(value_key);
    const Entry* schedule = item.find("schedule");
    if (value && schedule)
      ctx_.fail(schedule->key_mark, path + ".schedule",
                std::string("give either '") + value_key + "' (constant) or 'schedule', not both");
    a.value = number(value ? &value->value : nullptr, 0);
    if (schedule) {
      double previous = -1;
      for (std::size_t k = 0; k < schedule->value.items.size(); ++k) {
        const Node& pair = schedule->value.items[k];
        const double t = *yaml::to_number(pair.items[0]);
        if (!(t >= 0) || !(t > previous))
          ctx_.fail(pair.mark, yaml::index_path(path + ".schedule", k),
                    "times must be >= 0 and increasing, got " + pair.items[0].scalar);
        previous = t;
        a.schedule.push_back({t, *yaml::to_number(pair.items[1])});
      }
    }
    if (const Entry* limits = item.find("limits")) {
      const double lo = *yaml::to_number(limits->value.items[0]), hi = *yaml::to_number(limits->value.items[1]);
      if (!(lo <= hi))
        ctx_.fail(limits->key_mark, path + ".limits",
                  "min must not exceed max, got [" + limits->value.items[0].scalar + ", " + limits->value.items[1].scalar + "]");
      a.limits = std::array<double, 2>{lo, hi};
    }
    return a;
  }

  // A rigidify entry: {group} or {box} (as `fixed`, without nodes/axes) and attach.
  RigidifyDesc read_rigidify(const Node& item, const std::string& path) const {
    RigidifyDesc r;
    r.where = ctx_.where(item.mark, path);
    if (!item.find("group") && !item.find("box")) ctx_.fail(item.mark, path, "needs one of 'group', 'box'");
    r.nodes = read_fixed(item, path);
    r.attach_where = r.where;
    if (const Entry* attach = item.find("attach")) {
      r.attach = attach->value.scalar;
      r.attach_where = where(*attach, path + ".attach");
    }
    return r;
  }

  FixedDesc read_fixed(const Node& item, const std::string& path) const {
    FixedDesc f;
    const Entry* chosen = nullptr;
    for (const char* key : {"box", "group", "nodes"}) {
      const Entry* e = item.find(key);
      if (!e) continue;
      if (chosen)
        ctx_.fail(e->key_mark, path + "." + e->key,
                  "give only one of 'box', 'group', 'nodes' per entry (this one also has '" + chosen->key + "')");
      chosen = e;
    }
    if (!chosen) ctx_.fail(item.mark, path, "needs one of 'box', 'group', 'nodes'");
    f.where = where(*chosen, path + "." + chosen->key);
    const Node& v = chosen->value;
    if (chosen->key == "box") {
      f.kind = FixedDesc::Kind::box;
      for (int k = 0; k < 6; ++k) f.box[k] = *yaml::to_number(v.items[k]);
      static const char* const axis_names[] = {"x", "y", "z"};
      for (int k = 0; k < 3; ++k)
        if (f.box[k] > f.box[k + 3])
          ctx_.fail(chosen->key_mark, f.where.path,
                    std::string("min must not exceed max, got ") + axis_names[k] + "min " + v.items[k].scalar + " > " +
                        axis_names[k] + "max " + v.items[k + 3].scalar);
    } else if (chosen->key == "group") {
      f.kind = FixedDesc::Kind::group;
      f.group = v.scalar;
    } else {
      f.kind = FixedDesc::Kind::nodes;
      for (const Node& n : v.items) f.nodes.push_back(static_cast<long>(*yaml::to_integer(n)));
    }
    if (const Node* axes = get(item, "axes")) {
      f.axes = {false, false, false};
      for (const Node& a : axes->items) f.axes[static_cast<std::size_t>(a.scalar[0] - 'x')] = true;
    }
    return f;
  }

  void read_obstacles(const Node& root, SceneDesc& scene) const {
    const Node* list = root.get("obstacles");
    if (!list) return;
    for (std::size_t i = 0; i < list->items.size(); ++i) {
      const Node& item = list->items[i];
      const std::string path = yaml::index_path("obstacles", i);
      ObstacleDesc o;
      o.where = ctx_.where(item.mark, path);
      o.name = get(item, "name")->scalar;
      const std::string type = get(item, "type")->scalar;
      using K = ObstacleDesc::Kind;
      std::vector<std::string> allowed = {"name", "type"}, needed;
      if (type == "plane") { o.kind = K::plane; needed = {"normal", "offset"}; }
      else if (type == "box") { o.kind = K::box; needed = {"center", "half_extents"}; allowed.push_back("rotate_deg"); }
      else if (type == "sphere") { o.kind = K::sphere; needed = {"center", "radius"}; }
      else if (type == "capsule") { o.kind = K::capsule; needed = {"center", "radius", "half_length"}; allowed.push_back("rotate_deg"); }
      else if (type == "cylinder") { o.kind = K::cylinder; needed = {"center", "radius", "half_length"}; allowed.push_back("rotate_deg"); }
      else { o.kind = K::mesh; needed = {"mesh"}; allowed.push_back("mesh_scale"); }
      allowed.insert(allowed.end(), needed.begin(), needed.end());
      for (const Entry& e : item.entries)
        if (std::find(allowed.begin(), allowed.end(), e.key) == allowed.end())
          ctx_.fail(e.key_mark, path + "." + e.key, "not used by a " + type + " obstacle");
      for (const std::string& k : needed)
        if (!item.find(k)) ctx_.fail(item.mark, path, "a " + type + " obstacle needs '" + k + "'");
      o.normal = vec3(get(item, "normal"), o.normal);
      if (const Entry* off = item.find("offset"); off && off->value.is_sequence()) {
        // A moving plane (extension): offset(t) piecewise linear, held outside.
        double previous = -1;
        for (std::size_t k = 0; k < off->value.items.size(); ++k) {
          const Node& pair = off->value.items[k];
          const double t = *yaml::to_number(pair.items[0]);
          if (!(t >= 0) || !(t > previous))
            ctx_.fail(pair.mark, yaml::index_path(path + ".offset", k),
                      "times must be >= 0 and increasing, got " + pair.items[0].scalar);
          previous = t;
          o.offset_schedule.push_back({t, *yaml::to_number(pair.items[1])});
        }
        o.offset = o.offset_schedule.front()[1];
      } else {
        o.offset = number(get(item, "offset"), o.offset);
      }
      o.center = vec3(get(item, "center"), o.center);
      o.half_extents = vec3(get(item, "half_extents"), o.half_extents);
      o.rotate_deg = vec3(get(item, "rotate_deg"), o.rotate_deg);
      o.radius = number(get(item, "radius"), o.radius);
      o.half_length = number(get(item, "half_length"), o.half_length);
      o.mesh_scale = number(get(item, "mesh_scale"), o.mesh_scale);
      if (o.kind == K::plane && !(o.normal.norm() > 0))
        ctx_.fail(item.find("normal")->key_mark, path + ".normal", "must not be the zero vector");
      if (o.kind == K::box)
        for (int k = 0; k < 3; ++k)
          if (!(o.half_extents[k] > 0))
            ctx_.fail(item.find("half_extents")->key_mark, path + ".half_extents",
                      "must be > 0 on every axis, got " + format_number(o.half_extents[k]));
      if (o.kind == K::mesh) {
        const Entry* mesh = item.find("mesh");
        o.mesh = (folder_ / fs::path(mesh->value.scalar)).lexically_normal();
        std::error_code ec;
        const fs::file_status status = fs::status(o.mesh, ec);
        if (!fs::exists(status)) ctx_.fail(mesh->key_mark, path + ".mesh", "mesh file not found: " + o.mesh.string());
        if (fs::is_directory(status))
          ctx_.fail(mesh->key_mark, path + ".mesh", "is a directory, not a mesh file: " + o.mesh.string());
      }
      for (const auto& b : scene.bodies)
        if (b.name == o.name)
          ctx_.fail(item.find("name")->key_mark, path + ".name",
                    "obstacle name '" + o.name + "' is also a body's name (contact pairs refer to either)");
      for (const auto& r : scene.rigid_bodies)
        if (r.name == o.name)
          ctx_.fail(item.find("name")->key_mark, path + ".name",
                    "obstacle name '" + o.name + "' is also a rigid body's name (contact pairs refer to either)");
      for (const auto& other : scene.obstacles)
        if (other.name == o.name)
          ctx_.fail(item.find("name")->key_mark, path + ".name",
                    "duplicate obstacle name '" + o.name + "' (also " + other.where.path + ")");
      scene.obstacles.push_back(std::move(o));
    }
  }

  void read_contact(const Node& root, SceneDesc& scene) const {
    const Entry* section = root.find("contact");
    if (!section || section->value.is_null()) return;
    const Node& c = section->value;
    ContactDesc& d = scene.contact;
    d.where = where(*section, "contact");
    d.enabled = boolean(get(c, "enabled"), true);
    if (!d.enabled) return;
    d.friction = number(get(c, "friction"), d.friction);
    d.self_collision = boolean(get(c, "self_collision"), d.self_collision);
    d.margin = number(get(c, "margin"), d.margin);
    if (const Node* solver = get(c, "solver")) d.solver = solver->scalar == "pgs" ? ContactDesc::Solver::pgs : ContactDesc::Solver::admm;
    d.tolerance = number(get(c, "tolerance"), d.tolerance);
    d.max_iterations = static_cast<int>(integer(get(c, "max_iterations"), d.max_iterations));
    d.polish = boolean(get(c, "polish"), d.polish);
    if (const Node* at_scale = get(c, "polish_at_scale")) d.polish_at_scale_always = at_scale->scalar == "always";
    if (const Node* backend = get(c, "backend"))
      d.backend = backend->scalar == "dense"    ? ContactDesc::Backend::dense
                  : backend->scalar == "sparse" ? ContactDesc::Backend::sparse
                                                : ContactDesc::Backend::automatic;
    d.dense_max_contacts = static_cast<int>(integer(get(c, "dense_max_contacts"), d.dense_max_contacts));
    d.derivative_dense_max_active =
        static_cast<int>(integer(get(c, "derivative_dense_max_active"), d.derivative_dense_max_active));
    d.derivative_mixed_dense_max_active =
        static_cast<int>(integer(get(c, "derivative_mixed_dense_max_active"), d.derivative_mixed_dense_max_active));
    d.derivative_scale_iterations =
        static_cast<int>(integer(get(c, "derivative_scale_iterations"), d.derivative_scale_iterations));
    if (const Node* sm = get(c, "smoothing")) {
      d.smoothing_samples = static_cast<int>(integer(get(*sm, "samples"), d.smoothing_samples));
      d.smoothing_sigma = number(get(*sm, "sigma"), d.smoothing_sigma);
      d.smoothing_seed = integer(get(*sm, "seed"), d.smoothing_seed);
    }
    auto is_body = [&](const std::string& n) {  // soft or rigid (scene.md: rigid bodies in contact pairs)
      return std::any_of(scene.bodies.begin(), scene.bodies.end(), [&](const BodyDesc& b) { return b.name == n; }) ||
             std::any_of(scene.rigid_bodies.begin(), scene.rigid_bodies.end(),
                         [&](const RigidBodyDesc& b) { return b.name == n; });
    };
    auto is_obstacle = [&](const std::string& n) {
      return std::any_of(scene.obstacles.begin(), scene.obstacles.end(), [&](const ObstacleDesc& o) { return o.name == n; });
    };
    if (const Node* pairs = get(c, "pairs"))
      for (std::size_t i = 0; i < pairs->items.size(); ++i) {
        const Node& item = pairs->items[i];
        const std::string path = yaml::index_path("contact.pairs", i);
        ContactPairDesc p;
        p.where = ctx_.where(item.mark, path);
        p.first = item.items[0].scalar;
        p.second = item.items[1].scalar;
        if (!is_body(p.first))
          ctx_.fail(item.items[0].mark, path + "[0]",
                    is_obstacle(p.first) ? "must be a body (put the obstacle '" + p.first + "' second)"
                                         : "unknown body '" + p.first + "'");
        if (!is_body(p.second) && !is_obstacle(p.second))
          ctx_.fail(item.items[1].mark, path + "[1]", "unknown body or obstacle '" + p.second + "'");
        const std::optional<double> mu = yaml::to_number(item.items[2]);
        if (!mu || !(*mu >= 0) || !std::isfinite(*mu))
          ctx_.fail(item.items[2].mark, path + "[2]",
                    "friction must be a number >= 0, got " + (mu ? format_number(*mu) : yaml::describe(item.items[2])));
        p.mu = *mu;
        for (const auto& q : d.pairs)
          if ((q.first == p.first && q.second == p.second) || (q.first == p.second && q.second == p.first))
            ctx_.fail(item.mark, path, "duplicate pair [" + p.first + ", " + p.second + "] (also " + q.where.path + ")");
        d.pairs.push_back(p);
      }
  }

  void read_output(const Node& root, OutputDesc& out) const {
    const Node* o = root.get("output");
    if (const Node* file = get(o, "file")) out.file = (folder_ / fs::path(file->scalar)).lexically_normal();
    out.every = static_cast<long>(integer(get(o, "every"), out.every));
    if (const Node* fields = get(o, "fields"))
      for (const Node& f : fields->items) {
        out.v = out.v || f.scalar == "v";
        out.contact = out.contact || f.scalar == "contact";
        out.actuation = out.actuation || f.scalar == "actuation";
        out.effectors = out.effectors || f.scalar == "effectors";
      }
    if (const Node* jacobians = get(o, "jacobians"))
      for (const Node& j : jacobians->items) out.jacobians.push_back(j.scalar);
    if (const Entry* compression = o && o->is_map() ? o->find("compression") : nullptr)
      out.gzip_level = compression_level(*compression);
  }

  // output.compression: none | gzip (level 6, gzip's default) | gzip:LEVEL, LEVEL 1..9.
  int compression_level(const Entry& e) const {
    const std::string& text = e.value.scalar;
    if (text == "none") return 0;
    if (text == "gzip") return 6;
    if (text.size() == 6 && text.compare(0, 5, "gzip:") == 0 && text[5] >= '1' && text[5] <= '9') return text[5] - '0';
    ctx_.fail(e.key_mark, "output.compression",
              "must be none, gzip or gzip:LEVEL with LEVEL in 1..9; got '" + text + "'");
  }

  const schema::Context& ctx_;
  fs::path folder_;
};

// `softdiff: 1` must be there and be 1; checked first, since another version's
// keys would make every other message misleading.
void check_version(const Node& root, const schema::Context& ctx) {
  const Entry* e = root.find("softdiff");
  if (!e)
    ctx.fail(root.mark, "", "missing required key 'softdiff' (the format version; this softdiff reads 'softdiff: " +
                                std::to_string(supported_version) + "')");
  const std::optional<long long> v = yaml::to_integer(e->value);
  if (!v || *v != supported_version)
    ctx.fail(e->key_mark, "softdiff",
             "unsupported format version " + yaml::describe(e->value) + " (supported: " + std::to_string(supported_version) + ")");
}

}  // namespace

SceneDesc load_scene(const std::filesystem::path& file, const std::vector<std::string>& overrides) {
  SceneDesc scene;
  scene.file = file;
  scene.text = read_scene_text(file);
  const schema::Context ctx{file.string()};

  Node root;
  try {
    root = yaml::parse(scene.text, false);
  } catch (const yaml::ParseError& e) {
    ctx.fail(e.mark, e.path, e.message);
  }
  if (root.is_null())
    throw InputError(ctx.file + ": empty scene file (expected at least 'softdiff: 1', 'simulation' and 'bodies')");
  if (!root.is_map())
    ctx.fail(root.mark, "", "expected a map of scene keys (softdiff, simulation, bodies, ...), got " + yaml::describe(root));
  check_version(root, ctx);

  const schema::Spec& spec = scene_schema();
  for (const std::string& assignment : overrides) schema::apply_override(root, spec, assignment);
  check_version(root, ctx);

  schema::validate(root, spec, ctx, root.mark, "");
  Reader(ctx, file.parent_path()).read(root, scene);
  return scene;
}

}  // namespace softdiff::io
