#pragma once
// Embedding of points (cable points, effectors, calibration markers) in a tetrahedral
// mesh of 4-node or 10-node tetrahedra.
//
// An embedded point is p(x) = sum_a w_a x_{nodes[a]} with sum_a w_a = 1: a fixed
// linear combination of the element's node positions (4 for a linear tet, 10 for a
// quadratic one), so p is linear in x and its Jacobian dp/dx (3 x 3n) is constant:
// the block of node nodes[a] is w_a I.
//   - Linear tets: w are the barycentric coordinates of the point in the tet.
//   - Quadratic tets (fem/tet10.hpp): w_a = N_a(xi), the quadratic shape functions at
//     the point's reference coordinates xi, the solution of X(xi) = sum_a X_a N_a(xi) = p
//     (the isoparametric map at rest). On a straight-sided tet (every mid-edge node at
//     its edge's midpoint, to 1e-12 of the tet's longest edge) the map is affine and xi
//     are the barycentric coordinates of the vertex tet; on a curved tet xi comes from
//     Newton's method on X(xi) = p started there (at most 30 iterations, stopped when
//     the update is below 1e-14; the map is close to affine on a valid element, and
//     Newton converges quadratically). Embedding::w then holds the barycentric form
//     l = (1 - u - v - w, u, v, w) of xi, and embedded_point() turns it into the ten
//     N_a(xi). Sum N_a = 1, so a rigid motion moves the point rigidly, and p reproduces
//     the point at rest exactly (to Newton's tolerance).
//
// Points inside the mesh get the containing tet and its (non-negative) weights. A
// point outside the mesh gets, as SOFA's BarycentricMapping does, the nearest tet
// (by Euclidean distance to the solid tetrahedron) and the EXTRAPOLATED barycentric
// coordinates of the point with respect to it: some weights are negative, they still
// sum to 1 and still reproduce the point exactly at rest, and the point then moves
// with that tet's deformation (affine, or the quadratic map extended). How far outside is acceptable is the caller's
// choice (LocateOptions); beyond it `locate` returns LocateStatus::too_far (it never
// throws), and the caller reports an InputError with the scene location.
#include <softdiff/core/types.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

#include <array>
#include <vector>

namespace softdiff::actuation {

struct Embedding {
  int tet = -1;                                   // column of the mesh's Tets
  Eigen::Vector4d w = Eigen::Vector4d::Zero();    // barycentric weights, sum 1 (extrapolated outside: some < 0);
                                                  // quadratic tets: the reference coordinates' barycentric form
  double outside_distance = 0;                    // distance from the point to the tet (0 inside; quadratic
                                                  // tets: measured to the straight tet through the vertices)
  int order = 1;                                  // 1: 4-node tets; 2: 10-node tets
};

enum class LocateStatus {
  inside,   // in a tet (barycentric weights >= -PointLocator::inside_tolerance)
  outside,  // outside the mesh, within the allowed distance of the nearest tet: extrapolated weights (warn)
  too_far,  // outside, further than the allowed distance: an input error for the caller
  no_tets,  // the locator holds no usable (non-degenerate) tet
};

// How far outside the mesh a point may lie: the allowed distance is
//   max(max_distance, max_relative_distance * (longest edge of the nearest tet)).
// The default (half the local element size, no absolute allowance) accepts the
// SoftRobots Trunk's cable points with a wide margin (44 of its 84 points lie outside
// the tet mesh in the narrow necks, by up to 0.81 mm = 0.10 x the nearest tet's
// longest edge) and rejects points that are clearly off the body. A caller that
// wants an absolute bound only sets max_relative_distance = 0.
struct LocateOptions {
  double max_distance = 0;            // absolute allowance (mesh units)
  double max_relative_distance = 0.5; // allowance as a fraction of the nearest tet's longest edge
};

struct LocateResult {
  LocateStatus status = LocateStatus::no_tets;
  Embedding embedding;      // filled for inside, outside and too_far (the nearest tet, for messages)
  double allowed_distance = 0;  // the bound that was applied (outside / too_far)
};

// Barycentric coordinates of p with respect to tet `tet` (columns of X indexed by
// tets(:, tet)); extrapolated when p is outside the tet. The tet must not be degenerate.
Eigen::Vector4d barycentric_weights(const Mat3X& X, const Tets& tets, int tet, const Vec3& p);

// Euclidean distance from p to the solid tetrahedron (0 inside).
double point_tet_distance(const Mat3X& X, const Tets& tets, int tet, const Vec3& p);

// Reference coordinates of p in the 10-node tet with rest node positions X_e (3, 10),
// gmsh's order, in barycentric form l = (1 - u - v - w, u, v, w): Newton's method on
// X(xi) = p from the barycentric coordinates of the vertex tet `l0`. Returns false
// (and leaves l = l0) if Newton does not converge or det J <= 0 on the way (far
// outside a curved element); exact on a straight-sided element.
bool quadratic_reference_coordinates(const Eigen::Matrix<double, 3, 10>& X_e, const Vec3& p, const Eigen::Vector4d& l0,
                                     Eigen::Vector4d& l);

// The ten quadratic shape functions at barycentric coordinates l (gmsh's order).
Eigen::Matrix<double, 10, 1> quadratic_weights(const Eigen::Vector4d& l);

// Finds the tet containing a point, or the nearest one. Built once from rest
// positions X (3, n) and tets (4, m) (it keeps its own copy), and for a quadratic
// mesh its 10-node tets (10, m) (rows 0-3 == tets): a curved tet's box then covers its
// ten nodes, and a point is inside a tet when its reference coordinates are (weights
// of a curved tet come from quadratic_reference_coordinates). Uses a uniform grid over
// the tets' bounding boxes (about one cell per tet; each cell lists the tets whose box
// overlaps it). A point inside the grid is first tested against the tets of its own
// cell (every tet containing the point is listed there); otherwise, or if none
// contains it, the cells are visited in shells of growing Chebyshev radius around the
// point's (clamped) cell, stopping once the shell's lower distance bound exceeds the
// best distance found. Degenerate tets (|det| <= 1e-14 edge^3) are never returned.
// Ties (a point whose nearest feature is a vertex or edge shared by several tets, or a
// point on a face shared by two tets) go to the candidate whose smallest weight is
// largest (the least extrapolated), then to the first in grid order. Thread-safe:
// locate is const and uses no shared scratch.
class PointLocator {
 public:
  // Barycentric tolerance: a point whose smallest weight is >= -inside_tolerance is
  // inside (points on faces, up to rounding).
  static constexpr double inside_tolerance = 1e-10;

