#pragma once
// Shared fixtures of the collision tests: several tet meshes side by side in one
// global node numbering, and the detection model over them.
#include <softdiff/collision/detection.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

#include <support/meshes.hpp>

#include <Eigen/Geometry>

#include <string>
#include <vector>

namespace softdiff::collision {

// Several tet meshes side by side in one global node numbering.
struct Scene {
  Mat3X X;
  std::vector<BodySurface> surfaces;
  int add(const mesh::TetMesh& m, const Vec3& shift, const std::string& name) {
    const int offset = static_cast<int>(X.cols());
    X.conservativeResize(3, offset + m.num_nodes());
    X.rightCols(m.num_nodes()) = m.X.colwise() + shift;
    BodySurface s;
    s.name = name;
    s.triangles = mesh::boundary_triangles(m.tets).array() + offset;
    prepare_surface(s);
    surfaces.push_back(std::move(s));
    return offset;
  }
  VecX x() const { return Eigen::Map<const VecX>(X.data(), X.size()); }
};

// A vertex resting on a feature of a box's top face at a tiny gap (docs/method.md
// "Contact normals at tiny gaps"): box "a" (a 0.2 m cube, box_mesh(1, 1, 1): each face two
// triangles) and box "b" (a 0.1 m cube) standing on its corner (its body diagonal
// vertical), that corner at `target + gap * z`; then the whole scene turned by a generic
// rotation R, so that no coordinate is exact. up = R z, a's top face's outward normal.
inline Scene corner_on_box_top(const Vec3& target, double gap, Vec3& up) {
  Scene s;
  s.add(test::box_mesh(1, 1, 1, 0.2, 0.2, 0.2), Vec3::Zero(), "a");
  mesh::TetMesh b = test::box_mesh(1, 1, 1, 0.1, 0.1, 0.1);
  const Mat3 stand = Eigen::Quaterniond::FromTwoVectors(Vec3(-1, -1, -1), Vec3(0, 0, -1)).toRotationMatrix();
  b.X = stand * b.X;  // node 0 at the origin (box_mesh's corner (0, 0, 0)) is the lowest
  int low = 0;
  for (int k = 1; k < b.num_nodes(); ++k)
    if (b.X(2, k) < b.X(2, low)) low = k;
  s.add(b, target + Vec3(0, 0, gap) - b.X.col(low), "b");
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  s.X = R * s.X;
  up = R * Vec3::UnitZ();
  return s;
}

inline DetectionModel model_of(const Scene& s, std::vector<Obstacle> obstacles, std::vector<PairRule> pairs, double margin) {
  DetectionModel d;
  d.surfaces = s.surfaces;
  for (const auto& b : s.surfaces) d.names.push_back(b.name);
  for (const auto& o : obstacles) d.names.push_back(o.name);
  d.obstacles = std::move(obstacles);
  d.pairs = std::move(pairs);
  d.margin = margin;
  return d;
}

}  // namespace softdiff::collision
