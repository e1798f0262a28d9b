#pragma once
// Sparse symmetric positive-definite solvers for the step's system A dv = b.
// The matrix is given as its upper triangle in compressed-column form (the fixed
// pattern of fem::SystemPattern). analyze() runs once per scene (symbolic
// factorization, fill-reducing ordering); factorize() once per step (or once per
// run when A is constant); solve() any number of times with that factor.
#include <softdiff/core/types.hpp>

#include <memory>
#include <string>

namespace softdiff::integrator {

enum class SolverKind { cholmod, ldlt, cg };

struct SolverOptions {
  SolverKind kind = SolverKind::cholmod;
  double cg_tolerance = 1e-10;   // relative residual
  int cg_max_iterations = 10000;
  // Factor reuse (cholmod only; scene.md `linear_solver.factor_reuse: pcg`,
  // docs/method.md "Reusing the factor"): factorize() keeps the last numeric factor
  // while it preconditions well, and solve() runs conjugate gradients on the new
  // matrix preconditioned by it, to ||b - A x|| <= pcg_tolerance ||b||. A solve that
  // needed more than refactor_iterations iterations makes the next factorize()
  // factorize; one that has not converged after pcg_max_iterations (or meets
  // p^T A p <= 0) factorizes at once and solves directly.
  bool factor_reuse = false;
  double pcg_tolerance = 1e-10;
  int refactor_iterations = 8;
  int pcg_max_iterations = 40;
};

// Counts of a solver over its life (factor reuse: how often the factor was kept).
struct SolverCounters {
  long numeric_factorizations = 0;  // numeric factorizations actually run
  long kept_factors = 0;            // factorize() calls that kept a stale factor (factor reuse)
  long pcg_solves = 0;              // solves run as PCG with a stale factor
  long pcg_iterations = 0;          // their iterations (each one factor solve + one product with A)
  long pcg_fallbacks = 0;           // PCG solves abandoned for a factorization and a direct solve
  int last_pcg_iterations = 0;      // of the last PCG solve (0: the last solve was direct)
};

struct FactorStatus {
  bool ok = true;
  int column = -1;            // not positive definite: the column (dof) where it failed, if known
  std::string message;
};

class LinearSolver {
 public:
  virtual ~LinearSolver() = default;
  virtual std::string name() const = 0;
  virtual void analyze(const SparseMatrix& A_upper) = 0;
  virtual FactorStatus factorize(const SparseMatrix& A_upper) = 0;
  // x = A^{-1} b with the last factorization. Returns false if the (iterative)
  // solver did not reach its tolerance; x and b may not alias.
  virtual bool solve(const VecX& b, VecX& x) = 0;
  // The same with x on entry an initial guess (of b's size, else ignored): a PCG solve
  // with a kept factor starts from it (its stopping test stays ||b - A x|| <=
  // pcg_tolerance ||b||); a direct solve ignores it.
  virtual bool solve_from(const VecX& b, VecX& x) { return solve(b, x); }
  // Several right-hand sides (columns of B; X and B may not alias). CHOLMOD with a
  // current factor: one supernodal solve of the dense n x k B (workspaces kept: no
  // allocation per call once sized); with a kept factor (factor reuse) and the other
  // solvers: one solve per column.
  virtual bool solve(const MatX& B, MatX& X);
  // The congruence G = B^T A^{-1} B (m x m, dense, symmetric) for a sparse B (n x m)
  // with the last factorization: the Delassus matrix of the contacts (B = H_c^T).
  // CHOLMOD: forward solves Y = L^{-1} P E restricted to the elimination-tree reach of
  // the distinct rows E of B, Z = Y^T Y, G = W^T Z W (cholmod_congruence.hpp); where
  // that would cost more (rows not shared), dense blocks of 64 columns of B, full
  // solves. Either way the cost grows with the number of columns of B, not with n^2.
  // Others: m solves. Returns false if an iterative solve missed its tolerance.
  virtual bool inverse_congruence(const SparseMatrix& B, MatX& G);
  // Figures of the last factorization, for reports: nonzeros in L, flops.
  virtual double factor_nonzeros() const { return 0; }
  virtual double factor_flops() const { return 0; }
  // Counters (numeric_factorizations counts every successful or failed numeric
  // factorization of every solver; the PCG fields are zero without factor reuse).
  const SolverCounters& counters() const { return counters_; }
  // The status of the factorization a solve() ran itself (factor reuse: a PCG solve
  // that fell back to factorizing): ok unless that factorization failed, in which case
  // solve() returned false.
  const FactorStatus& solve_factor_status() const { return solve_factor_status_; }
  // Factor reuse: the next factorize() factorizes (called after a failed step, so that
  // the step after a failure never solves with a kept factor). No-op otherwise.
  virtual void refactorize_next() {}
  // Factor reuse with rigidified parts (integrator/rigidify.cpp: conjugate gradients on
  // the reduced system P^T A P, preconditioned by the kept factor's reduced inverse).
  // factor_kept(): the factor is an earlier matrix's (factorize() recorded A, kept L).
  virtual bool factor_kept() const { return false; }
  // z = (L L^T)^{-1} r with the factor as it is, kept or current (no PCG); r, z may not alias.
  virtual void apply_factor_as_is(const VecX& r, VecX& z) { solve(r, z); }
  // An outside PCG solve's iterations: counted as a PCG solve with the kept factor, and
  // the refactorization rule applied (more than refactor_iterations: the next
  // factorize() factorizes).
  virtual void count_outside_pcg(int /*iterations*/) {}
  // Factorize the recorded matrix now (an outside PCG that did not converge: counted as
  // a fallback); its status (solve_factor_status() too).
  virtual FactorStatus factorize_recorded() { return {}; }

 protected:
  SolverCounters counters_;
  FactorStatus solve_factor_status_;
};

std::unique_ptr<LinearSolver> make_linear_solver(const SolverOptions& options);

// Versions of linked libraries (for --version).
std::string suitesparse_version();

}  // namespace softdiff::integrator
