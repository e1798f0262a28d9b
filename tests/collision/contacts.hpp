#pragma once
// Shared fixtures of the collision-derivative tests: contacts built as the detector
// builds them on a few free nodes (node k of the contact at 3k in x), and central
// differences of a contact-geometry function over the contact's node coordinates.
#include <softdiff/collision/contact_derivatives.hpp>
#include <softdiff/collision/distance.hpp>

#include <functional>
#include <string>
#include <vector>

namespace softdiff::collision::contact_test {

// Positions of a few nodes in a global vector (node k at 3k).
inline VecX flat(const std::vector<Vec3>& p) {
  VecX x(3 * static_cast<Eigen::Index>(p.size()));
  for (std::size_t k = 0; k < p.size(); ++k) x.segment<3>(3 * static_cast<Eigen::Index>(k)) = p[k];
  return x;
}

// Vertex 0 against triangle 1-2-3: the closest point's region and barycentric
// weights, n from the triangle towards the vertex (the face normal at zero distance).
inline Contact vertex_triangle_contact(const VecX& x) {
  const Vec3 p = x.segment<3>(0), a = x.segment<3>(3), b = x.segment<3>(6), c = x.segment<3>(9);
  const PointTriangleResult r = point_triangle_closest(p, a, b, c);
  Contact k;
  k.kind = ContactKind::vertex_triangle;
  k.count = 4;
  k.nodes = {0, 1, 2, 3};
  k.weights = {1, -r.bary[0], -r.bary[1], -r.bary[2]};
  const Vec3 d = p - r.point;
  k.frame = frame_from_normal(d.norm() > 0 ? Vec3(d.normalized()) : Vec3((b - a).cross(c - a).normalized()));
  k.gap = d.norm();
  k.kind_b = r.feature;
  return k;
}

// Edge 0-1 against edge 2-3 at their closest points.
inline Contact edge_edge_contact(const VecX& x) {
  const SegmentSegmentResult r = segment_segment_closest(x.segment<3>(0), x.segment<3>(3), x.segment<3>(6), x.segment<3>(9));
  Contact k;
  k.kind = ContactKind::edge_edge;
  k.count = 4;
  k.nodes = {0, 1, 2, 3};
  k.weights = {1 - r.s, r.s, -(1 - r.t), -r.t};
  const Vec3 d = r.point_p - r.point_q;
  k.frame = frame_from_normal(d.normalized());
  k.gap = d.norm();
  k.kind_b = Feature::edge;
  return k;
}

// Vertex 0 (at p) against an obstacle.
inline Contact vertex_obstacle_contact(const Obstacle& o, const Vec3& p) {
  ClosestPoint cp;
  closest_point(o, p, 1.0, cp);
  Contact k;
  k.kind = ContactKind::vertex_obstacle;
  k.count = 1;
  k.nodes = {0, -1, -1, -1};
  k.weights = {1, 0, 0, 0};
  k.frame = frame_from_normal(cp.normal);
  k.gap = cp.distance;
  k.kind_b = cp.feature_kind;
  k.feature_b = cp.feature;
  return k;
}

// Central differences (step h) of a geometry g(x) over the contact's node coordinates,
// in the layout of ContactGeometryDerivative. ok is false if g failed somewhere.
struct GeometryDifferences {
  Eigen::Matrix<double, 3, 12> dn = Eigen::Matrix<double, 3, 12>::Zero();
  Eigen::Matrix<double, 1, 12> dgap = Eigen::Matrix<double, 1, 12>::Zero();
  Eigen::Matrix<double, 4, 12> dweights = Eigen::Matrix<double, 4, 12>::Zero();
  Eigen::Matrix<double, 9, 12> dframe = Eigen::Matrix<double, 9, 12>::Zero();
  bool ok = true;
};

inline GeometryDifferences geometry_differences(const Contact& c, const VecX& x, double h,
                                                const std::function<bool(const VecX&, ContactGeometry&)>& g) {
  GeometryDifferences d;
  for (int k = 0; k < c.count; ++k)
    for (int j = 0; j < 3; ++j) {
      VecX xp = x, xm = x;
      xp[3 * c.nodes[k] + j] += h;
      xm[3 * c.nodes[k] + j] -= h;
      ContactGeometry gp, gm;
      if (!g(xp, gp) || !g(xm, gm)) {
        d.ok = false;
        return d;
      }
      const int col = 3 * k + j;
      d.dn.col(col) = (gp.n - gm.n) / (2 * h);
      d.dgap(col) = (gp.gap - gm.gap) / (2 * h);
      for (int w = 0; w < 4; ++w) d.dweights(w, col) = (gp.weights[w] - gm.weights[w]) / (2 * h);
      d.dframe.col(col) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>((gp.frame - gm.frame).eval().data()) / (2 * h);
    }
  return d;
}

}  // namespace softdiff::collision::contact_test
