#pragma once
// Builds a one-body Model in code (no scene file), for unit and validation tests.
#include <softdiff/mesh/tet_mesh.hpp>
#include <softdiff/model.hpp>

#include <functional>
#include <string>
#include <vector>

namespace softdiff::test {

struct BodySpec {
  material::Law law = material::Law::corotational;
  double young = 1e5, poisson = 0.3, density = 1000;
  double rayleigh_mass = 0, rayleigh_stiffness = 0;
  bool psd_projection = false;
  fem::MassKind mass = fem::MassKind::lumped;
  std::function<bool(const Vec3&)> fixed;  // nodes where this is true are fixed (all axes)
};

struct BodyInput {
  mesh::TetMesh mesh;
  BodySpec spec;
  std::string name = "body";
};

// Several bodies (global nodes in the order given).
inline Model make_model(const std::vector<BodyInput>& inputs, const Vec3& gravity = Vec3(0, 0, -9.81),
                        double dt = 0.01, long steps = 1) {
  Model model;
  std::vector<fem::BodyModel> bodies;
  std::vector<unsigned char> fixed;
  for (const auto& in : inputs) {
    const auto& m = in.mesh;
    const auto& spec = in.spec;
    fem::BodyModel b;
    b.name = in.name;
    b.mesh = m;
    b.surface = mesh::boundary_triangles(m.tets);
    b.law = spec.law;
    b.young = spec.young;
    b.poisson = spec.poisson;
    b.density = spec.density;
    b.rayleigh_mass = spec.rayleigh_mass;
    b.rayleigh_stiffness = spec.rayleigh_stiffness;
    b.psd_projection = spec.psd_projection;
    b.mass_kind = spec.mass;
    for (int i = 0; i < m.num_nodes(); ++i) {
      const unsigned char f = spec.fixed && spec.fixed(m.X.col(i)) ? 1 : 0;
      fixed.insert(fixed.end(), 3, f);
    }
    bodies.push_back(std::move(b));
  }
  fem::build_fem_model(std::move(bodies), fixed, gravity, model.fem);
  model.step.dt = dt;
  model.step.steps = steps;
  model.step.gravity = gravity;
  const int ndof = 3 * model.fem.num_nodes;
  model.initial.x = Eigen::Map<const VecX>(model.fem.X.data(), ndof);
  model.initial.v = VecX::Zero(ndof);
  return model;
}

inline Model make_model(const mesh::TetMesh& m, const BodySpec& spec, const Vec3& gravity = Vec3(0, 0, -9.81),
                        double dt = 0.01, long steps = 1) {
  return make_model(std::vector<BodyInput>{{m, spec}}, gravity, dt, steps);
}

}  // namespace softdiff::test
