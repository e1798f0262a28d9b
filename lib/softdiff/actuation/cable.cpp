#include <softdiff/actuation/cable.hpp>
#include <softdiff/core/assert.hpp>

#include <algorithm>
#include <cmath>

namespace softdiff::actuation {

Cable::Cable(std::vector<EmbeddedPoint> points, std::optional<Vec3> pull_point)
    : points_(std::move(points)), pull_point_(std::move(pull_point)) {
  SOFTDIFF_DEMAND(points_.size() >= 2 || (points_.size() == 1 && pull_point_),
                  "a cable needs two points, or one point and a pull point");
  int max_node = 0;
  for (const auto& p : points_)
    for (int a = 0; a < p.count; ++a) {
      SOFTDIFF_DEMAND(p.nodes[a] >= 0, "negative node index");
      nodes_.push_back(p.nodes[a]);
      max_node = std::max(max_node, p.nodes[a]);
    }
  std::sort(nodes_.begin(), nodes_.end());
  nodes_.erase(std::unique(nodes_.begin(), nodes_.end()), nodes_.end());
  slots_.resize(points_.size());
  for (size_t k = 0; k < points_.size(); ++k)
    for (int a = 0; a < points_[k].count; ++a)
      slots_[k][a] = static_cast<int>(std::lower_bound(nodes_.begin(), nodes_.end(), points_[k].nodes[a]) -
                                      nodes_.begin());
  min_size_ = 3L * (max_node + 1);
}

void Cable::check_sizes(const VecX& x, const VecX& out) const {
  SOFTDIFF_DEMAND(x.size() >= min_size_ && x.size() % 3 == 0, "x is too short for the cable's nodes");
  SOFTDIFF_DEMAND(out.size() == x.size(), "output vector must be sized like x");
}

double Cable::length(const VecX& x) const {
  SOFTDIFF_DEMAND(x.size() >= min_size_, "x is too short for the cable's nodes");
  double L = 0;
  Vec3 prev = points_[0].position(x);
  if (pull_point_) L += (prev - *pull_point_).norm();
  for (size_t k = 1; k < points_.size(); ++k) {
    const Vec3 p = points_[k].position(x);
    L += (p - prev).norm();
    prev = p;
  }
  return L;
}

Cable::SegmentStencil Cable::segment_stencil(int s) const {
  SOFTDIFF_DEMAND(s >= 0 && s < num_segments(), "segment index out of range");
  const int k1 = s + (pull_point_ ? 0 : 1), k0 = k1 - 1;
  SegmentStencil st;
  const EmbeddedPoint& p1 = points_[k1];
  for (int a = 0; a < p1.count; ++a) {
    st.nodes[a] = p1.nodes[a];
    st.coeffs[a] = p1.w[a];
  }
  st.count = p1.count;
  if (k0 >= 0) {
    const EmbeddedPoint& p0 = points_[k0];
    for (int a = 0; a < p0.count; ++a) {
      st.nodes[st.count + a] = p0.nodes[a];
      st.coeffs[st.count + a] = -p0.w[a];
    }
    st.count += p0.count;
  }
  return st;
}

void Cable::add_force(const VecX& x, double lambda, double scale, VecX& f) const {
  check_sizes(x, f);
  const double s = scale * lambda;
  // -dL/dp_k1 = -u, -dL/dp_k0 = +u: the ends are pulled towards each other.
  for_each_segment(x, [&](int k0, int k1, const Vec3& u, double) {
    points_[k1].add_transpose(-s * u, f);
    if (k0 >= 0) points_[k0].add_transpose(s * u, f);
  });
}

void Cable::gradient(const VecX& x, VecX& H) const {
  check_sizes(x, H);
  H.setZero();
  add_force(x, 1.0, 1.0, H);
}

void Cable::gradient_sparse(const VecX& x, Mat3X& values) const {
  SOFTDIFF_DEMAND(x.size() >= min_size_, "x is too short for the cable's nodes");
  SOFTDIFF_DEMAND(values.cols() == static_cast<Eigen::Index>(nodes_.size()), "values must be (3, nodes().size())");
  values.setZero();
  auto add = [&](int k, const Vec3& g) {
    for (int a = 0; a < points_[k].count; ++a) values.col(slots_[k][a]) += points_[k].w[a] * g;
  };
  for_each_segment(x, [&](int k0, int k1, const Vec3& u, double) {
    add(k1, -u);
    if (k0 >= 0) add(k0, u);
  });
}

void Cable::add_force_derivative(const VecX& x, double lambda, const VecX& dx, VecX& out) const {
  check_sizes(x, out);
  SOFTDIFF_DEMAND(dx.size() == x.size(), "dx must be sized like x");
  for_each_segment(x, [&](int k0, int k1, const Vec3& u, double l) {
    Vec3 dd = points_[k1].position(dx);  // J is linear: J dx = position(dx)
    if (k0 >= 0) dd -= points_[k0].position(dx);
    // d(dL/dp_k1) = (I - u u^T) dd / l = -d(dL/dp_k0); force = -lambda dL/dx.
    const Vec3 v = (lambda / l) * (dd - u * u.dot(dd));
    points_[k1].add_transpose(-v, out);
    if (k0 >= 0) points_[k0].add_transpose(v, out);
  });
}

}  // namespace softdiff::actuation
