#pragma once
// The finite-element part of a Model: what does not change during a run.
// Built once by io::build_model (through fem::build_fem_model); algorithms take it by
// const reference. All soft bodies share one global node numbering: body b owns
// nodes [node_begin, node_begin + num_nodes), degrees of freedom 3 i + c.
#include <softdiff/core/types.hpp>
#include <softdiff/material/material.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

#include <string>
#include <vector>

namespace softdiff::fem {

enum class MassKind { lumped, consistent };

struct BodyModel {
  std::string name;
  int node_begin = 0, num_nodes = 0;   // global node range
  int tet_begin = 0, num_tets = 0;     // global element range
  material::Law law = material::Law::corotational;
  double young = 0, poisson = 0, density = 0;
  material::Lame lame;
  double rayleigh_mass = 0;            // alpha in D = alpha M + beta K
  double rayleigh_stiffness = 0;       // beta
  bool psd_projection = false;
  MassKind mass_kind = MassKind::lumped;
  mesh::TetMesh mesh;                  // the body's mesh with world rest positions (local node indices)
  Triangles surface;                   // (3, k) outward boundary triangles, local node indices (quadratic
                                       // body: each 6-node face split into 4, mesh::split_quadratic_triangles)
  mesh::Triangles6 surface6;           // (6, k) quadratic body: the outward 6-node boundary faces (gmsh order)
  int value_begin = 0, value_end = 0;  // this body's range in the system pattern's value array
  double bbox_diagonal = 0;            // rest bounding-box diagonal (divergence check scale)
};

// The sparsity pattern of every 3n x 3n system matrix (K, M, A): the upper triangle
// of the node-adjacency graph expanded to 3x3 blocks, compressed by columns, with
// precomputed scatter indices so that assembly writes straight into the values.
struct SystemPattern {
  SparseMatrix structure;              // (3n, 3n) upper triangle, values unused (zeros)
  std::vector<int> element_scatter;    // for element e and local dofs i <= j (row-major upper triangle
                                       // of the 12x12, or 30x30 for a quadratic element, matrix), the
                                       // value index: entries element_scatter_begin[e] .. [e + 1]
  std::vector<int> element_scatter_begin;  // (m + 1): 78 entries per linear element, 465 per quadratic
  std::vector<int> diagonal;           // (3n) value index of each diagonal entry
  std::vector<int> fixed_offdiagonal;  // value indices in a fixed row or column (off the diagonal)
  std::vector<int> fixed_diagonal;     // value indices of fixed diagonal entries
  std::vector<int> color_begin;        // element colors: elements color_elements[color_begin[c] ..
  std::vector<int> color_elements;     //   color_begin[c+1]) share no node (parallel assembly),
  bool last_color_shares_nodes = false; // except the last color if the coloring overflowed (serial)
  // Extra node cliques (build_fem_model's `cliques`: node groups coupled by something
  // other than an element, e.g. a cable segment's stiffness): every pair of a clique's
  // nodes has its 3x3 block in the pattern (zero in K and M). Clique c lists the nodes
  // clique_nodes[clique_node_begin[c] .. clique_node_begin[c+1]) (as given: repeats
  // allowed); for its k nodes, clique_scatter[clique_scatter_begin[c] + 9 (a k + b) +
  // 3 r + q] is the value index of entry (3 node_a + r, 3 node_b + q) if that entry is
  // in the upper triangle (row <= column), else -1 (the transposed entry, reached from
  // (b, a), holds it). Adding a symmetric clique matrix's blocks for all ordered pairs
  // (a, b) through this scatter therefore assembles exactly its upper triangle.
  std::vector<int> clique_node_begin{0};
  std::vector<int> clique_nodes;
  std::vector<int> clique_scatter_begin{0};
  std::vector<int> clique_scatter;
  int num_cliques() const { return static_cast<int>(clique_node_begin.size()) - 1; }
  long nnz() const { return structure.nonZeros(); }
};

struct FemModel {
  std::vector<BodyModel> bodies;
  int num_nodes = 0;
  int num_tets = 0;
  Mat3X X;                          // (3, n) rest positions, world frame
  Tets tets;                        // (4, m) global node indices of the vertices
  std::vector<int> tet_body;        // (m) body of each element
  std::vector<Mat3> Dm_inv;         // (m) inverse rest edge matrix [X1-X0, X2-X0, X3-X0]^-1 (of the vertices)
  VecX rest_volume;                 // (m) (quadratic: the curved element's volume, sum of qp_weight)
  // Quadratic (10-node) elements (bodies whose mesh has order 2; fem/tet10.hpp):
  std::vector<unsigned char> quadratic;  // (m) 1 for a 10-node element
  Eigen::Matrix<int, 10, Eigen::Dynamic> tets10;  // (10, m) global node indices in gmsh's order (rows
                                                  // 0-3 == tets); -1 in rows 4-9 of a linear element
  std::vector<int> quad_slot;       // (m) index of a quadratic element among the quadratic ones, else -1
  std::vector<Eigen::Matrix<double, 3, 10>> qp_G;  // (4 per slot, 4 s + q) dN_a/dX at the stiffness rule's
                                                   // point q (column a), rest configuration
  std::vector<double> qp_weight;    // (4 per slot) w_q det J_q: the point's share of the rest volume
  int num_quadratic = 0;
  int element_nodes(int e) const { return quadratic[e] ? 10 : 4; }
  std::vector<unsigned char> fixed; // (3n) 1 if the dof is fixed (projected out)
  long num_fixed_dofs = 0;
  SystemPattern pattern;
  VecX mass_values;                 // (nnz) mass matrix in the pattern (lumped: diagonal only)
  VecX mass_diagonal;               // (3n) lumped masses (linear consistent: row sums; quadratic: the
                                    // HRZ masses of both kinds, positive)
  VecX gravity_force;               // (3n) the consistent load int rho g N_a (= M g for linear elements)
  double total_mass = 0;
};

// Per-element derivative of F with respect to the element's 12 node coordinates:
// F = sum_a x_a g_a^T with g_a the shape-function gradients (g_0 = -(g_1+g_2+g_3),
// g_k = row k-1 of Dm_inv). Returns G = [g_0 g_1 g_2 g_3] (3 x 4).
inline Eigen::Matrix<double, 3, 4> shape_gradients(const Mat3& Dm_inv) {
  Eigen::Matrix<double, 3, 4> G;
  G.col(1) = Dm_inv.row(0).transpose();
  G.col(2) = Dm_inv.row(1).transpose();
  G.col(3) = Dm_inv.row(2).transpose();
  G.col(0) = -(G.col(1) + G.col(2) + G.col(3));
  return G;
}

// Rest positions (3 x 10) of quadratic element e.
Eigen::Matrix<double, 3, 10> element_rest_positions10(const FemModel& model, int e);

// Builds geometry (Dm_inv, volumes), mass, the pattern, coloring and gravity from
// bodies whose `mesh` (world rest positions), material and options are filled in.
// `fixed` (3n) marks fixed dofs. `cliques` (global node indices) extend the pattern
// (SystemPattern::clique_*); the actuators' stiffness needs them
// (actuation::ActuationModel::stiffness_cliques). Throws InputError for degenerate
// rest elements.
void build_fem_model(std::vector<BodyModel> bodies, const std::vector<unsigned char>& fixed,
                     const Vec3& gravity, FemModel& model,
                     const std::vector<std::vector<int>>& cliques = {});

}  // namespace softdiff::fem
