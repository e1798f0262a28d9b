// Obstacles: closed-form signed distances against independent formulas and dense
// surface sampling; box features; validation errors; mesh obstacles (STL binary and
// ASCII, Gmsh .msh ASCII and binary) against the analytic box and sphere.
#include <softdiff/collision/obstacle.hpp>
#include <softdiff/core/error.hpp>

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>

namespace softdiff::collision {
namespace {

namespace fs = std::filesystem;

// Independent signed distances, local coordinates (Quilez's formulas).
double sdf_box(const Vec3& q, const Vec3& h) {
  const Vec3 d = q.cwiseAbs() - h;
  return d.cwiseMax(0.0).norm() + std::min(d.maxCoeff(), 0.0);
}
double sdf_capsule(const Vec3& q, double r, double hl) {
  return (q - Vec3(0, 0, std::clamp(q[2], -hl, hl))).norm() - r;
}
double sdf_cylinder(const Vec3& q, double r, double hl) {
  const double dx = std::hypot(q[0], q[1]) - r, dz = std::abs(q[2]) - hl;
  return std::min(std::max(dx, dz), 0.0) + std::hypot(std::max(dx, 0.0), std::max(dz, 0.0));
}

Mat3 random_rotation(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  return Eigen::AngleAxisd(3 * u(rng), Vec3(u(rng), u(rng), u(rng)).normalized()).toRotationMatrix();
}

Obstacle make(ShapeKind kind, const std::string& name) {
  Obstacle o;
  o.kind = kind;
  o.name = name;
  return o;
}

// Dense samples of the surface (world), for brute-force distances.
std::vector<Vec3> sample_surface(const Obstacle& o, int n) {
  std::vector<Vec3> s;
  auto world = [&](const Vec3& q) { return Vec3(o.rotation * q + o.center); };
  if (o.kind == ShapeKind::box) {
    const Vec3& h = o.half_extents;
    for (int axis = 0; axis < 3; ++axis)
      for (int side = -1; side <= 1; side += 2)
        for (int i = 0; i <= n; ++i)
          for (int j = 0; j <= n; ++j) {
            const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
            Vec3 q;
            q[axis] = side * h[axis];
            q[a1] = -h[a1] + 2 * h[a1] * i / n;
            q[a2] = -h[a2] + 2 * h[a2] * j / n;
            s.push_back(world(q));
          }
  } else if (o.kind == ShapeKind::cylinder || o.kind == ShapeKind::capsule) {
    const double r = o.radius, hl = o.half_length;
    for (int i = 0; i <= n; ++i)
      for (int j = 0; j < n; ++j) {
        const double phi = 2 * M_PI * j / n;
        s.push_back(world(Vec3(r * std::cos(phi), r * std::sin(phi), -hl + 2 * hl * i / n)));
        for (int side = -1; side <= 1; side += 2) {
          if (o.kind == ShapeKind::cylinder) {
            const double rr = r * i / n;
            s.push_back(world(Vec3(rr * std::cos(phi), rr * std::sin(phi), side * hl)));
          } else {
            const double th = 0.5 * M_PI * i / n;
            s.push_back(world(Vec3(r * std::cos(th) * std::cos(phi), r * std::cos(th) * std::sin(phi),
                                   side * (hl + r * std::sin(th)))));
          }
        }
      }
  }
  return s;
}

// The checks every closest-point answer must pass, against the reference sdf (world).
void check_answer(const Obstacle& o, const Vec3& p, const std::function<double(const Vec3&)>& sdf,
                  double tol = 1e-12) {
  ClosestPoint cp;
  ASSERT_TRUE(closest_point(o, p, std::numeric_limits<double>::infinity(), cp));
  const double ref = sdf(p);
  EXPECT_NEAR(cp.distance, ref, tol) << o.name << " at " << p.transpose();
  EXPECT_NEAR(cp.normal.norm(), 1, 1e-12);
  EXPECT_LT((p - cp.distance * cp.normal - cp.point).norm(), 1e-12) << o.name << " at " << p.transpose();
  EXPECT_NEAR(sdf(cp.point), 0, 1e-11) << o.name << ": closest point not on the surface";
  // The normal is the gradient of the signed distance where that is smooth.
  const double h = 1e-6;
  Vec3 g;
  for (int i = 0; i < 3; ++i) {
    Vec3 e = Vec3::Zero();
    e[i] = h;
    g[i] = (sdf(p + e) - sdf(p - e)) / (2 * h);
  }
  if (std::abs(g.norm() - 1) < 1e-6) { EXPECT_LT((g - cp.normal).norm(), 1e-5) << o.name << " at " << p.transpose(); }
}

std::function<double(const Vec3&)> reference(const Obstacle& o) {
  return [o](const Vec3& p) {
    const Vec3 q = o.rotation.transpose() * (p - o.center);
    switch (o.kind) {
      case ShapeKind::box: return sdf_box(q, o.half_extents);
      case ShapeKind::sphere: return (p - o.center).norm() - o.radius;
      case ShapeKind::capsule: return sdf_capsule(q, o.radius, o.half_length);
      case ShapeKind::cylinder: return sdf_cylinder(q, o.radius, o.half_length);
      default: return o.normal.dot(p) - o.offset;
    }
  };
}

std::vector<Obstacle> analytic_shapes(std::mt19937& rng) {
  std::vector<Obstacle> v;
  Obstacle b = make(ShapeKind::box, "box");
  b.center = Vec3(0.3, -0.2, 0.1);
  b.rotation = random_rotation(rng);
  b.half_extents = Vec3(0.5, 0.8, 0.3);
  v.push_back(b);
  Obstacle s = make(ShapeKind::sphere, "ball");
  s.center = Vec3(-0.1, 0.2, 0.4);
  s.radius = 0.6;
  v.push_back(s);
  Obstacle c = make(ShapeKind::capsule, "capsule");
  c.center = Vec3(0.1, 0.1, -0.2);
  c.rotation = random_rotation(rng);
  c.radius = 0.3;
  c.half_length = 0.5;
  v.push_back(c);
  Obstacle y = make(ShapeKind::cylinder, "cylinder");
  y.center = Vec3(-0.2, 0.0, 0.1);
  y.rotation = random_rotation(rng);
  y.radius = 0.4;
  y.half_length = 0.6;
  v.push_back(y);
  Obstacle p = make(ShapeKind::plane, "floor");
  p.normal = Vec3(1, -2, 2);
  p.offset = 0.3;
  v.push_back(p);
  for (auto& o : v) prepare(o);
  return v;
}

TEST(Obstacle, AnalyticShapesAgainstIndependentFormulas) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  for (const auto& o : analytic_shapes(rng)) {
    const auto sdf = reference(o);
    int inside = 0;
    for (int i = 0; i < 3000; ++i) {
      const Vec3 p(u(rng), u(rng), u(rng));
      check_answer(o, p, sdf);
      inside += sdf(p) < 0;
    }
    EXPECT_GT(inside, 30) << o.name;  // both sides are exercised
  }
}

TEST(Obstacle, AnalyticShapesAgainstSurfaceSampling) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  for (const auto& o : analytic_shapes(rng)) {
    if (o.kind == ShapeKind::plane) continue;
    std::vector<Vec3> samples;
    if (o.kind == ShapeKind::sphere) {
      for (int i = 0; i <= 100; ++i)
        for (int j = 0; j < 200; ++j) {
          const double th = M_PI * i / 100, ph = 2 * M_PI * j / 200;
          samples.push_back(o.center + o.radius * Vec3(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th)));
        }
    } else {
      samples = sample_surface(o, 120);
    }
    for (int i = 0; i < 40; ++i) {
      const Vec3 p(u(rng), u(rng), u(rng));
      ClosestPoint cp;
      ASSERT_TRUE(closest_point(o, p, 1e300, cp));
      double best = 1e300;
      for (const auto& s : samples) best = std::min(best, (s - p).norm());
      EXPECT_LE(std::abs(cp.distance), best + 1e-12) << o.name;
      EXPECT_NEAR(std::abs(cp.distance), best, 0.02) << o.name << " at " << p.transpose();
    }
  }
}

