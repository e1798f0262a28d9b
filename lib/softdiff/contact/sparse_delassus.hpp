#pragma once
// The Delassus operator G = h H A^{-1} H^T of a step without its dense matrix
// (docs/method.md "Contact at scale"; Carpentier, Le Lidec, Montaut 2024, sec. IV-C,
// "sparse linear backend"). A is the step's system matrix (factorized once by the
// step), H = H_c the contact Jacobian (3 nc x 3n, projected). Every operation costs
// sparse solves, not (3 nc)^2:
//   apply        G_WW y = h H_W A^{-1} H_W^T y                 (one solve with A's factor)
//   apply_full   G_:W y (all contacts' rows)                    (one solve)
//   shifted      (G_WW + c I)^{-1} r by the Woodbury identity
//                  (c I + h H_W A^{-1} H_W^T)^{-1} = (1/c) (I - (h/c) H_W B^{-1} H_W^T),
//                  B = A + (h/c) H_W^T H_W,
//                sparse, symmetric positive definite (A is, H^T H >= 0): one CHOLMOD
//                factorization per c, one solve per application.
//   dense        G_WW as a dense matrix, for small sets W (LinearSolver::inverse_congruence).
// Per-contact scale (ADMM's rho_i = rho d_i, ncp.cpp): with D = diag(d_i I_3) set by
// set_scale, the shifted solve is (G_WW + c D)^{-1} = D^-1/2 (G~ + c I)^{-1} D^-1/2 with
// G~ = D^-1/2 G_WW D^-1/2 = h H~ A^{-1} H~^T, H~ = D^-1/2 H_W: the Woodbury identity
// above on H~, i.e. B = A + (h/c) H_W^T D^-1 H_W (the same pattern; a new scale costs
// one scatter of H~^T H~ and no analysis). largest_eigenvalue is that of G~.
// contact_compliance estimates d_i ~ G_ii without G: with the lumped masses m (set_mass),
// d_i = h tr(H_i M^-1 H_i^T) / 3, an upper bound of tr(G_ii) / 3 (A >= M); it carries
// the mass ratio between bodies, which is what the scale is for (docs/method.md).
// W is a subset of the contacts (restrict_to); after bind() it is all of them.
//
// Rigid bodies (set_rigid; docs/method.md "Rigid bodies in contact", Backends): their
// part of G is h sum_r H_r W_r H_r^T = h K K^T with K^T = Kt (k x 3 nc, dense, k <= 6 per
// body: Kt = L_r^T H_r^T, W_r = L_r L_r^T), i.e. k more dofs of unit mass bordering A:
// G = h [H_s K~] blockdiag(A, I_k)^{-1} [H_s K~]^T. Every operation adds its part
// exactly: the products and dense() add h K_W K_W^T y (O(k |W|)); the shifted solve is
// the Woodbury identity once more, on top of the soft one: with M = (c I + G~_soft)^{-1}
// (the B solve above) and K~ the scaled columns,
//   (c I + G~_soft + h K~ K~^T)^{-1} = M - Z C^{-1} Z^T,  Z = M K~,  C = I / h + K~^T Z,
// Z and C's Cholesky formed once per factorize_shifted (k solves with B), then one B
// solve and O(k |W|) per application. Where no soft dof is in W's contacts (H_W = 0: a
// rigid body on an obstacle) the soft part is 0: no solve with A or B at all.
//
// B's sparsity pattern is pattern(A) + pattern(H_W^T H_W). H_i couples the <= 4 nodes
// of contact i: a vertex-obstacle contact's 3x3 block is already in A's pattern; a
// soft-soft contact couples nodes that share no element. The pattern that was analyzed
// (CHOLMOD's ordering and symbolic factorization) only grows: a new B whose pattern it
// contains is scattered into it (explicit zeros elsewhere) and refactorized
// numerically; otherwise the union is analyzed once. With vertex-obstacle contacts
// only, the analysis is that of A's pattern, once per scene (analyses() counts them).
// A change of c rescales one value array (B = A_S + (h/c) P_S on the analyzed
// pattern S) and refactorizes: no analysis, no allocation.
//
// Shared storage (share_shifted_storage; docs/method.md "The derivative's memory"): the
// analyzed pattern S, the values A_S, P_S and B's factorization (with its solver's
// workspaces) are one storage that several operators may share: the step's NCP and the
// contact derivative (contact_step_derivatives.cpp) of the same record, whose Bs have one
// pattern. Each holds its own B (its W, scale or frames, c); the storage holds the last
// one written. An operator whose B was overwritten by another's since its
// factorize_shifted rebuilds its values and refactorizes at its next solve_shifted (the
// same numbers: the same factorization of the same B); the pattern only grows, as above.
#include <softdiff/core/types.hpp>
#include <softdiff/integrator/linear_solver.hpp>

