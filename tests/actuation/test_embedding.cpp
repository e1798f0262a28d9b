// PointLocator and embedded points (issue "Actuators and effectors"): exact weights
// inside, nearest tet with extrapolated weights outside, far points rejected with a
// status, agreement with brute force on a non-convex mesh, speed on 100k tets.
#include <softdiff/actuation/effector.hpp>
#include <softdiff/actuation/embedding.hpp>

#include "helpers.hpp"
#include <support/fd.hpp>

#include <chrono>
#include <gtest/gtest.h>

using namespace softdiff;
using namespace softdiff::actuation;

namespace {

Vec3 reproduce(const Mat3X& X, const Tets& tets, const Embedding& e) {
  Vec3 p = Vec3::Zero();
  for (int a = 0; a < 4; ++a) p += e.w[a] * X.col(tets(a, e.tet));
  return p;
}

// A unit box minus the block [0.5, 1] x [0.5, 1] x [0, 1] (an L-shaped, non-convex
// prism), interior nodes jittered.
mesh::TetMesh l_shape(std::mt19937& rng) {
  mesh::TetMesh full = test::jittered_box(6, 6, 4, 1.0, 1.0, 1.0, 0.2, rng);
  std::vector<int> keep;
  for (int e = 0; e < full.num_tets(); ++e) {
    Vec3 c = Vec3::Zero();
    for (int a = 0; a < 4; ++a) c += full.X.col(full.tets(a, e)) / 4;
    if (!(c[0] > 0.5 && c[1] > 0.5)) keep.push_back(e);
  }
  mesh::TetMesh m = full;
  m.tets.resize(4, static_cast<int>(keep.size()));
  for (size_t k = 0; k < keep.size(); ++k) m.tets.col(static_cast<int>(k)) = full.tets.col(keep[k]);
  return m;
}

}  // namespace

TEST(Embedding, InsidePointsGetTheirTetAndExactWeights) {
  std::mt19937 rng(1);
  const mesh::TetMesh m = test::jittered_box(4, 3, 2, 0.04, 0.03, 0.02, 0.2, rng);
  const PointLocator locator(m.X, m.tets);
  std::uniform_real_distribution<double> u(0.05, 1);
  std::uniform_int_distribution<int> pick(0, m.num_tets() - 1);
  double worst_w = 0, worst_p = 0;
  for (int trial = 0; trial < 500; ++trial) {
    const int e = pick(rng);
    Eigen::Vector4d w(u(rng), u(rng), u(rng), u(rng));
    w /= w.sum();  // every weight >= 0.05 / 4: well inside, the containing tet is unique
    Vec3 p = Vec3::Zero();
    for (int a = 0; a < 4; ++a) p += w[a] * m.X.col(m.tets(a, e));
    const LocateResult r = locator.locate(p);
    ASSERT_EQ(r.status, LocateStatus::inside);
    ASSERT_EQ(r.embedding.tet, e);
    EXPECT_EQ(r.embedding.outside_distance, 0);
    worst_w = std::max(worst_w, (r.embedding.w - w).cwiseAbs().maxCoeff());
    worst_p = std::max(worst_p, (reproduce(m.X, m.tets, r.embedding) - p).norm() / 0.04);
    EXPECT_NEAR(r.embedding.w.sum(), 1.0, 1e-15);
  }
  EXPECT_LT(worst_w, 1e-13);
  EXPECT_LT(worst_p, 1e-15);
  std::printf("inside: worst weight error %.2e, worst relative position error %.2e\n", worst_w, worst_p);
}

TEST(Embedding, PointsOnFacesEdgesAndNodesAreInside) {
  std::mt19937 rng(2);
  const mesh::TetMesh m = test::jittered_box(3, 3, 3, 1.0, 1.0, 1.0, 0.2, rng);
  const PointLocator locator(m.X, m.tets);
  std::uniform_int_distribution<int> pick(0, m.num_tets() - 1);
  for (int trial = 0; trial < 200; ++trial) {
    const int e = pick(rng);
    Eigen::Vector4d w(0.2, 0.3, 0.5, 0.0);  // on a face (shared, or on the box boundary)
    if (trial % 3 == 1) w << 0.4, 0.0, 0.6, 0.0;  // on an edge
    if (trial % 3 == 2) w << 0.0, 0.0, 0.0, 1.0;  // a node
    std::shuffle(w.data(), w.data() + 4, rng);
    Vec3 p = Vec3::Zero();
    for (int a = 0; a < 4; ++a) p += w[a] * m.X.col(m.tets(a, e));
    const LocateResult r = locator.locate(p);
    ASSERT_EQ(r.status, LocateStatus::inside);
    EXPECT_GE(r.embedding.w.minCoeff(), -PointLocator::inside_tolerance);
    EXPECT_LT((reproduce(m.X, m.tets, r.embedding) - p).norm(), 1e-15);
  }
}

