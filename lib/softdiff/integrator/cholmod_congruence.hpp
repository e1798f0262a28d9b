#pragma once
// G = B^T A^{-1} B from a CHOLMOD supernodal L L^T factor of A, for a sparse B whose
// columns share rows (the Delassus matrix: B = H_c^T, each contact's three columns on
// the same <= 12 dofs, neighbouring contacts on shared nodes). Exact, no approximation:
//
//  1. Distinct rows. B = E W: E (n x r) selects the r distinct non-zero rows of B and
//     W (r x m) is B with its rows renumbered. Then G = W^T Z W with
//     Z = E^T A^{-1} E = Y^T Y, Y = L^{-1} P E (A = P^T L L^T P).
//  2. Forward solves on the reach only. Column c of Y = L^{-1} e_k (k the permuted row)
//     is non-zero only on the supernodes of the path from k's supernode to its root in
//     the supernodal elimination tree. CHOLMOD postorders that tree, so with the columns
//     sorted by k the columns whose path crosses supernode s form one contiguous range
//     [clo_s, chi_s): Y restricted to s is a dense (ncol_s x (chi_s - clo_s)) block. One
//     pass over the supernodes, descendants first: triangular solve with the diagonal
//     block, Z(C_s, C_s) += Y_s^T Y_s, and the update L_21 Y_s scattered into the
//     ancestors' blocks. No backward solve; supernodes on no path are never touched; Z
//     is block diagonal over the trees (the bodies: A has no coupling between bodies).
//  3. G = W^T Z W: T = Z W (each column of Z restricted to its tree's rows), then the
//     upper triangle of G from T^T by contiguous axpys in tiles of 64 rows, mirrored, so
//     G is exactly symmetric.
//
// compute() declines (returns false; the caller then uses dense blocks of right-hand
// sides) if the factor is not supernodal L L^T with int indices, its supernodal tree is
// not postordered, r > max_rows_ratio m (Z is r x r), or its flop estimate exceeds
// decline_ratio times that of the dense solves (4 nnz(L) m).
//
// Measured (gripper scene, n = 14490, nnz(L) = 1.0e6, one core): 632 contacts
// (m = 1896, r = 876) 45 ms against 933 ms for dense blocks of 64 full solves, for a
// factorization of 73 ms; max |G - G_dense| / max |G_dense| <= 7e-15.
//
// Buffers grow only (a call allocates nothing once they have reached the largest sizes
// seen); the symbolic arrays are rebuilt after reset() (call it after each analysis).
#include <softdiff/core/types.hpp>

#include <cstddef>
#include <vector>

struct cholmod_factor_struct;  // cholmod.h (kept out of the public headers)

namespace softdiff::integrator {

class SupernodalCongruence {
 public:
  double decline_ratio = 1.0;   // decline when the flop estimate exceeds this times the dense solves'
  double max_rows_ratio = 2.0;  // decline when r > max_rows_ratio m (Z would exceed 4 G)

  // The symbolic structure (Perm, supernodes, patterns) is fixed by cholmod_analyze.
  void reset() { ready_ = false; }

  // G = B^T A^{-1} B (m x m, full, symmetric) from the numeric factor L of A; B (n x m),
  // compressed. Returns false (G unspecified) when it declines (see above).
  bool compute(const cholmod_factor_struct* L, const SparseMatrix& B, MatX& G);

 private:
  void build_symbolic(const cholmod_factor_struct* L);

  bool ready_ = false, usable_ = false;
  double lnz_ = 0;
  std::vector<int> iperm_, snode_, sparent_, sfirst_, stree_, pos_;  // symbolic (per analysis)
  std::vector<int> erow_, Wi_, cnt_, clo_, chi_, tlo_, thi_;        // per call, grow only
  std::vector<std::ptrdiff_t> off_;
  std::vector<double> y_, u_, zbuf_, tbuf_, ttbuf_;
};

}  // namespace softdiff::integrator
