// Collision detection: vertex-obstacle, soft-soft and self contacts; gaps, weights,
// frames, the gap rate against finite differences, determinism, refitting, timings.
#include <softdiff/collision/detection.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

#include <support/meshes.hpp>

#include "scene.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cstring>
#include <iostream>
#include <map>
#include <random>
#include <set>

namespace softdiff::collision {
namespace {

Obstacle floor_plane(double offset = 0) {
  Obstacle o;
  o.name = "floor";
  o.kind = ShapeKind::plane;
  o.normal = Vec3(0, 0, 1);
  o.offset = offset;
  prepare(o);
  return o;
}

// H_i v = C^T sum_k w_k v_{n_k}.
Vec3 relative_velocity(const Contact& c, const VecX& v) {
  Vec3 r = Vec3::Zero();
  for (int k = 0; k < c.count; ++k) r += c.weights[k] * v.segment<3>(3 * c.nodes[k]);
  return c.frame.transpose() * r;
}

void check_frame(const Mat3& C) {
  EXPECT_LT((C.transpose() * C - Mat3::Identity()).norm(), 1e-12);
  EXPECT_NEAR(C.determinant(), 1, 1e-12);
}

void check_contact(const Contact& c) {
  check_frame(c.frame);
  double sum = 0, positive = 0;
  for (int k = 0; k < c.count; ++k) {
    sum += c.weights[k];
    if (c.weights[k] > 0) positive += c.weights[k];
  }
  if (c.kind != ContactKind::vertex_obstacle) {
    EXPECT_EQ(c.count, 4);
    EXPECT_NEAR(sum, 0, 1e-14);
    EXPECT_NEAR(positive, 1, 1e-14);
  } else {
    EXPECT_EQ(c.count, 1);
    EXPECT_EQ(c.weights[0], 1);
  }
  EXPECT_NEAR(c.gap, c.frame.col(2).dot(c.point - c.point_b), 1e-15);
}

std::tuple<int, int, int, int> key(const Contact& c) {
  return {static_cast<int>(c.kind), c.side_a, c.feature_a, c.feature_b};
}

TEST(Frame, RightHandedAndDeterministic) {
  std::mt19937 rng(4);
  std::normal_distribution<double> g;
  for (int i = 0; i < 1000; ++i) {
    const Vec3 n = Vec3(g(rng), g(rng), g(rng)).normalized();
    const Mat3 C = frame_from_normal(n);
    check_frame(C);
    EXPECT_LT((C.col(2) - n).norm(), 1e-15);
    EXPECT_LT((C.col(0).cross(C.col(1)) - n).norm(), 1e-12);
    EXPECT_EQ(C, frame_from_normal(n));
  }
  const Mat3 C = frame_from_normal(Vec3(0, 0, 1));
  EXPECT_EQ(C.col(0), Vec3(1, 0, 0));
  EXPECT_EQ(C.col(1), Vec3(0, 1, 0));
}

TEST(PrepareSurface, VerticesAndEdges) {
  Scene s;
  s.add(test::box_mesh(2, 2, 1, 1, 1, 1), Vec3::Zero(), "box");
  const auto& b = s.surfaces[0];
  EXPECT_EQ(b.vertices.size(), 3u * 3 * 2);  // every node of a 2x2x1 grid is on the surface
  EXPECT_TRUE(std::is_sorted(b.vertices.begin(), b.vertices.end()));
  // Euler: V - E + F = 2.
  EXPECT_EQ(static_cast<long>(b.vertices.size()) - b.edges.cols() + b.triangles.cols(), 2);
  for (int e = 0; e < b.edges.cols(); ++e) EXPECT_LT(b.edges(0, e), b.edges(1, e));
}

TEST(Detection, BoxAbovePlane) {
  const double margin = 1e-3;
  for (const double lift : {5e-4, -3e-4, 2e-3}) {
    Scene s;
    s.add(test::box_mesh(4, 4, 2, 1, 1, 0.2), Vec3(0, 0, lift), "slab");
    CollisionDetector det(model_of(s, {floor_plane()}, {{0, 1, 0.4}}, margin));
    ContactSet cs;
    const auto stats = det.detect(s.x(), cs);
    if (lift > margin) {
      EXPECT_EQ(cs.size(), 0);
      continue;
    }
    ASSERT_EQ(cs.size(), 25);  // the bottom 5 x 5 nodes
    EXPECT_EQ(stats.contacts, 25);
    EXPECT_GE(stats.candidates, 25);
    int last = -1;
    for (const auto& c : cs.contacts) {
      check_contact(c);
      EXPECT_EQ(c.kind, ContactKind::vertex_obstacle);
      EXPECT_EQ(c.side_a, 0);
      EXPECT_EQ(c.side_b, 1);
      EXPECT_EQ(c.mu, 0.4);
      EXPECT_EQ(c.nodes[0], c.feature_a);
      EXPECT_GT(c.feature_a, last);  // by vertex
      last = c.feature_a;
      EXPECT_NEAR(c.gap, lift, 1e-15);
      EXPECT_EQ(c.frame.col(2), Vec3(0, 0, 1));
      EXPECT_EQ(c.point, s.X.col(c.nodes[0]));
      EXPECT_EQ(c.point_b[2], 0);
      EXPECT_EQ(c.kind_b, Feature::face);
    }
  }
}

TEST(Detection, BoxObstacleAndMeshObstacleAgree) {
  // A slab resting across the edge of a box, and the same box as a mesh obstacle.
  const double margin = 2e-3;
  Scene s;
  s.add(test::box_mesh(6, 6, 1, 0.6, 0.6, 0.1), Vec3(0.7, -0.3, 1.0005), "slab");
  Obstacle box;
  box.name = "support";
  box.kind = ShapeKind::box;
  box.center = Vec3(0.5, 0, 0.5);
  box.half_extents = Vec3(0.5, 0.5, 0.5);
  prepare(box);
  const auto cube = test::box_mesh(1, 1, 1, 1, 1, 1);
  Obstacle m;
  m.name = "support_mesh";
  m.kind = ShapeKind::mesh;
  m.mesh.vertices = cube.X.colwise() - Vec3(0, 0.5, 0);
  m.mesh.triangles = mesh::boundary_triangles(cube.tets);
  prepare(m);
  ContactSet a, b;
  CollisionDetector(model_of(s, {box}, {{0, 1, 0}}, margin)).detect(s.x(), a);
  CollisionDetector(model_of(s, {m}, {{0, 1, 0}}, margin)).detect(s.x(), b);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(a.size(), 4 * 7);  // nodes with x <= 1 on the bottom: columns x = 0.7, 0.8, 0.9, 1.0
  for (int i = 0; i < a.size(); ++i) {
    const auto &ca = a.contacts[i], &cb = b.contacts[i];
    check_contact(ca);
    check_contact(cb);
    EXPECT_EQ(ca.nodes[0], cb.nodes[0]);
    EXPECT_NEAR(ca.gap, cb.gap, 1e-12);
    EXPECT_NEAR(ca.gap, 5e-4, 1e-12);
    EXPECT_LT((ca.point_b - cb.point_b).norm(), 1e-12);
    EXPECT_LT((ca.frame.col(2) - cb.frame.col(2)).norm(), 1e-9);
  }
}

TEST(Detection, RotatedBoxEdgeAndVertex) {
  // A box rotated 45 degrees about y: its top is an edge; a vertex just above it.
  Scene s;
  s.add(test::box_mesh(2, 1, 1, 0.1, 0.1, 0.1), Vec3(-0.05, -0.05, 0.5 * std::sqrt(2.0) + 4e-4), "cube");
  Obstacle box;
  box.name = "ridge";
  box.kind = ShapeKind::box;
  box.rotation = Eigen::AngleAxisd(M_PI / 4, Vec3::UnitY()).toRotationMatrix();
  box.half_extents = Vec3(0.5, 0.5, 0.5);
  prepare(box);
  ContactSet cs;
  CollisionDetector(model_of(s, {box}, {{0, 1, 0}}, 1e-3)).detect(s.x(), cs);
  ASSERT_EQ(cs.size(), 2);  // the two bottom nodes at x = 0 (above the ridge line)
  for (const auto& c : cs.contacts) {
    EXPECT_EQ(c.kind_b, Feature::edge);
    EXPECT_NEAR(c.gap, 4e-4, 1e-12);
    EXPECT_LT((c.frame.col(2) - Vec3(0, 0, 1)).norm(), 1e-12);
  }
}

// Two boxes, B above A with a gap (or an overlap) and a lateral shift so that B's
// bottom grid is not aligned with A's top grid.
Scene two_boxes(double gap, const Vec3& shift = Vec3(0.013, 0.021, 0)) {
  Scene s;
  s.add(test::box_mesh(3, 3, 1, 0.3, 0.3, 0.1), Vec3::Zero(), "a");
  s.add(test::box_mesh(3, 3, 1, 0.3, 0.3, 0.1), shift + Vec3(0, 0, 0.1 + gap), "b");
  return s;
}

TEST(Detection, TwoBoxesFacing) {
  const double margin = 1e-3;
  for (const double gap : {4e-4, -2e-4}) {
    Scene s = two_boxes(gap);
    CollisionDetector det(model_of(s, {}, {{0, 1, 0.2}}, margin));
    ContactSet cs;
    det.detect(s.x(), cs);
    int vt_a = 0, vt_b = 0, ee = 0;
    std::set<std::tuple<int, int, int, int>> seen;
    for (const auto& c : cs.contacts) {
      check_contact(c);
      EXPECT_TRUE(seen.insert(key(c)).second) << "duplicate contact";
      EXPECT_NEAR(c.gap, gap, 1e-12);
      // n from B (above) to A (below), or from A to B when B's vertex is side A.
      const double nz = c.frame(2, 2);
      if (c.kind == ContactKind::vertex_triangle) {
        EXPECT_EQ(c.kind_b, Feature::face);
        if (c.side_a == 0) {
          ++vt_a;
          EXPECT_NEAR(nz, -1, 1e-12);
        } else {
          ++vt_b;
          EXPECT_EQ(c.side_b, 0);
          EXPECT_NEAR(nz, 1, 1e-12);
        }
      } else {
        ASSERT_EQ(c.kind, ContactKind::edge_edge);
        ++ee;
        EXPECT_EQ(c.side_a, 0);
        EXPECT_NEAR(nz, -1, 1e-12);
        for (int k = 0; k < 4; ++k) EXPECT_NE(c.weights[k], 0);
      }
    }
    EXPECT_EQ(vt_a, 9) << "gap " << gap;  // A's top nodes above B's bottom face
    EXPECT_EQ(vt_b, 9) << "gap " << gap;  // B's bottom nodes above A's top face
    EXPECT_GT(ee, 0) << "gap " << gap;    // A's top edges crossing B's bottom edges
    // Order: by kind, then side, then features.
    for (int i = 1; i < cs.size(); ++i) {
      const auto &p = cs.contacts[i - 1], &c = cs.contacts[i];
      const auto kp = std::make_tuple(static_cast<int>(p.kind), p.side_a != 0, p.feature_a, p.feature_b);
      const auto kc = std::make_tuple(static_cast<int>(c.kind), c.side_a != 0, c.feature_a, c.feature_b);
      EXPECT_LT(kp, kc);
    }
  }
}

// Contact normals at tiny gaps (2026-12-04, rnrm; docs/method.md "Contact normals at tiny
// gaps"). Two boxes facing at a gap of 2e-12 m (above detection's 1e-9 margin = 1e-12 m,
// below which the normal was already the pseudo-normal), turned to a generic orientation
// so that no coordinate is exact: d / |d| has components along the faces of ~eps |x| /
// gap ~ 1e-17 / 2e-12 = 5e-6 (rstack's measure on the former detection.cpp: 4.4e-6 to
// 8.9e-6 off for the vertex-triangle normals). Every normal, vertex-triangle (the face
// normal) and edge-edge (the edges' unit cross product), is the faces' +-R z to 1e-13 (a
// normalized cross product of 0.1 m vectors carries ~1e-16; 1e-13 is 1000 times that and
// 50 times below the former error), and the gap is 2e-12 to 1e-13 (0.3 m positions turned:
// ~1e-16 m round-off).
TEST(Detection, NormalsAtATinyGapAreTheFacesAndTheEdgesCrossProduct) {
  const double margin = 1e-3, gap = 2e-12;
  Scene s = two_boxes(gap);
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  s.X = R * s.X;
  CollisionDetector det(model_of(s, {}, {{0, 1, 0.2}}, margin));
  ContactSet cs;
  det.detect(s.x(), cs);
  const Vec3 up = R * Vec3::UnitZ();
  int vt = 0, ee = 0;
  for (const auto& c : cs.contacts) {
    check_contact(c);
    EXPECT_NEAR(c.gap, gap, 1e-13);
    const Vec3 n = c.frame.col(2);
    EXPECT_LT(std::min((n - up).norm(), (n + up).norm()), 1e-13)
        << "kind " << static_cast<int>(c.kind) << ", features " << c.feature_a << ", " << c.feature_b;
    if (c.kind == ContactKind::vertex_triangle) {
      ++vt;
      EXPECT_EQ(c.kind_b, Feature::face);
    } else {
      ++ee;
    }
  }
  EXPECT_EQ(vt, 18);  // as TwoBoxesFacing: 9 + 9 vertices above the other box's face
  EXPECT_GT(ee, 0);
}

// A vertex 1e-12 m above an edge or a vertex of a flat region (a diagonal of a box's top
// face: its two triangles coplanar) is recorded against the face's plane: kind_b = face,
// n = the face normal to 1e-13 (d / |d| would be ~1e-17 / 1e-12 = 1e-5 off or worse; the
// cube on a soft slab had such contacts, a cube's corner on a slab triangle's diagonal, up
// to 87 degrees off), gap 1e-12 to 1e-13. On a sharp edge (the top face's boundary, a
// 90-degree dihedral) it keeps the edge feature: only a flat feature takes the face.
TEST(Detection, FlatEdgeAtATinyGapIsTheFacesContactSharpEdgeIsNot) {
  const double margin = 1e-3, gap = 1e-12;
  Vec3 up;
  {  // on the top face's diagonal: its midpoint is the face's centre
    Scene s = corner_on_box_top(Vec3(0.1, 0.1, 0.2), gap, up);
    ContactSet cs;
    CollisionDetector(model_of(s, {}, {{0, 1, 0}}, margin)).detect(s.x(), cs);
    ASSERT_GT(cs.size(), 0);
    for (const auto& c : cs.contacts) {
      check_contact(c);
      ASSERT_EQ(c.kind, ContactKind::vertex_triangle);
      EXPECT_EQ(c.kind_b, Feature::face);
      EXPECT_LT((c.frame.col(2) - up).norm(), 1e-13);
      EXPECT_NEAR(c.gap, gap, 1e-13);
    }
  }
  {  // on the middle of the top face's edge y = 0, along the bisector of its two faces
    const Vec3 target = Vec3(0.1, 0, 0.2) + Vec3(0, -1, 0) * (gap / std::sqrt(2.0)) - Vec3(0, 0, gap - gap / std::sqrt(2.0));
    Scene s = corner_on_box_top(target, gap, up);
    ContactSet cs;
    CollisionDetector(model_of(s, {}, {{0, 1, 0}}, margin)).detect(s.x(), cs);
    ASSERT_EQ(cs.size(), 1);
    const auto& c = cs.contacts[0];
    check_contact(c);
    EXPECT_EQ(c.kind, ContactKind::vertex_triangle);
    EXPECT_EQ(c.kind_b, Feature::edge);
  }
}

// Records beside an edge or a vertex (docs/method.md *Records beside an edge or a
// vertex*). A plate's 9 top nodes under the bottom face of a 0.2 m box (box_mesh(1, 1, 1):
// the face is two triangles, split by a diagonal), 3 of them 7.1e-5 m beside that diagonal
// (alternately on either side), the others 0.035 m or more from it; the plate's top 1e-4 m
// or 1e-12 m below the face, or 1e-13 m inside it; the scene turned by a generic rotation.
// Each node has one record against the box: its face's (kind_b face, n the face normal to
// 1e-12, the gap to 1e-14: 0.2 m coordinates turned carry ~1e-16 m). Without the rule a
// node over the higher-index triangle also had the lower one's record with its closest
// point on the diagonal: d = p - q along the face, so a sideways normal and a gap of
// -|d| or +|d| (12 records for 9 nodes; at the tiny gaps |n . up| = 0).
TEST(Detection, NodesBesideAFlatDiagonalHaveOneContactEach) {
  const double margin = 1e-3, offset = 7.1e-5;
  for (const double gap : {1e-4, 1e-12, -1e-13}) {
    Scene s;
    const int plate = s.add(test::box_mesh(2, 2, 1, 0.1, 0.1, 0.02), Vec3(0.05, 0.05, -0.02 - gap), "plate");
    const int box = s.add(test::box_mesh(1, 1, 1, 0.2, 0.2, 0.2), Vec3::Zero(), "box");
    // The box's bottom diagonal: the edge shared by its two triangles at z = 0.
    const auto& tris = s.surfaces[1].triangles;
    std::map<std::pair<int, int>, int> bottom_edges;
    for (int t = 0; t < tris.cols(); ++t) {
      bool bottom = true;
      for (int k = 0; k < 3; ++k) bottom = bottom && s.X(2, tris(k, t)) == 0;
      if (!bottom) continue;
      for (int k = 0; k < 3; ++k)
        ++bottom_edges[std::minmax(tris(k, t), tris((k + 1) % 3, t))];
    }
    Vec3 d0, d1;
    int shared = 0;
    for (const auto& [e, count] : bottom_edges)
      if (count == 2) {
        ++shared;
        d0 = s.X.col(e.first);
        d1 = s.X.col(e.second);
      }
    ASSERT_EQ(shared, 1);
    const Vec3 along = (d1 - d0).normalized(), side = Vec3::UnitZ().cross(along);
    // The plate's top nodes on the diagonal, moved off it.
    int top = 0, moved = 0;
    for (int i = plate; i < box; ++i) {
      if (std::abs(s.X(2, i) + gap) > 1e-15) continue;
      ++top;
      const Vec3 r = Vec3(s.X(0, i), s.X(1, i), 0) - d0;  // in the face's plane z = 0
      if ((r - r.dot(along) * along).norm() < 1e-9) s.X.col(i) += (moved++ % 2 == 0 ? 1.0 : -1.0) * offset * side;
    }
    ASSERT_EQ(top, 9);
    ASSERT_EQ(moved, 3);
    const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
    s.X = R * s.X;
    const Vec3 down = -(R * Vec3::UnitZ());  // the box's bottom face's outward normal
    ContactSet cs;
    CollisionDetector(model_of(s, {}, {{0, 1, 0}}, margin)).detect(s.x(), cs);
    std::map<int, int> records;
    for (const auto& c : cs.contacts) {
      if (c.kind != ContactKind::vertex_triangle || c.side_a != 0) continue;
      check_contact(c);
      ++records[c.nodes[0]];
      EXPECT_EQ(c.kind_b, Feature::face) << "node " << c.nodes[0] << ", gap " << gap;
      EXPECT_LT((c.frame.col(2) - down).norm(), 1e-12) << "node " << c.nodes[0] << ", gap " << gap;
      EXPECT_NEAR(c.gap, gap, 1e-14) << "node " << c.nodes[0];
    }
    EXPECT_EQ(records.size(), 9u) << "gap " << gap;
    for (const auto& [node, count] : records) EXPECT_EQ(count, 1) << "node " << node << ", gap " << gap;
  }
}

// A single tetrahedron (its apex p, the apex's angle-weighted normal along c) beside a
// 0.2 m box (box_mesh(1, 1, 1)), the scene turned by a generic rotation.
Scene apex_by_box(const Vec3& p, const Vec3& c) {
  Scene s;
  s.add(test::box_mesh(1, 1, 1, 0.2, 0.2, 0.2), Vec3::Zero(), "box");
  const Vec3 u = c.normalized();
  const Vec3 e1 = u.unitOrthogonal(), e2 = u.cross(e1);
  mesh::TetMesh t;
  t.X.resize(3, 4);
  t.X.col(0) = p;
  for (int k = 0; k < 3; ++k) {
    const double a = 2 * M_PI * k / 3;
    t.X.col(k + 1) = p + 0.05 * (std::cos(a) * e1 + std::sin(a) * e2 - 1.5 * u);
  }
  t.tets.resize(4, 1);
  t.tets << 0, 1, 2, 3;
  if ((t.X.col(1) - p).cross(t.X.col(2) - p).dot(t.X.col(3) - p) < 0) std::swap(t.tets(1, 0), t.tets(2, 0));
  s.add(t, Vec3::Zero(), "tip");
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  s.X = R * s.X;
  return s;
}

// A vertex under a sharp edge: the fingertip case of configs/gripper_lift.yaml (a cylinder
// vertex 43 um below a fingertip's corner edge, beside its pad face). The apex 1e-5 m in
// front of the box's side face y = 0 and 4.3e-5 m below its top edge, its normal towards
// the box and down. One record: the side face's (n the face's outward normal -y, gap
// +1e-5 m). Without the rule the top face's triangle, where it is the edge's lower index,
// gave a second one with its closest point on the edge: d = p - q points out and down,
// the sign test against the edge's pseudo-normal flips it, so n = -d / |d| is mostly up
// (n_z 0.97) and the gap -|d| = -4.4e-5 m, a penetration read from an apex that is
// outside (it held the cylinder up without a friction limit). Outside the edge's wedge
// (the apex 2e-4 m beyond the side face and above the top face) the edge's record is the
// apex's closest point and stays: n along the edge's bisector, gap +|p - q|.
TEST(Detection, VertexUnderASharpEdgeHasOnlyTheFacesRecord) {
  const double margin = 1e-3;
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  const Vec3 centre(0.1, 0.1, 0.1);
  // Each of the top face's four edges (the configuration turned about the box's vertical
  // axis): whether the top triangle or the side one is the edge's lower index varies.
  for (int side = 0; side < 4; ++side) {
    SCOPED_TRACE("side " + std::to_string(side));
    const Mat3 Z = Eigen::AngleAxisd(side * M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
    const auto turned = [&](const Vec3& q) { return Vec3(Z * (q - centre) + centre); };
    // The apex's (node 8's) records against the box, each checked; expected: exactly one,
    // of kind `feature`, normal n to `n_tolerance`, gap `gap` to 1e-15 m.
    const auto expect_one_record = [&](const Vec3& apex, const Vec3& normal, Feature feature, const Vec3& n,
                                       double n_tolerance, double gap) {
      const Scene s = apex_by_box(turned(apex), Z * normal);
      ContactSet cs;
      CollisionDetector(model_of(s, {}, {{1, 0, 0}}, margin)).detect(s.x(), cs);
      int records = 0;
      for (const auto& c : cs.contacts) {
        if (c.kind != ContactKind::vertex_triangle || c.side_a != 1 || c.nodes[0] != 8) continue;
        ++records;
        check_contact(c);
        EXPECT_EQ(c.kind_b, feature);
        EXPECT_LT((c.frame.col(2) - R * Z * n).norm(), n_tolerance);
        EXPECT_NEAR(c.gap, gap, 1e-15);
      }
      EXPECT_EQ(records, 1);
    };
    expect_one_record(Vec3(0.1, -1e-5, 0.2 - 4.3e-5), Vec3(0, 1, -0.3), Feature::face, Vec3(0, -1, 0), 1e-12, 1e-5);
    expect_one_record(Vec3(0.1, -2e-4, 0.2 + 2e-4), Vec3(0, 1, -1), Feature::edge, Vec3(0, -1, 1).normalized(), 1e-10,
                      2e-4 * std::sqrt(2.0));
  }
}

TEST(Detection, RelativeVelocityAndGapRate) {
  const double margin = 1e-3;
  for (const double gap : {4e-4, -2e-4}) {
    Scene s = two_boxes(gap);
    CollisionDetector det(model_of(s, {}, {{0, 1, 0}}, margin));
    ContactSet cs;
    const VecX x = s.x();
    det.detect(x, cs);
    ASSERT_GT(cs.size(), 0);
    // A common rigid translation: no relative velocity.
    VecX v(x.size());
    for (int i = 0; i < v.size() / 3; ++i) v.segment<3>(3 * i) = Vec3(0.3, -0.2, 0.7);
    for (const auto& c : cs.contacts) EXPECT_LT(relative_velocity(c, v).norm(), 1e-14);
    // B moving down at 1: the normal relative velocity is -1 for B's triangles under A's
    // nodes (n = -z) ... i.e. n . (v_A - v_B) = n . (0, 0, 1).
    const int nb = static_cast<int>(test::box_mesh(3, 3, 1, 0.3, 0.3, 0.1).num_nodes());
    v.setZero();
    for (int i = nb; i < 2 * nb; ++i) v.segment<3>(3 * i) = Vec3(0, 0, -1);
    for (const auto& c : cs.contacts) {
      const double sign = c.side_a == 0 ? 1 : -1;
      EXPECT_NEAR(relative_velocity(c, v)[2], sign * c.frame.col(2).dot(Vec3(0, 0, 1)), 1e-12);
    }
    // Random node velocities: the normal row is the rate of the gap (central differences).
    std::mt19937 rng(8);
    std::uniform_real_distribution<double> u(-1, 1);
    for (int i = 0; i < v.size(); ++i) v[i] = u(rng);
    const double h = 1e-7;
    ContactSet plus, minus;
    det.detect(x + h * v, plus);
    det.detect(x - h * v, minus);
    std::map<std::tuple<int, int, int, int>, double> gp, gm;
    for (const auto& c : plus.contacts) gp[key(c)] = c.gap;
    for (const auto& c : minus.contacts) gm[key(c)] = c.gap;
    int checked = 0;
    for (const auto& c : cs.contacts) {
      if (!gp.count(key(c)) || !gm.count(key(c))) continue;
      const double fd = (gp[key(c)] - gm[key(c)]) / (2 * h);
      EXPECT_NEAR(relative_velocity(c, v)[2], fd, 1e-6) << static_cast<int>(c.kind);
      ++checked;
    }
    EXPECT_GT(checked, cs.size() / 2);
  }
}

TEST(Detection, CrossedEdgesOnly) {
  // Two boxes crossed at 90 degrees about z, B's bottom edge ridge above A's top: a
  // box rotated 45 degrees about x has a lowest edge along x; A rotated 45 degrees
  // about y has a highest edge along y. They cross: one edge-edge contact.
  Scene s;
  mesh::TetMesh a = test::box_mesh(1, 1, 1, 0.2, 0.2, 0.2), b = a;
  const Mat3 Ra = Eigen::AngleAxisd(M_PI / 4, Vec3::UnitY()).toRotationMatrix();
  const Mat3 Rb = Eigen::AngleAxisd(M_PI / 4, Vec3::UnitX()).toRotationMatrix();
  a.X = Ra * (a.X.colwise() - Vec3(0.1, 0.1, 0.1));
  b.X = Rb * (b.X.colwise() - Vec3(0.1, 0.1, 0.1));
  const double ridge = 0.1 * std::sqrt(2.0);
  const double gap = 3e-4;
  s.add(a, Vec3::Zero(), "a");
  s.add(b, Vec3(0, 0, 2 * ridge + gap), "b");
  ContactSet cs;
  CollisionDetector(model_of(s, {}, {{0, 1, 0}}, 1e-3)).detect(s.x(), cs);
  ASSERT_EQ(cs.size(), 1);
  const auto& c = cs.contacts[0];
  check_contact(c);
  EXPECT_EQ(c.kind, ContactKind::edge_edge);
  EXPECT_NEAR(c.gap, gap, 1e-12);
  EXPECT_LT((c.frame.col(2) - Vec3(0, 0, -1)).norm(), 1e-9);
  for (int k = 0; k < 4; ++k) EXPECT_NEAR(std::abs(c.weights[k]), 0.5, 1e-12);
  // Crossed through each other: a negative gap, same normal.
  s.X.rightCols(8).row(2).array() -= 2 * gap;
  CollisionDetector(model_of(s, {}, {{0, 1, 0}}, 1e-3)).detect(s.x(), cs);
  int ee = 0;
  for (const auto& k : cs.contacts)
    if (k.kind == ContactKind::edge_edge) {
      ++ee;
      EXPECT_NEAR(k.gap, -gap, 1e-12);
      EXPECT_LT((k.frame.col(2) - Vec3(0, 0, -1)).norm(), 1e-9);
    }
  EXPECT_EQ(ee, 1);
}

// A U: a 5 x 1 x 5 grid of cells without the cells i = 1..3, k >= 1; then the arms
// (nodes with z >= 0.4) are pushed towards each other until their inner faces are
// `inner_gap` apart.
Scene u_shape(int refine, double inner_gap) {
  const int nx = 5 * refine, nz = 5 * refine;
  mesh::TetMesh m = test::box_mesh(nx, refine, nz, 1, 0.2, 1);
  std::vector<int> keep;
  for (int e = 0; e < m.num_tets(); ++e) {
    Vec3 c = Vec3::Zero();
    for (int k = 0; k < 4; ++k) c += 0.25 * m.X.col(m.tets(k, e));
    if (c[0] < 0.2 || c[0] > 0.8 || c[2] < 0.2) keep.push_back(e);
  }
  Tets t(4, static_cast<int>(keep.size()));
  for (std::size_t i = 0; i < keep.size(); ++i) t.col(static_cast<int>(i)) = m.tets.col(keep[i]);
  m.tets = t;
  const double delta = 0.5 * (0.6 - inner_gap);
  for (int i = 0; i < m.num_nodes(); ++i)
    if (m.X(2, i) >= 0.4 - 1e-12) m.X(0, i) += m.X(0, i) < 0.5 ? delta : -delta;
  Scene s;
  s.add(m, Vec3::Zero(), "u");
  return s;
}

TEST(Detection, SelfContactOfAU) {
  const double margin = 1e-3, inner_gap = 5e-4;
  Scene s = u_shape(1, inner_gap);
  CollisionDetector det(model_of(s, {}, {{0, 0, 0.1}}, margin));
  ContactSet cs;
  det.detect(s.x(), cs);
  // The inner faces' 2 x 4 nodes face the other arm's nodes exactly: point-point pairs,
  // each reported once.
  ASSERT_EQ(cs.size(), 8);
  std::set<std::pair<int, int>> pairs;
  for (const auto& c : cs.contacts) {
    check_contact(c);
    EXPECT_EQ(c.side_a, 0);
    EXPECT_EQ(c.side_b, 0);
    EXPECT_EQ(c.kind, ContactKind::vertex_triangle);
    EXPECT_EQ(c.kind_b, Feature::vertex);
    EXPECT_NEAR(c.gap, inner_gap, 1e-12);
    EXPECT_LT((c.point[0] - 0.5) * (c.point_b[0] - 0.5), 0) << "contact within one arm";
    EXPECT_NEAR(std::abs(c.frame(0, 2)), 1, 1e-12);
    EXPECT_LT(c.point[2], 1 + 1e-12);
    EXPECT_GT(c.point[2], 0.4 - 1e-12);
    int w = -1;
    for (int k = 1; k < 4; ++k)
      if (c.weights[k] == -1) w = c.nodes[k];
    EXPECT_TRUE(pairs.insert({std::min(c.nodes[0], w), std::max(c.nodes[0], w)}).second);
  }
  // A finer U: the arms' facing nodes no longer align with a shifted grid; contacts
  // only between the arms.
  Scene f = u_shape(2, inner_gap);
  for (int i = 0; i < f.X.cols(); ++i)
    if (f.X(0, i) > 0.5 && f.X(2, i) >= 0.4) f.X(1, i) += 0.013;  // shift the right arm along y
  CollisionDetector detf(model_of(f, {}, {{0, 0, 0.1}}, margin));
  detf.detect(f.x(), cs);
  EXPECT_GT(cs.size(), 8);
  int ee = 0;
  for (const auto& c : cs.contacts) {
    check_contact(c);
    ee += c.kind == ContactKind::edge_edge;
    EXPECT_LT((c.point[0] - 0.5) * (c.point_b[0] - 0.5), 0) << "contact within one arm";
    EXPECT_NEAR(c.gap, inner_gap, 1e-12);
  }
  EXPECT_GT(ee, 0);
}

// A margin per surface (CollisionDetector::detect with surface_margin; the contact step
// widens each surface's margin by its own motion): a U's self pair uses its own margin, a
// pair of boxes the larger of theirs (the broad phase inflates surface k by m_k - mu / 2,
// detection.hpp), a box against the floor its own. Equal margins give exactly the
// scalar margin's contacts. Gaps: the U's inner gap 5e-4, the boxes' 4e-4, box a above
// the floor by 3e-4; margins 2e-4 (below every gap) or 1e-3 (above).
TEST(Detection, MarginPerSurface) {
  Scene s = u_shape(1, 5e-4);
  s.add(test::box_mesh(3, 3, 1, 0.3, 0.3, 0.1), Vec3(3, 0, 0), "a");
  s.add(test::box_mesh(3, 3, 1, 0.3, 0.3, 0.1), Vec3(3.013, 0.021, 0.1 + 4e-4), "b");
  CollisionDetector det(model_of(s, {floor_plane(-3e-4)}, {{0, 0, 0.1}, {1, 2, 0.2}, {1, 3, 0.3}}, 1e-3));
  ContactSet scalar, per;
  det.detect(s.x(), scalar, 1e-3);
  det.detect(s.x(), per, std::vector<double>{1e-3, 1e-3, 1e-3});
  ASSERT_EQ(per.size(), scalar.size());
  for (int i = 0; i < per.size(); ++i) EXPECT_EQ(key(per.contacts[i]), key(scalar.contacts[i])) << "contact " << i;
  auto count = [](const ContactSet& cs, int a, int b) {
    int k = 0;
    for (const auto& c : cs.contacts) k += (c.side_a == a && c.side_b == b) || (c.side_a == b && c.side_b == a);
    return k;
  };
  const int self = count(scalar, 0, 0), boxes = count(scalar, 1, 2), floor = count(scalar, 1, 3);
  EXPECT_EQ(self, 8);
  EXPECT_GT(boxes, 18);
  EXPECT_EQ(floor, 16);  // box a's bottom nodes (4 x 4)
  const double lo = 2e-4, hi = 1e-3;
  // A slow U and a slow box a against a fast box b: no self contact, the boxes' pair by
  // b's margin (the same contacts as with hi everywhere), nothing on the floor.
  det.detect(s.x(), per, std::vector<double>{lo, lo, hi});
  EXPECT_EQ(count(per, 0, 0), 0);
  EXPECT_EQ(count(per, 1, 2), boxes);
  EXPECT_EQ(count(per, 1, 3), 0);
  // Box a fast: the floor's contacts and the boxes' pair.
  det.detect(s.x(), per, std::vector<double>{lo, hi, lo});
  EXPECT_EQ(count(per, 0, 0), 0);
  EXPECT_EQ(count(per, 1, 2), boxes);
  EXPECT_EQ(count(per, 1, 3), floor);
  // The U fast, the boxes slow: only the U's self contacts.
  det.detect(s.x(), per, std::vector<double>{hi, lo, lo});
  EXPECT_EQ(count(per, 0, 0), self);
  EXPECT_EQ(count(per, 1, 2), 0);
  EXPECT_EQ(count(per, 1, 3), 0);
}

TEST(Detection, NoSelfContactOnUndeformedSurfaces) {
  // Flat, fine surface with a margin of 0.3 edge lengths: the one-ring rule removes
  // every adjacent pair; the rest are farther than the margin.
  Scene s;
  s.add(test::box_mesh(10, 10, 2, 1, 1, 0.2), Vec3::Zero(), "slab");
  CollisionDetector det(model_of(s, {}, {{0, 0, 0}}, 0.03));
  ContactSet cs;
  const auto stats = det.detect(s.x(), cs);
  EXPECT_EQ(cs.size(), 0);
  EXPECT_GT(stats.candidates, 0);  // pairs were examined
  Scene u = u_shape(2, 0.6);       // the undeformed U
  CollisionDetector detu(model_of(u, {}, {{0, 0, 0}}, 0.03));
  detu.detect(u.x(), cs);
  EXPECT_EQ(cs.size(), 0);
}

// The broad phase against brute force: the number of candidates the narrow phase examines
// (DetectionStats::candidates, after de-duplication) equals the number of feature pairs
// within the margin counted over all pairs: vertex v of a against triangle t of b with v
// within the margin of t's box (per axis), edges e1, e2 with boxes within the margin, and
// in self-contact minus the exclusions (t contains v or a one-ring neighbour of v; e1, e2
// share a vertex or an endpoint of one neighbours an endpoint of the other; each edge pair
// once). Since 2026-12-04 each candidate is emitted once, from the pair of its features'
// lowest-index triangles (detection.cpp add_candidates): this checks that none is lost,
// on two boxes turned generically, with one margin and with a margin per surface (the
// boxes' inflations then differ), and on a U folded onto itself (self-contact), every node
// moved by a random 0.2-margin so that no coordinate is aligned.
int brute_force_candidates(const Scene& s, const VecX& x, int a, int b, double margin) {
  const auto P = [&](int n) { return Vec3(x.segment<3>(3 * n)); };
  const BodySurface &A = s.surfaces[static_cast<std::size_t>(a)], &B = s.surfaces[static_cast<std::size_t>(b)];
  const bool self = a == b;
  std::map<int, std::set<int>> ring;
  for (int e = 0; e < A.edges.cols(); ++e) {
    ring[A.edges(0, e)].insert(A.edges(1, e));
    ring[A.edges(1, e)].insert(A.edges(0, e));
  }
  const auto neighbours = [&](int v, int w) { return v == w || ring[v].count(w) > 0; };
  const auto box = [&](std::initializer_list<int> nodes, Vec3& lo, Vec3& hi) {
    lo = Vec3::Constant(1e300);
    hi = Vec3::Constant(-1e300);
    for (int n : nodes) {
      lo = lo.cwiseMin(P(n));
      hi = hi.cwiseMax(P(n));
    }
  };
  int count = 0;
  // Vertex-triangle, both directions (in self-contact one direction covers all pairs).
  for (int dir = 0; dir < (self ? 1 : 2); ++dir) {
    const BodySurface &V = dir == 0 ? A : B, &T = dir == 0 ? B : A;
    for (int v : V.vertices)
      for (int t = 0; t < T.triangles.cols(); ++t) {
        Vec3 lo, hi;
        box({T.triangles(0, t), T.triangles(1, t), T.triangles(2, t)}, lo, hi);
        const Vec3 p = P(v);
        if (!((p.array() >= lo.array() - margin).all() && (p.array() <= hi.array() + margin).all())) continue;
        if (self) {
          bool skip = false;
          for (int k = 0; k < 3; ++k) skip = skip || neighbours(v, T.triangles(k, t));
          if (skip) continue;
        }
        ++count;
      }
  }
  for (int e1 = 0; e1 < A.edges.cols(); ++e1)
    for (int e2 = self ? e1 + 1 : 0; e2 < B.edges.cols(); ++e2) {
      Vec3 lo1, hi1, lo2, hi2;
      box({A.edges(0, e1), A.edges(1, e1)}, lo1, hi1);
      box({B.edges(0, e2), B.edges(1, e2)}, lo2, hi2);
      if (!((lo1.array() <= hi2.array() + margin).all() && (lo2.array() <= hi1.array() + margin).all())) continue;
      if (self) {
        bool skip = false;
        for (int i = 0; i < 2; ++i)
          for (int j = 0; j < 2; ++j) skip = skip || neighbours(A.edges(i, e1), A.edges(j, e2));
        if (skip) continue;
      }
      ++count;
    }
  return count;
}

TEST(Detection, BroadPhaseMissesNoPairWithinTheMargin) {
  std::mt19937 rng(11);
  const auto jitter = [&](Scene& s, double amount) {
    std::uniform_real_distribution<double> u(-amount, amount);
    for (int i = 0; i < s.X.cols(); ++i)
      for (int k = 0; k < 3; ++k) s.X(k, i) += u(rng);
  };
  const double margin = 3e-3;
  {
    Scene s = two_boxes(1e-3);
    s.X = Eigen::AngleAxisd(0.7, Vec3(0.3, -0.5, 0.8).normalized()).toRotationMatrix() * s.X;
    jitter(s, 0.2 * margin);
    for (const std::vector<double>& m : {std::vector<double>{margin, margin}, std::vector<double>{margin, 2.5 * margin}}) {
      CollisionDetector det(model_of(s, {}, {{0, 1, 0.2}}, margin));
      ContactSet cs;
      const DetectionStats st = det.detect(s.x(), cs, m);
      const int expected = brute_force_candidates(s, s.x(), 0, 1, std::max(m[0], m[1]));
      EXPECT_GT(expected, 50);
      EXPECT_EQ(st.candidates, expected) << "margins " << m[0] << ", " << m[1];
    }
  }
  {
    Scene s = u_shape(2, 2e-3);
    jitter(s, 0.2 * margin);
    CollisionDetector det(model_of(s, {}, {{0, 0, 0.2}}, margin));
    ContactSet cs;
    const DetectionStats st = det.detect(s.x(), cs);
    const int expected = brute_force_candidates(s, s.x(), 0, 0, margin);
    EXPECT_GT(expected, 50);
    EXPECT_EQ(st.candidates, expected);
  }
}

bool same(const ContactSet& a, const ContactSet& b) {
  if (a.size() != b.size()) return false;
  for (int i = 0; i < a.size(); ++i) {
    const auto &x = a.contacts[i], &y = b.contacts[i];
    if (x.kind != y.kind || x.side_a != y.side_a || x.side_b != y.side_b || x.count != y.count || x.nodes != y.nodes ||
        x.weights != y.weights || x.frame != y.frame || x.point != y.point || x.point_b != y.point_b ||
        x.gap != y.gap || x.mu != y.mu || x.feature_a != y.feature_a || x.feature_b != y.feature_b ||
        x.kind_b != y.kind_b)
      return false;
  }
  return true;
}

TEST(Detection, DeterministicAndRefitted) {
  Scene s = two_boxes(4e-4);
  s.add(test::box_mesh(3, 3, 1, 0.3, 0.3, 0.1), Vec3(0, 0, -0.1 - 2e-4), "c");  // a third body below A
  const DetectionModel model =
      model_of(s, {floor_plane(-0.1 - 2e-4 - 5e-4)}, {{0, 1, 0}, {2, 0, 0}, {2, 3, 0.5}, {0, 0, 0}}, 1e-3);
  CollisionDetector det(model), det2(model);
  ContactSet a, b, c;
  det.detect(s.x(), a);
  det.detect(s.x(), b);
  det2.detect(s.x(), c);
  EXPECT_GT(a.size(), 30);
  EXPECT_TRUE(same(a, b));
  EXPECT_TRUE(same(a, c));
  // Pair rules in order.
  int last_rule = 0;
  auto rule_of = [&](const Contact& k) {
    for (int r = 0; r < static_cast<int>(model.pairs.size()); ++r) {
      const auto& p = model.pairs[r];
      if ((k.side_a == p.a && k.side_b == p.b) || (k.side_a == p.b && k.side_b == p.a)) return r;
    }
    return -1;
  };
  for (const auto& k : a.contacts) {
    const int r = rule_of(k);
    EXPECT_GE(r, last_rule);
    last_rule = r;
  }
  // No allocation once grown: same buffer.
  const auto* data = a.contacts.data();
  det.detect(s.x(), a);
  EXPECT_EQ(a.contacts.data(), data);

  // Refit: move B away (no A-B contacts), then back with a lateral shift.
  Scene moved = s;
  const int nb = test::box_mesh(3, 3, 1, 0.3, 0.3, 0.1).num_nodes();
  moved.X.middleCols(nb, nb).row(2).array() += 0.05;
  det.detect(moved.x(), a);
  for (const auto& k : a.contacts) EXPECT_FALSE(k.side_a + k.side_b == 1 && k.side_a != k.side_b);
  moved.X.middleCols(nb, nb).row(2).array() -= 0.05;
  moved.X.middleCols(nb, nb).row(0).array() += 0.05;
  det.detect(moved.x(), a);
  CollisionDetector fresh(model);
  fresh.detect(moved.x(), b);
  EXPECT_TRUE(same(a, b));  // the refitted tree finds what a new one finds
  int ab = 0;
  for (const auto& k : a.contacts)
    if (k.side_a + k.side_b == 1 && k.side_a != k.side_b) {
      ++ab;
      EXPECT_GT(std::max(k.point[0], k.point_b[0]), 0.05 + 0.013 - 1e-12);
      EXPECT_NEAR(k.gap, 4e-4, 1e-12);
    }
  EXPECT_GT(ab, 0);
}

double time_ms(CollisionDetector& det, const VecX& x, ContactSet& cs, int reps) {
  det.detect(x, cs);  // warm up (buffers grow)
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < reps; ++i) det.detect(x, cs);
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / reps;
}

TEST(DetectionTiming, SlabOnPlaneAndSelfContact) {
  {
    // 32 x 32 x 2 nodes, all within the margin of the floor: 2048 contacts.
    Scene s;
    s.add(test::box_mesh(31, 31, 1, 1, 1, 4e-4), Vec3(0, 0, 1e-4), "slab");
    CollisionDetector det(model_of(s, {floor_plane()}, {{0, 1, 0}}, 1e-3));
    ContactSet cs;
    const double ms = time_ms(det, s.x(), cs, 200);
    EXPECT_EQ(cs.size(), 2048);
    std::cout << "[ timing ] vertex-plane, " << s.surfaces[0].vertices.size() << " vertices, " << cs.size()
              << " contacts: " << ms << " ms\n";
    EXPECT_LT(ms, 5.0);
  }
  {
    // Self-contact on a 10k-triangle surface (no contacts: the broad phase and the
    // one-ring filtering only), and a folded U with contacts.
    Scene s;
    s.add(test::box_mesh(50, 50, 1, 1, 1, 0.05), Vec3::Zero(), "sheet");
    CollisionDetector det(model_of(s, {}, {{0, 0, 0}}, 1e-3));
    ContactSet cs;
    const double ms = time_ms(det, s.x(), cs, 10);
    std::cout << "[ timing ] self-contact, flat sheet, " << s.surfaces[0].triangles.cols() << " triangles, "
              << cs.size() << " contacts: " << ms << " ms\n";
    EXPECT_EQ(cs.size(), 0);
    Scene u = u_shape(8, 5e-4);
    for (int i = 0; i < u.X.cols(); ++i)
      if (u.X(0, i) > 0.5 && u.X(2, i) >= 0.4) u.X(1, i) += 0.0013;
    CollisionDetector detu(model_of(u, {}, {{0, 0, 0}}, 1e-3));
    DetectionStats st = detu.detect(u.x(), cs);
    const double msu = time_ms(detu, u.x(), cs, 10);
    std::cout << "[ timing ] self-contact, folded U, " << u.surfaces[0].triangles.cols() << " triangles, "
              << cs.size() << " contacts, " << st.candidates << " candidates: " << msu << " ms\n";
    EXPECT_GT(cs.size(), 0);
  }
}

}  // namespace
}  // namespace softdiff::collision
