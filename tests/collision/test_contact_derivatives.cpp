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

#include "contacts.hpp"
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
  const auto fd = contact_test::geometry_differences(c, x, kStep, [&](const VecX& y, ContactGeometry& g) {
    return contact_geometry(c, y, o, g);
  });
  ASSERT_TRUE(fd.ok) << what;
  const auto& dn_fd = fd.dn;
  const auto& dgap_fd = fd.dgap;
  const auto& dw_fd = fd.dweights;
  const auto& dframe_fd = fd.dframe;
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

using contact_test::flat;

// A vertex-triangle contact as the detector builds it, in the expected region.
Contact vertex_triangle(const VecX& x, Feature expected) {
  const Contact k = contact_test::vertex_triangle_contact(x);
  EXPECT_EQ(k.kind_b, expected);
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
  ASSERT_TRUE(segment_segment_closest(p0, p1, q0, q1).interior());
  const Contact k = contact_test::edge_edge_contact(x);
  ContactGeometry g;
  ASSERT_TRUE(contact_geometry(k, x, nullptr, g));
  EXPECT_LT((g.frame - k.frame).norm(), 1e-10);
  EXPECT_NEAR(g.gap, k.gap, 1e-14);
  for (int w = 0; w < 4; ++w) EXPECT_NEAR(g.weights[w], k.weights[w], 1e-12);
  check_derivative(k, x, nullptr, "edge-edge");
}

// A vertex resting 1e-12 m above a flat diagonal edge (detection records it against the
// face's plane: Detection.FlatEdgeAtATinyGapIsTheFacesContactSharpEdgeIsNot): its normal,
// frame, gap and weights are the face's, and so is their derivative (the face normal's,
// not (I - n n^T) / |d| of the edge's d / |d|, ~1e12 here): against central differences
// of contact_geometry (kStep, kTol as above: the face formulas are smooth across the
// diagonal, so the 1e-7 m step may cross it).
TEST(ContactDerivatives, FlatEdgeAtATinyGapIsDifferentiatedAsTheFace) {
  Vec3 up;
  const Scene s = corner_on_box_top(Vec3(0.1, 0.1, 0.2), 1e-12, up);
  ContactSet cs;
  CollisionDetector(model_of(s, {}, {{0, 1, 0}}, 1e-3)).detect(s.x(), cs);
  ASSERT_GT(cs.size(), 0);
  for (const auto& c : cs.contacts) {
    ASSERT_EQ(c.kind_b, Feature::face);
    ContactGeometry g;
    ASSERT_TRUE(contact_geometry(c, s.x(), nullptr, g));
    EXPECT_LT((g.frame - c.frame).norm(), 1e-12);
    EXPECT_NEAR(g.gap, c.gap, 1e-14);
    for (int w = 0; w < 4; ++w) EXPECT_NEAR(g.weights[w], c.weights[w], 1e-12);
    check_derivative(c, s.x(), nullptr, "vertex on a flat edge");
  }
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
    const Contact k = contact_test::vertex_obstacle_contact(o, p);
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
