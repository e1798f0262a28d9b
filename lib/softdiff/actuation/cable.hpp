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
// nodes by the embedding's weights (barycentric, or the quadratic shape functions).
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
#include <softdiff/core/assert.hpp>

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
  // out += (d(H_a^T lambda)/dx)^T y: the same map (-lambda d^2L/dx^2 is symmetric).
  void add_force_derivative_transpose(const VecX& x, double lambda, const VecX& y, VecX& out) const {
    add_force_derivative(x, lambda, y, out);
  }

  // Segments, numbered s = 0 .. num_segments() - 1 in cable order: with a pull point,
  // segment 0 is q -> p_0 and segment s joins p_{s-1} and p_s; without, segment s
  // joins p_s and p_{s+1}. The numbering does not depend on x.
  int num_segments() const { return num_points() - 1 + (pull_point_ ? 1 : 0); }

  // The segment vector d_s = p_k1 - p_k0 (or p_0 - q) as a fixed linear combination
  // of node positions, d_s = sum_a coeffs[a] x_{nodes[a]} (+ const): the first
  // p_k1.count entries are p_k1's nodes with coeffs w, the next p_k0.count p_k0's with
  // -w (absent for the pull point segment); count = 8 for two points in linear tets,
  // 20 in quadratic ones. Nodes may repeat (two points in one tet); the stiffness
  // blocks of repeated nodes simply add up.
  struct SegmentStencil {
    static constexpr int max_count = 2 * EmbeddedPoint::max_nodes;
    std::array<int, max_count> nodes{};
    std::array<double, max_count> coeffs{};
    int count = 0;
  };
  SegmentStencil segment_stencil(int s) const;

  // The cable's stiffness lambda d^2L/dx^2 = -d(H_a^T lambda)/dx (symmetric positive
  // semi-definite for lambda >= 0: L is convex in the point positions), block by
  // block: calls fn(s, a, b, node_a, node_b, block) for every segment s with a usable
  // length (zero-length segments are skipped, as in add_force_derivative) and every
  // ordered pair (a, b) of its stencil (a, b < count), with the 3x3 block
  //     coeffs[a] coeffs[b] lambda (I - u u^T) / l     (u = d_s / l, l = |d_s|)
  // of the (node_a, node_b) block of the Hessian: lambda d^2L/dx^2 is the sum of all
  // these blocks (both orders, a == b included). Allocation-free.
  template <class Fn>
  void for_each_stiffness_block(const VecX& x, double lambda, Fn&& fn) const {
    SOFTDIFF_DEMAND(x.size() >= min_size_, "x is too short for the cable's nodes");
    const int shift = pull_point_ ? 1 : 0;
    for_each_segment(x, [&](int k0, int, const Vec3& u, double l) {
      const int s = k0 + shift;
      const SegmentStencil st = segment_stencil(s);
      const Mat3 B = (lambda / l) * (Mat3::Identity() - u * u.transpose());
      for (int a = 0; a < st.count; ++a)
        for (int b = 0; b < st.count; ++b) {
          const Mat3 block = (st.coeffs[a] * st.coeffs[b]) * B;
          fn(s, a, b, st.nodes[a], st.nodes[b], block);
        }
    });
  }

 private:
  // Calls fn(k0, k1, u, l) for every segment with a usable length, k0 = -1 for the
  // pull point segment (q to p_0); u = (p_k1 - p_k0)/l.
  template <class Fn>
  void for_each_segment(const VecX& x, Fn&& fn) const {
    const double threshold = zero_segment_ratio * length(x);
    auto segment = [&](int k0, const Vec3& a, int k1, const Vec3& b) {
      const Vec3 d = b - a;
      const double l = d.norm();
      if (l > threshold && l > 0) fn(k0, k1, Vec3(d / l), l);
    };
    Vec3 prev = points_[0].position(x);
    if (pull_point_) segment(-1, *pull_point_, 0, prev);
    for (int k = 1; k < num_points(); ++k) {
      const Vec3 p = points_[k].position(x);
      segment(k - 1, prev, k, p);
      prev = p;
    }
  }
  void check_sizes(const VecX& x, const VecX& out) const;

  std::vector<EmbeddedPoint> points_;
  std::optional<Vec3> pull_point_;
  std::vector<int> nodes_;                  // sorted distinct global nodes
  std::vector<std::array<int, EmbeddedPoint::max_nodes>> slots_;  // (K) position in nodes_ of each point's nodes
  long min_size_ = 0;                       // 3 (max node + 1)
};

}  // namespace softdiff::actuation
