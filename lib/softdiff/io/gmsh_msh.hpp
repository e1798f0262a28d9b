#pragma once
// Reader for Gmsh MSH files, versions 2.2 and 4.1, ASCII and binary.
// Keeps nodes (any tags, non-contiguous), linear tetrahedra (type 4), triangles
// (type 2), points/lines only as members of physical groups, physical groups and
// their names. Other element types are skipped with a count (higher-order tets
// are an error). The mesh is then cleaned:
//   - nodes that belong to no tetrahedron are dropped (TetMesh::orphan_nodes),
//   - tets with negative orientation are reordered (TetMesh::reoriented_tets),
//   - tets whose |volume| is below `degenerate_rel_tol` * (mean |volume|) are an
//     InputError listing them (ids in the file and volumes).
// Every error is an InputError whose message starts with `FILE:` (and the line
// number, for ASCII files: `FILE:LINE: ...`).
#include <softdiff/mesh/tet_mesh.hpp>

#include <filesystem>

namespace softdiff::io {

struct GmshReadOptions {
  double degenerate_rel_tol = 1e-10;
};

mesh::TetMesh read_gmsh(const std::filesystem::path& file, const GmshReadOptions& options = {});

}  // namespace softdiff::io