#include <Eigen/Cholesky>

#include <cstdint>
#include <memory>
#include <vector>

namespace softdiff::contact {

// out = the columns of Ht (3n x 3 nc) of the contacts ids (3 per contact, in order).
void select_contact_columns(const SparseMatrix& Ht, const std::vector<int>& ids, SparseMatrix& out);

class SparseDelassus {
 public:
  // For one step: A_solver holds the factorization of A_upper (the step's system,
  // upper triangle, the model's fixed pattern); Ht = H_c^T (3n x 3 nc); h the step's
  // force-to-velocity factor. Keeps references to all three until the next bind.
  // options: the kind of solver used for B (as for A).
  void bind(integrator::LinearSolver& A_solver, const SparseMatrix& A_upper, const SparseMatrix& Ht, double h,
            const integrator::SolverOptions& options);

  // The lumped masses (3n) for contact_compliance (a dynamic step, A >= M); an empty
  // vector (the default, and the static solver, whose A has no mass): all d_i = 1.
  void set_mass(const VecX& mass_diagonal) { mass_ = &mass_diagonal; }
  void clear_mass() { mass_ = nullptr; }
  // The rigid rows Kt (k x 3 nc', see above), stacked from up to two blocks (the second
  // may be nullptr; either may have 0 rows; a block with fewer columns is zero on the
  // others); after bind (which clears them). Zero rows are dropped (a body without
  // contact). nc' > nc (more columns than Ht's): rows of the NCP after the nc contacts
  // with no soft dof (a joint limit's, rigid_contact.hpp): Ht is taken with zero columns
  // for them (a padded copy) and the operator has nc' contacts, W = all of them.
  // Invalidates the shifted factorization.
  // Rigidified parts (integrator/rigidify.hpp rigidified_rows): their rank-6m part of G,
  // h W^T S^{-1} W, is h K_p^T K_p with K_p = L_S^{-1} W, i.e. rigid rows too: the
  // second block.
  void set_rigid(const MatX& Kt, const MatX* Kt_more = nullptr);
  int rigid_rows() const { return static_cast<int>(Kt_.rows()); }

  int contacts() const { return nc_; }
  // Restrict to the contacts W (ascending ids). Invalidates the shifted factorization.
  void restrict_to(const std::vector<int>& W);
  void restrict_to_all();
  int size() const { return static_cast<int>(W_.size()); }

  // out = G_WW y (3|W|). False: an iterative solver missed its tolerance.
  bool apply(const Eigen::Ref<const VecX>& y, Eigen::Ref<VecX> out);
  // out = G_:W y (3 nc): the velocities of every contact for forces on W.
  bool apply_full(const Eigen::Ref<const VecX>& y, Eigen::Ref<VecX> out);
  // G_WW, dense (3|W| x 3|W|).
  bool dense(MatX& G);
  // d_i ~ G_ii per contact of W (|W|), see above.
  void contact_compliance(Eigen::Ref<VecX> d) const;
  // The per-contact scale D (|W|, positive) of the shifted solves and of
  // largest_eigenvalue; restrict_to resets it to 1. Invalidates the shifted factorization.
  void set_scale(const Eigen::Ref<const VecX>& d);
  // Rotated, weighted rows (the mixed mode-fixed system's preconditioner, mode_system.hpp):
  // with R = blockdiag(frames[b]) (one 3x3 rotation per contact of W, rows: the directions
  // in the contact frame) and s (3|W|, >= 0) a weight per rotated row, the shifted
  // solve with c = 1 becomes r <- s (I + h H~ A^{-1} H~^T)^{-1} s r, H~ = diag(s) R H_W,
  // i.e. (diag(s)^{-2} + R G_WW R^T)^{-1} on the rows with s > 0 (0 on the others), and
  // B = A + h H~^T H~ (the same pattern). Replaces set_scale; restrict_to resets it;
  // largest_eigenvalue is then that of H~'s operator. Invalidates the shifted factorization.
  void set_frames(const std::vector<Mat3>& frames, const Eigen::Ref<const VecX>& s);
  // Factorize B for the shift c > 0; false if B is not positive definite (A is not).
  bool factorize_shifted(double c);
  // From now on, keep B's pattern, values and factorization in other's storage (see
  // above; other's next B may overwrite this one's: then this one refactorizes at its next
  // solve_shifted). Invalidates the shifted factorization.
  void share_shifted_storage(const SparseDelassus& other);
  // The factorizations of B in this operator's storage (shared: all its operators').
  bool shares_shifted_storage_with(const SparseDelassus& other) const { return storage_ == other.storage_; }
  // r <- (G_WW + c D)^{-1} r with the last factorize_shifted(c).
  bool solve_shifted(Eigen::Ref<VecX> r);
  // Largest eigenvalue of D^-1/2 G_WW D^-1/2 by power iteration (iterations applies),
  // warm-started from the previous call's vector when the size matches (steps change little).
  double largest_eigenvalue(int iterations);

