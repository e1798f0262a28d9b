#pragma once
// Collision-detection derivatives (method.md "Derivatives"; sibling of detection.hpp):
// how a contact's normal, frame, signed gap and barycentric weights move with the
// positions of its nodes, for the active feature pair recorded in the Contact
// (implicit differentiation of the closest-point optimality conditions).
//
// contact_geometry() recomputes the geometry of a recorded contact at positions x
// with the same rules as the detector (its feature pair and its orientation held
// fixed); contact_geometry_derivative() is its exact derivative. For contact i with
// nodes k = 0..count-1, column 3k + c is the coordinate c of node k.
//
// Feature pairs (A: the first side, B: the second; s the orientation sign, +-1):
//   vertex-obstacle  gap = signed distance, n = its gradient: dgap = n^T, dn = the
//                    obstacle's normal derivative (obstacle.hpp normal_derivative).
//   vertex-face      n = s N, N = (b - a) x (c - a) / |.|, gap = n . (p - a), weights
//                    (1, -bary), bary of the projection: [v w] = G^{-1} E^T (p - a),
//                    E = [b - a, c - a], G = E^T E.
//   vertex-edge      q = a + t (b - a), t = (p - a).e / |e|^2; n = s (p - q)/|p - q|;
//                    dgap = n . (dp - (1 - t) da - t db) (the envelope theorem: n ⊥ e).
//   vertex-vertex    n = s (p - q)/|p - q|, dgap = n . (dp - dq).
//   edge-edge        (interior closest points) n = s (d1 x d2)/|d1 x d2|, which is
//                    parallel to p(s) - q(t) there; gap = n . (p(s) - q(t)), dgap =
//                    n . (dp0 + s dd1 - dq0 - t dd2); (s, t) from the optimality
//                    conditions d1 . r = d2 . r = 0 (a 2x2 system).
// The frame follows n through frame_from_normal (its reference axis k is locally
// constant): t1 = u / |u|, u = e_k - n_k n; t2 = n x t1.
// Where a derivative does not exist (n undefined: zero distance at a vertex or edge
// region; the closest point on a region boundary; parallel edges) the functions return
// false: the caller must treat the contact as non-differentiable (randomized smoothing
// is the subject of a later change).
#include <softdiff/collision/contact_set.hpp>
#include <softdiff/collision/obstacle.hpp>

namespace softdiff::collision {

struct ContactGeometry {
  Vec3 n = Vec3::Zero();
  double gap = 0;
  std::array<double, 4> weights{};
  Mat3 frame = Mat3::Identity();
};

struct ContactGeometryDerivative {
  int count = 0;                         // nodes (columns 3 count are used)
  Eigen::Matrix<double, 3, 12> dn;       // d n / d x_nodes
  Eigen::Matrix<double, 1, 12> dgap;     // d gap / d x_nodes
  Eigen::Matrix<double, 4, 12> dweights; // d weights / d x_nodes
  Eigen::Matrix<double, 9, 12> dframe;   // d vec(frame) / d x_nodes (column-major: t1, t2, n)
};

// The geometry of contact c at positions x (its feature pair and orientation held).
// obstacle: the obstacle of a vertex-obstacle contact (nullptr otherwise). Returns
// false where it is undefined (see above).
bool contact_geometry(const Contact& c, const VecX& x, const Obstacle* obstacle, ContactGeometry& out);

// Its derivative at x.
bool contact_geometry_derivative(const Contact& c, const VecX& x, const Obstacle* obstacle,
                                 ContactGeometryDerivative& out);

// d vec(frame_from_normal(n)) for dn (3 x m): (9 x m).
Eigen::Matrix<double, 9, Eigen::Dynamic> frame_derivative(const Vec3& n, const Eigen::Matrix<double, 3, Eigen::Dynamic>& dn);

}  // namespace softdiff::collision
