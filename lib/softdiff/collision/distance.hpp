#pragma once
// Narrow-phase kernels (IPC-Toolkit style: one small header of exact closest-point
// queries): point-triangle and segment-segment closest points with barycentric
// weights and the region (feature) that holds the closest point.
//
// point_triangle: Ericson, "Real-Time Collision Detection", 5.1.5 (Voronoi regions
// of the vertices, then the edges, then the face). Local feature indices: vertex
// k = a, b, c (0, 1, 2); edge k = ab, bc, ca (0, 1, 2). A degenerate triangle
// (zero area) falls back to the closest of its three edges.
//
// segment_segment: Ericson 5.1.9, with the parallel / degenerate cases handled
// (s = 0 for parallel segments, then clamped), so that the result is a true
// minimizer; s and t are clamped exactly to 0 or 1 at the endpoints, which is how
// the region (endpoint or interior) is read.
#include <softdiff/collision/contact_set.hpp>
#include <softdiff/core/types.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <limits>

namespace softdiff::collision {

struct PointTriangleResult {
  Vec3 point = Vec3::Zero();      // closest point on the triangle
  Vec3 bary = Vec3::Zero();       // its barycentric coordinates (a, b, c), >= 0, sum 1
  Feature feature = Feature::face;
  int local = 0;                  // vertex 0..2 or edge 0..2 (ab, bc, ca); 0 for the face
  double dist2 = 0;               // squared distance
};

namespace detail {
inline double clamp01(double v) { return v < 0 ? 0 : (v > 1 ? 1 : v); }
// Closest point of p on segment [a, b]: parameter in [0, 1].
inline double segment_param(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double l2 = ab.squaredNorm();
  if (!(l2 > 0)) return 0;
  return clamp01((p - a).dot(ab) / l2);
}
}  // namespace detail

inline PointTriangleResult point_triangle_closest(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  PointTriangleResult r;
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  auto set_vertex = [&](int k, const Vec3& q) {
    r.point = q;
    r.bary.setZero();
    r.bary[k] = 1;
    r.feature = Feature::vertex;
    r.local = k;
  };
  auto set_edge = [&](int k, double t) {  // edge k from vertex k to vertex (k+1)%3, parameter t in (0, 1)
    const int k1 = (k + 1) % 3;
    r.bary.setZero();
    r.bary[k] = 1 - t;
    r.bary[k1] = t;
    r.point = r.bary[0] * a + r.bary[1] * b + r.bary[2] * c;
    r.feature = Feature::edge;
    r.local = k;
  };
  auto finish = [&]() {
    r.dist2 = (p - r.point).squaredNorm();
    return r;
  };
  if (d1 <= 0 && d2 <= 0) {
    set_vertex(0, a);
    return finish();
  }
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) {
    set_vertex(1, b);
    return finish();
  }
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    set_edge(0, d1 / (d1 - d3));
    return finish();
  }
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) {
    set_vertex(2, c);
    return finish();
  }
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    set_edge(2, 1 - d2 / (d2 - d6));  // edge ca: from c (t = 0) to a (t = 1); weight of a = d2/(d2-d6)
    return finish();
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    set_edge(1, (d4 - d3) / ((d4 - d3) + (d5 - d6)));
    return finish();
  }
  const double denom = va + vb + vc;
  if (!(denom > 0)) {  // degenerate triangle: the closest of the three edges
    PointTriangleResult best;
    best.dist2 = std::numeric_limits<double>::infinity();
    const std::array<const Vec3*, 3> v{&a, &b, &c};
    for (int k = 0; k < 3; ++k) {
      const double t = detail::segment_param(p, *v[k], *v[(k + 1) % 3]);
      set_edge(k, t);
      finish();
      if (r.dist2 < best.dist2) best = r;
    }
    return best;
  }
  const double v = vb / denom, w = vc / denom;
  r.bary = Vec3(1 - v - w, v, w);
  r.point = a + v * ab + w * ac;
  r.feature = Feature::face;
  r.local = 0;
  return finish();
}

struct SegmentSegmentResult {
  double s = 0, t = 0;            // parameters on [p0, p1] and [q0, q1], in [0, 1]
  Vec3 point_p = Vec3::Zero();    // p0 + s (p1 - p0)
  Vec3 point_q = Vec3::Zero();    // q0 + t (q1 - q0)
  double dist2 = 0;
  // Both closest points strictly inside their segments, by more than eps (parameter
  // units): closest points at an endpoint up to round-off are endpoint cases.
  bool interior(double eps = 1e-9) const { return s > eps && s < 1 - eps && t > eps && t < 1 - eps; }
};

inline SegmentSegmentResult segment_segment_closest(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1) {
  SegmentSegmentResult r;
  const Vec3 d1 = p1 - p0, d2 = q1 - q0, w = p0 - q0;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(w);
  // Relative tolerance for degenerate segments and parallelism.
  const double tiny = 1e-30;
  double s = 0, t = 0;
  if (a <= tiny && e <= tiny) {
    s = t = 0;
  } else if (a <= tiny) {
    s = 0;
    t = detail::clamp01(f / e);
  } else {
    const double c = d1.dot(w);
    if (e <= tiny) {
      t = 0;
      s = detail::clamp01(-c / a);
    } else {
      const double b = d1.dot(d2);
      const double denom = a * e - b * b;  // >= 0
      s = denom > 1e-14 * a * e ? detail::clamp01((b * f - c * e) / denom) : 0;
      const double tnom = b * s + f;
      if (tnom < 0) {
        t = 0;
        s = detail::clamp01(-c / a);
      } else if (tnom > e) {
        t = 1;
        s = detail::clamp01((b - c) / a);
      } else {
        t = tnom / e;
      }
    }
  }
  r.s = s;
  r.t = t;
  r.point_p = p0 + s * d1;
  r.point_q = q0 + t * d2;
  r.dist2 = (r.point_p - r.point_q).squaredNorm();
  return r;
}

}  // namespace softdiff::collision
