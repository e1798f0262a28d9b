#pragma once
// Programmatic test meshes (no file I/O): boxes split into tetrahedra.
#include <softdiff/mesh/tet_mesh.hpp>

#include <Eigen/LU>
#include <array>
#include <vector>

namespace softdiff::test {

// An nx x ny x nz grid of boxes of size (lx, ly, lz) from the origin, each box split
// into 6 tetrahedra around its main diagonal (Kuhn/Freudenthal: conforming across
// boxes, all positively oriented). Node (i, j, k) has index i + (nx+1) (j + (ny+1) k).
inline mesh::TetMesh box_mesh(int nx, int ny, int nz, double lx, double ly, double lz) {
  mesh::TetMesh m;
  m.source = "box_mesh";
  const int px = nx + 1, py = ny + 1, pz = nz + 1;
  m.X.resize(3, px * py * pz);
  for (int k = 0; k < pz; ++k)
    for (int j = 0; j < py; ++j)
      for (int i = 0; i < px; ++i) m.X.col(i + px * (j + py * k)) = Vec3(lx * i / nx, ly * j / ny, lz * k / nz);
  auto id = [&](int i, int j, int k) { return i + px * (j + py * k); };
  // The 6 monotone lattice paths from corner 000 to 111 (permutations of the axes).
  const int perms[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  std::vector<std::array<int, 4>> tets;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i)
        for (const auto& p : perms) {
          int c[3] = {0, 0, 0};
          std::array<int, 4> t;
          t[0] = id(i, j, k);
          for (int s = 0; s < 3; ++s) {
            c[p[s]] = 1;
            t[s + 1] = id(i + c[0], j + c[1], k + c[2]);
          }
          // Orientation: odd permutations give negative volume; swap two nodes.
          Mat3 D;
          for (int s = 0; s < 3; ++s) D.col(s) = m.X.col(t[s + 1]) - m.X.col(t[0]);
          if (D.determinant() < 0) std::swap(t[1], t[2]);
          tets.push_back(t);
        }
  m.tets.resize(4, static_cast<int>(tets.size()));
  for (size_t e = 0; e < tets.size(); ++e)
    for (int a = 0; a < 4; ++a) m.tets(a, static_cast<int>(e)) = tets[e][a];
  m.file_index.resize(m.X.cols());
  m.file_tag.resize(m.X.cols());
  for (int i = 0; i < m.X.cols(); ++i) {
    m.file_index[i] = i;
    m.file_tag[i] = i + 1;
  }
  return m;
}

}  // namespace softdiff::test
