#pragma once
// Shared fixtures of the collision tests: several tet meshes side by side in one
// global node numbering, and the detection model over them.
#include <softdiff/collision/detection.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

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
