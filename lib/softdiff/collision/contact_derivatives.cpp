// Collision-detection derivatives: see contact_derivatives.hpp for the formulas.
#include <softdiff/collision/contact_derivatives.hpp>

#include <softdiff/collision/distance.hpp>
#include <softdiff/core/assert.hpp>

#include <cmath>
#include <limits>

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

bool contact_geometry(const Contact& c, const VecX& x, const Obstacle* obstacle, ContactGeometry& out) {
  const Vec3 n_rec = c.frame.col(2);
  out.weights = c.weights;
  switch (c.kind) {
    case ContactKind::vertex_obstacle: {
      SOFTDIFF_DEMAND(obstacle != nullptr, "contact_geometry: a vertex-obstacle contact needs its obstacle");
      ClosestPoint cp;
      closest_point(*obstacle, node(x, c, 0), std::numeric_limits<double>::infinity(), cp);
      out.n = cp.normal;
      out.gap = cp.distance;
      break;
    }
    case ContactKind::vertex_triangle: {
      const Vec3 p = node(x, c, 0);
      if (c.kind_b == Feature::face) {
        const Vec3 a = node(x, c, 1), b = node(x, c, 2), cc = node(x, c, 3);
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
          const Vec3 a = node(x, c, k[0]), b = node(x, c, k[1]), e = b - a;
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
          const Vec3 d = p - node(x, c, k[0]);
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
      const Vec3 p0 = node(x, c, 0), p1 = node(x, c, 1), q0 = node(x, c, 2), q1 = node(x, c, 3);
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

bool contact_geometry_derivative(const Contact& c, const VecX& x, const Obstacle* obstacle,
                                 ContactGeometryDerivative& out) {
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
      const Vec3 p = node(x, c, 0);
      ClosestPoint cp;
      closest_point(*obstacle, p, std::numeric_limits<double>::infinity(), cp);
      n = cp.normal;
      out.dn.block<3, 3>(0, 0) = normal_derivative(*obstacle, p, cp);
      out.dgap.segment<3>(0) = n.transpose();
      break;
    }
    case ContactKind::vertex_triangle: {
      const Vec3 p = node(x, c, 0);
      const Mat3x12 Dp = select(0);
      if (c.kind_b == Feature::face) {
        const Vec3 a = node(x, c, 1), b = node(x, c, 2), cc = node(x, c, 3);
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
          const Vec3 a = node(x, c, k[0]), b = node(x, c, k[1]), e = b - a;
          const Mat3x12 Da = select(k[0]), De = select(k[1]) - Da;
          const double l2 = e.squaredNorm();
          if (!(l2 > 0)) return false;
          const double t = (p - a).dot(e) / l2;
          const Vec3 d = p - (a + t * e);
          const double ld = d.norm();
          if (!(ld > 0)) return false;
          n = orientation(n_rec, d) * d / ld;
          const Row12 dt = (e.transpose() * (Dp - Da) + (p - a).transpose() * De - 2 * t * e.transpose() * De) / l2;
          const Mat3x12 Dd = Dp - Da - t * De - e * dt;
          out.dn = (I - n * n.transpose()) * (orientation(n_rec, d) / ld) * Dd;
          out.dgap = n.transpose() * (Dp - Da - t * De);
          out.dweights.row(k[0]) = dt;
          out.dweights.row(k[1]) = -dt;
        } else if (c.kind_b == Feature::vertex && m == 1) {
          const Vec3 d = p - node(x, c, k[0]);
          const double ld = d.norm();
          if (!(ld > 0)) return false;
          const double s = orientation(n_rec, d);
          n = s * d / ld;
          const Mat3x12 Dd = Dp - select(k[0]);
          out.dn = (I - n * n.transpose()) * (s / ld) * Dd;
          out.dgap = n.transpose() * Dd;
        } else {
          return false;
        }
      }
      break;
    }
    case ContactKind::edge_edge: {
      const Vec3 p0 = node(x, c, 0), p1 = node(x, c, 1), q0 = node(x, c, 2), q1 = node(x, c, 3);
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
  return out.dn.allFinite() && out.dgap.allFinite() && out.dweights.allFinite();
}

}  // namespace softdiff::collision