TEST(Obstacle, BoxFeatures) {
  Obstacle b = make(ShapeKind::box, "box");
  b.half_extents = Vec3(1, 2, 3);
  prepare(b);
  struct Case {
    Vec3 p;
    Feature kind;
    int feature;
    double distance;
  };
  const Case cases[] = {
      {{2, 0, 0}, Feature::face, 1, 1},       {{-2, 0.5, 1}, Feature::face, 0, 1},
      {{0, 2.5, 0}, Feature::face, 3, 0.5},   {{0, -2.5, 0}, Feature::face, 2, 0.5},
      {{0, 0, -4}, Feature::face, 4, 1},      {{0.2, 0.1, 3.5}, Feature::face, 5, 0.5},
      {{2, 3, 0}, Feature::edge, 17, std::sqrt(2.0)},  // parallel to z at (+x, +y)
      {{0, -3, -4}, Feature::edge, 6, std::sqrt(2.0)},  // parallel to x at (-y, -z)
      {{2, 0, -4}, Feature::edge, 12, std::sqrt(2.0)},  // parallel to y at (+x, -z)
      {{2, -3, 4}, Feature::vertex, 23, std::sqrt(3.0)},
      {{-2, -3, -4}, Feature::vertex, 18, std::sqrt(3.0)},
      {{0.9, 0, 0}, Feature::face, 1, -0.1},  {{0, 0, -2.95}, Feature::face, 4, -0.05},
      {{0.5, -1.8, 0}, Feature::face, 2, -0.2},
  };
  for (const auto& c : cases) {
    ClosestPoint cp;
    ASSERT_TRUE(closest_point(b, c.p, 1e300, cp));
    EXPECT_EQ(cp.feature_kind, c.kind) << c.p.transpose();
    EXPECT_EQ(cp.feature, c.feature) << c.p.transpose();
    EXPECT_NEAR(cp.distance, c.distance, 1e-14) << c.p.transpose();
  }
  // Rotated and moved: the same features.
  std::mt19937 rng(1);
  b.rotation = random_rotation(rng);
  b.center = Vec3(1, 2, 3);
  prepare(b);
  for (const auto& c : cases) {
    ClosestPoint cp;
    ASSERT_TRUE(closest_point(b, b.rotation * c.p + b.center, 1e300, cp));
    EXPECT_EQ(cp.feature, c.feature);
    EXPECT_NEAR(cp.distance, c.distance, 1e-13);
  }
}

