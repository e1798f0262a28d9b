// Narrow-phase kernels (distance.hpp) against independent formulas and brute force.
#include <softdiff/collision/distance.hpp>

#include <gtest/gtest.h>

#include <Eigen/QR>

#include <random>

namespace softdiff::collision {
namespace {

// Independent point-triangle distance: the projection onto the plane if it is inside,
// else the best of the three clamped edge projections.
double brute_point_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 n = (b - a).cross(c - a).normalized();
  const Vec3 q = p - n.dot(p - a) * n;
  Mat3 A;
  A << a - c, b - c, n;
  const Vec3 l = A.colPivHouseholderQr().solve(q - c);
  if (l[0] >= 0 && l[1] >= 0 && l[0] + l[1] <= 1) return (p - q).norm();
  double best = 1e300;
  const Vec3* v[3] = {&a, &b, &c};
  for (int k = 0; k < 3; ++k) {
    const Vec3& s = *v[k];
    const Vec3& e = *v[(k + 1) % 3];
    const double t = std::clamp((p - s).dot(e - s) / (e - s).squaredNorm(), 0.0, 1.0);
    best = std::min(best, (p - (s + t * (e - s))).norm());
  }
  return best;
}

// Dense search over the parameter square, refined twice around the best sample.
double brute_segment_segment(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1) {
  double best = 1e300, bs = 0, bt = 0;
  double lo_s = 0, hi_s = 1, lo_t = 0, hi_t = 1;
  for (int level = 0; level < 4; ++level) {
    const int n = 200;
    for (int i = 0; i <= n; ++i)
      for (int j = 0; j <= n; ++j) {
        const double s = lo_s + (hi_s - lo_s) * i / n, t = lo_t + (hi_t - lo_t) * j / n;
        const double d = ((p0 + s * (p1 - p0)) - (q0 + t * (q1 - q0))).norm();
        if (d < best) {
          best = d;
          bs = s;
          bt = t;
        }
      }
    const double ws = (hi_s - lo_s) / 20, wt = (hi_t - lo_t) / 20;
    lo_s = std::max(0.0, bs - ws);
    hi_s = std::min(1.0, bs + ws);
    lo_t = std::max(0.0, bt - wt);
    hi_t = std::min(1.0, bt + wt);
  }
  return best;
}

TEST(PointTriangle, SevenRegions) {
  const Vec3 a(0, 0, 0), b(1, 0, 0), c(0, 1, 0);
  struct Case {
    Vec3 p;
    Feature feature;
    int local;
    Vec3 point;
  };
  const Case cases[] = {
      {{-1, -1, 0.3}, Feature::vertex, 0, a},         {{2, -0.5, -0.2}, Feature::vertex, 1, b},
      {{-0.2, 2, 0.1}, Feature::vertex, 2, c},        {{0.5, -1, 0.4}, Feature::edge, 0, {0.5, 0, 0}},
      {{1, 1, -0.3}, Feature::edge, 1, {0.5, 0.5, 0}}, {{-1, 0.25, 0.2}, Feature::edge, 2, {0, 0.25, 0}},
      {{0.2, 0.3, 0.7}, Feature::face, 0, {0.2, 0.3, 0}},
  };
  for (const auto& cs : cases) {
    const auto r = point_triangle_closest(cs.p, a, b, c);
    EXPECT_EQ(r.feature, cs.feature) << cs.p.transpose();
    EXPECT_EQ(r.local, cs.local) << cs.p.transpose();
    EXPECT_LT((r.point - cs.point).norm(), 1e-14) << cs.p.transpose();
    EXPECT_LT((r.bary[0] * a + r.bary[1] * b + r.bary[2] * c - r.point).norm(), 1e-14);
    EXPECT_NEAR(r.bary.sum(), 1, 1e-14);
  }
}

TEST(PointTriangle, RandomAgainstIndependentFormula) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  auto rv = [&] { return Vec3(u(rng), u(rng), u(rng)); };
  for (int i = 0; i < 2000; ++i) {
    const Vec3 a = rv(), b = rv(), c = rv(), p = 2 * rv();
    const auto r = point_triangle_closest(p, a, b, c);
    EXPECT_NEAR(std::sqrt(r.dist2), brute_point_triangle(p, a, b, c), 1e-12);
    EXPECT_GE(r.bary.minCoeff(), 0);
    EXPECT_NEAR(r.bary.sum(), 1, 1e-12);
    EXPECT_LT((r.bary[0] * a + r.bary[1] * b + r.bary[2] * c - r.point).norm(), 1e-12);
    const int zeros = (r.bary.array() == 0).count();
    EXPECT_EQ(zeros, r.feature == Feature::face ? 0 : (r.feature == Feature::edge ? 1 : 2));
  }
}

