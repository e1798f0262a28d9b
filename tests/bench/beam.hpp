#pragma once
// The benchmarks' cantilever beam: 0.2 x 0.02 x 0.02 m, 10 n x n x n cells of 6 tets
// (n = 3, 6, 12: 1.6k, 13k, 104k tets), E = 1 MPa, nu = 0.45, rho = 1070, Rayleigh 0.1 /
// 0.001, clamped at x = 0, gravity -z, dt 0.01. quadratic: the same tets as 10-node
// elements (straight mid-edge nodes added by mesh::elevate_to_quadratic).
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

namespace softdiff::bench {

inline Model cantilever_beam(int n, material::Law law = material::Law::corotational, long steps = 1,
                             bool quadratic = false) {
  test::BodySpec spec;
  spec.law = law;
  spec.young = 1e6;
  spec.poisson = 0.45;
  spec.density = 1070;
  spec.rayleigh_mass = 0.1;
  spec.rayleigh_stiffness = 0.001;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  mesh::TetMesh m = test::box_mesh(10 * n, n, n, 0.2, 0.02, 0.02);
  if (quadratic) mesh::elevate_to_quadratic(m);
  return test::make_model(m, spec, Vec3(0, 0, -9.81), 0.01, steps);
}

}  // namespace softdiff::bench