TEST(Obstacle, CylinderFeatures) {
  Obstacle y = make(ShapeKind::cylinder, "cyl");
  y.radius = 1;
  y.half_length = 2;
  prepare(y);
  ClosestPoint cp;
  ASSERT_TRUE(closest_point(y, Vec3(2, 0, 3), 1e300, cp));
  EXPECT_EQ(cp.feature_kind, Feature::edge);
  EXPECT_EQ(cp.feature, 4);
  EXPECT_NEAR(cp.distance, std::sqrt(2.0), 1e-15);
  ASSERT_TRUE(closest_point(y, Vec3(0.5, 0, -3), 1e300, cp));
  EXPECT_EQ(cp.feature_kind, Feature::face);
  EXPECT_EQ(cp.feature, 1);
  ASSERT_TRUE(closest_point(y, Vec3(0, 3, 0), 1e300, cp));
  EXPECT_EQ(cp.feature_kind, Feature::smooth);
  EXPECT_EQ(cp.feature, 0);
  EXPECT_NEAR(cp.distance, 2, 1e-15);
  ASSERT_TRUE(closest_point(y, Vec3(0.2, 0, 1.9), 1e300, cp));  // inside, near the top cap
  EXPECT_EQ(cp.feature, 2);
  EXPECT_NEAR(cp.distance, -0.1, 1e-14);
  ASSERT_TRUE(closest_point(y, Vec3(0, 0, 0), 1e300, cp));  // on the axis: the side, deterministic direction
  EXPECT_NEAR(cp.distance, -1, 1e-15);
  EXPECT_NEAR(cp.normal.norm(), 1, 1e-15);
}

