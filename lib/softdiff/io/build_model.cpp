#include <softdiff/io/build_model.hpp>

#include <softdiff/core/error.hpp>
#include <softdiff/io/gmsh_msh.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>
#include <unordered_map>

namespace softdiff::io {

Mat3 rotation_from_euler_deg(const Vec3& a) {
  const double k = std::numbers::pi / 180.0;
  return (Eigen::AngleAxisd(a.z() * k, Vec3::UnitZ()) * Eigen::AngleAxisd(a.y() * k, Vec3::UnitY()) *
          Eigen::AngleAxisd(a.x() * k, Vec3::UnitX()))
      .toRotationMatrix();
}

namespace {

[[noreturn]] void fail(const Where& where, const std::string& message) {
  throw InputError(where.str() + ": " + message);
}

std::string group_list(const mesh::TetMesh& m) {
  std::string s;
  for (const auto& g : m.groups) {
    if (g.name.empty()) continue;
    if (!s.empty()) s += ", ";
    s += "'" + g.name + "'";
  }
  return s.empty() ? "the mesh has no named physical groups" : "groups: " + s;
}

// Marks the fixed dofs of one body (local node indices).
void resolve_fixed(const BodyDesc& body, const mesh::TetMesh& m, std::vector<unsigned char>& fixed_local) {
  const Vec3 lo = m.X.rowwise().minCoeff(), hi = m.X.rowwise().maxCoeff();
  const double tol = 1e-9 * (hi - lo).norm();
  std::unordered_map<long, int> by_file_index;
  for (const auto& f : body.fixed) {
    std::vector<int> nodes;
    switch (f.kind) {
      case FixedDesc::Kind::box:
        for (int i = 0; i < m.num_nodes(); ++i) {
          const Vec3 p = m.X.col(i);
          bool inside = true;
          for (int c = 0; c < 3; ++c) inside = inside && p[c] >= f.box[c] - tol && p[c] <= f.box[c + 3] + tol;
          if (inside) nodes.push_back(i);
        }
        if (nodes.empty()) {
          std::ostringstream s;
          s.precision(6);
          s << "box selects no node of body '" << body.name << "' (its nodes span [" << lo.x() << ", " << lo.y()
            << ", " << lo.z() << "] to [" << hi.x() << ", " << hi.y() << ", " << hi.z()
            << "] after mesh_scale/rotate_deg/translate)";
          fail(f.where, s.str());
        }
        break;
      case FixedDesc::Kind::group: {
        const auto* g = m.find_group(f.group);
        if (!g) fail(f.where, "mesh " + m.source + " has no physical group '" + f.group + "' (" + group_list(m) + ")");
        if (g->nodes.empty()) fail(f.where, "physical group '" + f.group + "' has no node on the tetrahedral mesh");
        nodes = g->nodes;
        break;
      }
      case FixedDesc::Kind::nodes:
        if (by_file_index.empty())
          for (int i = 0; i < m.num_nodes(); ++i) by_file_index[m.file_index[i]] = i;
        for (long k : f.nodes) {
          auto it = by_file_index.find(k);
          if (it == by_file_index.end())
            fail(f.where, "node " + std::to_string(k) + " is not a node of a tetrahedron of " + m.source + " (" +
                              std::to_string(m.num_nodes() + m.orphan_nodes) + " nodes in the file)");
          nodes.push_back(it->second);
        }
        break;
    }
    for (int i : nodes)
      for (int c = 0; c < 3; ++c)
        if (f.axes[c]) fixed_local[3 * i + c] = 1;
  }
}

}  // namespace

Model build_model(const SceneDesc& scene, BuildReport* report) {
  Model model;
  model.name = scene.name;
  const auto& sim = scene.simulation;
  model.step.integrator =
      sim.integrator == Integrator::static_equilibrium ? IntegratorKind::static_equilibrium : IntegratorKind::implicit_euler;
  model.step.dt = sim.dt;
  model.step.steps = sim.steps;
  model.step.gravity = sim.gravity;
  model.step.newton_iterations = sim.newton_iterations;
  model.step.newton_tolerance = sim.newton_tolerance;
  model.step.static_max_iterations = sim.static_max_iterations;
  model.step.static_tolerance = sim.static_tolerance;
  model.step.static_load_steps = sim.static_load_steps;
  switch (scene.linear_solver.kind) {
    case LinearSolverKind::cholmod: model.solver.kind = integrator::SolverKind::cholmod; break;
    case LinearSolverKind::ldlt: model.solver.kind = integrator::SolverKind::ldlt; break;
    case LinearSolverKind::cg: model.solver.kind = integrator::SolverKind::cg; break;
  }
  model.solver.cg_tolerance = scene.linear_solver.cg_tolerance;
  model.solver.cg_max_iterations = scene.linear_solver.cg_max_iterations;

  std::vector<fem::BodyModel> bodies;
  std::vector<unsigned char> fixed;
  std::vector<Vec3> initial_velocity;
  for (const auto& bd : scene.bodies) {
    fem::BodyModel b;
    b.name = bd.name;
    b.mesh = read_gmsh(bd.mesh);
    if (report) {
      if (b.mesh.orphan_nodes > 0)
        report->warnings.push_back(b.mesh.source + ": " + std::to_string(b.mesh.orphan_nodes) +
                                   " nodes belong to no tetrahedron and were dropped (output node order = file order "
                                   "of the remaining nodes)");
      if (b.mesh.reoriented_tets > 0)
        report->warnings.push_back(b.mesh.source + ": " + std::to_string(b.mesh.reoriented_tets) +
                                   " tetrahedra had negative orientation and were reordered");
    }
    const Mat3 R = rotation_from_euler_deg(bd.rotate_deg);
    b.mesh.X = (R * (bd.mesh_scale * b.mesh.X)).colwise() + bd.translate;
    b.surface = mesh::boundary_triangles(b.mesh.tets);
    b.law = bd.material.law;
    b.young = bd.material.young;
    b.poisson = bd.material.poisson;
    b.density = bd.material.density;
    b.rayleigh_mass = bd.rayleigh_mass;
    b.rayleigh_stiffness = bd.rayleigh_stiffness;
    b.psd_projection = bd.psd_projection;
    b.mass_kind = bd.mass == MassKind::consistent ? fem::MassKind::consistent : fem::MassKind::lumped;
    std::vector<unsigned char> fixed_local(3 * b.mesh.num_nodes(), 0);
    resolve_fixed(bd, b.mesh, fixed_local);
    if (sim.integrator == Integrator::static_equilibrium &&
        std::find(fixed_local.begin(), fixed_local.end(), 1) == fixed_local.end()) {
      Where w = bd.where;
      w.path += ".fixed";
      fail(w, "a static scene needs fixed nodes on every body: body '" + bd.name +
                  "' is free, so it has no equilibrium under load");
    }
    fixed.insert(fixed.end(), fixed_local.begin(), fixed_local.end());
    initial_velocity.push_back(bd.initial_velocity);
    bodies.push_back(std::move(b));
  }
  fem::build_fem_model(std::move(bodies), fixed, sim.gravity, model.fem);

  const int ndof = 3 * model.fem.num_nodes;
  model.initial.t = 0;
  model.initial.x = Eigen::Map<const VecX>(model.fem.X.data(), ndof);
  model.initial.v = VecX::Zero(ndof);
  for (size_t bi = 0; bi < model.fem.bodies.size(); ++bi) {
    const auto& b = model.fem.bodies[bi];
    for (int i = b.node_begin; i < b.node_begin + b.num_nodes; ++i) model.initial.v.segment<3>(3 * i) = initial_velocity[bi];
  }
  for (int k = 0; k < ndof; ++k)
    if (model.fem.fixed[k]) model.initial.v[k] = 0;
  return model;
}

}  // namespace softdiff::io
