#pragma once
// Effector: a named point embedded in a body (scene.md `effectors`), followed by
// control and written to the output. Its position is p(x) = sum_a w_a x_{nodes[a]}
// (a = 0 .. count - 1: 4 nodes of a linear tet with barycentric weights, or 10 of a
// quadratic one with the shape functions' values), linear in x, so its Jacobian
// J = dp/dx (3 x 3n) is constant: the 3x3 block of node nodes[a] is w_a I, every
// other block zero. Embed the point with PointLocator
// (embedding.hpp) and embedded_point(). Allocation-free except jacobian_triplets.
#include <softdiff/actuation/embedding.hpp>
#include <softdiff/core/assert.hpp>

#include <vector>

namespace softdiff::actuation {

class Effector {
 public:
  Effector() = default;
  explicit Effector(const EmbeddedPoint& point) : point_(point) {
    SOFTDIFF_DEMAND(point.count == 4 || point.count == 10, "an embedded point has 4 or 10 nodes");
    for (int a = 0; a < point.count; ++a) SOFTDIFF_DEMAND(point.nodes[a] >= 0, "negative node index");
  }

  const EmbeddedPoint& point() const { return point_; }
  int num_nodes() const { return point_.count; }
  // The first num_nodes() entries are used.
  const std::array<int, EmbeddedPoint::max_nodes>& nodes() const { return point_.nodes; }
  const Eigen::Matrix<double, EmbeddedPoint::max_nodes, 1>& weights() const { return point_.w; }

  // p(x).
  Vec3 position(const VecX& x) const { return point_.position(x); }
  // J dx.
  Vec3 jacobian_times(const VecX& dx) const { return point_.position(dx); }
  // out += scale J^T g (out sized 3n).
  void add_jacobian_transpose(const Vec3& g, double scale, VecX& out) const { point_.add_transpose(scale * g, out); }
  // Appends J's 3 num_nodes() non-zeros (rows row_offset + c, columns 3 nodes[a] + c) to `out`.
  void jacobian_triplets(int row_offset, std::vector<Eigen::Triplet<double>>& out) const {
    for (int a = 0; a < point_.count; ++a)
      for (int c = 0; c < 3; ++c) out.emplace_back(row_offset + c, 3 * point_.nodes[a] + c, point_.w[a]);
  }

 private:
  EmbeddedPoint point_;
};

}  // namespace softdiff::actuation
