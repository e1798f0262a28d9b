#include <softdiff/integrator/static_solver.hpp>

#include <softdiff/integrator/implicit_euler.hpp>

#include <algorithm>
#include <softdiff/core/assert.hpp>
#include <softdiff/core/timer.hpp>

#include <chrono>
#include <cmath>

namespace softdiff::integrator {
namespace {

// Tangent regularization (see the Newton loop): the first shift relative to the
// largest diagonal entry of K on the free dofs, and the number of times it may grow
// tenfold (1e-3 * 10^16: far beyond any diagonal).
constexpr double kShiftMin = 1e-3;
constexpr int kMaxShifts = 16;

StepStatus not_converged(long load_step, int iterations, double residual, const char* detail) {
  StepStatus status;
  status.code = StepStatus::Code::not_converged;
  status.step = load_step;
  status.iterations = iterations;
  status.residual = residual;
  status.detail = detail;
  return status;
}

}  // namespace

StepStatus solve_static(const Model& model, Data& data, const State& in, State& out,
                        const LoadStepCallback& on_load_step) {
  const auto& fem = model.fem;
  const auto& settings = model.step;
  const int L = std::max(1, settings.static_load_steps);
  out = in;
  out.v.setZero();
  data.timings = {};
  VecX& residual = data.rhs;
  VecX& dx = data.dv;
  VecX& trial = data.x_iter;
  VecX load_full = fem.gravity_force;
  project(model, load_full);
  const double load_norm = load_full.norm();
  StepStatus status;
  int total_iterations = 0;
  // Actuators: H_a(x)^T lambda_a joins the residual, and the cables' stiffness
  // lambda d^2L/dx^2 = -d(H_a^T lambda)/dx joins the tangent (exact, symmetric
  // positive semi-definite; its blocks are in the pattern: stiffness cliques). Cavities
  // and servos keep their derivative out of the tangent (ActuationModel::add_stiffness):
  // exact Newton for cables and translation servos, modified Newton otherwise. The
  // line search is on the residual norm (no potential for follower loads).
  const bool actuated = !model.actuation.empty();
  // Cables, closed cavities and translation servos derive from a potential: the line
  // search then works on the total potential energy; otherwise on the residual norm.
  const bool conservative = model.actuation.conservative();
  SOFTDIFF_DEMAND(!actuated || model.actuation.stiffness_fits(fem.pattern),
                  "the FEM pattern lacks the actuators' stiffness cliques: build it with "
                  "build_fem_model(..., model.actuation.stiffness_cliques())");
  bool constant_values = true;
  for (const auto& a : model.actuation.actuators) constant_values = constant_values && a.value.points.empty();
  double shift = 0;  // the last diagonal shift of the tangent (0: the exact tangent)
  data.static_shifted_iterations = 0;
  double size_scale = 0;
  for (const auto& b : fem.bodies) size_scale = std::max(size_scale, b.bbox_diagonal);

  for (long s = 1; s <= L; ++s) {
    const double factor = static_cast<double>(s) / L;
    double rel = 0;
    int it = 0;
    for (;; ++it) {
      auto t0 = Clock::now();
      if (!fem::evaluate(fem, out.x, {true, true, true}, data.fem)) {
        status.code = StepStatus::Code::inverted_element;
        status.step = s;
        status.element = data.fem.bad_element;
        status.value = data.fem.bad_det;
        return status;
      }
      // Scale of the residual: the applied load, or the internal forces including
      // the reactions at fixed dofs (displacement-driven problems have no load).
      residual = data.fem.f_int + factor * fem.gravity_force;
      if (actuated) {
        model.actuation.values(factor, data.lambda_a);
        if (constant_values) data.lambda_a *= factor;
        data.f_act.setZero();
        model.actuation.add_forces(out.x, data.lambda_a, 1.0, data.f_act);
        residual += data.f_act;
      }
      const double reference =
          std::max({factor * load_norm, data.fem.f_int.norm(), actuated ? data.f_act.norm() : 0.0});
      project(model, residual);
      rel = reference > 0 ? residual.norm() / reference : 0.0;
      data.timings.assembly += seconds_since(t0);
      if (!std::isfinite(rel)) {
        status.code = StepStatus::Code::non_finite;
        status.step = s;
        return status;
      }
      if (rel <= settings.static_tolerance) break;
      if (it >= settings.static_max_iterations)
        return not_converged(s, it, rel, "static equilibrium not reached (increase static.max_iterations or static.load_steps)");
      // A dx = f + P + H_a^T lambda, A = K + sum_cables lambda d^2L/dx^2 (K = d^2E/dx^2;
      // projected). M and damping play no part.
      // The exact tangent first; where it is not positive definite (compression past
      // the point where an element's Hessian turns indefinite, on the way to a stable
      // equilibrium), the shifted tangent A + tau I on the free dofs (Nocedal and
      // Wright, "Cholesky with added multiple of the identity"): tau from
      // max(kShiftMin * max diag A, tau of the previous iteration / 10), times 10
      // until the factorization succeeds. dx is then a descent direction of Pi and the
      // line search below applies; once A is positive definite again the exact
      // Newton step (quadratic convergence) is back.
      bool shifted = false;
      for (int attempt = 0;; ++attempt) {
        t0 = Clock::now();
        double* A = data.A.valuePtr();
        for (long k = 0; k < data.A.nonZeros(); ++k) A[k] = data.fem.K_values[k];
        if (actuated) model.actuation.add_stiffness(out.x, data.lambda_a, fem.pattern, A);
        for (int k : fem.pattern.fixed_offdiagonal) A[k] = 0;
        for (int k : fem.pattern.fixed_diagonal) A[k] = 1;
        if (shifted)
          for (int d = 0; d < static_cast<int>(fem.pattern.diagonal.size()); ++d)
            if (!fem.fixed[d]) A[fem.pattern.diagonal[d]] += shift;
        data.timings.assembly += seconds_since(t0);
        t0 = Clock::now();
        status = factorize(model, data, s);
        data.timings.factorization += seconds_since(t0);
        if (status.ok()) break;
        if (status.code != StepStatus::Code::not_positive_definite || attempt >= kMaxShifts) return status;
        if (!shifted) {
          double diag_max = 0;
          for (int d = 0; d < static_cast<int>(fem.pattern.diagonal.size()); ++d)
            if (!fem.fixed[d]) diag_max = std::max(diag_max, std::abs(data.fem.K_values[fem.pattern.diagonal[d]]));
          shift = std::max(kShiftMin * diag_max, shift / 10);
          shifted = true;
        } else {
          shift *= 10;
        }
      }
      if (shifted) ++data.static_shifted_iterations;
      else shift = 0;
      t0 = Clock::now();
      data.solver->solve(residual, dx);
      project(model, dx);
      data.timings.solve += seconds_since(t0);
      // Stagnation at round-off: the residual of f_int + P cannot drop below ~eps
      // times the element forces that cancel in it; once the Newton correction is
      // below 1e-13 of the model's size, the equilibrium is as exact as doubles allow.
      // (Not with a shifted tangent: its step is not Newton's and may be small far from
      // the equilibrium.)
      if (!shifted && dx.cwiseAbs().maxCoeff() <= 1e-13 * size_scale) {
        out.x += dx;
        break;
      }

      // Backtracking (Armijo) on Pi(x) = E(x) - factor P.x along dx, a descent
      // direction when K is positive definite: dPi/dalpha = -(f + P).dx < 0. With
      // actuators: backtracking on the residual norm.
      t0 = Clock::now();
      const double pi0 = data.fem.energy - factor * fem.gravity_force.dot(out.x) +
                         (actuated && conservative ? model.actuation.potential(out.x, data.lambda_a) : 0.0);
      const double slope = -residual.dot(dx);
      const double r0 = residual.norm();
      double alpha = 1;
      bool accepted = false;
      for (int ls = 0; ls < 40; ++ls, alpha *= 0.5) {
        trial = out.x + alpha * dx;
        if (!actuated || conservative) {
          if (!fem::evaluate(fem, trial, {true, false, false}, data.fem)) continue;  // inverted: shorter step
          const double pi = data.fem.energy - factor * fem.gravity_force.dot(trial) +
                            (actuated ? model.actuation.potential(trial, data.lambda_a) : 0.0);
          if (pi <= pi0 + 1e-4 * alpha * slope || std::abs(pi - pi0) <= 1e-14 * std::abs(pi0)) {
            accepted = true;
            break;
          }
        } else {
          if (!fem::evaluate(fem, trial, {false, true, false}, data.fem)) continue;
          data.Kv = data.fem.f_int + factor * fem.gravity_force;
          model.actuation.add_forces(trial, data.lambda_a, 1.0, data.Kv);
          project(model, data.Kv);
          const double r = data.Kv.norm();
          if (r <= (1 - 1e-4 * alpha) * r0) {
            accepted = true;
            break;
          }
        }
      }
      data.timings.other += seconds_since(t0);
      if (!accepted)
        return not_converged(s, it, rel,
                             actuated && !conservative ? "line search found no decrease of the residual norm"
                                      : "line search found no decrease of the potential energy");
      out.x = trial;
      ++total_iterations;
    }
    out.t = factor;
    status = check_state(model, out, s);
    if (!status.ok()) return status;
    status.iterations = total_iterations;
    status.residual = rel;
    data.newton_iterations_used = total_iterations;
    data.newton_residual = rel;
    if (on_load_step) on_load_step(s, out);
  }
  return status;
}

}  // namespace softdiff::integrator
