#pragma once
// Factor reuse with rigidified parts (linear_solver.factor_reuse: pcg; docs/method.md
// "Rigidified parts", *Factor reuse*): conjugate gradients on the reduced system
// P^T A P (the step's own A, C_step, D_step: rigidify.hpp RigidifyData) preconditioned by
// the kept factorization's reduced inverse (its C, Y, S: one solve with the kept factor
// and products with the 3n x 6m columns per iteration). The step's solve
// (solve_rigidified) and its derivative's reduced solves (rigidify_derivatives.cpp) share
// it, each with its own workspace. Not in the precompiled header.
#include <softdiff/core/types.hpp>

namespace softdiff {
struct Model;
struct Data;
}  // namespace softdiff

namespace softdiff::integrator {

// The vectors one reduced PCG solve works in (sized by the caller: 3n for the _f ones
// and y, 6m for the _u ones); references into the owner's members.
struct ReducedPcgWork {
  VecX &r_f, &z_f, &p_f, &q_f;  // (3n) residual, preconditioned residual, direction, A p: soft rows
  VecX &r_u, &z_u, &p_u, &q_u;  // (6m) the same, the parts' rows
  VecX& y;                      // (3n) the preconditioner's solve with the kept factor
};

// P^T A P (f, u) = (b_f, g) in reduced coordinates: b_f the soft dofs' rows of the
// right-hand side (zero on the rigidified and fixed dofs), g = T^T b_r (plus any extra
// reduced right-hand side); f the soft dofs' velocities, u (v_p, omega) per part. From
// (f, u) on entry when `guess`, else from zero. Stops at ||residual|| <= pcg_tolerance
// ||(b_f, g)|| (the true residual, recomputed when the recurrence says so). Counts the
// solve in the linear solver's counters (count_outside_pcg: more than
// refactor_iterations iterations make the next step factorize). Returns the iterations,
// or -1 if not converged after pcg_max_iterations or p^T A p <= 0 (the caller falls back).
// Demands data.rigidify.reduced_pcg (a kept factor, prepare_rigidified's C_step, D_step).
int reduced_pcg(const Model& model, const Data& data, const VecX& b_f, const VecX& g, VecX& f, VecX& u, bool guess,
                const ReducedPcgWork& work);

}  // namespace softdiff::integrator
