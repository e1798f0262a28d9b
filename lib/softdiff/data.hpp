#pragma once
// Data: the preallocated workspace of a step and the record its derivative needs.
// Sized once by Data::Data(model); no allocation per step afterwards.
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/model.hpp>

#include <memory>
#include <string>

namespace softdiff {

// Outcome of a step or a static solve. Never thrown from the inner loop: the
// caller turns it into a message and an exit code.
struct StepStatus {
  enum class Code { ok, inverted_element, not_positive_definite, non_finite, diverged, not_converged, solver_failed };
  Code code = Code::ok;
  long step = -1;        // 1-based step (static: load step) where it happened
  int element = -1;      // global element index, if one is concerned
  int dof = -1;          // global dof, if one is concerned
  double value = 0;      // det F, residual, displacement, ...
  int iterations = 0;    // Newton iterations used
  double residual = 0;   // final relative residual (Newton / static)
  std::string detail;
  bool ok() const { return code == Code::ok; }
};

// Wall time of the last step, by stage (seconds).
struct StepTimings {
  double assembly = 0, factorization = 0, solve = 0, other = 0;
  double total() const { return assembly + factorization + solve + other; }
  StepTimings& operator+=(const StepTimings& o) {
    assembly += o.assembly; factorization += o.factorization; solve += o.solve; other += o.other;
    return *this;
  }
};

struct Data {
  explicit Data(const Model& model);

  fem::FemData fem;                 // record of the FEM stage at the last evaluation: x_i for the
                                    // linearized step, the last Newton iterate otherwise
  VecX K_i_values;                  // (nnz) K(x_i), kept for damping when newton_iterations > 1
  SparseMatrix A;                   // (3n, 3n) upper: A = M + h D + h^2 K, projected; written by the step
  VecX rhs;                         // (3n) right-hand side of the last solve (projected)
  VecX dv;                          // (3n) solution of the last solve
  VecX Mv, Kv, Mvi;                 // (3n) scratch: M v, K v, M v_i
  VecX lambda_a;                    // (n_a) actuation values used by the last step (at t_i + h)
  VecX f_act;                       // (3n) H_a(x_i)^T lambda_a of the last step (unprojected, without h)
  VecX x_iter, v_iter;              // (3n) Newton iterates
  std::unique_ptr<integrator::LinearSolver> solver;
  bool analyzed = false;            // symbolic factorization done (once per scene)
  bool factor_is_current = false;   // the factor matches A (constant matrices are factorized once)
  int newton_iterations_used = 0;
  double newton_residual = 0;
  StepTimings timings;              // of the last step
  long factorizations = 0;          // count over the run
};

// Human-readable one-line description of a failed status (names the model's body,
// element, node as the user sees them).
std::string describe(const Model& model, const StepStatus& status);

}  // namespace softdiff
