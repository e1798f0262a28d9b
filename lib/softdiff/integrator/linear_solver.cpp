#include <softdiff/integrator/linear_solver.hpp>

#include <softdiff/integrator/cholmod_congruence.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/core/threads.hpp>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCholesky>
#include <cholmod.h>
#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

namespace softdiff::integrator {

bool LinearSolver::solve(const MatX& B, MatX& X) {
  X.resize(B.rows(), B.cols());
  VecX b, x;
  bool ok = true;
  for (int k = 0; k < B.cols(); ++k) {
    b = B.col(k);
    ok = solve(b, x) && ok;
    X.col(k) = x;
  }
  return ok;
}

bool LinearSolver::inverse_congruence(const SparseMatrix& B, MatX& G) {
  const Eigen::Index m = B.cols();
  G.resize(m, m);
  if (m == 0) return true;
  constexpr Eigen::Index block = 64;
  MatX rhs, X;
  bool ok = true;
  for (Eigen::Index c0 = 0; c0 < m; c0 += block) {
    const Eigen::Index bs = std::min(block, m - c0);
    rhs = MatX(B.middleCols(c0, bs));
    ok = solve(rhs, X) && ok;
    G.middleCols(c0, bs).noalias() = B.transpose() * X;
  }
  G = 0.5 * (G + G.transpose()).eval();
  return ok;
}

namespace {

// CHOLMOD supernodal Cholesky. The cholmod_sparse header points at the caller's
// arrays (no copy). Workspaces of cholmod_solve2 are kept between solves so that
// repeated solves do not allocate.
class CholmodSolver final : public LinearSolver {
 public:
  explicit CholmodSolver(const SolverOptions& options) : options_(options) {
    cholmod_start(&common_);
    common_.supernodal = CHOLMOD_SUPERNODAL;
    common_.final_ll = 1;      // keep L L^T (no conversion to LDL^T)
    common_.quick_return_if_not_posdef = 1;
    common_.print = 0;
    common_.error_handler = nullptr;
  }
  ~CholmodSolver() override {
    if (factor_) cholmod_free_factor(&factor_, &common_);
    if (X_) cholmod_free_dense(&X_, &common_);
    if (Y_) cholmod_free_dense(&Y_, &common_);
    if (E_) cholmod_free_dense(&E_, &common_);
    if (Xb_) cholmod_free_dense(&Xb_, &common_);
    if (Yb_) cholmod_free_dense(&Yb_, &common_);
    if (Eb_) cholmod_free_dense(&Eb_, &common_);
    if (Z_) cholmod_free_dense(&Z_, &common_);
    if (Xm_) cholmod_free_dense(&Xm_, &common_);
    if (Ym_) cholmod_free_dense(&Ym_, &common_);
    if (Em_) cholmod_free_dense(&Em_, &common_);
    cholmod_finish(&common_);
  }
  std::string name() const override { return "cholmod"; }

  void analyze(const SparseMatrix& A) override {
    cholmod_sparse view = wrap(A);
    if (factor_) cholmod_free_factor(&factor_, &common_);
    factor_ = cholmod_analyze(&view, &common_);
    throw_if_out_of_memory("the analysis (ordering)", A.rows());
    SOFTDIFF_DEMAND(factor_ != nullptr, "cholmod_analyze failed (status " + std::to_string(common_.status) + ")");
    congruence_.reset();  // a new symbolic structure
    factored_ = false;
    stale_ = false;
    if (options_.factor_reuse) {
      // Factor reuse: the matrix of the last factorize() (PCG's operator) and the PCG
      // vectors, sized once per analysis.
      A_ = A;
      const Eigen::Index n = A.rows();
      for (VecX* v : {&pcg_r_, &pcg_z_, &pcg_p_, &pcg_q_}) v->resize(n);
    }
  }

