#pragma once
// A linear tetrahedral mesh as read from a file and cleaned for simulation.
#include <softdiff/core/types.hpp>

#include <map>
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
  // Parts of the group that are not on the simulated body (they belong to no
  // tetrahedron) and were therefore left out of `nodes` / `triangles`. Non-zero
  // values usually mean a physical group that does not touch the volume mesh.
  long dropped_nodes = 0;      // distinct file nodes of the group's elements that are in no tet
  long dropped_triangles = 0;  // distinct triangles of the group with a node in no tet
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
  std::vector<long> tet_file_tag;   // (m) Gmsh element tag of each tet (for messages)
  long dropped_triangles = 0;       // distinct file triangles with a node in no tet (not on the body; dropped)
  std::map<int, long> skipped_elements;  // Gmsh element type -> number of elements ignored (0D-2D types
                                         // other than points, lines and triangles)

  int num_nodes() const { return static_cast<int>(X.cols()); }
  int num_tets() const { return static_cast<int>(tets.cols()); }
  // First group (in `groups` order: by dimension, then tag) with this name; nullptr if none.
  const PhysicalGroup* find_group(const std::string& name) const;
  // The group with this name and dimension; nullptr if none.
  const PhysicalGroup* find_group(const std::string& name, int dim) const;
};

// Outward boundary triangles: faces that belong to exactly one tetrahedron,
// ordered so that their normal (b - a) x (c - a) points out of the solid, i.e.
// away from the tet's vertex that is not on the face. Tets must be positively
// oriented (as TetMesh stores them); indices must be >= 0. Output order is
// deterministic: by tet index, then by the local index of the opposite vertex.
// O(m) plus small sorts (faces are bucketed by their smallest node).
Triangles boundary_triangles(const Tets& tets);

struct Quality {
  double min_volume = 0, max_volume = 0, total_volume = 0;
  double min_aspect = 0, max_aspect = 0, median_aspect = 0;  // aspect = longest edge / (2 sqrt(6) inradius); 1 = regular
  int worst_tet = -1;                                          // index of the tet with the largest aspect ratio
  Vec3 bbox_min = Vec3::Zero(), bbox_max = Vec3::Zero();
};
// Volumes are signed (an inverted tet shows up as min_volume < 0); the aspect
// ratio of a zero-volume tet is +infinity. median_aspect is the mean of the two
// middle values for an even count. bbox covers all columns of X. With no tets,
// only the bbox is filled (worst_tet = -1).
Quality quality(const Mat3X& X, const Tets& tets);

}  // namespace softdiff::mesh
