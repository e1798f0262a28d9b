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
// region; parallel edges) the exact functions return false. On the boundary between
// two regions (a vertex exactly over an edge of a triangle, the closest point of a box
// on one of its edges, edges crossing at an endpoint) the one-sided derivatives differ.
//
// Randomized smoothing (the smoothing overload; Montaut et al., "Differentiable
// collision detection: a randomized smoothing approach", ICRA 2023, their first-order
// estimator with a Gaussian perturbation): the contact's nodes are perturbed by
// sigma z_j, z_j ~ N(0, I) (j = 1..samples, replayed from a seed derived from
// options.seed and the contact's identity, so that the result does not depend on the
// contact order or the threads). If the active feature pair is the same at every
// sample (and the exact derivative exists), the exact derivative is returned;
// otherwise the mean over the samples of the exact derivative of the feature pair
// active at that sample, which estimates the derivative of the smoothed geometry
// E[g(x + sigma z)] (g is continuous and piecewise smooth, so the mean of the
// derivatives is the derivative of the mean). Its sampling error is of order
// (spread of the one-sided derivatives) / sqrt(samples).
#include <softdiff/collision/contact_set.hpp>
#include <softdiff/collision/obstacle.hpp>

#include <cstdint>

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

// Its derivative at x (false where it does not exist).
bool contact_geometry_derivative(const Contact& c, const VecX& x, const Obstacle* obstacle,
                                 ContactGeometryDerivative& out);

struct SmoothingOptions {
  int samples = 16;        // 0: no smoothing (the exact derivative or none)
  double sigma = 0;        // standard deviation of the node perturbation (length); 0: no smoothing
  std::uint64_t seed = 0;
};

enum class GeometryDerivativeKind : std::int8_t {
  exact,     // the feature pair is unique at scale sigma: the exact derivative
  smoothed,  // the randomized-smoothing estimate (see above)
  none,      // no sample has a derivative (out is zero)
};

// The smoothed geometry itself: the mean over the same samples of the geometry of the
// feature pair active at each sample (n, frame are means, not unit). Its derivative is
// the smoothed derivative below wherever no sample sits on a region boundary (what the
// tests check by central differences with common samples). False if no sample has a
// geometry.
bool smoothed_contact_geometry(const Contact& c, const VecX& x, const Obstacle* obstacle, const SmoothingOptions& options,
                               ContactGeometry& out);

// The derivative with randomized smoothing where the active feature pair is not unique
// at scale sigma. Allocates nothing.
GeometryDerivativeKind contact_geometry_derivative(const Contact& c, const VecX& x, const Obstacle* obstacle,
                                                   const SmoothingOptions& options, ContactGeometryDerivative& out);

// d vec(frame_from_normal(n)) for dn (3 x m): (9 x m).
Eigen::Matrix<double, 9, Eigen::Dynamic> frame_derivative(const Vec3& n, const Eigen::Matrix<double, 3, Eigen::Dynamic>& dn);

}  // namespace softdiff::collision
