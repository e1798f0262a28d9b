// Randomized smoothing of the collision-detection derivatives
// (contact_derivatives.hpp, the SmoothingOptions overload) where the active feature pair
// is not unique: a vertex exactly over the edge between a triangle's face and edge
// regions, a point above a box edge's region boundary, edges whose closest points are
// at an endpoint, and a vertex at zero distance from an edge (no exact derivative).
//
// What is checked:
//   - away from region boundaries the exact derivative is returned, bit for bit;
//   - on a boundary the estimate is the derivative of the smoothed geometry
//     (smoothed_contact_geometry, the same seeded samples): central differences with
//     common samples. Step 1e-9: a sample's coordinate across a region boundary lies
//     within the step of it with probability ~ 2 step / (sigma sqrt(2 pi)) = 8e-5 per
//     sample (sigma = 1e-5), 0.5% over 64 samples; such a sample mixes its two
//     one-sided derivatives in the differences (with step 1e-8, the box case with seed
//     7 had one: an error of |D_edge - D_face| / (2 * 64) = 0.1). The differences'
//     round-off is ~ eps |g| / step ~ 2e-7 |g| against derivatives of size 1-30, their
//     truncation error ~ step^2 |g'''| ~ 1e-14: tolerance 1e-6 relative (floor 0.1);
//   - the estimate converges to the probability-weighted mean of the one-sided
//     derivatives (1/2 each at a planar region boundary): with N samples the mean of a
//     Bernoulli(1/2) choice between two matrices D1, D2 has standard deviation
//     |D1 - D2| / (2 sqrt(N)); tolerance 5 of those plus the O(sigma / size) = 1e-4
//     variation of each one-sided derivative over the samples;
//   - the result depends on the contact's identity and the seed only (not the order
//     in which contacts are processed), and is finite where no exact one exists.
#include <softdiff/collision/contact_derivatives.hpp>
#include <softdiff/collision/distance.hpp>

#include "contacts.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