  PointLocator(const Mat3X& X, const Tets& tets);
  PointLocator(const Mat3X& X, const Tets& tets, const mesh::Tets10& tets10);

  LocateResult locate(const Vec3& p, const LocateOptions& options = {}) const;

  int num_tets() const { return static_cast<int>(tets_.cols()); }
  const Mat3X& rest_positions() const { return X_; }
  const Tets& tets() const { return tets_; }
  int order() const { return tets10_.cols() > 0 ? 2 : 1; }
  const mesh::Tets10& tets10() const { return tets10_; }  // (10, m) order 2, else empty
  Eigen::Vector3i grid_size() const { return dims_; }

 private:
  struct Candidate {
    int tet = -1;
    double distance = 0, min_weight = 0;
    Eigen::Vector4d w = Eigen::Vector4d::Zero();
  };
  void evaluate(int tet, const Vec3& p, Candidate& c) const;
  bool better(const Candidate& a, const Candidate& b) const;  // a strictly preferred to b
  Eigen::Vector3i cell_of(const Vec3& p) const;                // clamped to the grid
  double cell_distance(const Vec3& p, int ix, int iy, int iz) const;
  void visit_cell(int cell, const Vec3& p, Candidate& best) const;

  void build();

  Mat3X X_;
  Tets tets_;
  mesh::Tets10 tets10_;                   // (10, m) order 2 only
  std::vector<unsigned char> curved_;  // (m) order 2: 1 if a mid-edge node is off its edge's midpoint
  std::vector<Mat3> Dm_inv_;        // (m) inverse of [X1-X0, X2-X0, X3-X0]
  std::vector<unsigned char> usable_;  // (m) 0 for degenerate tets
  Mat3X box_min_, box_max_;         // (3, m) tet bounding boxes
  Vec3 origin_ = Vec3::Zero();      // grid lower corner
  double h_ = 1;                    // cell size (cubic cells)
  Eigen::Vector3i dims_ = Eigen::Vector3i::Ones();
  std::vector<int> cell_begin_;     // (cells + 1)
  std::vector<int> cell_tets_;      // tets overlapping each cell
  double tie_distance_ = 0;         // distances closer than this are ties
  int usable_count_ = 0;
};

// A point embedded in a body: global node indices (the body's local tet nodes plus
// the body's first global node) and weights; `count` nodes (4 for a linear tet, 10
// for a quadratic one), the rest of the fixed-size arrays unused (nodes -1, w 0).
struct EmbeddedPoint {
  static constexpr int max_nodes = 10;
  std::array<int, max_nodes> nodes{-1, -1, -1, -1, -1, -1, -1, -1, -1, -1};
  Eigen::Matrix<double, max_nodes, 1> w = Eigen::Matrix<double, max_nodes, 1>::Zero();
  int count = 4;

  // p(x) = sum_a w_a x_{nodes[a]}; also J dx for a displacement dx (p is linear).
  Vec3 position(const VecX& x) const {
    Vec3 p = w[0] * x.segment<3>(3 * nodes[0]);
    for (int a = 1; a < count; ++a) p += w[a] * x.segment<3>(3 * nodes[a]);
    return p;
  }
  // out += J^T g: node nodes[a] receives w_a g.
  void add_transpose(const Vec3& g, VecX& out) const {
    for (int a = 0; a < count; ++a) out.segment<3>(3 * nodes[a]) += w[a] * g;
  }
};

// A linear tet's embedding (e.order must be 1).
EmbeddedPoint embedded_point(const Embedding& e, const Tets& tets, int node_offset);
// A quadratic tet's embedding (e.order must be 2): weights N_a(xi).
EmbeddedPoint embedded_point(const Embedding& e, const mesh::Tets10& tets10, int node_offset);
// The embedding of a point located by `locator`, in the locator's element order.
EmbeddedPoint embedded_point(const Embedding& e, const PointLocator& locator, int node_offset);

}  // namespace softdiff::actuation