// A point 3e-12 m outside a face of a mesh obstacle (a turned tetrahedron, no exact
// coordinate; above the 1e-12 (diagonal + 1) below which the normal was already the face's):
// the normal is the face's to 1e-13 (2026-12-04, rnrm; docs/method.md "Contact normals at
// tiny gaps"). d / |d| would carry the closest point's round-off over the gap, ~1e-17 /
// 3e-12 = 3e-6; a normalized cross product of 0.3 m edges ~1e-16. Distance: 3e-12 to 1e-13.
TEST(Obstacle, MeshFaceNormalAtATinyGapIsTheFaces) {
  Obstacle m = make(ShapeKind::mesh, "tet");
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  m.mesh.vertices.resize(3, 4);
  m.mesh.vertices << 0, 0.3, 0, 0, 0, 0, 0.3, 0, 0, 0, 0, 0.3;
  m.mesh.vertices = (R * m.mesh.vertices).colwise() + Vec3(0.1, -0.2, 0.3);
  m.mesh.triangles.resize(3, 4);
  m.mesh.triangles << 0, 0, 0, 1, 2, 1, 3, 2, 1, 3, 2, 3;
  prepare(m);
  const double gap = 3e-12;
  for (int t = 0; t < 4; ++t) {
    const Vec3 a = m.mesh.vertices.col(m.mesh.triangles(0, t)), b = m.mesh.vertices.col(m.mesh.triangles(1, t)),
               c = m.mesh.vertices.col(m.mesh.triangles(2, t));
    const Vec3 n = (b - a).cross(c - a).normalized();
    ClosestPoint cp;
    ASSERT_TRUE(closest_point(m, (a + b + c) / 3 + gap * n, 1e300, cp));
    EXPECT_EQ(cp.feature_kind, Feature::face);
    EXPECT_EQ(cp.feature, t);
    EXPECT_LT((cp.normal - n).norm(), 1e-13) << "face " << t;
    EXPECT_NEAR(cp.distance, gap, 1e-13);
  }
}

TEST(Obstacle, FastReject) {
  std::mt19937 rng(3);
  for (const auto& o : analytic_shapes(rng)) {
    ClosestPoint cp;
    const auto sdf = reference(o);
    const Vec3 far(10, 10, 10), near_in = o.kind == ShapeKind::plane ? Vec3(o.normal * (o.offset - 5)) : o.center;
    if (sdf(far) > 0.1) { EXPECT_FALSE(closest_point(o, far, 0.1, cp)) << o.name; }
    EXPECT_TRUE(closest_point(o, near_in, 0.1, cp)) << o.name;  // inside: never rejected
    EXPECT_LT(cp.distance, 0);
  }
}

TEST(Obstacle, PlaneNormalization) {
  Obstacle p = make(ShapeKind::plane, "floor");
  p.normal = Vec3(0, 0, 2);
  p.offset = 1;  // 2 z = 1
  prepare(p);
  EXPECT_NEAR(p.normal.norm(), 1, 1e-15);
  ClosestPoint cp;
  ASSERT_TRUE(closest_point(p, Vec3(3, 4, 1.5), 1e300, cp));
  EXPECT_NEAR(cp.distance, 1, 1e-15);
  EXPECT_LT((cp.point - Vec3(3, 4, 0.5)).norm(), 1e-15);
  EXPECT_EQ(cp.feature_kind, Feature::face);
  const auto bb = bounding_box(p);
  EXPECT_EQ(bb.max()[2], 0.5);
  EXPECT_TRUE(std::isinf(bb.min()[2]) && std::isinf(bb.max()[0]));
}

TEST(Obstacle, BoundingBoxes) {
  std::mt19937 rng(9);
  for (const auto& o : analytic_shapes(rng)) {
    if (o.kind == ShapeKind::plane || o.kind == ShapeKind::sphere) continue;
    const auto bb = bounding_box(o);
    const auto samples = sample_surface(o, 200);
    Eigen::AlignedBox3d sampled;
    sampled.setEmpty();
    for (const auto& s : samples) sampled.extend(s);
    EXPECT_GE((sampled.min() - bb.min()).minCoeff(), -1e-12) << o.name;
    EXPECT_GE((bb.max() - sampled.max()).minCoeff(), -1e-12) << o.name;
    EXPECT_LT((sampled.min() - bb.min()).maxCoeff(), 2e-3) << o.name << ": not tight";
    EXPECT_LT((bb.max() - sampled.max()).maxCoeff(), 2e-3) << o.name << ": not tight";
  }
}