  // Factor reuse: record A (its values: the pattern is the analyzed one) and keep the
  // last factor unless there is none, the last solve asked for a new one, or a solve
  // failed; otherwise (and without reuse) factorize A.
  FactorStatus factorize(const SparseMatrix& A) override {
    SOFTDIFF_DEMAND(factor_ != nullptr, "factorize() before analyze()");
    if (!options_.factor_reuse) return factorize_numeric(A);
    SOFTDIFF_DEMAND(A.nonZeros() == A_.nonZeros() && A.rows() == A_.rows(),
                    "factorize(): the matrix's pattern is not the analyzed one");
    std::copy(A.valuePtr(), A.valuePtr() + A.nonZeros(), A_.valuePtr());
    if (factored_ && !refactor_next_) {
      stale_ = true;
      ++counters_.kept_factors;
      return {};
    }
    return factorize_numeric(A_);
  }

  FactorStatus factorize_numeric(const SparseMatrix& A) {
    cholmod_sparse view = wrap(A);
    {
      // CHOLMOD's own OpenMP loops on one thread; its BLAS keeps the plan's threads
      // (core/threads.hpp).
      SerialOpenMP serial;
      use_planned_blas_threads();
      cholmod_factorize(&view, factor_, &common_);
    }
    throw_if_out_of_memory("the factorization", A.rows());
    FactorStatus status;
    if (common_.status == CHOLMOD_NOT_POSDEF) {
      status.ok = false;
      // factor_->minor is the column (in the permuted order) where it failed.
      const long minor = static_cast<long>(factor_->minor);
      if (factor_->Perm && minor < static_cast<long>(factor_->n))
        status.column = static_cast<const int*>(factor_->Perm)[minor];
      status.message = "matrix is not positive definite";
    } else if (common_.status < CHOLMOD_OK) {
      status.ok = false;
      status.message = "CHOLMOD factorization failed (status " + std::to_string(common_.status) + ")";
    }
    ++counters_.numeric_factorizations;
    factored_ = status.ok;
    stale_ = false;
    refactor_next_ = false;
    return status;
  }

  bool solve(const VecX& b, VecX& x) override {
    SOFTDIFF_DEMAND(factored_, "solve() without a valid factorization");
    solve_factor_status_ = {};
    counters_.last_pcg_iterations = 0;
    if (stale_) return pcg_solve(b, x, false);
    return direct_solve(b, x);
  }

  void refactorize_next() override { refactor_next_ = true; }

  bool factor_kept() const override { return stale_; }
  void apply_factor_as_is(const VecX& r, VecX& z) override {
    SOFTDIFF_DEMAND(factored_, "apply_factor_as_is() without a valid factorization");
    apply_factor(r, z);
  }
  void count_outside_pcg(int iterations) override {
    ++counters_.pcg_solves;
    counters_.pcg_iterations += iterations;
    counters_.last_pcg_iterations = iterations;
    if (iterations > options_.refactor_iterations) refactor_next_ = true;
  }
  FactorStatus factorize_recorded() override {
    ++counters_.pcg_fallbacks;
    refresh_factor();
    return solve_factor_status_;
  }

  bool solve_from(const VecX& b, VecX& x) override {
    SOFTDIFF_DEMAND(factored_, "solve() without a valid factorization");
    solve_factor_status_ = {};
    counters_.last_pcg_iterations = 0;
    if (stale_) return pcg_solve(b, x, x.size() == b.size() && x.allFinite());
    return direct_solve(b, x);
  }

  // Several right-hand sides: with the current factor, X = A^{-1} B in one
  // cholmod_solve2 call on the dense n x k B (the supernodes' triangular solves run as
  // BLAS-3 on all k columns at once, and the factor is read once, not k times). The
  // workspaces (Xm_, Ym_, Em_) are kept: repeated solves with the same k allocate
  // nothing once X is sized. A kept (stale) factor: PCG per column (the base class).
  bool solve(const MatX& B, MatX& X) override {
    SOFTDIFF_DEMAND(factored_, "solve() without a valid factorization");
    if (stale_ || B.cols() <= 1) return LinearSolver::solve(B, X);
    solve_factor_status_ = {};
    counters_.last_pcg_iterations = 0;
    const Eigen::Index n = B.rows(), k = B.cols();
    solve_block(B.data(), n, k, Xm_, Ym_, Em_, "a solve with several right-hand sides");
    X = Eigen::Map<const MatX, 0, Eigen::OuterStride<>>(static_cast<const double*>(Xm_->x), n, k,
                                                        Eigen::OuterStride<>(static_cast<Eigen::Index>(Xm_->d)));
    return true;
  }

