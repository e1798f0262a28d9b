// Rigid shapes (lib/softdiff/rigid/shapes.cpp): mass properties against closed forms,
// meshes against primitives, tessellations closed and outward.
#include <softdiff/collision/detection.hpp>
#include <softdiff/rigid/rigid_body.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <utility>
#include <vector>

using namespace softdiff;
using namespace softdiff::rigid;

namespace rigid_shapes_test {

constexpr double pi = std::numbers::pi;

Shape box(double a, double b, double c) {
  Shape s;
  s.kind = Shape::Kind::box;
  s.half_extents = Vec3(a, b, c);
  return s;
}
Shape round(Shape::Kind kind, double r, double L) {
  Shape s;
  s.kind = kind;
  s.radius = r;
  s.length = L;
  return s;
}
Shape mesh_of(const Surface& surface) {
  Shape s;
  s.kind = Shape::Kind::mesh;
  s.mesh_vertices = surface.vertices;
  s.mesh_triangles = surface.triangles;
  return s;
}

// Every directed edge once, and its reverse once (closed, consistently oriented).
bool closed(const Surface& s) {
  std::vector<std::pair<int, int>> e;
  for (Eigen::Index t = 0; t < s.triangles.cols(); ++t)
    for (int k = 0; k < 3; ++k) e.emplace_back(s.triangles(k, t), s.triangles((k + 1) % 3, t));
  std::sort(e.begin(), e.end());
  if (std::adjacent_find(e.begin(), e.end()) != e.end()) return false;
  for (auto [a, b] : e)
    if (!std::binary_search(e.begin(), e.end(), std::make_pair(b, a))) return false;
  return true;
}

// Convex shapes about their centre (the origin): every triangle's normal points away
// from it and no triangle is degenerate.
double min_outward(const Surface& s) {
  double worst = 1e300;
  for (Eigen::Index t = 0; t < s.triangles.cols(); ++t) {
    const Vec3 a = s.vertices.col(s.triangles(0, t)), b = s.vertices.col(s.triangles(1, t)),
               c = s.vertices.col(s.triangles(2, t));
    const Vec3 n = (b - a).cross(c - a);
    worst = std::min(worst, n.normalized().dot((a + b + c).normalized() / 3));
  }
  return worst;
}

TEST(RigidMassProperties, ClosedForms) {
  const double rho = 1200;
  {
    const MassProperties p = mass_properties(box(0.1, 0.2, 0.3), rho);
    const double m = rho * 0.2 * 0.4 * 0.6;
    EXPECT_NEAR(p.mass, m, 1e-12 * m);
    EXPECT_NEAR(p.inertia(0, 0), m * (0.4 * 0.4 + 0.6 * 0.6) / 12, 1e-12 * m);
    EXPECT_NEAR(p.inertia(1, 1), m * (0.2 * 0.2 + 0.6 * 0.6) / 12, 1e-12 * m);
    EXPECT_NEAR(p.inertia(2, 2), m * (0.2 * 0.2 + 0.4 * 0.4) / 12, 1e-12 * m);
    EXPECT_EQ(p.centre, Vec3::Zero());
  }
  {
    const MassProperties p = mass_properties(round(Shape::Kind::sphere, 0.05, 0), rho);
    const double m = rho * 4.0 / 3 * pi * 0.05 * 0.05 * 0.05;
    EXPECT_NEAR(p.mass, m, 1e-12 * m);
    EXPECT_NEAR(p.inertia(1, 1), 0.4 * m * 0.05 * 0.05, 1e-12 * m);
  }
  {
    const MassProperties p = mass_properties(round(Shape::Kind::cylinder, 0.05, 0.2), rho);
    const double m = rho * pi * 0.05 * 0.05 * 0.2;
    EXPECT_NEAR(p.mass, m, 1e-12 * m);
    EXPECT_NEAR(p.inertia(0, 0), m * (3 * 0.05 * 0.05 + 0.04) / 12, 1e-12 * m);
    EXPECT_NEAR(p.inertia(2, 2), m * 0.05 * 0.05 / 2, 1e-12 * m);
  }
  {
    // A capsule of zero length is a sphere.
    const MassProperties c = mass_properties(round(Shape::Kind::capsule, 0.05, 0), rho);
    const MassProperties s = mass_properties(round(Shape::Kind::sphere, 0.05, 0), rho);
    EXPECT_NEAR(c.mass, s.mass, 1e-14);
    EXPECT_NEAR((c.inertia - s.inertia).norm(), 0, 1e-14 * s.inertia.norm());
  }
}

TEST(RigidMassProperties, BoxMeshIsExact) {
  const Shape b = box(0.1, 0.2, 0.3);
  const Surface s = tessellate(b, Vec3::Zero(), 1);
  const MassProperties exact = mass_properties(b, 1000), from_mesh = mass_properties(mesh_of(s), 1000);
  EXPECT_NEAR(from_mesh.mass, exact.mass, 1e-12 * exact.mass);
  EXPECT_LT(from_mesh.centre.norm(), 1e-14);
  EXPECT_LT((from_mesh.inertia - exact.inertia).norm(), 1e-12 * exact.inertia.norm());
}

TEST(RigidMassProperties, OffCentreMeshGivesItsCentre) {
  const Shape b = box(0.1, 0.2, 0.3);
  Surface s = tessellate(b, Vec3::Zero(), 1);
  const Vec3 shift(0.3, -0.7, 1.1);
  s.vertices.colwise() += shift;
  const Shape m = mesh_of(s);
  const MassProperties p = mass_properties(m, 1000), exact = mass_properties(b, 1000);
  EXPECT_LT((p.centre - shift).norm(), 1e-13);
  EXPECT_LT((p.inertia - exact.inertia).norm(), 1e-11 * exact.inertia.norm());  // about its centre
  // tessellate shifts a mesh by -centre: the body's surface has its centre at the origin.
  const Surface t = tessellate(m, p.centre, 1);
  EXPECT_LT(mass_properties(mesh_of(t), 1000).centre.norm(), 1e-13);
}

// A tessellated cylinder converges to the closed form: its n-gon section has area
// n/2 sin(2 pi/n) r^2, relative error (2 pi/n)^2/6 to leading order; the inertia's error
// is of the same order (the section's second moments are O((2 pi/n)^2) off too): the
// bound 2 (2 pi/n)^2 leaves a factor of about 3 over the leading term of the mass.
TEST(RigidMassProperties, CylinderMeshWithinTessellationError) {
  const Shape c = round(Shape::Kind::cylinder, 0.05, 0.2);
  const MassProperties exact = mass_properties(c, 1000);
  double previous = 1;
  for (double max_edge : {0.02, 0.01, 0.005}) {
    const Surface s = tessellate(c, Vec3::Zero(), max_edge);
    const MassProperties p = mass_properties(mesh_of(s), 1000);
    const int n = static_cast<int>(std::ceil(2 * pi * 0.05 / max_edge));
    const double area_ratio = n / 2.0 * std::sin(2 * pi / n) / pi;
    EXPECT_NEAR(p.mass / exact.mass, area_ratio, 1e-12) << "max_edge " << max_edge;
    const double e = (p.inertia - exact.inertia).norm() / exact.inertia.norm();
    EXPECT_LT(e, 2 * std::pow(2 * pi / n, 2)) << "max_edge " << max_edge;
    EXPECT_LT(e, previous);
    previous = e;
    EXPECT_LT(p.centre.norm(), 1e-14);
  }
}

TEST(RigidMassProperties, BadMeshesThrow) {
  Surface s = tessellate(box(0.1, 0.2, 0.3), Vec3::Zero(), 1);
  Shape inside_out = mesh_of(s);
  for (Eigen::Index t = 0; t < inside_out.mesh_triangles.cols(); ++t)
    std::swap(inside_out.mesh_triangles(1, t), inside_out.mesh_triangles(2, t));
  EXPECT_THROW(
      try { mass_properties(inside_out, 1000); } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("inside-out"), std::string::npos) << e.what();
        throw;
      },
      std::invalid_argument);
  Shape open = mesh_of(s);
  open.mesh_triangles.conservativeResize(3, open.mesh_triangles.cols() - 1);
  EXPECT_THROW(
      try { mass_properties(open, 1000); } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("open"), std::string::npos) << e.what();
        throw;
      },
      std::invalid_argument);
  Shape flipped_one = mesh_of(s);
  std::swap(flipped_one.mesh_triangles(1, 0), flipped_one.mesh_triangles(2, 0));
  EXPECT_THROW(mass_properties(flipped_one, 1000), std::invalid_argument);
  EXPECT_THROW(mass_properties(box(0.1, 0, 0.1), 1000), std::invalid_argument);
  EXPECT_THROW(mass_properties(box(0.1, 0.1, 0.1), 0), std::invalid_argument);
  EXPECT_THROW(mass_properties(round(Shape::Kind::cylinder, 0.1, 0), 1000), std::invalid_argument);
}

