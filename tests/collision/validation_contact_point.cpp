// The paper's collision-detection toy (its Fig. 3.3): a chosen point of a tetrahedron
// is made the contact point by optimization with the analytic collision-detection
// gradient.
//
// A tetrahedron T (nodes 1-4, fixed: a low pyramid over the triangle 1-2-3, whose side
// faces meet at obtuse dihedral angles) and a free point P (node 0, a vertex of another
// body). The contact is P against the closest face of T, a vertex-triangle contact as
// the detector builds it (the closest point's region, barycentric weights, n from T
// towards P); its contact point on T is q = sum_k bary_k x_k over that face. The
// target is a point y of face f0 = {1, 2, 4} with its normal N0: the residual
//     r(P) = [q(P) - y; n(P) - N0]
// needs how the contact point and the normal move with P, i.e. the weights' and the
// normal's derivatives from contact_geometry_derivative (with randomized smoothing
// where the closest feature is not unique). P starts over the side face next to f0, so
// the contact must travel from one face over their common edge (face, edge, face
// regions) before it reaches y.
//
// Checks: Levenberg-Marquardt iterations converge to |r| < 1e-9 with the contact on
// f0; the gradient of 1/2 |r|^2 matches central differences where the feature is
// unique (step 1e-7 on a tet of size 1: truncation ~1e-14, round-off ~1e-9 relative;
// tolerance 1e-6); from a start exactly on a region boundary (f0's face and edge
// regions; built exactly in any floating-point rounding: T's coordinates are dyadic,
// and the test asserts that the start is on the boundary) the smoothed gradient is
// finite and a descent direction, and the iterations converge too; without the
// collision-detection derivative (weights and normal held, as a simulator that does
// not differentiate collision detection would) the gradient is zero and nothing moves.
#include <softdiff/collision/contact_derivatives.hpp>
#include <softdiff/collision/distance.hpp>

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <limits>
#include <vector>

namespace softdiff::collision {
namespace {

// T's faces, outward (node indices into x).
const int kFaces[4][3] = {{1, 3, 2}, {1, 2, 4}, {2, 3, 4}, {3, 1, 4}};
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat63 = Eigen::Matrix<double, 6, 3>;

struct Toy {
  Mat3X X;  // (3, 5): P (the start), then T's vertices
  Vec3 beta{0.5, 0.3, 0.2};
  int target_face = 1;
  bool collision_derivative = true;
  SmoothingOptions smoothing{32, 1e-6, 0};