  bool direct_solve(const VecX& b, VecX& x) {
    solve_with_factor(b, X_, "a solve", x);
    return true;
  }

  // out = (L L^T)^{-1} b with the current numeric factor; X: the CHOLMOD workspace
  // that receives the solution (reused across calls, no allocation once sized).
  void solve_with_factor(const VecX& b, cholmod_dense*& X, const char* what, VecX& out) {
    out = Eigen::Map<const VecX>(solve_block(b.data(), b.size(), 1, X, Y_, E_, what), b.size());
  }

  // A^{-1} times the n x k column-major block at b (leading dimension n) in one
  // cholmod_solve2 call with the current numeric factor; X, Y, E: CHOLMOD workspaces
  // reused across calls (no allocation once sized). Returns X's values (leading
  // dimension X->d).
  const double* solve_block(const double* b, Eigen::Index n, Eigen::Index k, cholmod_dense*& X,
                            cholmod_dense*& Y, cholmod_dense*& E, const char* what) {
    cholmod_dense B;
    B.nrow = n;
    B.ncol = k;
    B.nzmax = n * k;
    B.d = n;
    B.x = const_cast<double*>(b);
    B.z = nullptr;
    B.xtype = CHOLMOD_REAL;
    B.dtype = CHOLMOD_DOUBLE;
    use_planned_blas_threads();
    const int ok = cholmod_solve2(CHOLMOD_A, factor_, &B, nullptr, &X, nullptr, &Y, &E, &common_);
    throw_if_out_of_memory(what, n);
    SOFTDIFF_DEMAND(ok, "cholmod_solve2 failed (status " + std::to_string(common_.status) + ")");
    return static_cast<const double*>(X->x);
  }

  // G = B^T A^{-1} B by blocks of columns: X = A^{-1} B_block with one supernodal
  // solve of a dense (n x 64) right-hand side (BLAS-3 in the supernodes), then
  // G(:, block) = B^T X (B has a few entries per column). The cost is
  // (m / 64) solves, i.e. it grows with the number of contacts, never with n^2; no
  // n x m matrix is ever stored. The upper triangle is computed and mirrored, so G
  // is exactly symmetric.
  // G = B^T A^{-1} B: forward solves on the etree reach of B's distinct rows
  // (SupernodalCongruence), or, where that declines, dense blocks of right-hand sides.
  bool inverse_congruence(const SparseMatrix& B, MatX& G) override {
    SOFTDIFF_DEMAND(factored_, "inverse_congruence() without a valid factorization");
    // The congruence needs A's own factor (its reach solves are triangular solves with
    // L): a stale factor is replaced first.
    if (stale_ && !refresh_factor()) return false;
    if (congruence_.compute(factor_, B, G)) return true;
    return dense_block_congruence(B, G);
  }