TEST(Obstacle, ValidationErrors) {
  auto expect_error = [](Obstacle o, const std::string& needle) {
    try {
      prepare(o);
      ADD_FAILURE() << "no error for " << needle;
    } catch (const InputError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("'" + o.name + "'"), std::string::npos) << what;
      EXPECT_NE(what.find(needle), std::string::npos) << what;
    }
  };
  Obstacle s = make(ShapeKind::sphere, "ball");
  s.radius = -1;
  expect_error(s, "radius");
  Obstacle p = make(ShapeKind::plane, "floor");
  p.normal = Vec3::Zero();
  expect_error(p, "normal");
  Obstacle b = make(ShapeKind::box, "crate");
  b.half_extents = Vec3(1, 0, 1);
  expect_error(b, "half_extents");
  b.half_extents = Vec3(1, 1, 1);
  b.rotation = Mat3::Identity() * 2;
  expect_error(b, "rotation");
  Obstacle c = make(ShapeKind::cylinder, "pipe");
  c.radius = 1;
  c.half_length = 0;
  expect_error(c, "half_length");
  Obstacle m = make(ShapeKind::mesh, "key");
  expect_error(m, "no triangles");
}

// ------------------------------------------------------------------------------------
// Mesh obstacles.

fs::path temp_dir() {
  const fs::path d = fs::path(SOFTDIFF_TEST_DATA_DIR) / "collision";
  fs::create_directories(d);
  return d;
}

// The surface of the box [-h, h], each face split into n x n quads of 2 triangles,
// outward, as a triangle soup (3 points per triangle).
std::vector<Vec3> box_soup(const Vec3& h, int n, bool flip = false) {
  std::vector<Vec3> soup;
  for (int axis = 0; axis < 3; ++axis)
    for (int side = -1; side <= 1; side += 2) {
      const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
      auto P = [&](int i, int j) {
        Vec3 q;
        q[axis] = side * h[axis];
        q[a1] = -h[a1] + 2 * h[a1] * i / n;
        q[a2] = -h[a2] + 2 * h[a2] * j / n;
        return q;
      };
      for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
          // (e_a1 x e_a2) = e_axis: counter-clockwise in (a1, a2) is outward for side +1.
          std::array<Vec3, 3> t1{P(i, j), P(i + 1, j), P(i + 1, j + 1)}, t2{P(i, j), P(i + 1, j + 1), P(i, j + 1)};
          for (auto* t : {&t1, &t2}) {
            if ((side < 0) != flip) std::swap((*t)[1], (*t)[2]);
            soup.insert(soup.end(), t->begin(), t->end());
          }
        }
    }
  return soup;
}

void write_binary_stl(const fs::path& f, const std::vector<Vec3>& soup) {
  std::ofstream out(f, std::ios::binary);
  char header[80] = "binary stl written by test_obstacle";
  out.write(header, 80);
  const std::uint32_t n = static_cast<std::uint32_t>(soup.size() / 3);
  out.write(reinterpret_cast<const char*>(&n), 4);
  for (std::uint32_t t = 0; t < n; ++t) {
    float rec[12] = {0, 0, 0};
    for (int k = 0; k < 3; ++k)
      for (int d = 0; d < 3; ++d) rec[3 + 3 * k + d] = static_cast<float>(soup[3 * t + k][d]);
    out.write(reinterpret_cast<const char*>(rec), 48);
    const std::uint16_t attr = 0;
    out.write(reinterpret_cast<const char*>(&attr), 2);
  }
}

void write_ascii_stl(const fs::path& f, const std::vector<Vec3>& soup) {
  std::ofstream out(f);
  out.precision(17);
  out << "solid test\n";
  for (std::size_t t = 0; t < soup.size() / 3; ++t) {
    out << "  facet normal 0 0 0\n    outer loop\n";
    for (int k = 0; k < 3; ++k) out << "      vertex " << soup[3 * t + k].transpose() << "\n";
    out << "    endloop\n  endfacet\n";
  }
  out << "endsolid test\n";
}

Obstacle mesh_obstacle(const fs::path& f, double scale = 1) {
  Obstacle o = make(ShapeKind::mesh, "mesh");
  o.mesh = read_triangle_surface(f, scale);
  prepare(o);
  return o;
}