  double last_eigenvalue() const { return last_eigenvalue_; }
  // ADMM's rho at the end of the last solve on this operator (kept across bind()).
  double last_rho() const { return last_rho_; }
  void set_last_rho(double rho) { last_rho_ = rho; }
  // An iterative linear solver (cg) missed its tolerance since bind().
  bool failed() const { return failed_; }
  int analyses() const { return analyses_; }          // symbolic analyses of B
  Eigen::Index pattern_nonzeros() const { return storage_ ? storage_->S.nonZeros() : 0; }  // analyzed pattern (upper)
  int factorizations() const { return factorizations_; }
  // Wall seconds since bind() (reports only, never asserted): forming contact-system
  // matrices (restrict_to's columns, set_scale's H~, B's pattern and values from
  // H_W^T H_W, the dense G_WW of dense()), and B's numeric factorizations
  // (factorize_shifted without its pattern). contact_step.cpp books the first as the
  // assembly of the contact system, not as NCP time (docs/performance.md "Contact").
  double assembly_seconds() const { return assembly_seconds_; }
  double factorization_seconds() const { return factorization_seconds_; }

 private:
  void build_pattern();  // P = H_W^T H_W (upper), S grown if needed, values scattered
  void select_rigid_columns();  // KtW_ = Kt_'s columns of W; soft_empty_
  // r <- (c I + h H~ A^{-1} H~^T)^{-1} r, the soft part of the shifted solve (scaled space).
  bool shifted_soft(Eigen::Ref<VecX> r);
  const MatX& scaled_rigid() const { return scale_sqrt_inv_.size() > 0 ? KtWs_ : KtW_; }
  // out = h (soft_rows^T A^{-1} H_W + rigid_rows^T K_W^T) y: apply (W's rows) and
  // apply_full (every contact's rows) differ only in the rows they read out.
  bool product(const Eigen::Ref<const VecX>& y, const SparseMatrix& soft_rows, const MatX& rigid_rows,
               Eigen::Ref<VecX> out);

  integrator::LinearSolver* A_solver_ = nullptr;
  const SparseMatrix* A_ = nullptr;
  const SparseMatrix* Ht_ = nullptr;  // the bound Ht, or Ht_padded_
  SparseMatrix Ht_padded_;            // (3n x 3 nc') set_rigid with more columns than Ht
  double h_ = 0;
  int nc_ = 0;
  integrator::SolverOptions options_;
  std::vector<int> W_;
  SparseMatrix HtW_;                 // (3n x 3|W|) columns of Ht for W
  SparseMatrix HtWs_;                // (3n x 3|W|) HtW_ D^-1/2 (set_scale; unused when not scaled)
  VecX scale_sqrt_inv_;              // (3|W|) D^-1/2 per column, or set_frames' s (empty: not scaled)
  const VecX* mass_ = nullptr;       // (3n) set_mass
  bool pattern_ready_ = false;       // S holds B's pattern for the current W
  double c_ = 0;                     // the shift of the current factorization (0: none)
  // The analyzed pattern S (upper, compressed), B = A_S + (h/c) P_S on it and B's
  // solver: the storage (shared, see above). generation: bumped by each operator that
  // writes its values; an operator's B is the storage's while its generation_ is it.
  struct ShiftedStorage {
    SparseMatrix S;
    VecX a_values, p_values;         // (nnz S) A and H_W^T H_W scattered into S
    std::unique_ptr<integrator::LinearSolver> solver;
    bool analyzed = false;
    std::uint64_t generation = 0;
  };
  std::shared_ptr<ShiftedStorage> storage_ = std::make_shared<ShiftedStorage>();
  std::uint64_t generation_ = 0;     // 0: none written
  bool owns_storage() const { return generation_ != 0 && generation_ == storage_->generation; }
  VecX u_, w_, power_, power_next_;  // (3n) scratch; (3|W|) power iteration
  // Rigid rows (set_rigid): all contacts, W's columns, scaled; the shifted solve's Z, C.
  MatX Kt_, KtW_, KtWs_, Z_;
  Eigen::LLT<MatX> capacitance_;
  VecX kr_;                          // (k) scratch
  bool soft_empty_ = false;          // H_W has no entry: the soft part of G_WW is 0
  double last_eigenvalue_ = 0, last_rho_ = 0;
  bool failed_ = false;
  int analyses_ = 0, factorizations_ = 0;
  double assembly_seconds_ = 0, factorization_seconds_ = 0;  // since bind()
};

}  // namespace softdiff::contact