  VecX positions(const Vec3& p) const {
    Mat3X Y = X;
    Y.col(0) = p;
    return Eigen::Map<const VecX>(Y.data(), Y.size());
  }
  Vec3 vertex(int k) const { return X.col(k); }
  Vec3 target() const {
    Vec3 y = Vec3::Zero();
    for (int i = 0; i < 3; ++i) y += beta[i] * vertex(kFaces[target_face][i]);
    return y;
  }
  Vec3 target_normal() const {
    const auto& f = kFaces[target_face];
    return (vertex(f[1]) - vertex(f[0])).cross(vertex(f[2]) - vertex(f[0])).normalized();
  }
  // P against the closest face of T. A tie (P equidistant from two faces: over their
  // common edge, where the closest point on both is on that edge) goes to the first
  // face in kFaces: over edge 2-4, f0 = {1, 2, 4} rather than face {2, 3, 4}.
  Contact contact(const VecX& x) const {
    const Vec3 p = x.segment<3>(0);
    Contact best;
    double best_d2 = std::numeric_limits<double>::infinity();
    for (const auto& f : kFaces) {
      const PointTriangleResult r = point_triangle_closest(p, vertex(f[0]), vertex(f[1]), vertex(f[2]));
      if (!(r.dist2 < best_d2)) continue;
      best_d2 = r.dist2;
      best.kind = ContactKind::vertex_triangle;
      best.count = 4;
      best.nodes = {0, f[0], f[1], f[2]};
      best.weights = {1, -r.bary[0], -r.bary[1], -r.bary[2]};
      best.frame = frame_from_normal((p - r.point).normalized());
      best.kind_b = r.feature;
    }
    return best;
  }
  Vec6 value(const Vec3& p) const {
    const VecX x = positions(p);
    const Contact c = contact(x);
    ContactGeometry g;
    EXPECT_TRUE(contact_geometry(c, x, nullptr, g));
    Vec3 q = Vec3::Zero();
    for (int k = 1; k < 4; ++k) q -= g.weights[k] * x.segment<3>(3 * c.nodes[k]);
    Vec6 r;
    r.head<3>() = q - target();
    r.tail<3>() = g.n - target_normal();
    return r;
  }
  double loss(const Vec3& p) const { return 0.5 * value(p).squaredNorm(); }
  // r and its Jacobian with respect to P; the kind of geometry derivative used.
  GeometryDerivativeKind residual(const Vec3& p, Vec6& r, Mat63& J) const {
    const VecX x = positions(p);
    const Contact c = contact(x);
    r = value(p);
    ContactGeometryDerivative d;
    const GeometryDerivativeKind kind = contact_geometry_derivative(c, x, nullptr, smoothing, d);
    J.setZero();
    if (!collision_derivative) return kind;
    // P is the contact's node 0: columns 0..2. T's nodes do not move.
    for (int k = 1; k < 4; ++k) J.topRows<3>() -= x.segment<3>(3 * c.nodes[k]) * d.dweights.block<1, 3>(k, 0);
    J.bottomRows<3>() = d.dn.leftCols<3>();
    return kind;
  }
  Vec3 gradient(const Vec3& p) const {
    Vec6 r;
    Mat63 J;
    residual(p, r, J);
    return J.transpose() * r;
  }
};

// T's vertices are dyadic rationals with few bits (0.875 = 7/8, 0.125 = 1/8): the
// edge vectors, their cross products and the closest-point tests' dot products are
// exact in double precision, with or without fused multiply-adds, so that a point built
// on a region boundary is on it on every build (see the boundary test).
Toy make_toy() {
  Toy t;
  t.X.resize(3, 5);
  t.X.col(1) = Vec3(0, 0, 0);
  t.X.col(2) = Vec3(1, 0, 0);
  t.X.col(3) = Vec3(0.5, 0.875, 0);
  t.X.col(4) = Vec3(0.5, 0.25, 0.125);
  // P 0.3 above the centroid of face {2, 3, 4}, which shares edge 2-4 with f0.
  const auto& f = kFaces[2];
  const Vec3 a = t.X.col(f[0]), b = t.X.col(f[1]), c = t.X.col(f[2]);
  t.X.col(0) = (a + b + c) / 3 + 0.3 * (b - a).cross(c - a).normalized();
  return t;
}

struct Result {
  int iterations = 0;
  double residual = 0;
  int smoothed = 0;  // iterates whose geometry derivative was the smoothed estimate
  std::vector<Feature> features;
  Contact last;
};

// Levenberg-Marquardt on r(P) with a backtracking acceptance (J is rank 2 on a face:
// the distance along the normal is free).
Result optimize(const Toy& toy, Vec3 p, int max_iterations = 100) {
  Result res;
  double mu = 1e-3;
  for (int it = 0; it < max_iterations; ++it) {
    Vec6 r;
    Mat63 J;
    const GeometryDerivativeKind kind = toy.residual(p, r, J);
    res.smoothed += kind == GeometryDerivativeKind::smoothed;
    res.last = toy.contact(toy.positions(p));
    res.features.push_back(res.last.kind_b);
    res.residual = r.norm();
    res.iterations = it;
    if (res.residual < 1e-10) return res;
    const Vec3 g = J.transpose() * r;
    if (!(g.norm() > 1e-14)) return res;  // stalled
    bool accepted = false;
    for (int k = 0; k < 40 && !accepted; ++k) {
      const Vec3 dp = -(J.transpose() * J + mu * Mat3::Identity()).ldlt().solve(g);
      if (toy.loss(p + dp) < 0.5 * r.squaredNorm()) {
        p += dp;
        mu = std::max(mu / 3, 1e-12);
        accepted = true;
      } else {
        mu *= 4;
      }
    }
    if (!accepted) return res;
  }
  return res;
}

TEST(ContactPointToy, ConvergesWithTheAnalyticGradient) {
  const Toy toy = make_toy();
  const Vec3 p0 = toy.X.col(0);
  // The gradient against central differences at the start (over face {2, 3, 4}), over
  // the edge 2-4 and over f0.
  const Vec3 over_edge = 0.5 * (toy.vertex(2) + toy.vertex(4)) + Vec3(0.2, -0.1, 0.3);
  const Vec3 over_f0 = toy.target() + Vec3(0.05, -0.2, 0.3);
  for (const Vec3& p : {p0, over_edge, over_f0}) {
    constexpr double h = 1e-7;
    Vec3 fd;
    for (int i = 0; i < 3; ++i) {
      Vec3 pp = p, pm = p;
      pp[i] += h;
      pm[i] -= h;
      fd[i] = (toy.loss(pp) - toy.loss(pm)) / (2 * h);
    }
    const Vec3 g = toy.gradient(p);
    EXPECT_LE((g - fd).norm(), 1e-6 * fd.norm()) << "P = " << p.transpose() << "\n" << g.transpose() << "\n" << fd.transpose();
  }
  EXPECT_EQ(toy.contact(toy.positions(over_edge)).kind_b, Feature::edge);
  const Result r = optimize(toy, p0);
  EXPECT_LT(r.residual, 1e-9) << r.iterations << " iterations";
  EXPECT_LT(r.iterations, 50);
  // The contact crossed from face {2, 3, 4} over the edge onto f0.
  ASSERT_FALSE(r.features.empty());
  EXPECT_EQ(r.features.front(), Feature::face);
  EXPECT_NE(std::find(r.features.begin(), r.features.end(), Feature::edge), r.features.end());
  EXPECT_EQ(r.features.back(), Feature::face);
  EXPECT_EQ(r.last.nodes[1], kFaces[1][0]);
  EXPECT_EQ(r.last.nodes[3], kFaces[1][2]);
}

TEST(ContactPointToy, FromARegionBoundaryTheSmoothedGradientDescends) {
  const Toy toy = make_toy();
  // P on the boundary of f0's face region, over its edge 2-4: the edge's midpoint plus
  // half the (unnormalized) cross product of two of f0's edges. Every term is a dyadic
  // rational with few bits: P is exact, and so are the closest-point tests below,
  // whatever the instruction set (fused multiply-adds or not).
  const auto& f = kFaces[1];
  const Vec3 a = toy.vertex(f[0]), b = toy.vertex(f[1]), c = toy.vertex(f[2]);
  const Vec3 p = 0.5 * (b + c) + 0.5 * (b - a).cross(c - a);
  EXPECT_EQ(p, Vec3(0.75, 0.0625, 0.1875));
  // On the boundary: f0's closest point is the edge's midpoint, in the edge region
  // with vertex 1's weight exactly 0 (P projects onto the edge: the face and edge
  // regions meet there); face {2, 3, 4}'s closest point is the same (P is equidistant
  // from both faces, a tie that goes to f0), and the contact is on f0.
  const PointTriangleResult on_f0 = point_triangle_closest(p, a, b, c);
  ASSERT_EQ(on_f0.feature, Feature::edge);
  ASSERT_EQ(on_f0.bary[0], 0.0);
  ASSERT_EQ(on_f0.point, Vec3(0.5 * (b + c)));
  const auto& f2 = kFaces[2];
  ASSERT_EQ(point_triangle_closest(p, toy.vertex(f2[0]), toy.vertex(f2[1]), toy.vertex(f2[2])).dist2, on_f0.dist2);
  const Contact start = toy.contact(toy.positions(p));
  ASSERT_EQ(start.nodes[1], f[0]);
  ASSERT_EQ(start.nodes[2], f[1]);
  ASSERT_EQ(start.nodes[3], f[2]);
  Vec6 r;
  Mat63 J;
  ASSERT_EQ(toy.residual(p, r, J), GeometryDerivativeKind::smoothed);
  const Vec3 g = J.transpose() * r;
  ASSERT_TRUE(g.allFinite());
  ASSERT_GT(g.norm(), 0);
  EXPECT_LT(toy.loss(p - 1e-4 * g / g.norm()), toy.loss(p));  // a descent direction
  const Result res = optimize(toy, p);
  EXPECT_LT(res.residual, 1e-9);
  EXPECT_GE(res.smoothed, 1);
}

TEST(ContactPointToy, WithoutTheCollisionDerivativeItStalls) {
  Toy toy = make_toy();
  toy.collision_derivative = false;
  // The contact point held at its barycentric coordinates on the fixed T and the
  // normal held: the residual does not move with P, the gradient is zero.
  const Result r = optimize(toy, toy.X.col(0));
  EXPECT_GT(r.residual, 0.1);
  EXPECT_EQ(r.iterations, 0);
}

}  // namespace
}  // namespace softdiff::collision