void compare_with_box(const Obstacle& m, const Vec3& h, double tol) {
  Obstacle b = make(ShapeKind::box, "box");
  b.half_extents = h;
  prepare(b);
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(-2, 2);
  int inside = 0;
  for (int i = 0; i < 2000; ++i) {
    const Vec3 p(u(rng), u(rng), u(rng));
    ClosestPoint cm, cb;
    ASSERT_TRUE(closest_point(m, p, 1e300, cm));
    ASSERT_TRUE(closest_point(b, p, 1e300, cb));
    EXPECT_NEAR(cm.distance, cb.distance, tol) << p.transpose();
    EXPECT_NEAR(cm.normal.norm(), 1, 1e-12);
    EXPECT_LT((p - cm.distance * cm.normal - cm.point).norm(), 1e-12);
    if (std::abs(cb.distance) > 1e-3 && cb.feature_kind == Feature::face) { EXPECT_LT((cm.normal - cb.normal).norm(), 1e-6); }
    EXPECT_GE(cm.feature, 0);
    EXPECT_LT(cm.feature, m.mesh.triangles.cols());
    inside += cb.distance < 0;
  }
  EXPECT_GT(inside, 50);
}

TEST(MeshObstacle, BinaryAndAsciiStlAgainstBox) {
  const Vec3 h(0.5, 0.75, 1.0);  // exact in float
  const auto soup = box_soup(h, 3);
  const fs::path bin = temp_dir() / "box_binary.stl", ascii = temp_dir() / "box_ascii.stl";
  write_binary_stl(bin, soup);
  write_ascii_stl(ascii, soup);
  const Obstacle mb = mesh_obstacle(bin), ma = mesh_obstacle(ascii);
  EXPECT_EQ(mb.mesh.vertices.cols(), 6 * 16 - 12 * 4 + 8);  // welded: 56 vertices
  EXPECT_EQ(mb.mesh.triangles.cols(), 6 * 18);
  compare_with_box(mb, h, 1e-12);
  compare_with_box(ma, h, 1e-12);
  // Scale.
  const Obstacle ms = mesh_obstacle(bin, 2.0);
  compare_with_box(ms, 2 * h, 1e-12);
  // Inward-oriented input is reoriented.
  const fs::path flipped = temp_dir() / "box_flipped.stl";
  write_binary_stl(flipped, box_soup(h, 3, true));
  compare_with_box(mesh_obstacle(flipped), h, 1e-12);
  // Bounding box and fast reject.
  const auto bb = bounding_box(mb);
  EXPECT_LT((bb.max() - h).norm(), 1e-15);
  ClosestPoint cp;
  EXPECT_FALSE(closest_point(mb, Vec3(5, 0, 0), 0.1, cp));
  EXPECT_TRUE(closest_point(mb, Vec3(0.55, 0, 0), 0.1, cp));
  EXPECT_NEAR(cp.distance, 0.05, 1e-12);
}

bool run_gmsh(const std::string& geo, const fs::path& out, const std::string& format, bool binary = false) {
  const fs::path g = out.parent_path() / (out.stem().string() + ".geo");
  std::ofstream(g) << geo;
  const std::string cmd = std::string(GMSH_EXECUTABLE) + " -2 -format " + format + (binary ? " -bin" : "") + " \"" +
                          g.string() + "\" -o \"" + out.string() + "\" > /dev/null 2>&1";
  return std::system(cmd.c_str()) == 0 && fs::exists(out);
}

