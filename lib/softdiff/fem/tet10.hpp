#pragma once
// The quadratic (10-node) tetrahedron: shape functions in gmsh's node order and the
// quadrature rules that integrate over it (method.md, "Quadratic tetrahedra").
//
// Reference tet: vertices (0,0,0), (1,0,0), (0,1,0), (0,0,1) in xi = (u, v, w), volume
// 1/6; barycentric coordinates l = (1 - u - v - w, u, v, w). Nodes 0-3 are the vertices,
// node 4 + k the midpoint of edge k = mesh::kTet10Edge[k] (gmsh: 01, 12, 20, 30, 32, 31):
//   N_a = l_a (2 l_a - 1) (a < 4),   N_{4+k} = 4 l_i l_j (edge k = (i, j)).
// The geometry is isoparametric: X(xi) = sum_a X_a N_a(xi), so curved (gmsh -order 2)
// elements are exact.
//
// Quadrature (weights sum to 1/6, the reference volume; all weights positive):
//   - kStiffnessRule: 4 points, exact for polynomials of degree 2. On a straight-sided
//     element the linear law's integrand B^T C B is of degree 2 (B is linear in xi),
//     so K is exact; it is also CalculiX C3D10's rule for the stiffness, which the
//     same-mesh comparison reproduces. The nonlinear laws use the same points (the
//     usual choice; a degree-2 rule does not underintegrate: K has the rank 30 - 6).
//   - kMassRule: 14 points, exact for degree 5 (Walkington's rule). The consistent
//     mass N_a N_b is of degree 4 on a straight-sided element (exact), and the
//     consistent gravity N_a of degree 2; on a curved element det J adds degree 3,
//     and the rule is then accurate to the size of the curvature squared.
// Validity (io::read_gmsh) is det J > 0 at every point of both rules.
#include <softdiff/core/types.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

#include <array>

namespace softdiff::fem::tet10 {

constexpr int kNodes = 10;

struct QuadraturePoint {
  double u, v, w, weight;
};

// 4-point degree-2 rule: a = (5 + 3 sqrt 5) / 20, b = (5 - sqrt 5) / 20.
inline constexpr double kA2 = 0.5854101966249685, kB2 = 0.1381966011250105;
inline constexpr std::array<QuadraturePoint, 4> kStiffnessRule = {{
    {kB2, kB2, kB2, 1.0 / 24.0},
    {kA2, kB2, kB2, 1.0 / 24.0},
    {kB2, kA2, kB2, 1.0 / 24.0},
    {kB2, kB2, kA2, 1.0 / 24.0},
}};

// 14-point degree-5 rule (P. Walkington / Jaskowiec and Sukumar's tables): two orbits of
// 4 points (a, a, a, 1 - 3a) and one of 6 points (b, b, 1/2 - b, 1/2 - b).
inline constexpr double kM_a1 = 0.0927352503108912, kM_w1 = 0.01224884051939366;
inline constexpr double kM_a2 = 0.3108859192633006, kM_w2 = 0.01878132095300264;
inline constexpr double kM_b = 0.0455037041256496, kM_w3 = 0.007091003462846911;
inline constexpr double kM_c1 = 1.0 - 3.0 * kM_a1, kM_c2 = 1.0 - 3.0 * kM_a2, kM_d = 0.5 - kM_b;
inline constexpr std::array<QuadraturePoint, 14> kMassRule = {{
    {kM_a1, kM_a1, kM_a1, kM_w1}, {kM_c1, kM_a1, kM_a1, kM_w1}, {kM_a1, kM_c1, kM_a1, kM_w1}, {kM_a1, kM_a1, kM_c1, kM_w1},
    {kM_a2, kM_a2, kM_a2, kM_w2}, {kM_c2, kM_a2, kM_a2, kM_w2}, {kM_a2, kM_c2, kM_a2, kM_w2}, {kM_a2, kM_a2, kM_c2, kM_w2},
    // (l0, l1, l2, l3) over the 6 placements of {b, b, d, d}; (u, v, w) = (l1, l2, l3).
    {kM_b, kM_d, kM_d, kM_w3},  // l = (b, b, d, d)
    {kM_d, kM_b, kM_d, kM_w3},  // (b, d, b, d)
    {kM_d, kM_d, kM_b, kM_w3},  // (b, d, d, b)
    {kM_b, kM_b, kM_d, kM_w3},  // (d, b, b, d)
    {kM_b, kM_d, kM_b, kM_w3},  // (d, b, d, b)
    {kM_d, kM_b, kM_b, kM_w3},  // (d, d, b, b)
}};

// Shape functions at xi.
template <class T>
Eigen::Matrix<T, kNodes, 1> shape(const T& u, const T& v, const T& w) {
  const T l[4] = {T(1) - u - v - w, u, v, w};
  Eigen::Matrix<T, kNodes, 1> N;
  for (int a = 0; a < 4; ++a) N(a) = l[a] * (T(2) * l[a] - T(1));
  for (int k = 0; k < 6; ++k) N(4 + k) = T(4) * l[mesh::kTet10Edge[k][0]] * l[mesh::kTet10Edge[k][1]];
  return N;
}

// dN/dxi at xi: row a is the gradient of N_a with respect to (u, v, w).
inline Eigen::Matrix<double, kNodes, 3> shape_gradients_ref(double u, double v, double w) {
  const double l[4] = {1.0 - u - v - w, u, v, w};
  // dl/dxi: l0 -> (-1,-1,-1), l1 -> e_u, l2 -> e_v, l3 -> e_w.
  static constexpr double dl[4][3] = {{-1, -1, -1}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  Eigen::Matrix<double, kNodes, 3> dN;
  for (int a = 0; a < 4; ++a)
    for (int c = 0; c < 3; ++c) dN(a, c) = (4.0 * l[a] - 1.0) * dl[a][c];
  for (int k = 0; k < 6; ++k) {
    const int i = mesh::kTet10Edge[k][0], j = mesh::kTet10Edge[k][1];
    for (int c = 0; c < 3; ++c) dN(4 + k, c) = 4.0 * (dl[i][c] * l[j] + l[i] * dl[j][c]);
  }
  return dN;
}

// J = dX/dxi = X_e dN (3 x 3) for the element's 10 node positions X_e (3 x 10).
inline Mat3 jacobian(const Eigen::Matrix<double, 3, kNodes>& X_e, const Eigen::Matrix<double, kNodes, 3>& dN) {
  return X_e * dN;
}

// The smallest det J over the points of both rules (validity: > 0) and, in `where`,
// the index of that point (0-3 stiffness rule, 4-17 mass rule).
inline double min_det_jacobian(const Eigen::Matrix<double, 3, kNodes>& X_e, int* where = nullptr) {
  double lo = 0;
  int k = 0, at = -1;
  auto visit = [&](const QuadraturePoint& q) {
    const double d = jacobian(X_e, shape_gradients_ref(q.u, q.v, q.w)).determinant();
    if (at < 0 || d < lo) lo = d, at = k;
    ++k;
  };
  for (const auto& q : kStiffnessRule) visit(q);
  for (const auto& q : kMassRule) visit(q);
  if (where) *where = at;
  return lo;
}

}  // namespace softdiff::fem::tet10