TEST(Embedding, OutsidePointsGetNearestTetExtrapolatedWeightsAndDistance) {
  // Unit box, 4 cells a side: the longest tet edge is the cell diagonal sqrt(3)/4, so
  // the default allowance is 0.5 sqrt(3)/4 = 0.2165.
  const mesh::TetMesh m = test::box_mesh(4, 4, 4, 1.0, 1.0, 1.0);
  const PointLocator locator(m.X, m.tets);
  struct Case {
    Vec3 p;
    double distance;
  };
  const Case cases[] = {
      {{1.2, 0.5, 0.37}, 0.2},                          // beyond a face
      {{0.3, -0.15, 0.61}, 0.15},                       // beyond another face
      {{1.1, 1.1, 0.5}, std::sqrt(0.02)},               // beyond an edge
      {{-0.1, 1.1, -0.1}, std::sqrt(0.03)},             // beyond a corner
      {{0.5 + 1e-3, 1.0 + 1e-7, 0.25}, 1e-7},           // just outside
  };
  for (const auto& c : cases) {
    const LocateResult r = locator.locate(c.p);
    ASSERT_EQ(r.status, LocateStatus::outside) << c.p.transpose();
    EXPECT_NEAR(r.embedding.outside_distance, c.distance, 1e-14) << c.p.transpose();
    EXPECT_NEAR(r.allowed_distance, 0.5 * std::sqrt(3.0) / 4, 1e-15);
    EXPECT_LT(r.embedding.w.minCoeff(), 0) << "extrapolated weights have a negative entry";
    EXPECT_NEAR(r.embedding.w.sum(), 1.0, 1e-14);
    EXPECT_LT((reproduce(m.X, m.tets, r.embedding) - c.p).norm(), 1e-15) << c.p.transpose();
    EXPECT_NEAR(point_tet_distance(m.X, m.tets, r.embedding.tet, c.p), c.distance, 1e-14);
  }
}

TEST(Embedding, FarPointsAreReportedNotThrown) {
  const mesh::TetMesh m = test::box_mesh(4, 4, 4, 1.0, 1.0, 1.0);
  const PointLocator locator(m.X, m.tets);
  const Vec3 p(3.0, 0.5, 0.5);
  LocateResult r = locator.locate(p);
  EXPECT_EQ(r.status, LocateStatus::too_far);
  EXPECT_NEAR(r.embedding.outside_distance, 2.0, 1e-14);  // still filled for the message
  EXPECT_NEAR(r.allowed_distance, 0.5 * std::sqrt(3.0) / 4, 1e-15);
  // A slightly-outside point fails a tight absolute-only bound ...
  LocateOptions tight;
  tight.max_relative_distance = 0;
  tight.max_distance = 0.05;
  EXPECT_EQ(locator.locate(Vec3(1.1, 0.5, 0.5), tight).status, LocateStatus::too_far);
  EXPECT_EQ(locator.locate(Vec3(1.04, 0.5, 0.5), tight).status, LocateStatus::outside);
  // ... and a generous absolute bound accepts the far point.
  LocateOptions loose;
  loose.max_distance = 5;
  r = locator.locate(p, loose);
  EXPECT_EQ(r.status, LocateStatus::outside);
  EXPECT_LT((reproduce(m.X, m.tets, r.embedding) - p).norm(), 1e-14);
  // No usable tet: status, no throw.
  Mat3X X(3, 4);
  X << 0, 1, 2, 3, 0, 0, 0, 0, 0, 0, 0, 0;  // collinear: degenerate
  Tets T(4, 1);
  T << 0, 1, 2, 3;
  EXPECT_EQ(PointLocator(X, T).locate(Vec3::Zero()).status, LocateStatus::no_tets);
}