TEST(RigidTessellation, ClosedAndOutward) {
  const std::vector<Shape> shapes = {box(0.1, 0.2, 0.3), round(Shape::Kind::sphere, 0.05, 0),
                                     round(Shape::Kind::capsule, 0.05, 0.2), round(Shape::Kind::capsule, 0.05, 0),
                                     round(Shape::Kind::cylinder, 0.05, 0.2)};
  for (const Shape& shape : shapes)
    for (double max_edge : {0.02, 0.005}) {  // r / 2.5 and r / 10
      const Surface s = tessellate(shape, Vec3::Zero(), max_edge);
      SCOPED_TRACE(testing::Message() << "kind " << static_cast<int>(shape.kind) << ", max_edge " << max_edge);
      EXPECT_TRUE(closed(s));
      EXPECT_GT(min_outward(s), 0);
      // Inscribed: the volume approaches the closed form from below.
      const double v = mass_properties(mesh_of(s), 1).mass, exact = mass_properties(shape, 1).mass;
      EXPECT_LE(v, exact * (1 + 1e-12));
      EXPECT_GT(v, exact * (shape.kind == Shape::Kind::box ? 1 - 1e-12 : 0.8));
      if (shape.kind == Shape::Kind::box) {
        EXPECT_EQ(s.triangles.cols(), 12);
      }
    }
  // Finer max_edge, closer volume.
  const Shape sphere = round(Shape::Kind::sphere, 0.05, 0);
  const double exact = mass_properties(sphere, 1).mass;
  const double coarse = mass_properties(mesh_of(tessellate(sphere, Vec3::Zero(), 0.02)), 1).mass;
  const double fine = mass_properties(mesh_of(tessellate(sphere, Vec3::Zero(), 0.005)), 1).mass;
  EXPECT_LT(exact - fine, 0.25 * (exact - coarse));
  EXPECT_THROW(tessellate(sphere, Vec3::Zero(), 0), std::invalid_argument);
  EXPECT_THROW(tessellate(sphere, Vec3::Zero(), 1e-9), std::invalid_argument);
}

