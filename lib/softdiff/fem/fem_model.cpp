#include <softdiff/fem/fem_model.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>

#include <Eigen/LU>
#include <algorithm>
#include <bitset>
#include <cmath>
#include <sstream>

namespace softdiff::fem {
namespace {

// Upper-triangle block pattern of the node graph, expanded to 3x3 dof blocks.
// Extra cliques: all pairs of each clique's nodes.
void build_pattern(const FemModel& m, const std::vector<std::vector<int>>& cliques, SystemPattern& p) {
  const int n = m.num_nodes;
  std::vector<std::vector<int>> lower_neighbors(n);  // for node j: nodes i <= j sharing an element or a clique
  for (int e = 0; e < m.num_tets; ++e)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        const int i = m.tets(a, e), j = m.tets(b, e);
        if (i <= j) lower_neighbors[j].push_back(i);
      }
  for (const auto& clique : cliques)
    for (int i : clique) {
      SOFTDIFF_DEMAND(i >= 0 && i < n, "clique node index out of range");
      for (int j : clique)
        if (i <= j) lower_neighbors[j].push_back(i);
    }
  for (auto& list : lower_neighbors) {
    std::sort(list.begin(), list.end());
    list.erase(std::unique(list.begin(), list.end()), list.end());
  }
  const int ndof = 3 * n;
  std::vector<int> outer(ndof + 1, 0);
  for (int j = 0; j < n; ++j)
    for (int c = 0; c < 3; ++c)
      outer[3 * j + c + 1] = static_cast<int>(3 * (lower_neighbors[j].size() - 1) + c + 1);
  for (int k = 0; k < ndof; ++k) outer[k + 1] += outer[k];
  const long nnz = outer[ndof];
  SOFTDIFF_DEMAND(nnz < std::numeric_limits<int>::max(), "system matrix too large for 32-bit indices");
  std::vector<int> inner(nnz);
  for (int j = 0; j < n; ++j)
    for (int c = 0; c < 3; ++c) {
      int k = outer[3 * j + c];
      for (int i : lower_neighbors[j]) {
        const int rmax = (i == j) ? c : 2;
        for (int r = 0; r <= rmax; ++r) inner[k++] = 3 * i + r;
      }
    }
  p.structure.resize(ndof, ndof);
  p.structure.resizeNonZeros(nnz);
  std::copy(outer.begin(), outer.end(), p.structure.outerIndexPtr());
  std::copy(inner.begin(), inner.end(), p.structure.innerIndexPtr());
  std::fill_n(p.structure.valuePtr(), nnz, 0.0);
  p.structure.finalize();

  auto find = [&](int row, int col) {
    const int* begin = inner.data() + outer[col];
    const int* end = inner.data() + outer[col + 1];
    const int* it = std::lower_bound(begin, end, row);
    SOFTDIFF_ASSERT(it != end && *it == row);
    return static_cast<int>(it - inner.data());
  };
  p.diagonal.resize(ndof);
  for (int k = 0; k < ndof; ++k) p.diagonal[k] = find(k, k);
  p.element_scatter.resize(78 * static_cast<size_t>(m.num_tets));
  for (int e = 0; e < m.num_tets; ++e) {
    int* out = p.element_scatter.data() + 78 * static_cast<size_t>(e);
    int k = 0;
    for (int i = 0; i < 12; ++i)
      for (int j = i; j < 12; ++j) {
        const int gi = 3 * m.tets(i / 3, e) + i % 3, gj = 3 * m.tets(j / 3, e) + j % 3;
        out[k++] = find(std::min(gi, gj), std::max(gi, gj));
      }
  }
  p.clique_node_begin.assign(1, 0);
  p.clique_nodes.clear();
  p.clique_scatter_begin.assign(1, 0);
  p.clique_scatter.clear();
  for (const auto& clique : cliques) {
    const int k = static_cast<int>(clique.size());
    p.clique_nodes.insert(p.clique_nodes.end(), clique.begin(), clique.end());
    p.clique_node_begin.push_back(static_cast<int>(p.clique_nodes.size()));
    for (int a = 0; a < k; ++a)
      for (int b = 0; b < k; ++b)
        for (int r = 0; r < 3; ++r)
          for (int q = 0; q < 3; ++q) {
            const int gi = 3 * clique[a] + r, gj = 3 * clique[b] + q;
            p.clique_scatter.push_back(gi <= gj ? find(gi, gj) : -1);
          }
    p.clique_scatter_begin.push_back(static_cast<int>(p.clique_scatter.size()));
  }
  p.fixed_offdiagonal.clear();
  p.fixed_diagonal.clear();
  for (int col = 0; col < ndof; ++col)
    for (int k = outer[col]; k < outer[col + 1]; ++k) {
      const int row = inner[k];
      if (!m.fixed[row] && !m.fixed[col]) continue;
      (row == col ? p.fixed_diagonal : p.fixed_offdiagonal).push_back(k);
    }
}

// Greedy element coloring: no two elements of one color share a node. Elements
// that find no free color among the first kMaxColors go to a last color that is
// assembled serially (rare: a node with hundreds of incident elements).
void color_elements(const FemModel& m, SystemPattern& p) {
  constexpr int kMaxColors = 256;
  std::vector<std::bitset<kMaxColors>> used(m.num_nodes);
  std::vector<int> color(m.num_tets);
  int num_colors = 0;
  for (int e = 0; e < m.num_tets; ++e) {
    std::bitset<kMaxColors> taken;
    for (int a = 0; a < 4; ++a) taken |= used[m.tets(a, e)];
    int c = 0;
    while (c < kMaxColors && taken[c]) ++c;
    if (c < kMaxColors)
      for (int a = 0; a < 4; ++a) used[m.tets(a, e)].set(c);
    color[e] = c;
    num_colors = std::max(num_colors, c + 1);
  }
  p.last_color_shares_nodes = (num_colors > kMaxColors);
  p.color_begin.assign(num_colors + 1, 0);
  for (int e = 0; e < m.num_tets; ++e) ++p.color_begin[color[e] + 1];
  for (int c = 0; c < num_colors; ++c) p.color_begin[c + 1] += p.color_begin[c];
  p.color_elements.resize(m.num_tets);
  std::vector<int> cursor(p.color_begin.begin(), p.color_begin.end() - 1);
  for (int e = 0; e < m.num_tets; ++e) p.color_elements[cursor[color[e]]++] = e;
}

}  // namespace

