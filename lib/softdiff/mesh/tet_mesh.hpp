#pragma once
// A linear tetrahedral mesh as read from a file and cleaned for simulation.
#include <softdiff/core/types.hpp>

#include <string>
#include <vector>

namespace softdiff::mesh {

// A Gmsh physical group. Node and element indices refer to the cleaned mesh
// (TetMesh::X columns, TetMesh::tets columns, TetMesh::triangles columns).
struct PhysicalGroup {
  int dim = 0;                 // 0 points, 1 lines, 2 surfaces, 3 volumes
  int tag = 0;                 // Gmsh physical tag
  std::string name;            // from $PhysicalNames; empty if the file has none
  std::vector<int> nodes;      // sorted, unique: every node of every element of the group
  std::vector<int> triangles;  // dim 2: columns of TetMesh::triangles
  std::vector<int> tets;       // dim 3: columns of TetMesh::tets
};

struct TetMesh {
  std::string source;           // file path, for messages
  Mat3X X;                      // (3, n) node positions (file units)
  Tets tets;                    // (4, m) node indices, positive orientation
  Triangles triangles;          // (3, k) triangles listed in the file (for groups), file orientation
  std::vector<PhysicalGroup> groups;
  std::vector<long> file_index; // (n) 0-based position of each node in the file's node list
  std::vector<long> file_tag;   // (n) Gmsh node tag of each node
  long orphan_nodes = 0;        // nodes in the file that belong to no tetrahedron (dropped)
  long reoriented_tets = 0;     // tets whose file orientation was negative (reordered)

  int num_nodes() const { return static_cast<int>(X.cols()); }
  int num_tets() const { return static_cast<int>(tets.cols()); }
  const PhysicalGroup* find_group(const std::string& name) const;
};

// Outward boundary triangles: faces that belong to exactly one tetrahedron,
// ordered so that their normal (b - a) x (c - a) points out of the solid.
Triangles boundary_triangles(const Tets& tets);

struct Quality {
  double min_volume = 0, max_volume = 0, total_volume = 0;
  double min_aspect = 0, max_aspect = 0, median_aspect = 0;  // aspect = longest edge / (2 sqrt(6) inradius); 1 = regular
  int worst_tet = -1;                                          // index of the tet with the largest aspect ratio
  Vec3 bbox_min = Vec3::Zero(), bbox_max = Vec3::Zero();
};
Quality quality(const Mat3X& X, const Tets& tets);

}  // namespace softdiff::mesh
