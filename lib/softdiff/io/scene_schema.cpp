#include <softdiff/io/scene_schema.hpp>

#include <climits>

namespace softdiff::io {

namespace {

using namespace schema;
using yaml::Node;

bool empty_list(const Node& n) { return n.is_null() || (n.is_sequence() && n.items.empty()); }

SpecPtr box6() { return numbers(6, "a list of 6 numbers [xmin, ymin, zmin, xmax, ymax, zmax]"); }

// {box: [...]} | {group: name} | {nodes: [...]}, for `fixed` with optional axes.
// (Exactly one of box/group/nodes: checked in scene.cpp.)
SpecPtr node_selection(bool with_nodes_and_axes) {
  std::vector<Field> fields = {
      key("box", box6()),
      key("group", text(true)),
  };
  if (with_nodes_and_axes) {
    fields.push_back(key("nodes", list(integer(ge(0), LONG_MAX), "a list of node indices", 1)));
    fields.push_back(key("axes", list(choice({"x", "y", "z"}), "a list of axes (x, y, z)", 1, true)));
  }
  return map(std::move(fields));
}

SpecPtr material() {
  return map({
      key("law", choice({"corotational", "stvk", "neo_hookean", "linear"})),
      required("young", number(gt(0))),
      required("poisson", number(half_open(0, 0.5))),
      required("density", number(gt(0))),
  });
}

// Planned (scene.md): obstacles, contact. Described fully so
// that their keys are known (suggestions, --set) and enabling one is a table edit
// plus its reader in scene.cpp. Type-specific keys (points for cables, radius for
// spheres, ...) are to be checked by that reader.
SpecPtr actuator() {
  return map({
      required("name", name()),
      required("type", choice({"cable", "pressure", "servo"})),
      key("points", list(vec3(), "a list of points [[x, y, z], ...]", 1)),
      key("pull_point", vec3()),
      excludes(key("force", number()), "schedule"),  // --set force=... replaces a schedule
      key("limits", numbers(2, "a list of 2 numbers [min, max]")),
      key("surface", text(true)),
      excludes(key("pressure", number()), "schedule"),
      key("nodes", node_selection(false)),
      key("direction", vec3()),
      key("axis", vec3()),
      key("center", vec3()),
      // extension: lambda_a(t), piecewise linear: [[t0, v0], [t1, v1], ...]
      // (--set schedule=... replaces a constant force; a constant pressure stays: an error)
      excludes(key("schedule", list(numbers(2, "a pair [time, value]"), "a list of [time, value] pairs", 1)), "force"),
  });
}

SpecPtr effector() {
  return map({
      required("name", name()),
      required("point", vec3()),
  });
}

// A plane's offset: a number, or (extension) a piecewise-linear schedule of the
// plane's motion along its normal.
SpecPtr plane_offset() {
  auto s = std::make_shared<Spec>(*number());
  s->or_sequence = list(numbers(2, "a pair [time, offset]"), "a list of [time, offset] pairs", 1);
  s->expected = "a number or a list of [time, offset] pairs";
  return s;
}

SpecPtr obstacle() {
  return map({
      required("name", name()),
      required("type", choice({"plane", "box", "sphere", "capsule", "cylinder", "mesh"})),
      key("normal", vec3()),
      key("offset", plane_offset()),  // extension: or a schedule [[t, offset], ...] (a moving plane)
      key("center", vec3()),
      key("half_extents", vec3()),
      key("rotate_deg", vec3()),
      key("radius", number(gt(0))),
      key("mesh", text(true)),
      key("mesh_scale", number(gt(0))),
      key("half_length", number(gt(0))),  // extension: capsule, cylinder
  });
}

SpecPtr contact() {
  auto pair = std::make_shared<Spec>(*list(text(), "a list of 3 [body, obstacle-or-body, mu]"));
  pair->min_items = pair->max_items = 3;
  return map({
      key("enabled", boolean()),
      key("friction", number(ge(0))),
      key("pairs", list(pair)),
      key("self_collision", boolean()),
      key("margin", number(ge(0))),
      key("solver", choice({"admm", "pgs"})),
      key("tolerance", number(gt(0))),
      key("max_iterations", integer(ge(1))),
      key("polish", boolean()),  // extension
      key("polish_at_scale", choice({"stalled", "always"})),  // extension (docs/method.md "The mode-fixed system at scale")
      key("backend", choice({"auto", "dense", "sparse"})),  // extension (docs/method.md "Contact at scale")
      key("dense_max_contacts", integer(ge(0))),            // extension
      key("derivative_dense_max_active", integer(ge(0))),   // extension (docs/method.md "The mode-fixed system at scale")
      key("derivative_mixed_dense_max_active", integer(ge(0))),  // extension
      key("derivative_scale_iterations", integer(ge(1))),   // extension (docs/method.md "The derivative's scale")
      key("smoothing", map({      // extension: collision-detection derivatives
                           key("samples", integer(ge(0), 1000000)),
                           key("sigma", number(gt(0))),
                           key("seed", integer(ge(0), LONG_MAX)),
                       })),
  });
}

// `type` of a body: soft (the default) or rigid; the keys of each are below.
SpecPtr body_type() { return choice({"soft", "rigid"}, "static rigid shapes are 'obstacles'"); }

SpecPtr soft_body() {
  return map({
      required("name", name()),
      key("type", body_type()),
      required("mesh", text(true)),
      key("mesh_scale", number(gt(0))),
      key("translate", vec3()),
      key("rotate_deg", vec3()),
      required("material", material()),
      key("elements", choice({"linear", "quadratic"})),
      key("mass", choice({"lumped", "consistent"})),
      key("damping", map({
                         key("rayleigh_mass", number(ge(0))),
                         key("rayleigh_stiffness", number(ge(0))),
                     })),
      key("psd_projection", boolean()),
      key("fixed", list(node_selection(true))),
      key("initial_velocity", vec3()),
      key("actuators", list(actuator(), "a list", 0, false, "actuator")),
      key("effectors", list(effector(), "a list", 0, false, "effector")),
      key("rigidify", list(map({key("group", text(true)), key("box", box6()), key("attach", text(true))}))),
  });
}

// A rigid body (scene.md, additions of 2026-12). Keys that depend on the shape type
// or the joint type (radius for a sphere, axis for a hinge), `density` against
// `mass` + `inertia`, and the values that relate several numbers (a unit quaternion,
// an inertia that is positive definite, limits in order) are checked by scene.cpp.
SpecPtr rigid_shape() {
  return map({
      required("type", choice({"box", "sphere", "capsule", "cylinder", "mesh"})),
      key("half_extents", vec3()),
      key("radius", number(gt(0))),
      key("length", number(gt(0))),
      key("mesh", text(true)),
      key("mesh_scale", number(gt(0))),
  });
}

SpecPtr rigid_joint() {
  return map({
      required("type", choice({"fixed", "hinge", "slider"})),
      key("anchor", vec3()),
      key("axis", vec3()),
      key("limits", numbers(2, "a list of 2 numbers [lo, hi]")),
  });
}

SpecPtr rigid_body() {
  auto inertia = std::make_shared<Spec>(
      *list(number(), "a list of 3 numbers [Ixx, Iyy, Izz] or 6 [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]", 3));
  inertia->max_items = 6;
  return map({
      required("name", name()),
      required("type", body_type()),
      required("shape", rigid_shape()),
      key("density", number(gt(0))),
      key("mass", number(gt(0))),
      key("inertia", inertia),
      key("position", vec3()),
      key("orientation", numbers(4, "a list of 4 numbers [w, x, y, z] (a unit quaternion)")),
      key("velocity", vec3()),
      key("angular_velocity", vec3()),
      key("joint", rigid_joint()),
  });
}

// A body: soft unless `type: rigid`.
SpecPtr body() { return variants("type", {{"soft", soft_body()}, {"rigid", rigid_body()}}); }

SpecPtr simulation() {
  return map({
      key("integrator", choice({"implicit_euler", "bdf2", "static"})),
      key("dt", number(gt(0))),
      excludes(key("duration", number(gt(0))), "steps"),
      excludes(key("steps", integer(ge(1), LONG_MAX)), "duration"),
      key("gravity", vec3()),
      key("newton_iterations", integer(ge(1))),
      key("newton_tolerance", number(gt(0))),  // extension
      key("static", map({
                        key("max_iterations", integer(ge(1))),
                        key("tolerance", number(gt(0))),
                        key("load_steps", integer(ge(1))),
                        key("convergence", choice({"answer", "residual"})),  // extension
                        key("displacement_tolerance", number(Range{0.0, 0.1, true, false})),  // extension
                        key("residual_tolerance", number(Range{0.0, 0.1, true, false})),      // extension
                        key("friction", choice({"iterate", "load_step"})),                    // extension
                    })),
  });
}

SpecPtr linear_solver() {
  // `linear_solver: cg`, or (extension) {type: cg, tolerance: 1e-10, max_iterations: N},
  // or {type: cholmod, factor_reuse: pcg, tolerance, max_iterations, refactor_iterations}
  return map(
      {
          key("type", choice({"cholmod", "ldlt", "cg"})),
          key("tolerance", number(gt(0))),
          key("max_iterations", integer(ge(1))),
          key("factor_reuse", choice({"off", "pcg"})),        // extension (cholmod)
          key("refactor_iterations", integer(ge(1))),         // extension (factor_reuse: pcg)
      },
      "type");
}

SpecPtr output() {
  const auto field_names =
      choice({"x", "v", "contact", "actuation", "effectors"});
  const auto parameters =
      choice({"young", "poisson", "density", "rayleigh_mass", "rayleigh_stiffness", "friction", "actuation", "x0", "v0"});
  return map({
      key("file", text(true)),
      key("every", integer(ge(1), LONG_MAX)),
      key("fields", list(field_names, "a list of fields (x, v, contact, actuation, effectors)", 0, true)),
      key("compression", text(true)),  // none | gzip | gzip:LEVEL, checked by the scene reader
      planned(key("jacobians", list(parameters, "a list of parameters", 0, true)), "jacobians", empty_list),
  });
}

SpecPtr scene() {
  return map({
      required("softdiff", integer()),
      key("name", text()),
      key("simulation", simulation()),
      key("linear_solver", linear_solver()),
      required("bodies", list(body(), "a list", 1, false, "body")),
      key("obstacles", list(obstacle(), "a list", 0, false, "obstacle")),
      key("contact", contact()),
      key("output", output()),
  });
}

}  // namespace

const Spec& scene_schema() {
  static const SpecPtr spec = scene();
  return *spec;
}

}  // namespace softdiff::io
