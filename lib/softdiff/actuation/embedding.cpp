#include <softdiff/actuation/embedding.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/fem/tet10.hpp>

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>

namespace softdiff::actuation {

namespace {

// Closest point to p on triangle (a, b, c): Ericson, "Real-Time Collision Detection",
// section 5.1.5 (Voronoi regions of the vertices, edges and face).
Vec3 closest_point_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + (d1 / (d1 - d3)) * ab;
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + (d2 / (d2 - d6)) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  const double denom = 1 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

// Distance from p to the boundary of the tet (the solid's distance when p is outside).
double distance_to_tet_faces(const Eigen::Matrix<double, 3, 4>& x, const Vec3& p) {
  static constexpr int faces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  double d2 = std::numeric_limits<double>::infinity();
  for (const auto& f : faces) {
    const Vec3 q = closest_point_on_triangle(p, x.col(f[0]), x.col(f[1]), x.col(f[2]));
    d2 = std::min(d2, (p - q).squaredNorm());
  }
  return std::sqrt(d2);
}

Eigen::Matrix<double, 3, 4> tet_positions(const Mat3X& X, const Tets& tets, int tet) {
  Eigen::Matrix<double, 3, 4> x;
  for (int a = 0; a < 4; ++a) x.col(a) = X.col(tets(a, tet));
  return x;
}

double longest_edge(const Eigen::Matrix<double, 3, 4>& x) {
  double l2 = 0;
  for (int a = 0; a < 4; ++a)
    for (int b = a + 1; b < 4; ++b) l2 = std::max(l2, (x.col(a) - x.col(b)).squaredNorm());
  return std::sqrt(l2);
}

Mat3 edge_matrix(const Eigen::Matrix<double, 3, 4>& x) {
  Mat3 D;
  for (int k = 0; k < 3; ++k) D.col(k) = x.col(k + 1) - x.col(0);
  return D;
}

Eigen::Vector4d weights_from(const Mat3& Dm_inv, const Vec3& x0, const Vec3& p) {
  const Vec3 l = Dm_inv * (p - x0);
  Eigen::Vector4d w;
  w << 1 - l.sum(), l;
  return w;
}

Eigen::Matrix<double, 3, 10> tet10_positions(const Mat3X& X, const mesh::Tets10& tets10, int tet) {
  Eigen::Matrix<double, 3, 10> x;
  for (int a = 0; a < 10; ++a) x.col(a) = X.col(tets10(a, tet));
  return x;
}

}  // namespace

Eigen::Matrix<double, 10, 1> quadratic_weights(const Eigen::Vector4d& l) {
  return fem::tet10::shape(l[1], l[2], l[3]);
}

bool quadratic_reference_coordinates(const Eigen::Matrix<double, 3, 10>& X_e, const Vec3& p, const Eigen::Vector4d& l0,
                                     Eigen::Vector4d& l) {
  Vec3 xi = l0.tail<3>();
  l = l0;
  for (int it = 0; it < 30; ++it) {
    const Vec3 r = X_e * fem::tet10::shape(xi[0], xi[1], xi[2]) - p;
    const Mat3 J = fem::tet10::jacobian(X_e, fem::tet10::shape_gradients_ref(xi[0], xi[1], xi[2]));
    const double det = J.determinant();
    if (!(det > 0) || !std::isfinite(det)) return false;
    const Vec3 step = J.inverse() * r;
    xi -= step;
    if (!xi.allFinite()) return false;
    if (step.norm() <= 1e-14 * std::max(1.0, xi.norm())) {
      l << 1 - xi.sum(), xi;
      return true;
    }
  }
  return false;
}

EmbeddedPoint embedded_point(const Embedding& e, const Tets& tets, int node_offset) {
  SOFTDIFF_DEMAND(e.order == 1, "embedded_point: a quadratic embedding needs the 10-node tets");
  EmbeddedPoint p;
  for (int a = 0; a < 4; ++a) {
    p.nodes[a] = tets(a, e.tet) + node_offset;
    p.w[a] = e.w[a];
  }
  p.count = 4;
  return p;
}

EmbeddedPoint embedded_point(const Embedding& e, const mesh::Tets10& tets10, int node_offset) {
  SOFTDIFF_DEMAND(e.order == 2, "embedded_point: a linear embedding needs the 4-node tets");
  EmbeddedPoint p;
  for (int a = 0; a < 10; ++a) p.nodes[a] = tets10(a, e.tet) + node_offset;
  p.w = quadratic_weights(e.w);
  p.count = 10;
  return p;
}

EmbeddedPoint embedded_point(const Embedding& e, const PointLocator& locator, int node_offset) {
  return locator.order() == 2 ? embedded_point(e, locator.tets10(), node_offset)
                              : embedded_point(e, locator.tets(), node_offset);
}

Eigen::Vector4d barycentric_weights(const Mat3X& X, const Tets& tets, int tet, const Vec3& p) {
  const Eigen::Matrix<double, 3, 4> x = tet_positions(X, tets, tet);
  return weights_from(edge_matrix(x).inverse(), x.col(0), p);
}

double point_tet_distance(const Mat3X& X, const Tets& tets, int tet, const Vec3& p) {
  const Eigen::Matrix<double, 3, 4> x = tet_positions(X, tets, tet);
  const Eigen::Vector4d w = weights_from(edge_matrix(x).inverse(), x.col(0), p);
  if (w.minCoeff() >= 0) return 0;
  return distance_to_tet_faces(x, p);
}

PointLocator::PointLocator(const Mat3X& X, const Tets& tets) : X_(X), tets_(tets) { build(); }

PointLocator::PointLocator(const Mat3X& X, const Tets& tets, const mesh::Tets10& tets10)
    : X_(X), tets_(tets), tets10_(tets10) {
  SOFTDIFF_DEMAND(tets10_.cols() == tets_.cols(), "PointLocator: tets10 must have one column per tet");
  build();
}

void PointLocator::build() {
  const int m = static_cast<int>(tets_.cols());
  const int n = static_cast<int>(X_.cols());
  const bool quadratic = tets10_.cols() > 0;
  curved_.assign(m, 0);
  Dm_inv_.assign(m, Mat3::Zero());
  usable_.assign(m, 0);
  box_min_.resize(3, m);
  box_max_.resize(3, m);
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (int e = 0; e < m; ++e) {
    for (int a = 0; a < 4; ++a)
      SOFTDIFF_DEMAND(tets_(a, e) >= 0 && tets_(a, e) < n, "tet node index out of range");
    const Eigen::Matrix<double, 3, 4> x = tet_positions(X_, tets_, e);
    box_min_.col(e) = x.rowwise().minCoeff();
    box_max_.col(e) = x.rowwise().maxCoeff();
    const Mat3 D = edge_matrix(x);
    const double det = D.determinant(), l = longest_edge(x);
    if (quadratic) {
      for (int a = 0; a < 10; ++a)
        SOFTDIFF_DEMAND(tets10_(a, e) >= 0 && tets10_(a, e) < n, "tet node index out of range");
      const Eigen::Matrix<double, 3, 10> x10 = tet10_positions(X_, tets10_, e);
      box_min_.col(e) = x10.rowwise().minCoeff();
      box_max_.col(e) = x10.rowwise().maxCoeff();
      for (int k = 0; k < 6; ++k) {
        const Vec3 mid = 0.5 * (x.col(mesh::kTet10Edge[k][0]) + x.col(mesh::kTet10Edge[k][1]));
        if ((x10.col(4 + k) - mid).norm() > 1e-12 * l) curved_[e] = 1;
      }
    }
    if (std::abs(det) > 1e-14 * l * l * l && std::isfinite(det)) {
      usable_[e] = 1;
      Dm_inv_[e] = D.inverse();
      ++usable_count_;
      lo = lo.cwiseMin(box_min_.col(e));
      hi = hi.cwiseMax(box_max_.col(e));
    }
  }
  if (usable_count_ == 0) {
    cell_begin_.assign(2, 0);
    return;
  }
  // About one cubic cell per tet; flat extents are padded so the cell size stays positive.
  const double diag = (hi - lo).norm();
  const Vec3 extent = (hi - lo).cwiseMax(Vec3::Constant(1e-3 * diag));
  h_ = std::cbrt(extent.prod() / usable_count_);
  for (int c = 0; c < 3; ++c)
    dims_[c] = std::max(1, std::min(1 << 20, static_cast<int>(std::ceil(extent[c] / h_))));
  origin_ = lo;
  tie_distance_ = 1e-12 * diag;

  const long cells = static_cast<long>(dims_[0]) * dims_[1] * dims_[2];
  cell_begin_.assign(cells + 1, 0);
  auto for_each_cell_of = [&](int e, auto&& fn) {
    const Eigen::Vector3i a = cell_of(box_min_.col(e)), b = cell_of(box_max_.col(e));
    for (int iz = a[2]; iz <= b[2]; ++iz)
      for (int iy = a[1]; iy <= b[1]; ++iy)
        for (int ix = a[0]; ix <= b[0]; ++ix) fn(ix + dims_[0] * (iy + dims_[1] * iz));
  };
  for (int e = 0; e < m; ++e)
    if (usable_[e]) for_each_cell_of(e, [&](int cell) { ++cell_begin_[cell + 1]; });
  for (long c = 0; c < cells; ++c) cell_begin_[c + 1] += cell_begin_[c];
  cell_tets_.resize(cell_begin_[cells]);
  std::vector<int> fill(cell_begin_.begin(), cell_begin_.end() - 1);
  for (int e = 0; e < m; ++e)
    if (usable_[e]) for_each_cell_of(e, [&](int cell) { cell_tets_[fill[cell]++] = e; });
}

Eigen::Vector3i PointLocator::cell_of(const Vec3& p) const {
  Eigen::Vector3i c;
  for (int k = 0; k < 3; ++k) {
    const double f = std::floor((p[k] - origin_[k]) / h_);
    c[k] = f < 0 ? 0 : (f >= dims_[k] ? dims_[k] - 1 : static_cast<int>(f));
  }
  return c;
}

double PointLocator::cell_distance(const Vec3& p, int ix, int iy, int iz) const {
  const Vec3 lo = origin_ + h_ * Vec3(ix, iy, iz);
  const Vec3 d = (lo - p).cwiseMax(p - (lo + Vec3::Constant(h_))).cwiseMax(0.0);
  return d.norm();
}

void PointLocator::evaluate(int tet, const Vec3& p, Candidate& c) const {
  c.tet = tet;
  c.w = weights_from(Dm_inv_[tet], X_.col(tets_(0, tet)), p);
  if (curved_[tet]) {
    // The reference coordinates of the curved element (the vertex tet's barycentric
    // coordinates when Newton fails, far outside it).
    Eigen::Vector4d l;
    if (quadratic_reference_coordinates(tet10_positions(X_, tets10_, tet), p, c.w, l)) c.w = l;
  }
  c.min_weight = c.w.minCoeff();
  c.distance = c.min_weight >= -inside_tolerance ? 0.0 : distance_to_tet_faces(tet_positions(X_, tets_, tet), p);
}

bool PointLocator::better(const Candidate& a, const Candidate& b) const {
  if (b.tet < 0) return true;
  if (a.distance < b.distance - tie_distance_) return true;
  if (a.distance > b.distance + tie_distance_) return false;
  return a.min_weight > b.min_weight;
}

void PointLocator::visit_cell(int cell, const Vec3& p, Candidate& best) const {
  Candidate c;
  for (int k = cell_begin_[cell]; k < cell_begin_[cell + 1]; ++k) {
    const int e = cell_tets_[k];
    if (best.tet >= 0) {
      const double box = (box_min_.col(e) - p).cwiseMax(p - box_max_.col(e)).cwiseMax(0.0).norm();
      if (box > best.distance + tie_distance_) continue;
    }
    evaluate(e, p, c);
    if (better(c, best)) best = c;
  }
}

LocateResult PointLocator::locate(const Vec3& p, const LocateOptions& options) const {
  LocateResult r;
  if (usable_count_ == 0 || !p.allFinite()) return r;
  Candidate best;
  const Eigen::Vector3i c = cell_of(p);
  const Vec3 grid_max = origin_ + h_ * dims_.cast<double>();
  const double grid_distance = (origin_ - p).cwiseMax(p - grid_max).cwiseMax(0.0).norm();
  // Fast path: every tet that contains p overlaps p's cell.
  if (grid_distance == 0) visit_cell(c[0] + dims_[0] * (c[1] + dims_[1] * c[2]), p, best);
  if (best.tet < 0 || best.distance > 0) {
    const int kmax = dims_.maxCoeff();
    for (int k = 0; k <= kmax; ++k) {
      const double lower_bound = std::max(grid_distance, (k - 1) * h_);
      if (best.tet >= 0 && lower_bound > best.distance + tie_distance_) break;
      auto visit = [&](int ix, int iy, int iz) {
        if (ix < 0 || ix >= dims_[0]) return;
        if (best.tet >= 0 && cell_distance(p, ix, iy, iz) > best.distance + tie_distance_) return;
        visit_cell(ix + dims_[0] * (iy + dims_[1] * iz), p, best);
      };
      for (int iz = std::max(0, c[2] - k); iz <= std::min(dims_[2] - 1, c[2] + k); ++iz)
        for (int iy = std::max(0, c[1] - k); iy <= std::min(dims_[1] - 1, c[1] + k); ++iy) {
          if (std::abs(iz - c[2]) == k || std::abs(iy - c[1]) == k) {
            for (int ix = std::max(0, c[0] - k); ix <= std::min(dims_[0] - 1, c[0] + k); ++ix) visit(ix, iy, iz);
          } else {
            visit(c[0] - k, iy, iz);
            if (k > 0) visit(c[0] + k, iy, iz);
          }
        }
    }
  }
  SOFTDIFF_ASSERT(best.tet >= 0);
  r.embedding.tet = best.tet;
  r.embedding.w = best.w;
  r.embedding.outside_distance = best.distance;
  r.embedding.order = order();
  if (best.distance == 0) {
    r.status = LocateStatus::inside;
    return r;
  }
  r.allowed_distance = std::max(options.max_distance,
                                options.max_relative_distance * longest_edge(tet_positions(X_, tets_, best.tet)));
  r.status = best.distance <= r.allowed_distance ? LocateStatus::outside : LocateStatus::too_far;
  return r;
}

}  // namespace softdiff::actuation
