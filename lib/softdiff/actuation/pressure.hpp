#pragma once
// Pressure actuator (method.md "Actuation Jacobians"): a cavity is a set of boundary
// triangles of one body (a Gmsh physical group, any orientation in the file).
//
// Orientation. Each triangle (a, b, c) is stored oriented INTO THE SOLID: its normal
// (b - a) x (c - a) is opposite to the body's outward boundary normal there (the
// outward side of a boundary face is the side away from the face's one tet). Its area
// vector n = (b - a) x (c - a) / 2 therefore points into the material, and the
// pressure force p n (p > 0) pushes the wall into the solid: the cavity inflates.
//
// H_a: each triangle's area vector, one third to each of its three nodes:
// H_a[node i] = sum over the triangles containing i of n_t / 3. This is translation
// invariant and defined for open faces too. For a CLOSED cavity (every edge shared
// by exactly two cavity triangles, traversed once in each direction) it equals
// dV/dx, where
//
//     V(x) = sum_t (1/6) a_t . (b_t x c_t)
//
// is the enclosed volume, positive for the into-the-solid orientation: for a cavity
// (a void inside the body) "into the solid" is "out of the void", i.e. the void's
// outward normal, and the divergence theorem gives V = +|void|. Proof that
// dV/dx = H_a: d/da of (1/6) a.(b x c) is (1/6) b x c, while n/3 = (1/6)(a x b +
// b x c + c x a); the difference (1/6) a x (b - c) summed over the ring of triangles
// (a, v_j, v_{j+1}) around node a telescopes to (1/6) a x sum_j (v_j - v_{j+1}) = 0
// on a closed ring. (Test: the whole outer boundary of a box taken as a "cavity" is
// oriented inward, into the box, and gives V = -(box volume).) For an open face V is
// not defined (it would depend on the origin); volume() requires a closed cavity.
//
// Quadratic bodies: 6-node triangles (a, b, c, m_ab, m_bc, m_ca), gmsh's order, whose
// surface x(xi, eta) = sum_i N_i(xi, eta) x_i is the quadratic (possibly curved) face
// of the 10-node tet. With the area-vector density n(xi, eta) = x_xi x x_eta (the
// same orientation, into the solid, as for 3-node triangles):
//
//     V(x)      = (1/3) sum_t int_T (x - o) . n dxi deta     (divergence theorem)
//     H_a[i]    = sum_t int_T N_i n dxi deta                 (the consistent pressure load)
//
// and for a closed cavity H_a = dV/dx exactly: the variation of the enclosed volume
// of a closed continuous surface is int dx . n dA (the other two terms of dV
// integrate by parts to twice this, around a closed surface). Both integrands are
// polynomials of degree 4 in (xi, eta) (x and N_i of degree 2, x_xi and x_eta of
// degree 1), so the 6-point degree-4 triangle rule (Strang and Fix; Dunavant's
// degree-4 rule, positive weights) integrates them exactly, and V, H_a and
// d(H_a^T p)/dx = p sum_t int N_i (dx_xi x x_eta + x_xi x dx_eta) are exact for the
// curved quadratic surface, not an approximation of it. On a straight (flat)
// 6-node triangle the load is n/3 on each mid-edge node and 0 on the vertices.
//
// Every evaluation is allocation-free.
#include <softdiff/core/types.hpp>

#include <array>
#include <string>
#include <vector>

namespace softdiff::actuation {

enum class CavityError {
  none,
  empty,         // no triangle
  bad_index,     // a node index outside [0, n)
  not_boundary,  // not a face of any tet (tets_sharing = 0) or an interior face (2)
  duplicate,     // the same face listed twice
};

struct CavityStatus {
  CavityError error = CavityError::none;
  int triangle = -1;             // column of the input Triangles at fault
  std::array<int, 3> nodes{};    // its (local) node indices, as given
  int tets_sharing = 0;          // not_boundary: how many tets have this face
  bool ok() const { return error == CavityError::none; }
  std::string message() const;   // e.g. "triangle 3 (nodes 4, 9, 12) is an interior face ..."
};

class Cavity {
 public:
  // triangles (3, k): node indices local to the body whose rest positions X (3, n)
  // and tets (4, m) are given (any tet orientation); node_offset: global index of
  // the body's node 0. On error `out` is left empty and the status names the triangle.
  // quadratic: for a quadratic body, the 6-node triangles (6, k) of `triangles` (rows
  // 0-2 equal to them; mesh::quadratic_triangles), whose mid-edge nodes follow the
  // triangles' orientation; nullptr for 3-node triangles.
  static CavityStatus create(const Mat3X& X, const Tets& tets, const Triangles& triangles, int node_offset,
                             Cavity& out, const Eigen::Matrix<int, 6, Eigen::Dynamic>* quadratic = nullptr);

  int num_triangles() const { return static_cast<int>(triangles_.cols()); }
  const Triangles& triangles() const { return triangles_; }  // global vertex nodes, oriented into the solid
  int order() const { return triangles6_.cols() > 0 ? 2 : 1; }
  // (6, k) order 2: global nodes in gmsh's order, oriented into the solid (rows 0-2 == triangles()).
  const Eigen::Matrix<int, 6, Eigen::Dynamic>& triangles6() const { return triangles6_; }
  bool closed() const { return num_open_edges_ == 0 && triangles_.cols() > 0; }
  int num_open_edges() const { return num_open_edges_; }     // edges not paired by an opposite edge

  // V(x) (closed cavity only: SOFTDIFF_DEMAND).
  double volume(const VecX& x) const;

  // f += scale * p * H_a^T.
  void add_force(const VecX& x, double p, double scale, VecX& f) const;
  // H = H_a^T (overwritten; sized like x).
  void gradient(const VecX& x, VecX& H) const;
  // Sparse form: sorted distinct global nodes, values (3, nodes().size()) sized by the caller.
  const std::vector<int>& nodes() const { return nodes_; }
  void gradient_sparse(const VecX& x, Mat3X& values) const;
  // out += d(H_a^T p)/dx . dx (exact): each node of triangle t gets p/3 dn_t with
  // dn = ((db - da) x (c - a) + (b - a) x (dc - da)) / 2. For a closed cavity this is
  // p (d^2V/dx^2) dx (symmetric); for an open face it is not symmetric in general.
  void add_force_derivative(const VecX& x, double p, const VecX& dx, VecX& out) const;
  // out += (d(H_a^T p)/dx)^T y: per triangle, with Y = y_a + y_b + y_c (the three nodes
  // get the same dn_t / 3), Y . dn_t = (p/2) [de1 . (e2 x Y) + de2 . (Y x e1)].
  void add_force_derivative_transpose(const VecX& x, double p, const VecX& y, VecX& out) const;

 private:
  void check_sizes(const VecX& x, const VecX& out) const;

  double volume6(const VecX& x) const;
  void add_force6(const VecX& x, double p, double scale, VecX& f) const;
  void add_force_derivative6(const VecX& x, double p, const VecX& dx, VecX& out) const;
  void add_force_derivative_transpose6(const VecX& x, double p, const VecX& y, VecX& out) const;

  Triangles triangles_;                    // (3, k) global nodes, oriented into the solid
  Eigen::Matrix<int, 6, Eigen::Dynamic> triangles6_;  // (6, k) order 2 only
  std::vector<int> nodes_;                 // sorted distinct global nodes (mid-edge nodes included)
  std::vector<std::array<int, 6>> slots_;  // (k) position in nodes_ of each triangle's nodes (3 or 6)
  int num_open_edges_ = 0;
  long min_size_ = 0;
};

}  // namespace softdiff::actuation
