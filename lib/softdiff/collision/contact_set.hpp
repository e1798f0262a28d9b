#pragma once
// The contacts of one step: what collision detection produces and what the
// contact solver, the corrected step, the output and (later) the derivatives read.
//
// Conventions (docs/method.md): contact i has a right-handed frame C_i with columns
// (t1, t2, n); n points from the second side (obstacle or second body) towards the
// first (a soft body). Its Jacobian block H_i (3 x 3n) maps node velocities to the
// relative velocity of the contact point in that frame:
//     H_i v = C_i^T sum_k weights[k] v_{nodes[k]}
// with positive weights on the first side (barycentric) and negative weights on
// the second side (minus its barycentric weights). An obstacle is static and
// contributes no column. The signed gap is < 0 when penetrating.
#include <softdiff/core/types.hpp>

#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

namespace softdiff::collision {

enum class ContactKind : std::int8_t {
  vertex_obstacle = 0,  // a surface vertex of a soft body against a static obstacle
  vertex_triangle = 1,  // a surface vertex of body A against a surface triangle of body B (or of A: self)
  edge_edge = 2,        // a surface edge of A against a surface edge of B (or of A: self)
};

// Which feature of a shape holds the closest point (for the derivatives: the active
// feature pair). For a triangle: vertex / edge / face; for a segment: vertex /
// interior (edge); for an analytic obstacle: face (plane, box face, mesh triangle),
// edge, vertex (box), or smooth (sphere, capsule, cylinder side).
enum class Feature : std::int8_t { vertex = 0, edge = 1, face = 2, smooth = 3 };

struct Contact {
  ContactKind kind = ContactKind::vertex_obstacle;
  int side_a = -1;  // index into the contact names: bodies first, then obstacles
  int side_b = -1;
  int count = 0;                            // nodes used (1: vertex-obstacle, 4: vertex-triangle or edge-edge)
  std::array<int, 4> nodes{-1, -1, -1, -1};  // global node indices
  std::array<double, 4> weights{};         // relative velocity = sum weights[k] v_{nodes[k]}
  Mat3 frame = Mat3::Identity();           // columns t1, t2, n
  Vec3 point = Vec3::Zero();               // world contact point: on side A (the vertex, or A's edge point)
  Vec3 point_b = Vec3::Zero();             // closest point on side B
  double gap = 0;                          // signed distance along n: n . (point - point_b)
  double mu = 0;                           // friction coefficient of the pair
  // Closest-feature record (which vertex / edge / triangle), for the collision-
  // detection derivatives. feature_a: the vertex node (vertex_*), or the surface
  // edge index (edge_edge). feature_b: obstacle feature index (box face 0..5 /
  // edge / vertex, mesh triangle), the surface triangle index (vertex_triangle) or
  // surface edge index (edge_edge) of side B.
  int feature_a = -1;
  int feature_b = -1;
  Feature kind_b = Feature::face;          // the kind of B's feature that holds point_b

  // Identity across steps (kind, sides, nodes): the contact stage's warm-start key.
  using Key = std::array<int, 7>;
  Key key() const { return {static_cast<int>(kind), side_a, side_b, nodes[0], nodes[1], nodes[2], nodes[3]}; }
};

// A frame built deterministically from the unit normal n: t1 is the unit projection
// of the reference axis e_k onto the plane orthogonal to n, e_k = x unless
// |n_x| > 0.8 (then y); t2 = n x t1, so that t1 x t2 = n. The frame is smooth in n
// except where |n_x| = 0.8 (normals 37 degrees from the x axis): in particular around
// every axis-aligned normal, where a "least aligned axis" rule would flip between two
// tied axes under round-off (and its derivative would not exist). t1 is then never
// closer than 37 degrees to n (|u| >= 0.6 below).
inline int frame_reference_axis(const Vec3& n) { return std::abs(n[0]) > 0.8 ? 1 : 0; }

inline Mat3 frame_from_normal(const Vec3& n) {
  const int k = frame_reference_axis(n);
  Vec3 e = Vec3::Zero();
  e[k] = 1;
  const Vec3 t1 = (e - n[k] * n).normalized();
  Mat3 C;
  C.col(0) = t1;
  C.col(1) = n.cross(t1);
  C.col(2) = n;
  return C;
}

// The contacts of a step. clear() keeps the capacity: detection refills it without
// allocating once it has grown to the largest contact count seen.
struct ContactSet {
  std::vector<Contact> contacts;
  int size() const { return static_cast<int>(contacts.size()); }
  bool empty() const { return contacts.empty(); }
  void clear() { contacts.clear(); }
};

}  // namespace softdiff::collision
