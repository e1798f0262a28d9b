// Tests of the mesh utilities (lib/softdiff/mesh/tet_mesh.cpp): boundary
// extraction, quality measures, group lookup. Meshes are built in code so that
// these tests do not depend on the Gmsh reader.
#include <softdiff/mesh/tet_mesh.hpp>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>
#include <vector>

namespace {

using softdiff::Mat3X;
using softdiff::Tets;
using softdiff::Triangles;
using softdiff::Vec3;
using softdiff::mesh::boundary_triangles;
using softdiff::mesh::quality;

double signed_volume(const Mat3X& X, const Tets& tets, Eigen::Index t) {
  const Vec3 a = X.col(tets(0, t));
  return (X.col(tets(1, t)) - a).dot((X.col(tets(2, t)) - a).cross(X.col(tets(3, t)) - a)) / 6.0;
}

// An n x n x n grid of cubes of side h, each split into 6 tets around its main
// diagonal (Kuhn): conforming, all tets positively oriented.
struct Grid {
  Mat3X X;
  Tets tets;
};
Grid cube_grid(int n, double h) {
  Grid g;
  auto id = [n](int i, int j, int k) { return i + (n + 1) * (j + (n + 1) * k); };
  g.X.resize(3, (n + 1) * (n + 1) * (n + 1));
  for (int k = 0; k <= n; ++k)
    for (int j = 0; j <= n; ++j)
      for (int i = 0; i <= n; ++i) g.X.col(id(i, j, k)) = Vec3(i, j, k) * h;
  const int perms[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  g.tets.resize(4, 6 * n * n * n);
  int t = 0;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i)
        for (const auto& p : perms) {
          std::array<int, 3> c{i, j, k};
          g.tets(0, t) = id(c[0], c[1], c[2]);
          ++c[p[0]];
          g.tets(1, t) = id(c[0], c[1], c[2]);
          ++c[p[1]];
          g.tets(2, t) = id(c[0], c[1], c[2]);
          ++c[p[2]];
          g.tets(3, t) = id(c[0], c[1], c[2]);
          if (signed_volume(g.X, g.tets, t) < 0) std::swap(g.tets(2, t), g.tets(3, t));
          ++t;
        }
  return g;
}

// Straightforward reference: count sorted faces in a map, then list the faces
// seen once in (tet, opposite vertex) order with the documented orientation.
Triangles reference_boundary(const Tets& tets) {
  const int face[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  auto key = [&](Eigen::Index t, int f) {
    std::array<int, 3> k{tets(face[f][0], t), tets(face[f][1], t), tets(face[f][2], t)};
    std::sort(k.begin(), k.end());
    return k;
  };
  std::map<std::array<int, 3>, int> count;
  for (Eigen::Index t = 0; t < tets.cols(); ++t)
    for (int f = 0; f < 4; ++f) ++count[key(t, f)];
  std::vector<std::array<int, 3>> out;
  for (Eigen::Index t = 0; t < tets.cols(); ++t)
    for (int f = 0; f < 4; ++f)
      if (count[key(t, f)] == 1) out.push_back({tets(face[f][0], t), tets(face[f][1], t), tets(face[f][2], t)});
  Triangles r(3, static_cast<Eigen::Index>(out.size()));
  for (std::size_t k = 0; k < out.size(); ++k)
    for (int j = 0; j < 3; ++j) r(j, static_cast<Eigen::Index>(k)) = out[k][j];
  return r;
}

Vec3 area_normal(const Mat3X& X, const Triangles& tris, Eigen::Index k) {
  const Vec3 a = X.col(tris(0, k));
  return 0.5 * (X.col(tris(1, k)) - a).cross(X.col(tris(2, k)) - a);
}

TEST(BoundaryTriangles, OneTetHasFourOutwardFaces) {
  Mat3X X(3, 4);
  X << 0, 1, 0, 0,  //
      0, 0, 1, 0,   //
      0, 0, 0, 1;
  Tets tets(4, 1);
  tets << 0, 1, 2, 3;
  const Triangles b = boundary_triangles(tets);
  ASSERT_EQ(b.cols(), 4);
  for (Eigen::Index f = 0; f < 4; ++f) {
    // Face f is opposite vertex f (documented order) and its normal points away from it.
    for (int j = 0; j < 3; ++j) EXPECT_NE(b(j, f), tets(f, 0));
    const Vec3 centroid = (X.col(b(0, f)) + X.col(b(1, f)) + X.col(b(2, f))) / 3.0;
    EXPECT_GT(area_normal(X, b, f).dot(centroid - X.col(tets(f, 0))), 0);
  }
  EXPECT_TRUE(b == reference_boundary(tets));
}

TEST(BoundaryTriangles, SharedFaceIsInterior) {
  Mat3X X(3, 5);
  X << 0, 1, 0, 0, 1,  //
      0, 0, 1, 0, 1,   //
      0, 0, 0, 1, 1;
  Tets tets(4, 2);
  tets.col(0) << 0, 1, 2, 3;
  tets.col(1) << 1, 2, 3, 4;
  ASSERT_GT(signed_volume(X, tets, 1), 0);
  const Triangles b = boundary_triangles(tets);
  ASSERT_EQ(b.cols(), 6);
  for (Eigen::Index k = 0; k < b.cols(); ++k) {
    std::array<int, 3> key{b(0, k), b(1, k), b(2, k)};
    std::sort(key.begin(), key.end());
    EXPECT_NE(key, (std::array<int, 3>{1, 2, 3}));
  }
  EXPECT_TRUE(b == reference_boundary(tets));
}

TEST(BoundaryTriangles, CubeGridIsClosedOutwardAndEnclosesItsVolume) {
  const int n = 4;
  const double h = 0.25;
  const Grid g = cube_grid(n, h);
  const Triangles b = boundary_triangles(g.tets);
  ASSERT_EQ(b.cols(), 6 * n * n * 2);

  // Closed and consistently oriented: each directed edge once, its reverse once.
  std::map<std::pair<int, int>, int> edges;
  for (Eigen::Index k = 0; k < b.cols(); ++k)
    for (int j = 0; j < 3; ++j) ++edges[{b(j, k), b((j + 1) % 3, k)}];
  for (const auto& [e, count] : edges) {
    EXPECT_EQ(count, 1);
    EXPECT_EQ(edges.count({e.second, e.first}), 1u);
  }

  // Divergence theorem: sum (centroid . n) |A| / 3 = volume; normals are
  // axis-aligned and point away from the cube center.
  double volume = 0;
  const Vec3 center = Vec3::Constant(0.5 * n * h);
  for (Eigen::Index k = 0; k < b.cols(); ++k) {
    const Vec3 na = area_normal(g.X, b, k);
    const Vec3 centroid = (g.X.col(b(0, k)) + g.X.col(b(1, k)) + g.X.col(b(2, k))) / 3.0;
    volume += centroid.dot(na) / 3.0;
    EXPECT_NEAR(na.cwiseAbs().maxCoeff(), na.norm(), 1e-14);
    EXPECT_GT(na.dot(centroid - center), 0);
  }
  EXPECT_NEAR(volume, std::pow(n * h, 3), 1e-12);
  EXPECT_TRUE(b == reference_boundary(g.tets));
}

TEST(BoundaryTriangles, MatchesReferenceOnShuffledRelabeledGrid) {
  // Random node labels and tet order exercise the bucketing with uneven buckets.
  Grid g = cube_grid(3, 1.0);
  std::mt19937 rng(7);
  std::vector<int> relabel(static_cast<std::size_t>(g.X.cols()));
  for (std::size_t i = 0; i < relabel.size(); ++i) relabel[i] = static_cast<int>(i);
  std::shuffle(relabel.begin(), relabel.end(), rng);
  std::vector<Eigen::Index> order(static_cast<std::size_t>(g.tets.cols()));
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = static_cast<Eigen::Index>(i);
  std::shuffle(order.begin(), order.end(), rng);
  Tets tets(4, g.tets.cols());
  for (Eigen::Index t = 0; t < tets.cols(); ++t)
    for (int j = 0; j < 4; ++j) tets(j, t) = relabel[static_cast<std::size_t>(g.tets(j, order[static_cast<std::size_t>(t)]))];
  EXPECT_TRUE(boundary_triangles(tets) == reference_boundary(tets));
}

TEST(BoundaryTriangles, EdgeCases) {
  EXPECT_EQ(boundary_triangles(Tets(4, 0)).cols(), 0);
  // A face shared by three tets (non-manifold) is not a boundary face.
  Tets tets(4, 3);
  tets.col(0) << 0, 1, 2, 3;
  tets.col(1) << 0, 2, 1, 4;
  tets.col(2) << 0, 1, 2, 5;
  const Triangles b = boundary_triangles(tets);
  EXPECT_EQ(b.cols(), 9);
  EXPECT_TRUE(b == reference_boundary(tets));
  Tets bad(4, 1);
  bad << 0, 1, 2, -1;
  EXPECT_THROW(boundary_triangles(bad), std::logic_error);
}

Mat3X regular_tet(double a) {
  Mat3X X(3, 4);
  X.col(0) = Vec3(1, 1, 1);
  X.col(1) = Vec3(1, -1, -1);
  X.col(2) = Vec3(-1, 1, -1);
  X.col(3) = Vec3(-1, -1, 1);
  return X * (a / std::sqrt(8.0));  // edge length a
}

TEST(Quality, RegularTetHasAspectOne) {
  const double a = 2.0;
  const Mat3X X = regular_tet(a);
  Tets tets(4, 1);
  tets << 0, 1, 2, 3;
  if (signed_volume(X, tets, 0) < 0) std::swap(tets(2, 0), tets(3, 0));
  const auto q = quality(X, tets);
  EXPECT_NEAR(q.min_aspect, 1.0, 1e-12);
  EXPECT_NEAR(q.max_aspect, 1.0, 1e-12);
  EXPECT_NEAR(q.median_aspect, 1.0, 1e-12);
  const double v = a * a * a / (6.0 * std::sqrt(2.0));
  EXPECT_NEAR(q.min_volume, v, 1e-12);
  EXPECT_NEAR(q.max_volume, v, 1e-12);
  EXPECT_NEAR(q.total_volume, v, 1e-12);
  EXPECT_EQ(q.worst_tet, 0);
  EXPECT_TRUE(q.bbox_min.isApprox(Vec3::Constant(-a / std::sqrt(8.0))));
  EXPECT_TRUE(q.bbox_max.isApprox(Vec3::Constant(a / std::sqrt(8.0))));
}

TEST(Quality, StatisticsOverSeveralTets) {
  // Tet 0: unit corner tet; tet 1: a flattened tet; tet 2: inverted corner tet.
  Mat3X X(3, 6);
  X << 0, 1, 0, 0, 1, 0,  //
      0, 0, 1, 0, 1, 0,   //
      0, 0, 0, 1, 1, 0.01;
  X.col(5) = Vec3(0.3, 0.3, 0.01);
  Tets tets(4, 3);
  tets.col(0) << 0, 1, 2, 3;
  tets.col(1) << 0, 1, 2, 5;
  tets.col(2) << 0, 2, 1, 3;
  const auto q = quality(X, tets);
  EXPECT_NEAR(q.max_volume, 1.0 / 6.0, 1e-15);
  EXPECT_NEAR(q.min_volume, -1.0 / 6.0, 1e-15);
  EXPECT_NEAR(q.total_volume, 0.01 / 6.0, 1e-15);
  EXPECT_EQ(q.worst_tet, 1);
  EXPECT_GT(q.max_aspect, 10.0);
  // Corner tet: L = sqrt(2), faces 3 x 1/2 + sqrt(3)/2, V = 1/6.
  const double corner = std::sqrt(2.0) * (1.5 + std::sqrt(3.0) / 2.0) / (6.0 * std::sqrt(6.0) / 6.0);
  EXPECT_NEAR(q.min_aspect, corner, 1e-12);  // the inverted tet has the same shape
  EXPECT_NEAR(q.median_aspect, corner, 1e-12);
  EXPECT_EQ(q.bbox_min, Vec3(0, 0, 0));
  EXPECT_EQ(q.bbox_max, Vec3(1, 1, 1));

  // Even count: the median is the mean of the two middle values.
  const auto q2 = quality(X, tets.leftCols(2));
  EXPECT_NEAR(q2.median_aspect, 0.5 * (corner + q2.max_aspect), 1e-12);
}

TEST(Quality, DegenerateAndEmpty) {
  Mat3X X(3, 4);
  X << 0, 1, 0, 1,  //
      0, 0, 1, 1,   //
      0, 0, 0, 0;
  Tets tets(4, 1);
  tets << 0, 1, 2, 3;
  const auto q = quality(X, tets);
  EXPECT_EQ(q.total_volume, 0);
  EXPECT_EQ(q.max_aspect, std::numeric_limits<double>::infinity());
  EXPECT_EQ(q.worst_tet, 0);

  const auto empty = quality(X, Tets(4, 0));
  EXPECT_EQ(empty.worst_tet, -1);
  EXPECT_EQ(empty.total_volume, 0);
  EXPECT_EQ(empty.bbox_max, Vec3(1, 1, 0));

  Tets bad(4, 1);
  bad << 0, 1, 2, 4;
  EXPECT_THROW(quality(X, bad), std::logic_error);
}

TEST(TetMesh, FindGroup) {
  softdiff::mesh::TetMesh mesh;
  auto add = [&](int dim, int tag, const char* name) {
    softdiff::mesh::PhysicalGroup g;
    g.dim = dim;
    g.tag = tag;
    g.name = name;
    mesh.groups.push_back(g);
  };
  add(0, 3, "top");
  add(2, 1, "top");
  add(3, 1, "solid");
  EXPECT_EQ(mesh.find_group("top"), &mesh.groups[0]);
  EXPECT_EQ(mesh.find_group("top", 2), &mesh.groups[1]);
  EXPECT_EQ(mesh.find_group("solid"), &mesh.groups[2]);
  EXPECT_EQ(mesh.find_group("solid", 2), nullptr);
  EXPECT_EQ(mesh.find_group("missing"), nullptr);
}

}  // namespace