void build_fem_model(std::vector<BodyModel> bodies, const std::vector<unsigned char>& fixed, const Vec3& gravity,
                     FemModel& m, const std::vector<std::vector<int>>& cliques) {
  m = FemModel{};
  m.bodies = std::move(bodies);
  for (auto& b : m.bodies) {
    b.node_begin = m.num_nodes;
    b.num_nodes = b.mesh.num_nodes();
    b.tet_begin = m.num_tets;
    b.num_tets = b.mesh.num_tets();
    m.num_nodes += b.num_nodes;
    m.num_tets += b.num_tets;
    b.lame = material::lame_from_young_poisson(b.young, b.poisson);
    const Vec3 lo = b.mesh.X.rowwise().minCoeff(), hi = b.mesh.X.rowwise().maxCoeff();
    b.bbox_diagonal = (hi - lo).norm();
  }
  SOFTDIFF_DEMAND(static_cast<int>(fixed.size()) == 3 * m.num_nodes, "fixed: expected 3n entries");
  m.fixed = fixed;
  m.num_fixed_dofs = std::count(fixed.begin(), fixed.end(), 1);
  m.X.resize(3, m.num_nodes);
  m.tets.resize(4, m.num_tets);
  m.tet_body.resize(m.num_tets);
  for (int bi = 0; bi < static_cast<int>(m.bodies.size()); ++bi) {
    const auto& b = m.bodies[bi];
    m.X.middleCols(b.node_begin, b.num_nodes) = b.mesh.X;
    m.tets.middleCols(b.tet_begin, b.num_tets) = b.mesh.tets.array() + b.node_begin;
    std::fill_n(m.tet_body.begin() + b.tet_begin, b.num_tets, bi);
  }

  // Rest geometry.
  m.Dm_inv.resize(m.num_tets);
  m.rest_volume.resize(m.num_tets);
  for (int e = 0; e < m.num_tets; ++e) {
    Mat3 Dm;
    for (int k = 0; k < 3; ++k) Dm.col(k) = m.X.col(m.tets(k + 1, e)) - m.X.col(m.tets(0, e));
    const double det = Dm.determinant();
    if (!(det > 0)) {
      const auto& b = m.bodies[m.tet_body[e]];
      std::ostringstream s;
      s << b.mesh.source << ": tetrahedron " << (e - b.tet_begin) << " of body '" << b.name
        << "' has non-positive rest volume " << det / 6 << " after the scene's transform";
      throw InputError(s.str());
    }
    m.Dm_inv[e] = Dm.inverse();
    m.rest_volume[e] = det / 6.0;
  }

  build_pattern(m, cliques, m.pattern);
  color_elements(m, m.pattern);
  for (auto& b : m.bodies) {
    b.value_begin = m.pattern.structure.outerIndexPtr()[3 * b.node_begin];
    b.value_end = m.pattern.structure.outerIndexPtr()[3 * (b.node_begin + b.num_nodes)];
  }

  // Mass: lumped (rho V / 4 per node) or consistent (rho V / 20 (1 + delta_ab) I3).
  m.mass_values = VecX::Zero(m.pattern.nnz());
  for (int e = 0; e < m.num_tets; ++e) {
    const auto& b = m.bodies[m.tet_body[e]];
    const double me = b.density * m.rest_volume[e];
    m.total_mass += me;
    const int* scatter = m.pattern.element_scatter.data() + 78 * static_cast<size_t>(e);
    int k = 0;
    for (int i = 0; i < 12; ++i)
      for (int j = i; j < 12; ++j, ++k) {
        if (i % 3 != j % 3) continue;
        const bool same_node = (i / 3 == j / 3);
        if (b.mass_kind == MassKind::lumped) {
          if (same_node) m.mass_values[scatter[k]] += me / 4.0;
        } else {
          m.mass_values[scatter[k]] += me / 20.0 * (same_node ? 2.0 : 1.0);
        }
      }
  }
  // Row sums (= the lumped masses for both kinds: consistent rows sum to rho V / 4).
  m.mass_diagonal = VecX::Zero(3 * m.num_nodes);
  const auto& S = m.pattern.structure;
  for (int col = 0; col < S.outerSize(); ++col)
    for (int k = S.outerIndexPtr()[col]; k < S.outerIndexPtr()[col + 1]; ++k) {
      const int row = S.innerIndexPtr()[k];
      m.mass_diagonal[row] += m.mass_values[k];
      if (row != col) m.mass_diagonal[col] += m.mass_values[k];
    }
  m.gravity_force.resize(3 * m.num_nodes);
  for (int i = 0; i < m.num_nodes; ++i)
    for (int c = 0; c < 3; ++c) m.gravity_force[3 * i + c] = m.mass_diagonal[3 * i + c] * gravity[c];
}

}  // namespace softdiff::fem
