#pragma once
// Builds a one-body Model in code (no scene file), for unit and validation tests.
#include <softdiff/mesh/tet_mesh.hpp>
#include <softdiff/model.hpp>

#include <functional>

namespace softdiff::test {

struct BodySpec {
  material::Law law = material::Law::corotational;
  double young = 1e5, poisson = 0.3, density = 1000;
  double rayleigh_mass = 0, rayleigh_stiffness = 0;
  bool psd_projection = false;
  fem::MassKind mass = fem::MassKind::lumped;
  std::function<bool(const Vec3&)> fixed;  // nodes where this is true are fixed (all axes)
};

inline Model make_model(const mesh::TetMesh& m, const BodySpec& spec, const Vec3& gravity = Vec3(0, 0, -9.81),
                        double dt = 0.01, long steps = 1) {
  Model model;
  fem::BodyModel b;
  b.name = "body";
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
  std::vector<unsigned char> fixed(3 * m.num_nodes(), 0);
  if (spec.fixed)
    for (int i = 0; i < m.num_nodes(); ++i)
      if (spec.fixed(m.X.col(i))) fixed[3 * i] = fixed[3 * i + 1] = fixed[3 * i + 2] = 1;
  std::vector<fem::BodyModel> bodies;
  bodies.push_back(std::move(b));
  fem::build_fem_model(std::move(bodies), fixed, gravity, model.fem);
  model.step.dt = dt;
  model.step.steps = steps;
  model.step.gravity = gravity;
  const int ndof = 3 * model.fem.num_nodes;
  model.initial.x = Eigen::Map<const VecX>(model.fem.X.data(), ndof);
  model.initial.v = VecX::Zero(ndof);
  return model;
}

}  // namespace softdiff::test
