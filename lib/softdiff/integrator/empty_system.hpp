#pragma once
// The soft system of a scene of rigid bodies only (docs/method.md "Scenes of rigid bodies
// only"): no soft dof, so no factorization; the system is 0 x 0 and every solve with it is
// empty. The mode-fixed contact system of a derivative then has only the rigid rows (the
// record's dense G = h sum_r H_r W_r H_r^T, or on the sparse backend G_AA = 0 + h Kt_A^T
// Kt_A). Used by the dynamic step's derivative (implicit_euler_derivatives.cpp) and the
// static one (static_solver_derivatives.cpp). Stateless. Not in the precompiled header.
#include <softdiff/integrator/linear_solver.hpp>

#include <string>

namespace softdiff::integrator {

class EmptySystem final : public LinearSolver {
 public:
  std::string name() const override { return "none (no soft dof)"; }
  void analyze(const SparseMatrix&) override {}
  FactorStatus factorize(const SparseMatrix&) override { return {}; }
  // Only empty systems (a right-hand side with rows is a programming error: false).
  bool solve(const VecX& b, VecX& x) override {
    x.resize(0);
    return b.size() == 0;
  }
  bool solve(const MatX& B, MatX& X) override {
    X.resize(0, B.cols());
    return B.rows() == 0;
  }
  bool inverse_congruence(const SparseMatrix& B, MatX& G) override {
    G.setZero(B.cols(), B.cols());  // B^T A^{-1} B with no row
    return B.rows() == 0;
  }
};

}  // namespace softdiff::integrator
