#pragma once
// Shared fixtures of the actuation tests: jittered box meshes, deformed positions,
// and the box's boundary faces found geometrically (independently of the library).
#include <softdiff/actuation/cable.hpp>
#include <softdiff/actuation/pressure.hpp>
#include <softdiff/actuation/servo.hpp>
#include <softdiff/core/types.hpp>
#include <support/meshes.hpp>

#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <random>
#include <vector>

namespace softdiff::test {

// box_mesh with its interior nodes moved randomly by up to `amplitude` times the
// cell size along each axis (boundary nodes stay on the box faces).
inline mesh::TetMesh jittered_box(int nx, int ny, int nz, double lx, double ly, double lz, double amplitude,
                                  std::mt19937& rng) {
  mesh::TetMesh m = box_mesh(nx, ny, nz, lx, ly, lz);
  std::uniform_real_distribution<double> u(-amplitude, amplitude);
  const Vec3 cell(lx / nx, ly / ny, lz / nz), size(lx, ly, lz);
  for (int i = 0; i < m.num_nodes(); ++i) {
    Vec3 p = m.X.col(i);
    bool interior = true;
    for (int c = 0; c < 3; ++c) interior = interior && p[c] > 1e-9 * size[c] && p[c] < size[c] * (1 - 1e-9);
    if (interior)
      for (int c = 0; c < 3; ++c) p[c] += u(rng) * cell[c];
    m.X.col(i) = p;
  }
  return m;
}

// box_mesh elevated to 10-node tets (mesh::elevate_to_quadratic) with every mid-edge
// node moved randomly by up to `amplitude` times the cell size along each axis: curved
// edges and faces, the boundary's included (the vertices stay on the box). Amplitudes
// up to ~0.1 keep det J > 0 everywhere (tests check with tet10::min_det_jacobian).
inline mesh::TetMesh curved_box(int nx, int ny, int nz, double lx, double ly, double lz, double amplitude,
                                std::mt19937& rng) {
  mesh::TetMesh m = box_mesh(nx, ny, nz, lx, ly, lz);
  const int vertices = m.num_nodes();
  mesh::elevate_to_quadratic(m);
  std::uniform_real_distribution<double> u(-amplitude, amplitude);
  const Vec3 cell(lx / nx, ly / ny, lz / nz);
  for (int i = vertices; i < m.num_nodes(); ++i)
    for (int c = 0; c < 3; ++c) m.X(c, i) += u(rng) * cell[c];
  return m;
}

inline VecX flatten(const Mat3X& X) { return Eigen::Map<const VecX>(X.data(), X.size()); }

// A smooth random deformation (rotation, stretch, bending) plus small noise of size
// `noise` (absolute), applied to rest positions x (3n).
inline VecX deform(const VecX& x, double noise, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  const Mat3 R = Eigen::AngleAxisd(0.7 * u(rng), Vec3(u(rng), u(rng), u(rng)).normalized()).toRotationMatrix();
  Mat3 S = Mat3::Identity();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) S(i, j) += 0.15 * u(rng);
  VecX y(x.size());
  for (Eigen::Index i = 0; i < x.size() / 3; ++i) {
    const Vec3 p = x.segment<3>(3 * i);
    Vec3 q = R * S * p;
    q[2] += 3.0 * p[0] * p[0];  // bending (x in meters, sizes ~ 0.01-0.1)
    for (int c = 0; c < 3; ++c) q[c] += noise * u(rng);
    y.segment<3>(3 * i) = q;
  }
  return y;
}

// Boundary faces of a box mesh found geometrically: tet faces whose three nodes lie
// on one side plane of the box [0, lx] x [0, ly] x [0, lz], oriented with the normal
// out of the box. side in {0..5} = -x, +x, -y, +y, -z, +z; side = -1: all sides.
inline Triangles box_boundary(const mesh::TetMesh& m, const Vec3& size, int side = -1) {
  static constexpr int faces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  std::vector<std::array<int, 3>> out;
  const double tol = 1e-9 * size.maxCoeff();
  for (int e = 0; e < m.num_tets(); ++e)
    for (const auto& f : faces) {
      std::array<int, 3> t = {m.tets(f[0], e), m.tets(f[1], e), m.tets(f[2], e)};
      for (int s = 0; s < 6; ++s) {
        if (side >= 0 && s != side) continue;
        const int c = s / 2;
        const double plane = (s % 2) ? size[c] : 0.0;
        bool on = true;
        for (int a = 0; a < 3; ++a) on = on && std::abs(m.X(c, t[a]) - plane) < tol;
        if (!on) continue;
        const Vec3 n = (m.X.col(t[1]) - m.X.col(t[0])).cross(m.X.col(t[2]) - m.X.col(t[0]));
        if ((n[c] > 0) != (s % 2 == 1)) std::swap(t[1], t[2]);  // outward
        out.push_back(t);
      }
    }
  Triangles T(3, static_cast<int>(out.size()));
  for (size_t k = 0; k < out.size(); ++k)
    for (int a = 0; a < 3; ++a) T(a, static_cast<int>(k)) = out[k][a];
  return T;
}

// Sum of signed tet volumes at positions x.
inline double mesh_volume(const Tets& tets, const VecX& x) {
  double V = 0;
  for (int e = 0; e < tets.cols(); ++e) {
    Mat3 D;
    for (int k = 0; k < 3; ++k) D.col(k) = x.segment<3>(3 * tets(k + 1, e)) - x.segment<3>(3 * tets(0, e));
    V += D.determinant() / 6;
  }
  return V;
}

// One of each actuator on a jittered 0.03 x 0.02 x 0.02 m box: a 3-point cable with a
// pull point, the whole boundary as a closed cavity, a translation servo on 4 nodes.
struct ActuatorSet {
  Vec3 size{0.03, 0.02, 0.02};
  mesh::TetMesh mesh;
  VecX x_rest;
  std::vector<actuation::EmbeddedPoint> points;
  actuation::Cable cable;
  actuation::Cavity cavity;
  actuation::Servo translation;
  bool ok = false;  // the cavity and the servo were created

  explicit ActuatorSet(std::mt19937& rng, const Vec3& servo_direction = Vec3::UnitX())
      : mesh(jittered_box(3, 2, 2, size[0], size[1], size[2], 0.2, rng)),
        x_rest(flatten(mesh.X)),
        points(embed({Vec3(0.001, 0.01, 0.01), Vec3(0.015, 0.017, 0.006), Vec3(0.029, 0.003, 0.009)})),
        cable(points, Vec3(-0.01, 0.01, 0.01)) {
    ok = actuation::Cavity::create(mesh.X, mesh.tets, box_boundary(mesh, size), 0, cavity).ok() &&
         actuation::Servo::translation({0, 1, 2, 5}, servo_direction, x_rest, translation).ok();
  }

 private:
  std::vector<actuation::EmbeddedPoint> embed(const std::vector<Vec3>& ps) const {
    const actuation::PointLocator locator(mesh.X, mesh.tets);
    std::vector<actuation::EmbeddedPoint> out;
    for (const Vec3& p : ps) out.push_back(actuation::embedded_point(locator.locate(p).embedding, mesh.tets, 0));
    return out;
  }
};

}  // namespace softdiff::test
