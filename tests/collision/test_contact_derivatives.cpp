// Collision-detection derivatives (contact_derivatives.hpp): the normal, frame, gap and
// weights of a contact against central differences of contact_geometry(), for every
// feature pair: vertex-face, vertex-edge, vertex-vertex, edge-edge, and a vertex against
// each obstacle (plane, box face / edge / vertex, sphere, capsule side and cap,
// cylinder side, cap and rim, mesh face / edge / vertex); and contact_geometry() at the
// detector's positions reproduces the detector's contacts.
//
// Step: 1e-7 m on configurations of size 0.1-1 m (1e-6 of the element size, as
// support/fd.hpp), away from region boundaries; central differences then carry ~1e-10
// relative error: tolerance 1e-6 per block.
#include <softdiff/collision/contact_derivatives.hpp>
#include <softdiff/collision/distance.hpp>

#include <support/meshes.hpp>

#include "scene.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>

namespace softdiff::collision {
namespace {

constexpr double kStep = 1e-7;
constexpr double kTol = 1e-6;

// Finite differences of contact_geometry over the contact's node coordinates.
void check_derivative(const Contact& c, const VecX& x, const Obstacle* o, const std::string& what) {
  ContactGeometryDerivative d;
  ASSERT_TRUE(contact_geometry_derivative(c, x, o, d)) << what;
  Eigen::Matrix<double, 3, 12> dn_fd = Eigen::Matrix<double, 3, 12>::Zero();
  Eigen::Matrix<double, 1, 12> dgap_fd = Eigen::Matrix<double, 1, 12>::Zero();
  Eigen::Matrix<double, 4, 12> dw_fd = Eigen::Matrix<double, 4, 12>::Zero();
  Eigen::Matrix<double, 9, 12> dframe_fd = Eigen::Matrix<double, 9, 12>::Zero();
  for (int k = 0; k < c.count; ++k)
    for (int j = 0; j < 3; ++j) {
      VecX xp = x, xm = x;
      xp[3 * c.nodes[k] + j] += kStep;
      xm[3 * c.nodes[k] + j] -= kStep;
      ContactGeometry gp, gm;
      ASSERT_TRUE(contact_geometry(c, xp, o, gp) && contact_geometry(c, xm, o, gm)) << what;
      const int col = 3 * k + j;
      dn_fd.col(col) = (gp.n - gm.n) / (2 * kStep);
      dgap_fd(col) = (gp.gap - gm.gap) / (2 * kStep);
      for (int w = 0; w < 4; ++w) dw_fd(w, col) = (gp.weights[w] - gm.weights[w]) / (2 * kStep);
      dframe_fd.col(col) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>((gp.frame - gm.frame).eval().data()) / (2 * kStep);
    }
  auto expect_close = [&](const auto& a, const auto& b, const char* name) {
    // A floor of 0.1 (the natural size of dn ~ 1/distance is 1-10 here): a derivative
    // that is zero (a flat face) then compares its finite differences' round-off,
    // ~eps |n| / step ~ 1e-9 per entry, with 1e-7.
    const double scale = std::max(b.norm(), 0.1);
    EXPECT_LE((a - b).norm(), kTol * scale) << what << " " << name << ": analytic\n" << a << "\nfd\n" << b;
  };
  expect_close(d.dn, dn_fd, "dn");
  expect_close(d.dgap, dgap_fd, "dgap");
  expect_close(d.dframe, dframe_fd, "dframe");
  if (dw_fd.norm() > 0 || d.dweights.norm() > 0) expect_close(d.dweights, dw_fd, "dweights");
  EXPECT_GT(d.dgap.norm(), 0) << what;
}

// Positions of 4 nodes in a global vector (node k at 3k).
VecX flat(const std::vector<Vec3>& p) {
  VecX x(3 * p.size());
  for (std::size_t k = 0; k < p.size(); ++k) x.segment<3>(3 * k) = p[k];
  return x;
}

// A vertex-triangle contact built as the detector builds it (the closest point's
// region and barycentric weights; n from the triangle towards the vertex).
Contact vertex_triangle(const VecX& x, Feature expected) {
  const Vec3 p = x.segment<3>(0), a = x.segment<3>(3), b = x.segment<3>(6), c = x.segment<3>(9);
  const PointTriangleResult r = point_triangle_closest(p, a, b, c);
  EXPECT_EQ(r.feature, expected);
  Contact k;
  k.kind = ContactKind::vertex_triangle;
  k.count = 4;
  k.nodes = {0, 1, 2, 3};
  k.weights = {1, -r.bary[0], -r.bary[1], -r.bary[2]};
  const Vec3 d = p - r.point;
  k.frame = frame_from_normal(d.normalized());
  k.gap = d.norm();
  k.kind_b = r.feature;
  return k;
}

TEST(ContactDerivatives, VertexTriangleFaceEdgeVertex) {
  const Vec3 a(0, 0, 0), b(0.3, 0.05, 0.02), c(0.07, 0.25, -0.03);
  // Above the face, beyond edge ab, beyond vertex c.
  const Vec3 face = (a + b + c) / 3 + Vec3(0.01, -0.02, 0.15);
  const Vec3 edge = 0.4 * a + 0.6 * b + Vec3(0.02, -0.12, 0.05);
  const Vec3 vertex = c + Vec3(-0.05, 0.1, 0.08);
  for (const auto& [p, feature, name] : {std::tuple{face, Feature::face, "face"}, std::tuple{edge, Feature::edge, "edge"},
                                         std::tuple{vertex, Feature::vertex, "vertex"}}) {
    const VecX x = flat({p, a, b, c});
    const Contact k = vertex_triangle(x, feature);
    ContactGeometry g;
    ASSERT_TRUE(contact_geometry(k, x, nullptr, g));
    EXPECT_LT((g.frame - k.frame).norm(), 1e-12) << name;
    EXPECT_NEAR(g.gap, k.gap, 1e-14) << name;
    for (int w = 0; w < 4; ++w) EXPECT_NEAR(g.weights[w], k.weights[w], 1e-14) << name;
    check_derivative(k, x, nullptr, std::string("vertex-") + name);
  }
}

TEST(ContactDerivatives, EdgeEdgeInterior) {
  const Vec3 p0(0, 0, 0.01), p1(0.3, 0.02, 0.03), q0(0.1, -0.1, -0.04), q1(0.16, 0.2, -0.02);
  const VecX x = flat({p0, p1, q0, q1});
  const SegmentSegmentResult r = segment_segment_closest(p0, p1, q0, q1);
  ASSERT_TRUE(r.interior());
  Contact k;
  k.kind = ContactKind::edge_edge;
  k.count = 4;
  k.nodes = {0, 1, 2, 3};
  k.weights = {1 - r.s, r.s, -(1 - r.t), -r.t};
  const Vec3 d = r.point_p - r.point_q;
  k.frame = frame_from_normal(d.normalized());
  k.gap = d.norm();
  k.kind_b = Feature::edge;
  ContactGeometry g;
  ASSERT_TRUE(contact_geometry(k, x, nullptr, g));
  EXPECT_LT((g.frame - k.frame).norm(), 1e-10);
  EXPECT_NEAR(g.gap, k.gap, 1e-14);
  for (int w = 0; w < 4; ++w) EXPECT_NEAR(g.weights[w], k.weights[w], 1e-12);
  check_derivative(k, x, nullptr, "edge-edge");
}

Obstacle shape(ShapeKind kind) {
  Obstacle o;
  o.name = "o";
  o.kind = kind;
  o.rotation = Eigen::AngleAxisd(0.4, Vec3(1, 2, 0.5).normalized()).toRotationMatrix();
  o.center = Vec3(0.1, -0.05, 0.02);
  o.normal = Vec3(0.2, -0.3, 1).normalized();
  o.offset = 0.01;
  o.half_extents = Vec3(0.2, 0.15, 0.1);
  o.radius = 0.08;
  o.half_length = 0.12;
  if (kind == ShapeKind::mesh) {
    // A box as a closed triangle surface (outward), rotated.
    const mesh::TetMesh m = test::box_mesh(1, 1, 1, 0.4, 0.3, 0.2);
    o.mesh.vertices = o.rotation * (m.X.colwise() - Vec3(0.2, 0.15, 0.1));
    o.mesh.vertices.colwise() += o.center;
    o.mesh.triangles = mesh::boundary_triangles(m.tets);
  }
  prepare(o);
  return o;
}

TEST(ContactDerivatives, VertexAgainstEveryObstacleFeature) {
  struct Case {
    ShapeKind kind;
    Vec3 local;  // query in the obstacle's local frame (world for the plane and the sphere)
    Feature feature;
    const char* name;
  };
  const Case cases[] = {
      {ShapeKind::plane, Vec3(0.3, 0.1, 0.05), Feature::face, "plane"},
      {ShapeKind::sphere, Vec3(0.15, 0.02, 0.09), Feature::smooth, "sphere"},
      {ShapeKind::box, Vec3(0.05, 0.02, 0.13), Feature::face, "box face"},
      {ShapeKind::box, Vec3(0.05, 0.19, 0.14), Feature::edge, "box edge"},
      {ShapeKind::box, Vec3(0.23, 0.19, 0.14), Feature::vertex, "box vertex"},
      {ShapeKind::capsule, Vec3(0.07, 0.05, 0.03), Feature::smooth, "capsule side"},
      {ShapeKind::capsule, Vec3(0.03, 0.04, 0.19), Feature::smooth, "capsule cap"},
      {ShapeKind::cylinder, Vec3(0.07, 0.06, 0.02), Feature::smooth, "cylinder side"},
      {ShapeKind::cylinder, Vec3(0.02, 0.03, 0.16), Feature::face, "cylinder cap"},
      {ShapeKind::cylinder, Vec3(0.09, 0.04, 0.15), Feature::edge, "cylinder rim"},
      {ShapeKind::mesh, Vec3(0.05, 0.02, 0.13), Feature::face, "mesh face"},
      {ShapeKind::mesh, Vec3(0.05, 0.19, 0.14), Feature::edge, "mesh edge"},
      {ShapeKind::mesh, Vec3(0.23, 0.19, 0.14), Feature::vertex, "mesh vertex"},
  };
  for (const Case& c : cases) {
    const Obstacle o = shape(c.kind);
    const bool posed = c.kind != ShapeKind::plane && c.kind != ShapeKind::sphere;
    const Vec3 p = posed ? Vec3(o.rotation * c.local + o.center) : Vec3(c.kind == ShapeKind::sphere ? o.center + c.local : c.local);
    ClosestPoint cp;
    ASSERT_TRUE(closest_point(o, p, 1.0, cp)) << c.name;
    ASSERT_EQ(cp.feature_kind, c.feature) << c.name;
    Contact k;
    k.kind = ContactKind::vertex_obstacle;
    k.count = 1;
    k.nodes = {0, -1, -1, -1};
    k.weights = {1, 0, 0, 0};
    k.frame = frame_from_normal(cp.normal);
    k.gap = cp.distance;
    k.kind_b = cp.feature_kind;
    const VecX x = p;
    ContactGeometry g;
    ASSERT_TRUE(contact_geometry(k, x, &o, g));
    EXPECT_LT((g.frame - k.frame).norm(), 1e-14) << c.name;
    check_derivative(k, x, &o, c.name);
    ContactGeometryDerivative d;
    ASSERT_TRUE(contact_geometry_derivative(k, x, &o, d));
    // Curved features turn the normal; flat ones do not.
    if (c.feature == Feature::face) EXPECT_EQ(d.dn.norm(), 0) << c.name;
    else EXPECT_GT(d.dn.norm(), 0) << c.name;
  }
}

TEST(ContactDerivatives, GeometryReproducesTheDetectorsContacts) {
  // Two jittered boxes facing (vertex-face from both sides, edge-edge) and a pair of
  // crossed ridges (edge-edge): contact_geometry at the detector's positions gives the
  // detector's frame, gap and weights; the derivative is checked on each.
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-1, 1);
  Scene s;
  mesh::TetMesh a = test::box_mesh(3, 3, 1, 0.3, 0.3, 0.1), b = a;
  for (int i = 0; i < b.num_nodes(); ++i)
    for (int c = 0; c < 3; ++c) b.X(c, i) += 2e-3 * u(rng);
  b.X = Eigen::AngleAxisd(0.05, Vec3(0.3, 1, 0).normalized()).toRotationMatrix() * b.X;
  s.add(a, Vec3::Zero(), "a");
  s.add(b, Vec3(0.013, 0.021, 0.1 + 2e-4), "b");
  ContactSet cs;
  CollisionDetector(model_of(s, {}, {{0, 1, 0.2}}, 6e-3)).detect(s.x(), cs);
  int counts[3] = {0, 0, 0};
  for (const auto& c : cs.contacts) {
    ContactGeometry g;
    ASSERT_TRUE(contact_geometry(c, s.x(), nullptr, g));
    EXPECT_LT((g.frame - c.frame).norm(), 1e-9) << "contact kind " << static_cast<int>(c.kind);
    EXPECT_NEAR(g.gap, c.gap, 1e-12);
    for (int w = 0; w < 4; ++w) EXPECT_NEAR(g.weights[w], c.weights[w], 1e-12);
    ++counts[static_cast<int>(c.kind)];
    if (counts[static_cast<int>(c.kind)] <= 5) check_derivative(c, s.x(), nullptr, "detected contact");
  }
  EXPECT_GT(counts[1], 5);  // vertex-triangle
  EXPECT_GT(counts[2], 0);  // edge-edge
}

}  // namespace
}  // namespace softdiff::collision
