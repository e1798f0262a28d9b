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
  // Several right-hand sides (columns of B).
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
};

std::unique_ptr<LinearSolver> make_linear_solver(const SolverOptions& options);

// Versions of linked libraries (for --version).
std::string suitesparse_version();

}  // namespace softdiff::integrator