TEST(Embedding, LocatorAgreesWithBruteForceOnNonConvexMesh) {
  std::mt19937 rng(3);
  const mesh::TetMesh m = l_shape(rng);
  const PointLocator locator(m.X, m.tets);
  std::uniform_real_distribution<double> u(-0.3, 1.3);
  int inside = 0, outside = 0;
  double worst_d = 0, worst_p = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    const Vec3 p(u(rng), u(rng), u(rng));
    double best = std::numeric_limits<double>::infinity();
    int best_tet = -1;
    double best_min_w = -1;
    for (int e = 0; e < m.num_tets(); ++e) {
      const double d = point_tet_distance(m.X, m.tets, e, p);
      if (d < best) best = d, best_tet = e;
      if (d == 0) best_min_w = std::max(best_min_w, barycentric_weights(m.X, m.tets, e, p).minCoeff());
    }
    LocateOptions any;
    any.max_distance = 10;
    const LocateResult r = locator.locate(p, any);
    ASSERT_NE(r.status, LocateStatus::too_far);
    worst_d = std::max(worst_d, std::abs(r.embedding.outside_distance - best));
    worst_p = std::max(worst_p, (reproduce(m.X, m.tets, r.embedding) - p).norm());
    EXPECT_NEAR(point_tet_distance(m.X, m.tets, r.embedding.tet, p), r.embedding.outside_distance, 1e-14);
    if (best == 0 && best_min_w > 1e-9) {  // strictly inside one tet: unique
      ++inside;
      EXPECT_EQ(r.status, LocateStatus::inside);
      EXPECT_EQ(r.embedding.tet, best_tet);
    } else if (best > 0) {
      ++outside;
      EXPECT_EQ(r.status, LocateStatus::outside);
    }
  }
  EXPECT_LT(worst_d, 1e-14);
  EXPECT_LT(worst_p, 1e-13);
  EXPECT_GT(inside, 500);
  EXPECT_GT(outside, 500);  // including points in the notch (outside the mesh, inside its bounding box)
  std::printf("brute force: %d inside, %d outside; worst distance error %.2e, worst position error %.2e\n", inside,
              outside, worst_d, worst_p);
}

TEST(Embedding, HundredThousandTetsTenThousandPoints) {
  const mesh::TetMesh m = test::box_mesh(26, 26, 26, 0.26, 0.26, 0.26);  // 105456 tets
  ASSERT_GT(m.num_tets(), 100000);
  const auto t0 = std::chrono::steady_clock::now();
  const PointLocator locator(m.X, m.tets);
  const auto t1 = std::chrono::steady_clock::now();
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-0.01, 0.27);
  std::vector<Vec3> points(10000);
  for (auto& p : points) p = Vec3(u(rng), u(rng), u(rng));
  std::vector<LocateResult> results(points.size());
  LocateOptions any;  // points up to 1 cell outside each face: accept them all
  any.max_distance = 0.05;
  for (size_t i = 0; i < points.size(); ++i) results[i] = locator.locate(points[i], any);
  const auto t2 = std::chrono::steady_clock::now();
  const double build = std::chrono::duration<double>(t1 - t0).count();
  const double query = std::chrono::duration<double>(t2 - t1).count();
  std::printf("100k tets: build %.3f s, 10k points %.3f s (grid %d x %d x %d)\n", build, query,
              locator.grid_size()[0], locator.grid_size()[1], locator.grid_size()[2]);
  EXPECT_LT(build + query, 1.0);
  for (size_t i = 0; i < points.size(); ++i) {
    ASSERT_NE(results[i].status, LocateStatus::too_far);
    ASSERT_LT((reproduce(m.X, m.tets, results[i].embedding) - points[i]).norm(), 1e-15);
  }
  // Spot-check the distance against brute force.
  for (size_t i = 0; i < 20; ++i) {
    double best = std::numeric_limits<double>::infinity();
    for (int e = 0; e < m.num_tets(); ++e) best = std::min(best, point_tet_distance(m.X, m.tets, e, points[i]));
    EXPECT_NEAR(results[i].embedding.outside_distance, best, 1e-15);
  }
}

TEST(Effector, PositionAndConstantJacobian) {
  std::mt19937 rng(5);
  const mesh::TetMesh m = test::jittered_box(3, 2, 2, 0.03, 0.02, 0.02, 0.2, rng);
  const PointLocator locator(m.X, m.tets);
  const int offset = 7;  // the body's first global node
  const Vec3 p(0.021, 0.013, 0.0111);
  const LocateResult r = locator.locate(p);
  ASSERT_EQ(r.status, LocateStatus::inside);
  const Effector eff(embedded_point(r.embedding, m.tets, offset));
  VecX x_rest = VecX::Zero(3 * (m.num_nodes() + offset + 2));
  x_rest.segment(3 * offset, 3 * m.num_nodes()) = test::flatten(m.X);
  EXPECT_LT((eff.position(x_rest) - p).norm(), 1e-17);
  const VecX x = test::deform(x_rest, 1e-3, rng);
  const MatX J_fd = test::fd_jacobian([&](const VecX& y) -> VecX { return eff.position(y); }, x, 1e-8);
  std::vector<Eigen::Triplet<double>> trips;
  eff.jacobian_triplets(0, trips);
  SparseMatrix J(3, x.size());
  J.setFromTriplets(trips.begin(), trips.end());
  EXPECT_LT(test::compare(MatX(J), J_fd).rel_error, 1e-9);
  const VecX dx = VecX::Random(x.size());
  EXPECT_LT((eff.jacobian_times(dx) - J * dx).norm(), 1e-15);
  VecX g = VecX::Zero(x.size());
  const Vec3 c(0.3, -1.2, 2.0);
  eff.add_jacobian_transpose(c, 2.0, g);
  EXPECT_LT((g - 2.0 * J.transpose() * c).norm(), 1e-15);
}
