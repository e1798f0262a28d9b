#pragma once
// Cable actuator (method.md "Actuation Jacobians"): an ordered list of embedded
// points p_0 .. p_{K-1}, listed from the pulled end (p_0 is where the cable leaves the
// body towards the optional fixed pull point q; p_{K-1} is the anchored end). Length
//
//     L(x) = |p_0 - q| (with a pull point) + sum_k |p_{k+1} - p_k|,
//
// H_a = -dL/dx (1 x 3n), so the actuation force h H_a^T lambda with a tension
// lambda >= 0 shortens the cable: each segment pulls its two end points towards each
// other (and p_0 towards q) with force lambda along the segment, spread to the tet
// nodes by the barycentric weights.
//
// Zero-length segments. |d| is not differentiable at d = 0 (its subdifferential is
// the unit ball) and its Hessian (I - u u^T)/|d| grows without bound as |d| -> 0. A
// segment whose current length is <= zero_segment_ratio * L(x) (or exactly 0)
// contributes its length to L but nothing to H_a and to its derivative: the zero
// subgradient, the natural choice at the kink (no NaN, no spurious force). Two
// consecutive points embedded identically (same tet and weights, e.g. a point listed
// twice) stay together under any deformation, and this is then exact; distinct points
// that nearly coincide at rest deserve a warning from the scene loader.
//
// Every evaluation is allocation-free (fixed-size Eigen types only).
#include <softdiff/actuation/embedding.hpp>

#include <array>
#include <optional>
#include <vector>

namespace softdiff::actuation {

class Cable {
 public:
  static constexpr double zero_segment_ratio = 1e-12;

  // At least two points, or one point and a pull point (SOFTDIFF_DEMAND: the scene
  // loader reports an InputError before constructing).
  explicit Cable(std::vector<EmbeddedPoint> points, std::optional<Vec3> pull_point = std::nullopt);

  int num_points() const { return static_cast<int>(points_.size()); }
  const std::vector<EmbeddedPoint>& points() const { return points_; }
  const std::optional<Vec3>& pull_point() const { return pull_point_; }

  // L(x).
  double length(const VecX& x) const;

  // f += scale * lambda * H_a^T (f sized like x).
  void add_force(const VecX& x, double lambda, double scale, VecX& f) const;

  // H = H_a^T = -dL/dx (H sized like x; overwritten).
  void gradient(const VecX& x, VecX& H) const;

  // Sparse form of H_a: nodes() are the distinct global nodes the cable touches
  // (sorted, fixed at construction); values (3, nodes().size()), sized by the caller,
  // receives H_a's 3-vector of each: H_a[3 nodes()[j] + c] = values(c, j).
  const std::vector<int>& nodes() const { return nodes_; }
  void gradient_sparse(const VecX& x, Mat3X& values) const;

  // out += d(H_a^T lambda)/dx . dx = -lambda (d^2L/dx^2) dx (exact; out sized like x).
  // Per segment d = p_{k+1} - p_k (or p_0 - q), u = d/|d|, the Hessian of |d| is
  // (I - u u^T)/|d| applied to dd = dp_{k+1} - dp_k, with dp = J dx.
  void add_force_derivative(const VecX& x, double lambda, const VecX& dx, VecX& out) const;

 private:
  // Calls fn(k0, k1, u, l) for every segment with a usable length, k0 = -1 for the
  // pull point segment (q to p_0); u = (p_k1 - p_k0)/l.
  template <class Fn>
  void for_each_segment(const VecX& x, Fn&& fn) const;
  void check_sizes(const VecX& x, const VecX& out) const;

  std::vector<EmbeddedPoint> points_;
  std::optional<Vec3> pull_point_;
  std::vector<int> nodes_;                  // sorted distinct global nodes
  std::vector<std::array<int, 4>> slots_;   // (K) position in nodes_ of each point's nodes
  long min_size_ = 0;                       // 3 (max node + 1)
};

}  // namespace softdiff::actuation
