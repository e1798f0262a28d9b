#pragma once
// Reader for Gmsh MSH files, versions 2.2 and 4.1, ASCII and binary.
// Keeps nodes (any tags, non-contiguous), linear (type 4) or quadratic (type 11, gmsh's
// node order) tetrahedra, triangles (types 2 and 9; TetMesh::triangles holds their
// vertices), points/lines (types 15, 1, 8) only as members of physical groups, physical
// groups and their names. Other element types are skipped with a count (other 3D
// elements are an error, and so are type 4 and type 11 tets in one file). The mesh is
// then cleaned:
//   - nodes that belong to no tetrahedron are dropped (TetMesh::orphan_nodes),
//   - tets with negative orientation are reordered (TetMesh::reoriented_tets),
//   - tets whose |volume| is below `degenerate_rel_tol` * (mean |volume|) are an
//     InputError listing them (ids in the file and volumes).
// Every error is an InputError whose message starts with `FILE:` (and the line
// number, for ASCII files: `FILE:LINE: ...`; in binary data: `FILE: byte N: ...`).
//
// Details of the cleaning (see also TetMesh / PhysicalGroup):
//   - An element listed more than once with the same node set (MSH 2 repeats an
//     element once per physical group it belongs to) is kept once and belongs to
//     all those groups; its first occurrence gives its node order and tag.
//   - A negative tet (a, b, c, d) becomes (a, b, d, c) (quadratic: mid-edge nodes
//     5 <-> 9 and 6 <-> 7 follow). Orientation and degeneracy use the vertices.
//   - Quadratic tets must have det J > 0 at every quadrature point (fem/tet10.hpp);
//     otherwise an InputError lists them (gmsh tags, min det J relative to the
//     straight element's).
//   - Quadratic meshes: a group's `nodes` include its tets' 10 nodes and the mid-edge
//     nodes of its triangles (from type 9, or from the tets' edges for type 2).
//   - Degenerate means |volume| <= degenerate_rel_tol * mean |volume|.
//   - Triangles with a node that is in no tet are not on the body: they are
//     dropped (TetMesh::dropped_triangles, PhysicalGroup::dropped_triangles).
//   - A group's `nodes` are the nodes of all its elements as listed in the file
//     (dropped triangles included) that are simulation nodes; the others are
//     counted in PhysicalGroup::dropped_nodes.
//   - Groups are sorted by (dim, tag); a group named in $PhysicalNames without
//     elements in the file is still listed, with empty index lists.
//   - MSH 4.1: physical tags come from $Entities (or $PartitionedEntities for
//     partitioned meshes); a file without $Entities has no physical groups.
//   - Binary files must have the byte order of this machine.
#include <softdiff/mesh/tet_mesh.hpp>

#include <filesystem>

namespace softdiff::io {

struct GmshReadOptions {
  double degenerate_rel_tol = 1e-10;
};

mesh::TetMesh read_gmsh(const std::filesystem::path& file, const GmshReadOptions& options = {});

// The triangles (element type 2) of a Gmsh file, for surfaces (obstacles): same
// versions, encodings and messages as read_gmsh, no tetrahedra needed. A triangle
// listed more than once with the same node set (once per physical group, MSH 2) is
// kept once, in its first occurrence's order; the points are the nodes the triangles
// use, in order of first use. No triangle is an InputError.
struct GmshTriangles {
  Mat3X points;
  Eigen::Matrix<int, 3, Eigen::Dynamic> triangles;
};
GmshTriangles read_gmsh_triangles(const std::filesystem::path& file);

}  // namespace softdiff::io