  // Blocks of 64 columns of B as dense right-hand sides, full solves, G block = B^T X.
  bool dense_block_congruence(const SparseMatrix& B, MatX& G) {
    const Eigen::Index n = B.rows(), m = B.cols();
    G.resize(m, m);
    if (m == 0) return true;
    constexpr Eigen::Index block = 64;
    const Eigen::Index bs_max = std::min(block, m);
    if (block_.rows() != n || block_.cols() != bs_max) block_.resize(n, bs_max);
    Bt_ = B.transpose();  // (m x n) row access to B's columns' dual
    for (Eigen::Index c0 = 0; c0 < m; c0 += block) {
      const Eigen::Index bs = std::min(block, m - c0);
      auto rhs = block_.leftCols(bs);
      rhs.setZero();
      for (Eigen::Index j = 0; j < bs; ++j)
        for (SparseMatrix::InnerIterator it(B, c0 + j); it; ++it) rhs(it.row(), j) = it.value();
      const double* x = solve_block(block_.data(), n, bs, Xb_, Yb_, Eb_, "a solve");
      const Eigen::Map<const MatX, 0, Eigen::OuterStride<>> X(x, n, bs,
                                                               Eigen::OuterStride<>(static_cast<Eigen::Index>(Xb_->d)));
      // Rows 0 .. c0 + bs of G(:, block): the upper triangle and the diagonal block.
      G.block(0, c0, c0 + bs, bs).noalias() = Bt_.topRows(c0 + bs) * X;
    }
    for (Eigen::Index j = 0; j < m; ++j)
      for (Eigen::Index i = j + 1; i < m; ++i) G(i, j) = G(j, i);
    return true;
  }

  double factor_nonzeros() const override { return common_.lnz; }
  double factor_flops() const override { return common_.fl; }

 private:
  // Factor reuse: factorize the recorded A now (a stale factor that cannot serve).
  bool refresh_factor() {
    solve_factor_status_ = factorize_numeric(A_);
    return solve_factor_status_.ok;
  }

  // z = (L L^T)^{-1} r with the (stale) factor: the preconditioner.
  void apply_factor(const VecX& r, VecX& z) { solve_with_factor(r, Z_, "a preconditioner solve", z); }

  // Conjugate gradients on A_ (the matrix of the last factorize()) preconditioned by
  // the stale factor, from x = 0 or the caller's guess, until ||b - A x|| <= pcg_tolerance ||b|| (the true
  // residual, recomputed when the recurrence says so: the recurrence drifts from it).
  // More than refactor_iterations iterations: the next factorize() factorizes. No
  // convergence after pcg_max_iterations, or p^T A p <= 0 (A not positive definite, or
  // round-off): factorize A now and solve directly (a failed factorization is
  // solve_factor_status(), and solve() returns false).
  bool pcg_solve(const VecX& b, VecX& x, bool from_guess) {
    ++counters_.pcg_solves;
    const auto A = A_.selfadjointView<Eigen::Upper>();
    const double target = options_.pcg_tolerance * b.norm();
    if (target == 0) {  // b = 0
      x.setZero(b.size());
      return true;
    }
    pcg_r_ = b;
    if (from_guess) {
      pcg_r_.noalias() -= A * x;
    } else {
      x.setZero(b.size());
    }
    int it = 0;
    bool converged = pcg_r_.norm() <= target;
    while (!converged && it < options_.pcg_max_iterations) {
      // (Re)start from the true residual pcg_r_.
      apply_factor(pcg_r_, pcg_z_);
      pcg_p_ = pcg_z_;
      double rz = pcg_r_.dot(pcg_z_);
      bool breakdown = false;
      while (it < options_.pcg_max_iterations) {
        pcg_q_.noalias() = A * pcg_p_;
        const double pq = pcg_p_.dot(pcg_q_);
        if (!(pq > 0)) {
          breakdown = true;
          break;
        }
        const double alpha = rz / pq;
        x.noalias() += alpha * pcg_p_;
        pcg_r_.noalias() -= alpha * pcg_q_;
        ++it;
        if (pcg_r_.norm() <= target) break;
        apply_factor(pcg_r_, pcg_z_);
        const double rz_next = pcg_r_.dot(pcg_z_);
        pcg_p_ = pcg_z_ + (rz_next / rz) * pcg_p_;
        rz = rz_next;
      }
      if (breakdown) break;
      // The recurrence's residual says converged (or the budget is spent): check the
      // true one.
      pcg_r_ = b;
      pcg_r_.noalias() -= A * x;
      converged = pcg_r_.norm() <= target;
    }
    counters_.pcg_iterations += it;
    counters_.last_pcg_iterations = it;
    if (it > options_.refactor_iterations) refactor_next_ = true;
    if (converged) return true;
    ++counters_.pcg_fallbacks;
    if (!refresh_factor()) return false;
    return direct_solve(b, x);
  }

