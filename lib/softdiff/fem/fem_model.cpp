#include <softdiff/fem/fem_model.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/fem/tet10.hpp>

#include <Eigen/LU>
#include <algorithm>
#include <bitset>
#include <cmath>
#include <sstream>

namespace softdiff::fem {
namespace {

// Global node of element e's local node a (a < element_nodes(e)).
int element_node(const FemModel& m, int e, int a) { return m.quadratic[e] ? m.tets10(a, e) : m.tets(a, e); }

// Upper-triangle block pattern of the node graph, expanded to 3x3 dof blocks.
// Extra cliques: all pairs of each clique's nodes.
void build_pattern(const FemModel& m, const std::vector<std::vector<int>>& cliques, SystemPattern& p) {
  const int n = m.num_nodes;
  std::vector<std::vector<int>> lower_neighbors(n);  // for node j: nodes i <= j sharing an element or a clique
  for (int e = 0; e < m.num_tets; ++e)
    for (int a = 0; a < m.element_nodes(e); ++a)
      for (int b = 0; b < m.element_nodes(e); ++b) {
        const int i = element_node(m, e, a), j = element_node(m, e, b);
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
  p.element_scatter_begin.assign(static_cast<size_t>(m.num_tets) + 1, 0);
  for (int e = 0; e < m.num_tets; ++e) {
    const int d = 3 * m.element_nodes(e);
    p.element_scatter_begin[e + 1] = p.element_scatter_begin[e] + d * (d + 1) / 2;
  }
  p.element_scatter.resize(static_cast<size_t>(p.element_scatter_begin.back()));
  for (int e = 0; e < m.num_tets; ++e) {
    int* out = p.element_scatter.data() + p.element_scatter_begin[e];
    const int d = 3 * m.element_nodes(e);
    int k = 0;
    for (int i = 0; i < d; ++i)
      for (int j = i; j < d; ++j) {
        const int gi = 3 * element_node(m, e, i / 3) + i % 3, gj = 3 * element_node(m, e, j / 3) + j % 3;
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
    for (int a = 0; a < m.element_nodes(e); ++a) taken |= used[element_node(m, e, a)];
    int c = 0;
    while (c < kMaxColors && taken[c]) ++c;
    if (c < kMaxColors)
      for (int a = 0; a < m.element_nodes(e); ++a) used[element_node(m, e, a)].set(c);
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

Eigen::Matrix<double, 3, 10> element_rest_positions10(const FemModel& m, int e) {
  Eigen::Matrix<double, 3, 10> X_e;
  for (int a = 0; a < 10; ++a) X_e.col(a) = m.X.col(m.tets10(a, e));
  return X_e;
}

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
  m.tets10.setConstant(10, m.num_tets, -1);
  m.quadratic.assign(m.num_tets, 0);
  m.quad_slot.assign(m.num_tets, -1);
  m.tet_body.resize(m.num_tets);
  for (int bi = 0; bi < static_cast<int>(m.bodies.size()); ++bi) {
    const auto& b = m.bodies[bi];
    m.X.middleCols(b.node_begin, b.num_nodes) = b.mesh.X;
    m.tets.middleCols(b.tet_begin, b.num_tets) = b.mesh.tets.array() + b.node_begin;
    if (b.mesh.order == 2) {
      m.tets10.middleCols(b.tet_begin, b.num_tets) = b.mesh.tets10.array() + b.node_begin;
      for (int e = b.tet_begin; e < b.tet_begin + b.num_tets; ++e) {
        m.quadratic[e] = 1;
        m.quad_slot[e] = m.num_quadratic++;
      }
    } else {
      m.tets10.block(0, b.tet_begin, 4, b.num_tets) = m.tets.middleCols(b.tet_begin, b.num_tets);
    }
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
  // Quadratic elements: dN/dX and w det J at the stiffness rule's points; det J > 0 at
  // every point of both rules (read_gmsh checks the file's elements; this catches a
  // transform or an elevation that broke one).
  m.qp_G.resize(4 * static_cast<size_t>(m.num_quadratic));
  m.qp_weight.resize(4 * static_cast<size_t>(m.num_quadratic));
  for (int e = 0; e < m.num_tets; ++e) {
    if (!m.quadratic[e]) continue;
    const Eigen::Matrix<double, 3, 10> X_e = element_rest_positions10(m, e);
    const double rel = tet10::min_det_jacobian(X_e) / (6.0 * m.rest_volume[e]);
    if (!(rel > 0)) {
      const auto& b = m.bodies[m.tet_body[e]];
      std::ostringstream s;
      const size_t local = static_cast<size_t>(e - b.tet_begin);
      s << b.mesh.source << ": quadratic tetrahedron " << local;
      if (local < b.mesh.tet_file_tag.size()) s << " (gmsh element " << b.mesh.tet_file_tag[local] << ")";
      s << " of body '" << b.name
        << "' is invalid: det J <= 0 at a quadrature point (min det J / det J of the straight element " << rel << ")";
      throw InputError(s.str());
    }
    double volume = 0;
    for (int q = 0; q < 4; ++q) {
      const auto& p = tet10::kStiffnessRule[q];
      const Eigen::Matrix<double, 10, 3> dN = tet10::shape_gradients_ref(p.u, p.v, p.w);
      const Mat3 J = tet10::jacobian(X_e, dN);
      const size_t k = 4 * static_cast<size_t>(m.quad_slot[e]) + q;
      m.qp_G[k] = (dN * J.inverse()).transpose();  // dN/dX = dN/dxi J^-1
      m.qp_weight[k] = p.weight * J.determinant();
      volume += m.qp_weight[k];
    }
    m.rest_volume[e] = volume;
  }

  build_pattern(m, cliques, m.pattern);
  color_elements(m, m.pattern);
  for (auto& b : m.bodies) {
    b.value_begin = m.pattern.structure.outerIndexPtr()[3 * b.node_begin];
    b.value_end = m.pattern.structure.outerIndexPtr()[3 * (b.node_begin + b.num_nodes)];
  }

  // Mass. Linear elements: lumped (rho V / 4 per node) or consistent (rho V / 20
  // (1 + delta_ab) I3). Quadratic elements (tet10.hpp's 14-point rule): consistent
  // M_ab = rho int N_a N_b, or lumped by HRZ: M_aa scaled so that the element's masses
  // sum to rho V (a row sum would give negative vertex masses, -rho V / 20 each).
  m.mass_values = VecX::Zero(m.pattern.nnz());
  m.mass_diagonal = VecX::Zero(3 * m.num_nodes);
  m.gravity_force = VecX::Zero(3 * m.num_nodes);
  for (int e = 0; e < m.num_tets; ++e) {
    const auto& b = m.bodies[m.tet_body[e]];
    const int* scatter = m.pattern.element_scatter.data() + m.pattern.element_scatter_begin[e];
    if (!m.quadratic[e]) {
      const double me = b.density * m.rest_volume[e];
      m.total_mass += me;
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
      continue;
    }
    const Eigen::Matrix<double, 3, 10> X_e = element_rest_positions10(m, e);
    Eigen::Matrix<double, 10, 10> Me = Eigen::Matrix<double, 10, 10>::Zero();
    Eigen::Matrix<double, 10, 1> load = Eigen::Matrix<double, 10, 1>::Zero();
    double me = 0;
    for (const auto& p : tet10::kMassRule) {
      const Eigen::Matrix<double, 10, 1> N = tet10::shape(p.u, p.v, p.w);
      const double dm = b.density * p.weight * tet10::jacobian(X_e, tet10::shape_gradients_ref(p.u, p.v, p.w)).determinant();
      Me.noalias() += dm * N * N.transpose();
      load += dm * N;
      me += dm;
    }
    m.total_mass += me;
    const Eigen::Matrix<double, 10, 1> hrz = Me.diagonal() * (me / Me.diagonal().sum());
    int k = 0;
    for (int i = 0; i < 30; ++i)
      for (int j = i; j < 30; ++j, ++k) {
        if (i % 3 != j % 3) continue;
        if (b.mass_kind == MassKind::lumped) {
          if (i / 3 == j / 3) m.mass_values[scatter[k]] += hrz[i / 3];
        } else {
          m.mass_values[scatter[k]] += Me(i / 3, j / 3);
        }
      }
    for (int a = 0; a < 10; ++a) {
      m.mass_diagonal.segment<3>(3 * m.tets10(a, e)).array() += hrz[a];
      m.gravity_force.segment<3>(3 * m.tets10(a, e)) += load[a] * gravity;
    }
  }
  // Linear bodies: row sums (= the lumped masses for both kinds: consistent rows sum to
  // rho V / 4), and the load M g (= the consistent load, rho g V / 4 per node).
  VecX row_sum = VecX::Zero(3 * m.num_nodes);
  const auto& S = m.pattern.structure;
  for (int col = 0; col < S.outerSize(); ++col)
    for (int k = S.outerIndexPtr()[col]; k < S.outerIndexPtr()[col + 1]; ++k) {
      const int row = S.innerIndexPtr()[k];
      row_sum[row] += m.mass_values[k];
      if (row != col) row_sum[col] += m.mass_values[k];
    }
  for (const auto& b : m.bodies) {
    if (b.mesh.order == 2) continue;
    for (int i = b.node_begin; i < b.node_begin + b.num_nodes; ++i)
      for (int c = 0; c < 3; ++c) {
        m.mass_diagonal[3 * i + c] = row_sum[3 * i + c];
        m.gravity_force[3 * i + c] = row_sum[3 * i + c] * gravity[c];
      }
  }
}

}  // namespace softdiff::fem