TEST(RigidTessellation, CentreShiftsTheSurface) {
  const Vec3 c(0.01, 0.02, 0.03);
  const Surface a = tessellate(box(0.1, 0.2, 0.3), Vec3::Zero(), 1), b = tessellate(box(0.1, 0.2, 0.3), c, 1);
  EXPECT_LT(((a.vertices.colwise() - c) - b.vertices).norm(), 1e-15);
}

// The planar-edge flags of a rigid surface (collision::mark_planar_edges, computed once at
// model build for the contact step's O(1) drop of edge-edge contacts on a face's
// diagonal): checked against the shape's own geometry, at pseudo-node numbers starting
// at 7 (the flags must read the body's local vertices). A box: exactly its six face
// diagonals (endpoints differing in two of the three coordinate signs) among its 18 edges.
// A cylinder: every edge but the two rims (endpoints at radius r on one cap) and the side's
// vertical edges (endpoints at radius r and the same angle), whose two triangles meet at
// 90 degrees and at 360 / n_theta degrees; the caps' fans and annuli and the side quads'
// diagonals and rings are coplanar pairs.
TEST(RigidTessellation, PlanarEdgeFlags) {
  const int begin = 7;
  {
    const Surface s = tessellate(box(0.1, 0.2, 0.3), Vec3::Zero(), 1);
    collision::BodySurface b = collision::make_surface("box", s.triangles, begin);
    collision::mark_planar_edges(b, s.vertices, begin);
    ASSERT_EQ(b.edges.cols(), 18);
    ASSERT_EQ(b.planar_edge.size(), 18u);
    int diagonals = 0;
    for (Eigen::Index e = 0; e < b.edges.cols(); ++e) {
      const Vec3 d = s.vertices.col(b.edges(0, e) - begin) - s.vertices.col(b.edges(1, e) - begin);
      const int differ = (d.array().abs() > 1e-12).count();
      EXPECT_EQ(b.planar_edge[static_cast<std::size_t>(e)] != 0, differ == 2) << "edge " << e;
      diagonals += b.planar_edge[static_cast<std::size_t>(e)];
    }
    EXPECT_EQ(diagonals, 6);
  }
  for (double max_edge : {1.0, 0.02}) {  // 8 sectors, one side segment; 16 sectors, annuli
    const double r = 0.05, L = 0.2;
    const Surface s = tessellate(round(Shape::Kind::cylinder, r, L), Vec3::Zero(), max_edge);
    collision::BodySurface b = collision::make_surface("cylinder", s.triangles, begin);
    collision::mark_planar_edges(b, s.vertices, begin);
    ASSERT_EQ(b.planar_edge.size(), static_cast<std::size_t>(b.edges.cols()));
    int sharp = 0, rims = 0;
    for (Eigen::Index e = 0; e < b.edges.cols(); ++e) {
      const Vec3 p = s.vertices.col(b.edges(0, e) - begin), q = s.vertices.col(b.edges(1, e) - begin);
      const bool on_side = std::abs(p.head<2>().norm() - r) < 1e-12 && std::abs(q.head<2>().norm() - r) < 1e-12;
      const bool rim = on_side && std::abs(p.z() - q.z()) < 1e-12 && std::abs(std::abs(p.z()) - L / 2) < 1e-12;
      const bool vertical = on_side && (p - q).head<2>().norm() < 1e-12;
      EXPECT_EQ(b.planar_edge[static_cast<std::size_t>(e)] == 0, rim || vertical)
          << "max_edge " << max_edge << ", edge " << e << ": " << p.transpose() << " - " << q.transpose();
      sharp += b.planar_edge[static_cast<std::size_t>(e)] == 0;
      rims += rim;
    }
    if (max_edge == 1.0) {  // n_theta = 8: rims 2 x 8, verticals 8, of 6 x 8 edges
      EXPECT_EQ(b.edges.cols(), 48);
      EXPECT_EQ(rims, 16);
      EXPECT_EQ(sharp, 24);
    }
  }
}

}  // namespace rigid_shapes_test