  // CHOLMOD could not allocate (CHOLMOD_OUT_OF_MEMORY) or the sizes overflow its
  // integers (CHOLMOD_TOO_LARGE): not a property of the matrix, so not a
  // FactorStatus: a ComputationError naming the cause and, once the analysis has
  // counted them, the factor's nonzeros and the memory they need (8 bytes each for
  // the values, 4 for their row indices in the worst case: at least 8).
  void throw_if_out_of_memory(const char* stage, Eigen::Index n) const {
    if (common_.status != CHOLMOD_OUT_OF_MEMORY && common_.status != CHOLMOD_TOO_LARGE) return;
    char text[400];
    const bool too_large = common_.status == CHOLMOD_TOO_LARGE;
    int length = std::snprintf(text, sizeof text, "CHOLMOD %s during %s of the %ld x %ld system matrix",
                               too_large ? "found the problem too large (CHOLMOD_TOO_LARGE)"
                                         : "ran out of memory (CHOLMOD_OUT_OF_MEMORY)",
                               stage, static_cast<long>(n), static_cast<long>(n));
    if (common_.lnz > 0 && length > 0 && length < static_cast<int>(sizeof text))
      length += std::snprintf(text + length, sizeof text - static_cast<std::size_t>(length),
                              ": its Cholesky factor has %.3g nonzeros, at least %.3g GB", common_.lnz,
                              8 * common_.lnz / 1e9);
    if (length > 0 && length < static_cast<int>(sizeof text))
      std::snprintf(text + length, sizeof text - static_cast<std::size_t>(length),
                    " (more memory, a coarser mesh, or linear_solver: cg, which needs no factor)");
    throw ComputationError(text);
  }

  // OpenBLAS's threads for this factor's size (core/threads.hpp), before every CHOLMOD
  // call that runs BLAS.
  void use_planned_blas_threads() const { use_blas_threads(factorization_threads(common_.fl)); }

  static cholmod_sparse wrap(const SparseMatrix& A) {
    SOFTDIFF_DEMAND(A.isCompressed(), "matrix must be compressed");
    cholmod_sparse s{};
    s.nrow = A.rows();
    s.ncol = A.cols();
    s.nzmax = A.nonZeros();
    s.p = const_cast<int*>(A.outerIndexPtr());
    s.i = const_cast<int*>(A.innerIndexPtr());
    s.nz = nullptr;
    s.x = const_cast<double*>(A.valuePtr());
    s.z = nullptr;
    s.stype = 1;  // upper triangle stored
    s.itype = CHOLMOD_INT;
    s.xtype = CHOLMOD_REAL;
    s.dtype = CHOLMOD_DOUBLE;
    s.sorted = 1;
    s.packed = 1;
    return s;
  }

