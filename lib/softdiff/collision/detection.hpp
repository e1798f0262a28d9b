#pragma once
// Collision detection: the contacts of a configuration x, with a margin.
//   - surface vertices of soft bodies against static obstacles (obstacle.hpp);
//   - vertex against triangle, and edge against edge, between two soft bodies and,
//     with self-collision, within one body (skipping a vertex's incident triangles
//     and its one-ring, and edges that share a vertex);
// Broad phase: FCL dynamic AABB trees over each body's deforming surface (refitted
// every call) and the static obstacles' boxes (built once). Narrow phase: exact
// closest points with barycentric weights and the closest-feature record.
#include <softdiff/collision/contact_set.hpp>
#include <softdiff/collision/obstacle.hpp>
#include <softdiff/core/types.hpp>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace softdiff::collision {

// The outward boundary surface of one soft body, in global node indices.
struct BodySurface {
  std::string name;
  Triangles triangles;          // (3, k) outward, global node indices
  // Filled by prepare_surface(): the surface vertices (sorted) and the unique edges
  // (2, m). (The detector builds its own adjacency: edge-triangle, one-rings.)
  std::vector<int> vertices;
  Eigen::Matrix<int, 2, Eigen::Dynamic> edges;
  // A rigid body's surface only (mark_planar_edges; empty for a soft body's): 1 where
  // edge e is a diagonal inside a planar face (its two triangles coplanar to round-off),
  // for the contact step's O(1) test of an edge-edge contact (contact_step.cpp).
  std::vector<std::uint8_t> planar_edge;
};
void prepare_surface(BodySurface& surface);
// Fills surface.planar_edge (one flag per surfaces.edges column) from the surface's
// fixed vertex positions (a rigid body's local vertices; vertex k is node node_begin + k):
// the two triangles of the edge have unit normals n0, n1 with n0 . n1 > 0 and
// |n0 x n1|^2 < 1e-20.
void mark_planar_edges(BodySurface& surface, const Mat3X& local_vertices, int node_begin);
// The prepared surface of a body from its boundary triangles in local node indices
// (the body's nodes start at node_begin in the global numbering).
BodySurface make_surface(const std::string& name, const Triangles& local_triangles, int node_begin);

// Which pairs collide, and with which friction coefficient. Sides are indices into
// `names` = bodies then obstacles (Contact::side_a/side_b).
struct PairRule {
  int a = -1, b = -1;  // a: a body; b: an obstacle, another body, or a (self-collision)
  double mu = 0;
};

struct DetectionModel {
  std::vector<BodySurface> surfaces;  // one per soft body, in body order
  std::vector<Obstacle> obstacles;    // prepared
  std::vector<PairRule> pairs;
  double margin = 1e-3;               // pairs closer than this (signed distance) become contacts
  std::vector<std::string> names;     // bodies then obstacles

  // The largest friction coefficient of the pair rules with `side` (a surface or obstacle
  // index, as PairRule's a and b) on either side; 0 if none.
  double max_friction(int side) const {
    double mu = 0;
    for (const auto& rule : pairs)
      if (rule.a == side || rule.b == side) mu = mu > rule.mu ? mu : rule.mu;
    return mu;
  }
};

struct DetectionStats {
  int candidates = 0;  // broad-phase pairs examined by the narrow phase
  int contacts = 0;
};

class CollisionDetector {
 public:
  explicit CollisionDetector(const DetectionModel& model);
  ~CollisionDetector();
  // Fills `out` (cleared first) with every contact of configuration x (3n, node-major),
  // in a deterministic order (by pair rule, then kind, then feature indices).
  DetectionStats detect(const VecX& x, ContactSet& out);
  // The same with another margin than the model's (the contact step widens it by the
  // step's predicted motion: contact_step.cpp).
  DetectionStats detect(const VecX& x, ContactSet& out, double margin);
  // The same with a margin per surface (surface_margin[k] for surfaces[k], each >= the
  // model's): a pair of surfaces a, b uses max(m_a, m_b) (a self pair m_a), a surface
  // against an obstacle m_a. The contact step widens each surface's margin by its own
  // predicted motion (contact_step.cpp), so that a fast body (a free rigid body falling
  // onto its support) does not widen the slow bodies' self-contact search. The broad
  // phase inflates surface k's boxes by m_k - mu / 2 (mu = min_k m_k): two boxes then
  // overlap whenever their triangles are within max(m_a, m_b) (m_a + m_b - mu >= that),
  // and with equal margins this is the single margin's m / 2.
  DetectionStats detect(const VecX& x, ContactSet& out, const std::vector<double>& surface_margin);
  // Moving planes (Obstacle::offset_schedule): the detector's copies take their offsets
  // at time t (the contact stage passes the step's end time t_{n+1}; the static solver
  // its load step's time). Obstacles without a schedule are unchanged.
  void set_time(double t);
  // Some obstacle has an offset schedule.
  bool has_moving_obstacles() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace softdiff::collision