TEST(MeshObstacle, GmshMshAgainstBoxAndSphere) {
  const Vec3 h(0.5, 0.75, 1.0);
  const std::string box_geo = "SetFactory(\"OpenCASCADE\");\nBox(1) = {-0.5, -0.75, -1, 1, 1.5, 2};\nMesh.MeshSizeMax = 0.3;\n";
  for (const std::string format : {"msh22", "msh41"})
    for (const bool binary : {false, true}) {  // the bodies' Gmsh reader: every version and encoding
      const fs::path f = temp_dir() / ("box_" + format + (binary ? "_bin" : "") + ".msh");
      ASSERT_TRUE(run_gmsh(box_geo, f, format, binary)) << "gmsh failed";
      const Obstacle m = mesh_obstacle(f);
      compare_with_box(m, h, 1e-12);
    }
  // A sphere: the polyhedron is within the chord error of the sphere; signs exact.
  const std::string sphere_geo = "SetFactory(\"OpenCASCADE\");\nSphere(1) = {0, 0, 0, 1};\nMesh.MeshSizeMax = 0.08;\n";
  const fs::path f = temp_dir() / "sphere.msh";
  ASSERT_TRUE(run_gmsh(sphere_geo, f, "msh41"));
  const Obstacle m = mesh_obstacle(f);
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-2, 2);
  for (int i = 0; i < 1000; ++i) {
    const Vec3 p(u(rng), u(rng), u(rng));
    ClosestPoint cp;
    ASSERT_TRUE(closest_point(m, p, 1e300, cp));
    const double ref = p.norm() - 1;
    EXPECT_NEAR(cp.distance, ref, 5e-3) << p.transpose();
    if (std::abs(ref) > 5e-3) { EXPECT_EQ(cp.distance < 0, ref < 0); }
    if (std::abs(ref) > 0.1 && p.norm() > 0.2) { EXPECT_LT((cp.normal - p.normalized()).norm(), 0.1); }
  }
}

void expect_read_error(const fs::path& f, const std::string& needle) {
  try {
    read_triangle_surface(f, 1.0);
    ADD_FAILURE() << "no error for " << f;
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.rfind(f.string() + ":", 0), 0u) << what;
    EXPECT_NE(what.find(needle), std::string::npos) << what;
  }
}

TEST(MeshObstacle, BadFiles) {
  const Vec3 h(0.5, 0.75, 1.0);
  auto soup = box_soup(h, 2);
  // Open: one triangle missing.
  auto open = soup;
  open.resize(open.size() - 3);
  write_binary_stl(temp_dir() / "open.stl", open);
  expect_read_error(temp_dir() / "open.stl", "not closed");
  // Non-manifold: a fin on an existing edge (and its back face, so that every edge is
  // used twice except the shared one, used 4 times).
  auto fin = soup;
  const Vec3 a = soup[0], b = soup[1], c = a + Vec3(3, 3, 3);
  fin.insert(fin.end(), {a, b, c, b, a, c});
  write_ascii_stl(temp_dir() / "fin.stl", fin);
  expect_read_error(temp_dir() / "fin.stl", "not manifold");
  // Inconsistent orientation: one triangle reversed.
  auto bad = soup;
  std::swap(bad[1], bad[2]);
  write_binary_stl(temp_dir() / "reversed.stl", bad);
  expect_read_error(temp_dir() / "reversed.stl", "not consistently oriented");
  // Empty, garbage, missing, unknown extension.
  std::ofstream(temp_dir() / "empty.stl").close();
  expect_read_error(temp_dir() / "empty.stl", "empty");
  std::ofstream(temp_dir() / "garbage.stl") << "this is not a mesh\n";
  expect_read_error(temp_dir() / "garbage.stl", "not an STL");
  std::ofstream(temp_dir() / "garbage.msh") << "hello\n";
  expect_read_error(temp_dir() / "garbage.msh", "MSH");
  // A valid Gmsh file with a tetrahedron but no triangle is not a surface.
  std::ofstream(temp_dir() / "tet_only.msh") << "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n"
                                                "2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n$Elements\n1\n"
                                                "1 4 0 1 2 3 4\n$EndElements\n";
  expect_read_error(temp_dir() / "tet_only.msh", "no triangles");
  std::ofstream(temp_dir() / "solid_empty.stl") << "solid x\nendsolid x\n";
  expect_read_error(temp_dir() / "solid_empty.stl", "empty");
  expect_read_error(temp_dir() / "does_not_exist.stl", "cannot open");
  std::ofstream(temp_dir() / "box.obj") << "v 0 0 0\n";
  expect_read_error(temp_dir() / "box.obj", "unknown surface format");
  // prepare() on an open surface in memory names the obstacle.
  Obstacle o = make(ShapeKind::mesh, "key");
  write_binary_stl(temp_dir() / "ok.stl", soup);
  o.mesh = read_triangle_surface(temp_dir() / "ok.stl", 1.0);
  o.mesh.triangles.conservativeResize(3, o.mesh.triangles.cols() - 1);
  try {
    prepare(o);
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("obstacle 'key': mesh: not closed"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace softdiff::collision