  cholmod_common common_{};
  cholmod_factor* factor_ = nullptr;
  cholmod_dense* X_ = nullptr;
  cholmod_dense* Y_ = nullptr;
  cholmod_dense* E_ = nullptr;
  cholmod_dense *Xb_ = nullptr, *Yb_ = nullptr, *Eb_ = nullptr;  // inverse_congruence's blocks
  cholmod_dense *Xm_ = nullptr, *Ym_ = nullptr, *Em_ = nullptr;  // solve()'s several right-hand sides
  MatX block_;                     // inverse_congruence's right-hand sides (n x 64)
  SupernodalCongruence congruence_;  // inverse_congruence's reach solves (buffers grow only)
  Eigen::SparseMatrix<double, Eigen::RowMajor, int> Bt_;  // B^T, rows = columns of B
  bool factored_ = false;
  // Factor reuse (SolverOptions::factor_reuse).
  SolverOptions options_;
  SparseMatrix A_;        // (n x n, upper) the matrix of the last factorize(); analyze() sizes it
  bool stale_ = false;    // factor_ is that of an earlier matrix than A_
  bool refactor_next_ = false;  // the last PCG solve needed more than refactor_iterations
  VecX pcg_r_, pcg_z_, pcg_p_, pcg_q_;  // (n) PCG's residual, preconditioned residual, direction, A p
  cholmod_dense* Z_ = nullptr;          // the preconditioner's output
};

// Eigen's simplicial LDL^T (no BLAS): a dependable reference, slower on large meshes.
class LdltSolver final : public LinearSolver {
 public:
  std::string name() const override { return "ldlt"; }
  void analyze(const SparseMatrix& A) override { ldlt_.analyzePattern(A); }
  FactorStatus factorize(const SparseMatrix& A) override {
    ldlt_.factorize(A);
    ++counters_.numeric_factorizations;
    FactorStatus status;
    if (ldlt_.info() != Eigen::Success) {
      status.ok = false;
      status.message = "LDL^T factorization failed (zero pivot)";
      return status;
    }
    const auto& D = ldlt_.vectorD();
    Eigen::Index k;
    if (!(D.minCoeff(&k) > 0)) {
      status.ok = false;
      status.column = static_cast<int>(ldlt_.permutationPinv().indices()[k]);
      status.message = "matrix is not positive definite";
    }
    return status;
  }
  bool solve(const VecX& b, VecX& x) override {
    x = ldlt_.solve(b);
    return true;
  }

 private:
  Eigen::SimplicialLDLT<SparseMatrix, Eigen::Upper> ldlt_;
};

// Conjugate gradients with a Jacobi preconditioner: no factorization, memory linear
// in the matrix size; accuracy set by the tolerance (relative residual).
class CgSolver final : public LinearSolver {
 public:
  explicit CgSolver(const SolverOptions& o) {
    cg_.setTolerance(o.cg_tolerance);
    cg_.setMaxIterations(o.cg_max_iterations);
  }
  std::string name() const override { return "cg"; }
  void analyze(const SparseMatrix& A) override { cg_.analyzePattern(A); }
  FactorStatus factorize(const SparseMatrix& A) override {
    cg_.factorize(A);
    ++counters_.numeric_factorizations;
    FactorStatus status;
    for (int k = 0; k < A.cols(); ++k)
      if (!(A.coeff(k, k) > 0)) {
        status.ok = false;
        status.column = k;
        status.message = "matrix has a non-positive diagonal entry (not positive definite)";
        break;
      }
    return status;
  }
  bool solve(const VecX& b, VecX& x) override {
    x = cg_.solveWithGuess(b, VecX::Zero(b.size()));
    return cg_.info() == Eigen::Success;
  }

 private:
  Eigen::ConjugateGradient<SparseMatrix, Eigen::Upper> cg_;
};

}  // namespace

std::unique_ptr<LinearSolver> make_linear_solver(const SolverOptions& options) {
  switch (options.kind) {
    case SolverKind::cholmod: return std::make_unique<CholmodSolver>(options);
    case SolverKind::ldlt: return std::make_unique<LdltSolver>();
    case SolverKind::cg: return std::make_unique<CgSolver>(options);
  }
  return nullptr;
}

std::string suitesparse_version() {
  return std::to_string(SUITESPARSE_MAIN_VERSION) + "." + std::to_string(SUITESPARSE_SUB_VERSION) + "." +
         std::to_string(SUITESPARSE_SUBSUB_VERSION) + " (CHOLMOD " + std::to_string(CHOLMOD_MAIN_VERSION) + "." +
         std::to_string(CHOLMOD_SUB_VERSION) + "." + std::to_string(CHOLMOD_SUBSUB_VERSION) + ")";
}

}  // namespace softdiff::integrator
