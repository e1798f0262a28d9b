#pragma once
// A tetrahedral mesh (4-node, or 10-node in gmsh's order) as read from a file and
// cleaned for simulation.
#include <softdiff/core/types.hpp>

#include <map>
#include <string>
#include <vector>

namespace softdiff::mesh {

// gmsh's 10-node tetrahedron (element type 11): nodes 0-3 are the vertices, node 4 + k
// the mid-edge node of edge k = (kTet10Edge[k][0], kTet10Edge[k][1]).
inline constexpr int kTet10Edge[6][2] = {{0, 1}, {1, 2}, {2, 0}, {3, 0}, {3, 2}, {3, 1}};
// gmsh's 6-node triangle (type 9): nodes 0-2 the vertices, node 3 + k the mid-edge node
// of edge (k, (k + 1) % 3).
using Tets10 = Eigen::Matrix<int, 10, Eigen::Dynamic>;       // one column per 10-node tet
using Triangles6 = Eigen::Matrix<int, 6, Eigen::Dynamic>;    // one column per 6-node triangle

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
  Tets tets;                    // (4, m) vertex node indices, positive orientation
  int order = 1;                // 1: 4-node tets; 2: 10-node tets (`tets10`)
  Tets10 tets10;                // (10, m) order 2 only: all nodes in gmsh's order, rows 0-3 == tets
  long added_nodes = 0;         // order 2 from elevate_to_quadratic: the straight mid-edge nodes
                                // added after the file's nodes (the last added_nodes columns of X;
                                // their file_index and file_tag are -1)
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
  int nodes_per_tet() const { return order == 2 ? 10 : 4; }
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

// Order 2: the 6-node triangles of 3-node triangles `tris` whose edges are edges of
// `mesh`'s tets (a triangle edge that is no tet edge gets -1). Rows 0-2 are `tris`.
Triangles6 quadratic_triangles(const TetMesh& mesh, const Triangles& tris);

// Each 6-node triangle (a, b, c, m_ab, m_bc, m_ca) as the four 3-node triangles
// (a, m_ab, m_ca), (m_ab, b, m_bc), (m_ca, m_bc, c), (m_ab, m_bc, m_ca), oriented as the
// 6-node one; triangle t gives columns 4 t .. 4 t + 3.
Triangles split_quadratic_triangles(const Triangles6& tris);

// Turns a linear mesh into a quadratic one with straight edges: one node at the
// midpoint of each distinct tet edge, appended after the file's nodes in the order the
// edges first appear (tets in order, edges in gmsh's order), file_index/file_tag -1;
// tets10 lists them in gmsh's order. Groups gain the mid-edge nodes of their tets
// and of their triangles' edges (points and lines keep their own nodes).
void elevate_to_quadratic(TetMesh& mesh);

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
