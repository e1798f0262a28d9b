// softdiff info FILE: describe a mesh, or validate and describe a scene.
#include "commands.hpp"
#include "common.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/gmsh_msh.hpp>
#include <softdiff/io/plausibility.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/material/material.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>
#include <variant>

namespace softdiff::app {
namespace {

std::vector<double> v3(const Vec3& v) { return {v.x(), v.y(), v.z()}; }

// A rigid body's shape, joint and inertia in words and numbers (info, docs/cli.md).
const char* shape_name(const rigid::Shape& s) {
  switch (s.kind) {
    case rigid::Shape::Kind::box: return "box";
    case rigid::Shape::Kind::sphere: return "sphere";
    case rigid::Shape::Kind::capsule: return "capsule";
    case rigid::Shape::Kind::cylinder: return "cylinder";
    case rigid::Shape::Kind::mesh: return "mesh";
  }
  return "?";
}
// A rigidified part's lumped mass and centroid at the initial state (info).
struct RigidifiedSummary {
  double mass = 0;
  Vec3 centroid = Vec3::Zero();
};
RigidifiedSummary summarize(const Model& model, const integrator::RigidifiedPart& p) {
  RigidifiedSummary s;
  for (int i : p.nodes) s.mass += model.fem.mass_diagonal[3 * i];
  s.centroid = integrator::part_centre(model, p, model.initial.x);
  return s;
}

const char* joint_name(const rigid::Joint& j) {
  switch (j.kind) {
    case rigid::Joint::Kind::free: return "free";
    case rigid::Joint::Kind::fixed: return "fixed";
    case rigid::Joint::Kind::hinge: return "hinge";
    case rigid::Joint::Kind::slider: return "slider";
  }
  return "?";
}
// [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (the scene's `inertia` order)
std::vector<double> inertia6(const Mat3& I) { return {I(0, 0), I(1, 1), I(2, 2), I(0, 1), I(0, 2), I(1, 2)}; }

// Unit of an actuator's value: cable tension and servo force in N, pressure in Pa,
// servo torque in N m.
const char* value_unit(const actuation::ActuatorModel& a) {
  if (std::holds_alternative<actuation::Cavity>(a.kind)) return "Pa";
  if (const auto* s = std::get_if<actuation::Servo>(&a.kind); s && s->is_rotation()) return "N m";
  return "N";
}

// "0.25 N" or "schedule of 2 points, 0 to 0.25 N over [0, 1] s".
std::string describe_value(const actuation::ActuatorModel& a) {
  char buf[160];
  const auto& p = a.value.points;
  if (p.empty()) {
    std::snprintf(buf, sizeof buf, "%g %s", a.value.constant, value_unit(a));
  } else {
    double lo = p[0][1], hi = p[0][1];
    for (const auto& q : p) lo = std::min(lo, q[1]), hi = std::max(hi, q[1]);
    std::snprintf(buf, sizeof buf, "schedule of %zu points, %g to %g %s over [%g, %g] s", p.size(), lo, hi,
                  value_unit(a), p.front()[0], p.back()[0]);
  }
  return buf;
}

int info_mesh(const std::string& file, bool json) {
  const mesh::TetMesh m = io::read_gmsh(file);
  const Triangles surface = mesh::boundary_triangles(m.tets);
  const mesh::Quality q = mesh::quality(m.X, m.tets);
  if (json) {
    Json j;
    j.begin_object().value("file", file).value("nodes", m.num_nodes()).value("tets", m.num_tets());
    j.value("elements", m.order == 2 ? "quadratic" : "linear").value("nodes_per_tet", m.nodes_per_tet());
    j.value("triangles", static_cast<long>(m.triangles.cols())).value("boundary_triangles", static_cast<long>(surface.cols()));
    j.value("orphan_nodes", m.orphan_nodes).value("reoriented_tets", m.reoriented_tets);
    j.value("bbox_min", v3(q.bbox_min)).value("bbox_max", v3(q.bbox_max));
    j.begin_object("quality")
        .value("volume", q.total_volume)
        .value("min_volume", q.min_volume)
        .value("max_volume", q.max_volume)
        .value("min_aspect", q.min_aspect)
        .value("median_aspect", q.median_aspect)
        .value("max_aspect", q.max_aspect)
        .value("worst_tet", q.worst_tet)
        .end_object();
    j.begin_array("groups");
    for (const auto& g : m.groups)
      j.begin_object()
          .value("name", g.name)
          .value("dim", g.dim)
          .value("tag", g.tag)
          .value("nodes", static_cast<long>(g.nodes.size()))
          .value("triangles", static_cast<long>(g.triangles.size()))
          .value("tets", static_cast<long>(g.tets.size()))
          .end_object();
    j.end_array().end_object();
    std::printf("%s\n", j.str().c_str());
    return kExitOk;
  }
  std::printf("mesh        %s\n", file.c_str());
  std::printf("nodes       %d (%ld orphan nodes dropped)\n", m.num_nodes(), m.orphan_nodes);
  std::printf("tets        %d (%ld reoriented)\n", m.num_tets(), m.reoriented_tets);
  std::printf("elements    %s\n", m.order == 2 ? "quadratic (10-node tetrahedra, gmsh type 11)"
                                               : "linear (4-node tetrahedra, gmsh type 4)");
  std::printf("triangles   %ld in the file, %ld on the boundary\n", static_cast<long>(m.triangles.cols()),
              static_cast<long>(surface.cols()));
  std::printf("bbox        [%.6g, %.6g, %.6g] to [%.6g, %.6g, %.6g]\n", q.bbox_min.x(), q.bbox_min.y(), q.bbox_min.z(),
              q.bbox_max.x(), q.bbox_max.y(), q.bbox_max.z());
  std::printf("volume      %.6g (tet volume min %.4g, max %.4g)\n", q.total_volume, q.min_volume, q.max_volume);
  std::printf("aspect      min %.3f, median %.3f, max %.3f (tet %d); 1 = regular\n", q.min_aspect, q.median_aspect,
              q.max_aspect, q.worst_tet);
  std::printf("groups      %zu\n", m.groups.size());
  for (const auto& g : m.groups)
    std::printf("  %-20s dim %d tag %-4d %zu nodes, %zu triangles, %zu tets\n",
                g.name.empty() ? "(unnamed)" : g.name.c_str(), g.dim, g.tag, g.nodes.size(), g.triangles.size(),
                g.tets.size());
  return kExitOk;
}

int info_scene(const std::string& file, const std::vector<std::string>& set, bool json, bool strict) {
  const io::SceneDesc scene = io::load_scene(file, set);
  io::BuildReport report;
  report.strict = strict;
  const Model model = io::build_model(scene, &report);
  for (const auto& w : report.warnings) warn(w);
  const auto& fem = model.fem;
  const bool is_static = model.step.integrator == IntegratorKind::static_equilibrium;
  if (json) {
    Json j;
    j.begin_object().value("file", file).value("valid", true).value("name", model.name);
    j.begin_array("warnings");
    for (const auto& w : report.warnings) j.value("", w);
    j.end_array();
    j.value("integrator", is_static ? "static" : model.step.integrator == IntegratorKind::bdf2 ? "bdf2" : "implicit_euler").value("dt", model.step.dt).value("steps", model.step.steps);
    j.value("dofs", 3L * fem.num_nodes).value("fixed_dofs", fem.num_fixed_dofs).value("nonzeros", fem.pattern.nnz());
    j.value("colors", static_cast<long>(fem.pattern.color_begin.size()) - 1).value("total_mass", fem.total_mass);
    j.begin_array("bodies");
    for (std::size_t bi = 0; bi < fem.bodies.size(); ++bi) {
      const auto& b = fem.bodies[bi];
      const io::BodySize size = io::body_size(model, static_cast<int>(bi));
      j.begin_object()
          .value("name", b.name)
          .value("law", std::string(material::law_name(b.law)))
          .value("nodes", b.num_nodes)
          .value("tets", b.num_tets)
          .value("elements", b.mesh.order == 2 ? "quadratic" : "linear")
          .value("size", v3(size.extents))
          .value("mass", size.mass)
          .end_object();
    }
    j.end_array();
    j.begin_array("rigid_bodies");
    for (const auto& r : model.rigid) {
      j.begin_object()
          .value("name", r.name)
          .value("shape", shape_name(r.shape))
          .value("surface_vertices", static_cast<long>(r.surface.vertices.cols()))
          .value("mass", r.mass)
          .value("inertia", inertia6(r.inertia));
      j.begin_object("joint").value("type", joint_name(r.joint));
      if (r.joint.kind != rigid::Joint::Kind::free) j.value("anchor", v3(r.joint.anchor));
      if (r.joint.kind == rigid::Joint::Kind::hinge || r.joint.kind == rigid::Joint::Kind::slider)
        j.value("axis", v3(r.joint.axis));
      if (r.joint.limits) j.value("limits", std::vector<double>{r.joint.limits->first, r.joint.limits->second});
      j.end_object().end_object();
    }
    j.end_array();
    // Rigidified parts (free or servo-attached; attach: fixed parts are fixed nodes).
    j.begin_array("rigidified_parts");
    for (const auto& p : model.rigidify.parts) {
      const RigidifiedSummary s = summarize(model, p);
      j.begin_object()
          .value("name", p.name)
          .value("body", fem.bodies[p.body].name)
          .value("nodes", static_cast<long>(p.nodes.size()))
          .value("mass", s.mass)
          .value("centroid", v3(s.centroid))
          .value("attach", p.servo < 0 ? std::string("free") : model.actuation.actuators[p.servo].name)
          .end_object();
    }
    j.end_array();
    j.begin_array("actuators");
    for (const auto& a : model.actuation.actuators) {
      j.begin_object().value("name", a.name).value("type", a.kind_name()).value("body", fem.bodies[a.body].name);
      j.value("unit", value_unit(a));
      if (a.value.points.empty()) {
        j.value("value", a.value.constant);
      } else {
        j.begin_array("schedule");
        for (const auto& q : a.value.points) j.value("", std::vector<double>{q[0], q[1]});
        j.end_array();
      }
      if (a.has_limits) j.value("limits", std::vector<double>{a.limits[0], a.limits[1]});
      if (a.has_measure()) j.value(a.measure_name(), a.measure(model.initial.x));
      j.end_object();
    }
    j.end_array();
    j.begin_array("effectors");
    for (const auto& e : model.actuation.effectors)
      j.begin_object()
          .value("name", e.name)
          .value("body", fem.bodies[e.body].name)
          .value("point", v3(e.effector.position(model.initial.x)))
          .end_object();
    j.end_array().end_object();
    std::printf("%s\n", j.str().c_str());
    return kExitOk;
  }
  std::printf("scene       %s (valid)%s%s\n", file.c_str(), model.name.empty() ? "" : ": ", model.name.c_str());
  if (!report.warnings.empty()) std::printf("warnings    %zu (on stderr)\n", report.warnings.size());
  if (is_static)
    std::printf("integrator  static, %d load steps\n", model.step.static_load_steps);
  else
    std::printf("integrator  %s, dt %g s, %ld steps (%g s), newton_iterations %d\n",
                model.step.integrator == IntegratorKind::bdf2 ? "bdf2" : "implicit_euler", model.step.dt,
                model.step.steps, model.step.dt * model.step.steps, model.step.newton_iterations);
  if (fem.num_nodes == 0)  // a scene of rigid bodies only (integrator/bdf2.cpp time_step_rigid_only)
    std::printf("system      no soft body: the step skips the soft stage (no matrix, no factorization)\n");
  else
    std::printf("system      %d dofs (%ld fixed), %ld nonzeros in the upper triangle, %zu element colors\n",
                3 * fem.num_nodes, fem.num_fixed_dofs, fem.pattern.nnz(), fem.pattern.color_begin.size() - 1);
  for (std::size_t bi = 0; bi < fem.bodies.size(); ++bi) {
    const auto& b = fem.bodies[bi];
    long fixed_nodes = 0;
    for (int i = b.node_begin; i < b.node_begin + b.num_nodes; ++i)
      fixed_nodes += (fem.fixed[3 * i] || fem.fixed[3 * i + 1] || fem.fixed[3 * i + 2]) ? 1 : 0;
    const io::BodySize size = io::body_size(model, static_cast<int>(bi));
    std::printf("body        %s: %d nodes, %d tets (%s), %ld fixed nodes, %s E=%g Pa nu=%g rho=%g kg/m^3, "
                "size %.4g x %.4g x %.4g m, mass %.4g kg\n",
                b.name.c_str(), b.num_nodes, b.num_tets, b.mesh.order == 2 ? "quadratic" : "linear", fixed_nodes, std::string(material::law_name(b.law)).c_str(),
                b.young, b.poisson, b.density, size.extents.x(), size.extents.y(), size.extents.z(), size.mass);
  }
  for (const auto& r : model.rigid) {
    const Mat3& I = r.inertia;
    std::printf("rigid       %s: %s, %ld surface vertices, mass %.4g kg, inertia [%.4g, %.4g, %.4g, %.4g, %.4g, %.4g] kg m^2 "
                "(Ixx Iyy Izz Ixy Ixz Iyz), joint %s",
                r.name.c_str(), shape_name(r.shape), static_cast<long>(r.surface.vertices.cols()), r.mass, I(0, 0),
                I(1, 1), I(2, 2), I(0, 1), I(0, 2), I(1, 2), joint_name(r.joint));
    if (r.joint.kind != rigid::Joint::Kind::free)
      std::printf(" at [%g, %g, %g]", r.joint.anchor.x(), r.joint.anchor.y(), r.joint.anchor.z());
    if (r.joint.kind == rigid::Joint::Kind::hinge || r.joint.kind == rigid::Joint::Kind::slider)
      std::printf(", axis [%g, %g, %g]", r.joint.axis.x(), r.joint.axis.y(), r.joint.axis.z());
    if (r.joint.limits)
      std::printf(", limits [%g, %g] %s", r.joint.limits->first, r.joint.limits->second,
                  r.joint.kind == rigid::Joint::Kind::hinge ? "rad" : "m");
    std::printf("\n");
  }
  for (const auto& p : model.rigidify.parts) {
    const RigidifiedSummary s = summarize(model, p);
    std::printf("rigidified  %s: %zu nodes, mass %.4g kg, centroid [%.6g, %.6g, %.6g], attach %s\n", p.name.c_str(),
                p.nodes.size(), s.mass, s.centroid.x(), s.centroid.y(), s.centroid.z(),
                p.servo < 0 ? "free" : ("servo '" + model.actuation.actuators[p.servo].name + "'").c_str());
  }
  for (const auto& a : model.actuation.actuators) {
    std::string line = "actuator    " + a.name + ": " + a.kind_name() + " on " + fem.bodies[a.body].name + ", " +
                       describe_value(a);
    char buf[96];
    if (a.has_limits) {
      std::snprintf(buf, sizeof buf, ", limits [%g, %g]", a.limits[0], a.limits[1]);
      line += buf;
    }
    if (a.has_measure()) {
      std::snprintf(buf, sizeof buf, ", rest %s %g %s", a.measure_name(), a.measure(model.initial.x),
                    std::string(a.measure_name()) == "length" ? "m" : "m^3");
      line += buf;
    }
    std::printf("%s\n", line.c_str());
  }
  for (const auto& e : model.actuation.effectors) {
    const Vec3 p = e.effector.position(model.initial.x);
    std::printf("effector    %s: on %s at [%g, %g, %g]\n", e.name.c_str(), fem.bodies[e.body].name.c_str(), p.x(), p.y(),
                p.z());
  }
  return kExitOk;
}

}  // namespace

void add_info(CLI::App& app, InfoOptions& o) {
  app.add_option("file", o.file, "A mesh (.msh) or a scene (.yaml/.yml)")->required()->check(CLI::ExistingFile);
  app.add_option("--set", o.set, "Scene override KEY=VALUE (scenes only; repeatable)");
  app.add_flag("--json", o.json, "Print a JSON object on stdout");
  app.add_flag("--strict", o.strict, "Scenes: a body of implausible size or mass is bad input (exit 2)");
}

int run_info(const InfoOptions& o) {
  const std::string ext = std::filesystem::path(o.file).extension().string();
  if (ext == ".yaml" || ext == ".yml") return info_scene(o.file, o.set, o.json, o.strict);
  if (ext == ".msh") return info_mesh(o.file, o.json);
  throw InputError(o.file + ": unknown file type '" + ext + "' (expected a mesh .msh or a scene .yaml/.yml)");
}

}  // namespace softdiff::app