namespace softdiff::collision {
namespace {

using contact_test::flat;

// A vertex-triangle contact with a forced region (the detector's record at a region
// boundary is one of the two).
Contact vertex_triangle(const VecX& x, Feature feature) {
  Contact k = contact_test::vertex_triangle_contact(x);
  k.kind_b = feature;
  if (feature == Feature::edge) {  // the edge of the two largest weights
    int smallest = 1;
    for (int w = 2; w < 4; ++w)
      if (std::abs(k.weights[w]) < std::abs(k.weights[smallest])) smallest = w;
    k.weights[smallest] = 0;
  }
  if (feature == Feature::face)  // the face's weights on its boundary: keep all three nodes active
    for (int w = 1; w < 4; ++w)
      if (k.weights[w] == 0) k.weights[w] = -1e-300;
  return k;
}

Obstacle box() {
  Obstacle o;
  o.name = "box";
  o.kind = ShapeKind::box;
  o.rotation = Eigen::AngleAxisd(0.4, Vec3(1, 2, 0.5).normalized()).toRotationMatrix();
  o.center = Vec3(0.1, -0.05, 0.02);
  o.half_extents = Vec3(0.2, 0.15, 0.1);
  prepare(o);
  return o;
}

// The smoothed derivative against central differences of the smoothed geometry.
void check_smoothed(const Contact& c, const VecX& x, const Obstacle* o, const SmoothingOptions& opt, const char* what) {
  ContactGeometryDerivative d;
  ASSERT_EQ(contact_geometry_derivative(c, x, o, opt, d), GeometryDerivativeKind::smoothed) << what;
  constexpr double h = 1e-9;
  const auto fd = contact_test::geometry_differences(c, x, h, [&](const VecX& y, ContactGeometry& g) {
    return smoothed_contact_geometry(c, y, o, opt, g);
  });
  ASSERT_TRUE(fd.ok) << what;
  const auto& dn = fd.dn;
  const auto& dgap = fd.dgap;
  const auto& dw = fd.dweights;
  const auto& dframe = fd.dframe;
  auto expect_close = [&](const auto& a, const auto& b, const char* name) {
    EXPECT_LE((a - b).norm(), 1e-6 * std::max(b.norm(), 0.1)) << what << " " << name << ": smoothed\n" << a << "\nfd\n" << b;
  };
  expect_close(d.dn, dn, "dn");
  expect_close(d.dgap, dgap, "dgap");
  expect_close(d.dweights, dw, "dweights");
  expect_close(d.dframe, dframe, "dframe");
}

const Vec3 kA(0, 0, 0), kB(0.3, 0.05, 0.02), kC(0.07, 0.25, -0.03);

// A vertex whose projection onto the triangle's plane lies on edge ab: the boundary
// between the face region and edge ab's region.
Vec3 over_edge_ab() {
  const Vec3 N = (kB - kA).cross(kC - kA).normalized();
  return 0.4 * kA + 0.6 * kB + 0.1 * N;
}

TEST(ContactSmoothing, AwayFromRegionBoundariesTheExactDerivative) {
  const Vec3 N = (kB - kA).cross(kC - kA).normalized();
  const VecX x = flat({(kA + kB + kC) / 3 + 0.1 * N, kA, kB, kC});
  const Contact c = vertex_triangle(x, Feature::face);
  ContactGeometryDerivative exact, d;
  ASSERT_TRUE(contact_geometry_derivative(c, x, nullptr, exact));
  ASSERT_EQ(contact_geometry_derivative(c, x, nullptr, SmoothingOptions{64, 1e-5, 0}, d), GeometryDerivativeKind::exact);
  EXPECT_EQ((d.dn - exact.dn).norm(), 0);
  EXPECT_EQ((d.dweights - exact.dweights).norm(), 0);
  EXPECT_EQ((d.dgap - exact.dgap).norm(), 0);
}

TEST(ContactSmoothing, IsTheDerivativeOfTheSmoothedGeometry) {
  const SmoothingOptions opt{64, 1e-5, 7};
  // Vertex over edge ab, recorded as the face or as the edge: the same smoothed result.
  const VecX x = flat({over_edge_ab(), kA, kB, kC});
  check_smoothed(vertex_triangle(x, Feature::face), x, nullptr, opt, "vertex over an edge (face record)");
  check_smoothed(vertex_triangle(x, Feature::edge), x, nullptr, opt, "vertex over an edge (edge record)");
  // A point above the box's top face, on the boundary of the region of its +y edge.
  const Obstacle o = box();
  const Vec3 p = o.rotation * Vec3(0.05, 0.15, 0.13) + o.center;
  for (std::uint64_t seed : {1, 2, 3, 7}) check_smoothed(contact_test::vertex_obstacle_contact(o, p), p, &o, SmoothingOptions{64, 1e-5, seed}, "box face/edge boundary");
  // Edges whose closest point on the first edge is at s = 1e-6, within sigma of its
  // endpoint: samples with the endpoint (a point against the second edge) and with the
  // interior.
  const Vec3 p0(0, 0, 0.01), p1(0.3, 0.02, 0.03), q0(0.1, -0.1, -0.04), q1(0.16, 0.2, -0.02);
  // The first edge shortened to start 1e-6 of its length before its closest point.
  const SegmentSegmentResult r0 = segment_segment_closest(p0, p1, q0, q1);
  const VecX xe = flat({Vec3(r0.point_p - 1e-6 * (p1 - p0)), p1, q0, q1});
  const SegmentSegmentResult r = segment_segment_closest(xe.segment<3>(0), xe.segment<3>(3), q0, q1);
  ASSERT_TRUE(r.interior(1e-7)) << r.s << " " << r.t;
  ASSERT_LT(r.s, 1e-4);
  check_smoothed(contact_test::edge_edge_contact(xe), xe, nullptr, SmoothingOptions{64, 1e-5 * 0.3, 7}, "edge-edge near an endpoint");
}

TEST(ContactSmoothing, ConvergesToTheMeanOfTheOneSidedDerivatives) {
  const VecX x = flat({over_edge_ab(), kA, kB, kC});
  ContactGeometryDerivative face, edge, d;
  ASSERT_TRUE(contact_geometry_derivative(vertex_triangle(x, Feature::face), x, nullptr, face));
  ASSERT_TRUE(contact_geometry_derivative(vertex_triangle(x, Feature::edge), x, nullptr, edge));
  const double spread = (face.dn - edge.dn).norm();
  ASSERT_GT(spread, 0.1);  // the one-sided derivatives differ: a true kink
  constexpr int N = 4096;
  ASSERT_EQ(contact_geometry_derivative(vertex_triangle(x, Feature::face), x, nullptr, SmoothingOptions{N, 1e-5, 3}, d),
            GeometryDerivativeKind::smoothed);
  const Eigen::Matrix<double, 3, 12> mean = 0.5 * (face.dn + edge.dn);
  EXPECT_LE((d.dn - mean).norm(), 5 * spread / (2 * std::sqrt(double(N))) + 1e-4 * mean.norm());
  const Eigen::Matrix<double, 4, 12> mean_w = 0.5 * (face.dweights + edge.dweights);
  EXPECT_LE((d.dweights - mean_w).norm(), 5 * (face.dweights - edge.dweights).norm() / (2 * std::sqrt(double(N))) + 1e-4 * mean_w.norm());
}

TEST(ContactSmoothing, DependsOnTheContactAndTheSeedOnly) {
  const VecX x = flat({over_edge_ab(), kA, kB, kC});
  const Contact c = vertex_triangle(x, Feature::edge);
  ContactGeometryDerivative d1, d2, d3;
  contact_geometry_derivative(c, x, nullptr, SmoothingOptions{16, 1e-5, 1}, d1);
  // The same contact at other global node numbers has another identity (key).
  VecX x2(15);
  x2 << Vec3::Zero(), x;
  Contact c2 = c;
  c2.nodes = {1, 2, 3, 4};
  contact_geometry_derivative(c, x, nullptr, SmoothingOptions{16, 1e-5, 1}, d2);
  contact_geometry_derivative(c, x, nullptr, SmoothingOptions{16, 1e-5, 2}, d3);
  EXPECT_EQ((d1.dn - d2.dn).norm(), 0);  // replayed bit for bit
  EXPECT_GT((d1.dn - d3.dn).norm(), 0);  // another seed, other samples
  ContactGeometryDerivative e1, e2;
  contact_geometry_derivative(c2, x2, nullptr, SmoothingOptions{16, 1e-5, 1}, e1);
  contact_geometry_derivative(c2, x2, nullptr, SmoothingOptions{16, 1e-5, 1}, e2);
  EXPECT_EQ((e1.dn - e2.dn).norm(), 0);
}

TEST(ContactSmoothing, FiniteWhereNoExactDerivativeExists) {
  // The vertex on edge ab itself: zero distance, the normal undefined.
  const VecX x = flat({0.4 * kA + 0.6 * kB, kA, kB, kC});
  const Contact c = vertex_triangle(x, Feature::edge);
  ContactGeometryDerivative d;
  EXPECT_FALSE(contact_geometry_derivative(c, x, nullptr, d));
  EXPECT_EQ(contact_geometry_derivative(c, x, nullptr, SmoothingOptions{16, 1e-5, 0}, d), GeometryDerivativeKind::smoothed);
  EXPECT_TRUE(d.dn.allFinite() && d.dgap.allFinite() && d.dweights.allFinite() && d.dframe.allFinite());
  // Without smoothing: none.
  EXPECT_EQ(contact_geometry_derivative(c, x, nullptr, SmoothingOptions{0, 1e-5, 0}, d), GeometryDerivativeKind::none);
}

}  // namespace
}  // namespace softdiff::collision
