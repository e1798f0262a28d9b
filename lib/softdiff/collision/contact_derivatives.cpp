// Collision-detection derivatives: see contact_derivatives.hpp for the formulas.
#include <softdiff/collision/contact_derivatives.hpp>

#include <softdiff/collision/distance.hpp>
#include <softdiff/core/assert.hpp>

#include <cmath>
#include <limits>
#include <random>

namespace softdiff::collision {

namespace {

using Mat3x12 = Eigen::Matrix<double, 3, 12>;
using Row12 = Eigen::Matrix<double, 1, 12>;

Mat3 skew(const Vec3& w) {
  Mat3 W;
  W << 0, -w(2), w(1), w(2), 0, -w(0), -w(1), w(0), 0;
  return W;
}

// D_k: the 3 x 12 selection of node k's coordinates.
Mat3x12 select(int k) {
  Mat3x12 D = Mat3x12::Zero();
  D.block<3, 3>(0, 3 * k).setIdentity();
  return D;
}

Vec3 node(const VecX& x, const Contact& c, int k) { return x.segment<3>(3 * c.nodes[k]); }

// Local positions (1..3) of the triangle's nodes with a non-zero weight, in order.
int active_triangle_nodes(const Contact& c, int out[3]) {
  int m = 0;
  for (int k = 1; k < 4; ++k)
    if (c.weights[k] != 0) out[m++] = k;
  return m;
}

double orientation(const Vec3& recorded_n, const Vec3& direction) { return recorded_n.dot(direction) < 0 ? -1.0 : 1.0; }

}  // namespace

Eigen::Matrix<double, 9, Eigen::Dynamic> frame_derivative(const Vec3& n, const Eigen::Matrix<double, 3, Eigen::Dynamic>& dn) {
  const int k = frame_reference_axis(n);
  Vec3 e = Vec3::Zero();
  e[k] = 1;
  const Vec3 u = e - n[k] * n;
  const double lu = u.norm();
  const Vec3 t1 = u / lu;
  const Eigen::Matrix<double, 3, Eigen::Dynamic> du = -n * dn.row(k) - n[k] * dn;
  const Eigen::Matrix<double, 3, Eigen::Dynamic> dt1 = (Mat3::Identity() - t1 * t1.transpose()) * du / lu;
  Eigen::Matrix<double, 9, Eigen::Dynamic> out(9, dn.cols());
  out.middleRows<3>(0) = dt1;
  out.middleRows<3>(3) = -skew(t1) * dn + skew(n) * dt1;
  out.middleRows<3>(6) = dn;
  return out;
}

namespace {

// The derivative of the geometry of contact c (its feature pair in c.kind / c.kind_b /
// c.weights, its orientation from c.frame) at node positions P[0..count-1].
struct Positions {
  std::array<Vec3, 4> p;
};

// Point P[kp] against the segment P[ka] P[kb] (its interior): n = o d / |d|,
// d = P[kp] - q, q = P[ka] + t (P[kb] - P[ka]); o orients n along the recorded normal.
// side = +1 when the point is on side A (gap = n . d), -1 on side B (gap = -n . d).
// The segment's weights are -side (1 - t), -side t.
bool point_segment(const Positions& P, int kp, int ka, int kb, double side, const Vec3& n_rec, Vec3& n,
                   ContactGeometryDerivative& out) {
  const Mat3 I = Mat3::Identity();
  const Vec3 p = P.p[kp], a = P.p[ka], e = P.p[kb] - a;
  const Mat3x12 Dp = select(kp), Da = select(ka), De = select(kb) - Da;
  const double l2 = e.squaredNorm();
  if (!(l2 > 0)) return false;
  const double t = (p - a).dot(e) / l2;
  const Vec3 d = p - (a + t * e);
  const double ld = d.norm();
  if (!(ld > 0)) return false;
  const double o = orientation(n_rec, d);
  n = o * d / ld;
  const Row12 dt = (e.transpose() * (Dp - Da) + (p - a).transpose() * De - 2 * t * e.transpose() * De) / l2;
  const Mat3x12 Dd = Dp - Da - t * De - e * dt;
  out.dn = (I - n * n.transpose()) * (o / ld) * Dd;
  out.dgap = side * n.transpose() * (Dp - Da - t * De);  // the envelope theorem: n ⊥ e
  out.dweights.row(ka) = side * dt;
  out.dweights.row(kb) = -side * dt;
  return true;
}

// Point P[kp] against point P[kq]: n = o d / |d|, d = P[kp] - P[kq]; side as above.
bool point_point(const Positions& P, int kp, int kq, double side, const Vec3& n_rec, Vec3& n,
                 ContactGeometryDerivative& out) {
  const Vec3 d = P.p[kp] - P.p[kq];
  const double ld = d.norm();
  if (!(ld > 0)) return false;
  const double o = orientation(n_rec, d);
  n = o * d / ld;
  const Mat3x12 Dd = select(kp) - select(kq);
  out.dn = (Mat3::Identity() - n * n.transpose()) * (o / ld) * Dd;
  out.dgap = side * n.transpose() * Dd;
  return true;
}

bool derivative_at(const Contact& c, const Positions& P, const Obstacle* obstacle, ContactGeometryDerivative& out) {
  out.count = c.count;
  out.dn.setZero();
  out.dgap.setZero();
  out.dweights.setZero();
  const Vec3 n_rec = c.frame.col(2);
  const Mat3 I = Mat3::Identity();
  Vec3 n;
  switch (c.kind) {
    case ContactKind::vertex_obstacle: {
      SOFTDIFF_DEMAND(obstacle != nullptr, "contact_geometry_derivative: a vertex-obstacle contact needs its obstacle");
      const Vec3 p = P.p[0];
      ClosestPoint cp;
      closest_point(*obstacle, p, std::numeric_limits<double>::infinity(), cp);
      n = cp.normal;
      out.dn.block<3, 3>(0, 0) = normal_derivative(*obstacle, p, cp);
      out.dgap.segment<3>(0) = n.transpose();
      break;
    }
    case ContactKind::vertex_triangle: {
      const Vec3 p = P.p[0];
      const Mat3x12 Dp = select(0);
      if (c.kind_b == Feature::face) {
        const Vec3 a = P.p[1], b = P.p[2], cc = P.p[3];
        const Mat3x12 Da = select(1), De1 = select(2) - Da, De2 = select(3) - Da;
        const Vec3 e1 = b - a, e2 = cc - a, cr = e1.cross(e2);
        const double lc = cr.norm();
        if (!(lc > 0)) return false;
        const Vec3 N = cr / lc;
        const double s = orientation(n_rec, N);
        n = s * N;
        const Mat3x12 dcr = -skew(e2) * De1 + skew(e1) * De2;
        out.dn = s * (I - N * N.transpose()) * dcr / lc;
        out.dgap = (p - a).transpose() * out.dn + n.transpose() * (Dp - Da);
        Eigen::Matrix<double, 3, 2> E;
        E << e1, e2;
        const Eigen::Matrix2d G_inv = (E.transpose() * E).inverse();
        const Eigen::Vector2d vw = G_inv * (E.transpose() * (p - a));
        const Vec3 r = p - a - E * vw;  // p - q (along the normal)
        Eigen::Matrix<double, 2, 12> rhs;
        rhs.row(0) = r.transpose() * De1;
        rhs.row(1) = r.transpose() * De2;
        rhs += E.transpose() * (Dp - Da);
        rhs -= E.transpose() * (De1 * vw[0] + De2 * vw[1]);
        const Eigen::Matrix<double, 2, 12> dvw = G_inv * rhs;
        out.dweights.row(1) = dvw.row(0) + dvw.row(1);
        out.dweights.row(2) = -dvw.row(0);
        out.dweights.row(3) = -dvw.row(1);
      } else {
        int k[3];
        const int m = active_triangle_nodes(c, k);
        if (c.kind_b == Feature::edge && m == 2) {
          if (!point_segment(P, 0, k[0], k[1], 1.0, n_rec, n, out)) return false;
        } else if (c.kind_b == Feature::vertex && m == 1) {
          if (!point_point(P, 0, k[0], 1.0, n_rec, n, out)) return false;
        } else {
          return false;
        }
      }
      break;
    }
    case ContactKind::edge_edge: {
      const Vec3 p0 = P.p[0], p1 = P.p[1], q0 = P.p[2], q1 = P.p[3];
      // An endpoint pair (a smoothing sample: c.weights from segment_segment_closest at
      // P): a point against a segment, or two points.
      const bool s_end = c.weights[0] == 0 || c.weights[1] == 0, t_end = c.weights[2] == 0 || c.weights[3] == 0;
      if (s_end || t_end) {
        const int kp = c.weights[0] == 0 ? 1 : 0, kq = c.weights[2] == 0 ? 3 : 2;
        bool ok = false;
        if (s_end && t_end) ok = point_point(P, kp, kq, 1.0, n_rec, n, out);
        else if (s_end) ok = point_segment(P, kp, 2, 3, 1.0, n_rec, n, out);
        else ok = point_segment(P, kq, 0, 1, -1.0, n_rec, n, out);
        if (!ok) return false;
        break;
      }
      const Vec3 d1 = p1 - p0, d2 = q1 - q0, w = p0 - q0;
      const double a = d1.squaredNorm(), b = d1.dot(d2), e = d2.squaredNorm(), cc = d1.dot(w), f = d2.dot(w);
      const double denom = a * e - b * b;
      const Vec3 cr = d1.cross(d2);
      const double lc = cr.norm();
      if (!(denom > 1e-14 * a * e) || !(lc > 0)) return false;
      const double s = (b * f - cc * e) / denom, t = (a * f - b * cc) / denom;
      const Vec3 r = w + s * d1 - t * d2;
      const Mat3x12 Dd1 = select(1) - select(0), Dd2 = select(3) - select(2), Dw = select(0) - select(2);
      const Mat3x12 Dr0 = Dw + s * Dd1 - t * Dd2;
      // [a -b; b -e] [ds; dt] = -[r.dd1 + d1.dr0; r.dd2 + d2.dr0]
      Eigen::Matrix<double, 2, 12> rhs;
      rhs.row(0) = r.transpose() * Dd1 + d1.transpose() * Dr0;
      rhs.row(1) = r.transpose() * Dd2 + d2.transpose() * Dr0;
      Eigen::Matrix2d M;
      M << a, -b, b, -e;
      const Eigen::Matrix<double, 2, 12> dst = -M.inverse() * rhs;
      const Vec3 N = cr / lc;
      const double sign = orientation(n_rec, N);
      n = sign * N;
      out.dn = sign * (I - N * N.transpose()) * (-skew(d2) * Dd1 + skew(d1) * Dd2) / lc;
      out.dgap = n.transpose() * Dr0;
      out.dweights.row(0) = -dst.row(0);
      out.dweights.row(1) = dst.row(0);
      out.dweights.row(2) = dst.row(1);
      out.dweights.row(3) = -dst.row(1);
      break;
    }
  }
  out.dframe = frame_derivative(n, out.dn);
  return out.dn.allFinite() && out.dgap.allFinite() && out.dweights.allFinite() && out.dframe.allFinite();
}

bool geometry_at(const Contact& c, const Positions& P, const Obstacle* obstacle, ContactGeometry& out) {
  const Vec3 n_rec = c.frame.col(2);
  out.weights = c.weights;
  switch (c.kind) {
    case ContactKind::vertex_obstacle: {
      SOFTDIFF_DEMAND(obstacle != nullptr, "contact_geometry: a vertex-obstacle contact needs its obstacle");
      ClosestPoint cp;
      closest_point(*obstacle, P.p[0], std::numeric_limits<double>::infinity(), cp);
      out.n = cp.normal;
      out.gap = cp.distance;
      break;
    }
    case ContactKind::vertex_triangle: {
      const Vec3 p = P.p[0];
      if (c.kind_b == Feature::face) {
        const Vec3 a = P.p[1], b = P.p[2], cc = P.p[3];
        const Vec3 cr = (b - a).cross(cc - a);
        if (!(cr.norm() > 0)) return false;
        const Vec3 N = cr.normalized();
        out.n = orientation(n_rec, N) * N;
        out.gap = out.n.dot(p - a);
        Eigen::Matrix<double, 3, 2> E;
        E << b - a, cc - a;
        const Eigen::Vector2d vw = (E.transpose() * E).inverse() * (E.transpose() * (p - a));
        out.weights = {1, -(1 - vw[0] - vw[1]), -vw[0], -vw[1]};
      } else {
        int k[3];
        const int m = active_triangle_nodes(c, k);
        if (c.kind_b == Feature::edge && m == 2) {
          const Vec3 a = P.p[k[0]], b = P.p[k[1]], e = b - a;
          if (!(e.squaredNorm() > 0)) return false;
          const double t = (p - a).dot(e) / e.squaredNorm();
          const Vec3 d = p - (a + t * e);
          if (!(d.norm() > 0)) return false;
          out.n = orientation(n_rec, d) * d.normalized();
          out.gap = out.n.dot(d);
          out.weights = {1, 0, 0, 0};
          out.weights[k[0]] = -(1 - t);
          out.weights[k[1]] = -t;
        } else if (c.kind_b == Feature::vertex && m == 1) {
          const Vec3 d = p - P.p[k[0]];
          if (!(d.norm() > 0)) return false;
          out.n = orientation(n_rec, d) * d.normalized();
          out.gap = out.n.dot(d);
        } else {
          return false;
        }
      }
      break;
    }
    case ContactKind::edge_edge: {
      const Vec3 p0 = P.p[0], p1 = P.p[1], q0 = P.p[2], q1 = P.p[3];
      if (c.weights[0] == 0 || c.weights[1] == 0 || c.weights[2] == 0 || c.weights[3] == 0) {
        // An endpoint pair (a smoothing sample): the closest points at the recorded
        // parameters, n along their difference.
        const double s = c.weights[1], t = -c.weights[3];
        const Vec3 pa = p0 + s * (p1 - p0), qb = q0 + t * (q1 - q0), d = pa - qb;
        if (c.weights[0] != 0 && c.weights[1] != 0) {  // q's endpoint against p's interior
          const Vec3 e = p1 - p0;
          const double s2 = (qb - p0).dot(e) / e.squaredNorm();
          out.weights[0] = 1 - s2;
          out.weights[1] = s2;
          const Vec3 d2 = p0 + s2 * e - qb;
          if (!(d2.norm() > 0)) return false;
          out.n = orientation(n_rec, d2) * d2.normalized();
          out.gap = out.n.dot(d2);
        } else if (c.weights[2] != 0 && c.weights[3] != 0) {  // p's endpoint against q's interior
          const Vec3 e = q1 - q0;
          const double t2 = (pa - q0).dot(e) / e.squaredNorm();
          out.weights[2] = -(1 - t2);
          out.weights[3] = -t2;
          const Vec3 d2 = pa - (q0 + t2 * e);
          if (!(d2.norm() > 0)) return false;
          out.n = orientation(n_rec, d2) * d2.normalized();
          out.gap = out.n.dot(d2);
        } else {
          if (!(d.norm() > 0)) return false;
          out.n = orientation(n_rec, d) * d.normalized();
          out.gap = out.n.dot(d);
        }
        break;
      }
      const Vec3 d1 = p1 - p0, d2 = q1 - q0, w = p0 - q0;
      const double a = d1.squaredNorm(), b = d1.dot(d2), e = d2.squaredNorm(), cc = d1.dot(w), f = d2.dot(w);
      const double denom = a * e - b * b;
      const Vec3 cr = d1.cross(d2);
      if (!(denom > 1e-14 * a * e) || !(cr.norm() > 0)) return false;  // parallel edges
      const double s = (b * f - cc * e) / denom, t = (a * f - b * cc) / denom;
      const Vec3 N = cr.normalized();
      out.n = orientation(n_rec, N) * N;
      out.gap = out.n.dot(w + s * d1 - t * d2);
      out.weights = {1 - s, s, -(1 - t), -t};
      break;
    }
  }
  out.frame = frame_from_normal(out.n);
  return true;
}

Positions positions(const Contact& c, const VecX& x) {
  Positions P;
  for (int k = 0; k < 4; ++k) P.p[k] = k < c.count ? node(x, c, k) : Vec3::Zero();
  return P;
}

// The active feature pair of contact c at positions P (for a smoothing sample): c with
// its kind_b / weights (vertex-triangle, edge-edge) or its obstacle feature
// (vertex-obstacle) at P. Returns whether it is the recorded one.
bool feature_at(const Contact& recorded, const Positions& P, const Obstacle* obstacle, Contact& c) {
  c = recorded;
  switch (recorded.kind) {
    case ContactKind::vertex_obstacle: {
      ClosestPoint cp;
      closest_point(*obstacle, P.p[0], std::numeric_limits<double>::infinity(), cp);
      c.kind_b = cp.feature_kind;
      c.feature_b = cp.feature;
      return c.kind_b == recorded.kind_b && c.feature_b == recorded.feature_b;
    }
    case ContactKind::vertex_triangle: {
      const PointTriangleResult r = point_triangle_closest(P.p[0], P.p[1], P.p[2], P.p[3]);
      c.kind_b = r.feature;
      c.weights = {1, -r.bary[0], -r.bary[1], -r.bary[2]};
      break;
    }
    case ContactKind::edge_edge: {
      const SegmentSegmentResult r = segment_segment_closest(P.p[0], P.p[1], P.p[2], P.p[3]);
      const double s = r.s <= 1e-9 ? 0 : (r.s >= 1 - 1e-9 ? 1 : r.s), t = r.t <= 1e-9 ? 0 : (r.t >= 1 - 1e-9 ? 1 : r.t);
      c.weights = {1 - s, s, -(1 - t), -t};
      break;
    }
  }
  if (c.kind_b != recorded.kind_b) return false;
  for (int k = 0; k < 4; ++k)
    if ((c.weights[k] == 0) != (recorded.weights[k] == 0)) return false;
  return true;
}

// A seed per contact from its identity (independent of the contact order and of the
// threads): splitmix64 over the key.
std::uint64_t contact_seed(const Contact& c, std::uint64_t seed) {
  std::uint64_t h = seed ^ 0x9e3779b97f4a7c15ULL;
  for (const int k : c.key()) {
    h ^= static_cast<std::uint64_t>(static_cast<std::uint32_t>(k)) + 0x9e3779b97f4a7c15ULL + (h << 6) + (h >> 2);
    h = (h ^ (h >> 30)) * 0xbf58476d1ce4e5b9ULL;
    h = (h ^ (h >> 27)) * 0x94d049bb133111ebULL;
    h ^= h >> 31;
  }
  return h;
}

}  // namespace

bool contact_geometry(const Contact& c, const VecX& x, const Obstacle* obstacle, ContactGeometry& out) {
  return geometry_at(c, positions(c, x), obstacle, out);
}

bool contact_geometry_derivative(const Contact& c, const VecX& x, const Obstacle* obstacle,
                                 ContactGeometryDerivative& out) {
  return derivative_at(c, positions(c, x), obstacle, out);
}

GeometryDerivativeKind contact_geometry_derivative(const Contact& c, const VecX& x, const Obstacle* obstacle,
                                                   const SmoothingOptions& options, ContactGeometryDerivative& out) {
  const Positions P0 = positions(c, x);
  const bool exact = derivative_at(c, P0, obstacle, out);
  if (options.samples <= 0 || !(options.sigma > 0)) return exact ? GeometryDerivativeKind::exact : GeometryDerivativeKind::none;
  // The perturbations z_j (3 count standard normal numbers each) are replayed from the
  // seed: first to test whether the active feature is the same at every sample, then
  // (if not) to average the derivatives.
  auto sample = [&](std::mt19937_64& rng, std::normal_distribution<double>& normal, Positions& P) {
    for (int k = 0; k < c.count; ++k)
      for (int i = 0; i < 3; ++i) P.p[k][i] = P0.p[k][i] + options.sigma * normal(rng);
  };
  Contact cj;
  Positions P = P0;
  bool unique = exact;
  if (unique) {
    std::mt19937_64 rng(contact_seed(c, options.seed));
    std::normal_distribution<double> normal;
    for (int j = 0; j < options.samples && unique; ++j) {
      sample(rng, normal, P);
      unique = feature_at(c, P, obstacle, cj);
    }
  }
  if (unique) return GeometryDerivativeKind::exact;
  std::mt19937_64 rng(contact_seed(c, options.seed));
  std::normal_distribution<double> normal;
  ContactGeometryDerivative sum, dj;
  sum.count = c.count;
  sum.dn.setZero();
  sum.dgap.setZero();
  sum.dweights.setZero();
  sum.dframe.setZero();
  int used = 0;
  for (int j = 0; j < options.samples; ++j) {
    sample(rng, normal, P);
    feature_at(c, P, obstacle, cj);
    if (!derivative_at(cj, P, obstacle, dj)) continue;  // a sample on a measure-zero set
    sum.dn += dj.dn;
    sum.dgap += dj.dgap;
    sum.dweights += dj.dweights;
    sum.dframe += dj.dframe;
    ++used;
  }
  if (used == 0) {
    out = sum;
    return GeometryDerivativeKind::none;
  }
  const double inv = 1.0 / used;
  out.count = c.count;
  out.dn = sum.dn * inv;
  out.dgap = sum.dgap * inv;
  out.dweights = sum.dweights * inv;
  out.dframe = sum.dframe * inv;
  return GeometryDerivativeKind::smoothed;
}

bool smoothed_contact_geometry(const Contact& c, const VecX& x, const Obstacle* obstacle, const SmoothingOptions& options,
                               ContactGeometry& out) {
  SOFTDIFF_DEMAND(options.samples > 0 && options.sigma > 0, "smoothed_contact_geometry: needs samples > 0 and sigma > 0");
  const Positions P0 = positions(c, x);
  std::mt19937_64 rng(contact_seed(c, options.seed));
  std::normal_distribution<double> normal;
  Positions P = P0;
  Contact cj;
  ContactGeometry gj;
  out = ContactGeometry{};
  out.frame.setZero();
  std::array<double, 4> w{};
  int used = 0;
  for (int j = 0; j < options.samples; ++j) {
    for (int k = 0; k < c.count; ++k)
      for (int i = 0; i < 3; ++i) P.p[k][i] = P0.p[k][i] + options.sigma * normal(rng);
    feature_at(c, P, obstacle, cj);
    if (!geometry_at(cj, P, obstacle, gj)) continue;
    out.n += gj.n;
    out.gap += gj.gap;
    for (int k = 0; k < 4; ++k) w[k] += gj.weights[k];
    out.frame += gj.frame;
    ++used;
  }
  if (used == 0) return false;
  out.n /= used;
  out.gap /= used;
  for (int k = 0; k < 4; ++k) out.weights[k] = w[k] / used;
  out.frame /= used;
  return true;
}

}  // namespace softdiff::collision