TEST(PointTriangle, DegenerateTriangle) {
  const Vec3 a(0, 0, 0), b(1, 0, 0), c(2, 0, 0);  // collinear
  const auto r = point_triangle_closest(Vec3(1.5, 1, 0), a, b, c);
  EXPECT_NEAR(std::sqrt(r.dist2), 1, 1e-14);
  EXPECT_EQ(r.feature, Feature::edge);
}

TEST(SegmentSegment, Crossing) {
  const auto r = segment_segment_closest(Vec3(-1, 0, 0), Vec3(1, 0, 0), Vec3(0.5, -1, 0.3), Vec3(0.5, 1, 0.3));
  EXPECT_NEAR(r.s, 0.75, 1e-15);
  EXPECT_NEAR(r.t, 0.5, 1e-15);
  EXPECT_NEAR(std::sqrt(r.dist2), 0.3, 1e-15);
  EXPECT_TRUE(r.interior());
}

TEST(SegmentSegment, Parallel) {
  // Overlapping parallel segments: distance 0.2, closest points not unique.
  const auto r = segment_segment_closest(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0.5, 0.2, 0), Vec3(1.5, 0.2, 0));
  EXPECT_NEAR(std::sqrt(r.dist2), 0.2, 1e-15);
  EXPECT_NEAR((r.point_p - r.point_q).norm(), 0.2, 1e-15);
  // Disjoint collinear segments: endpoint to endpoint.
  const auto r2 = segment_segment_closest(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(2, 0, 0), Vec3(3, 0, 0));
  EXPECT_NEAR(std::sqrt(r2.dist2), 1, 1e-15);
  EXPECT_EQ(r2.s, 1);
  EXPECT_EQ(r2.t, 0);
  EXPECT_FALSE(r2.interior());
  // Anti-parallel.
  const auto r3 = segment_segment_closest(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(3, 1, 0), Vec3(2, 1, 0));
  EXPECT_NEAR(std::sqrt(r3.dist2), std::sqrt(2.0), 1e-15);
}

TEST(SegmentSegment, EndpointRegions) {
  // Closest at an endpoint of one and the interior of the other.
  const auto r = segment_segment_closest(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0.3, 0.5, 1), Vec3(0.3, 0.5, 3));
  EXPECT_EQ(r.t, 0);
  EXPECT_NEAR(r.s, 0.3, 1e-15);
  EXPECT_NEAR(std::sqrt(r.dist2), std::hypot(0.5, 1.0), 1e-15);
  // Endpoint - endpoint.
  const auto r2 = segment_segment_closest(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(2, 1, 0), Vec3(2, 2, 0));
  EXPECT_EQ(r2.s, 1);
  EXPECT_EQ(r2.t, 0);
  // Degenerate segments (points).
  const auto r3 = segment_segment_closest(Vec3(0, 0, 0), Vec3(0, 0, 0), Vec3(-1, 1, 0), Vec3(1, 1, 0));
  EXPECT_NEAR(std::sqrt(r3.dist2), 1, 1e-15);
  EXPECT_NEAR(r3.t, 0.5, 1e-15);
}

TEST(SegmentSegment, RandomAgainstBruteForce) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  auto rv = [&] { return Vec3(u(rng), u(rng), u(rng)); };
  for (int i = 0; i < 60; ++i) {
    Vec3 p0 = rv(), p1 = rv(), q0 = rv(), q1 = rv();
    if (i % 10 == 0) q1 = q0 + (p1 - p0) * 0.7;  // parallel cases
    const auto r = segment_segment_closest(p0, p1, q0, q1);
    const double brute = brute_segment_segment(p0, p1, q0, q1);
    EXPECT_LE(std::sqrt(r.dist2), brute + 1e-12);
    EXPECT_NEAR(std::sqrt(r.dist2), brute, 1e-7);
    EXPECT_NEAR((r.point_p - r.point_q).squaredNorm(), r.dist2, 1e-14);
  }
}

}  // namespace
}  // namespace softdiff::collision
