#include <softdiff/integrator/implicit_euler.hpp>

#include <softdiff/core/assert.hpp>

#include <softdiff/contact/contact_step.hpp>
#include <softdiff/core/timer.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>

namespace softdiff {

namespace integrator {
namespace {



StepStatus inverted(const Model& model, const Data& data, long step_index) {
  (void)model;
  StepStatus s;
  s.code = StepStatus::Code::inverted_element;
  s.step = step_index;
  s.element = data.fem.bad_element;
  s.value = data.fem.bad_det;
  return s;
}

// r = -R(v) = M v_i + h (P + f) - (1 + h alpha) M v - h beta K_i v (per body), projected.
// Mvi = M v_i; data.Mv and data.Kv are scratch.
void newton_residual(const Model& model, Data& data, double h, const VecX& Mvi, const VecX& v, VecX& r) {
  const auto& fem = model.fem;
  fem::symmetric_multiply(fem, fem.mass_values, v, data.Mv);
  fem::symmetric_multiply(fem, data.K_i_values, v, data.Kv);
  for (const auto& b : fem.bodies) {
    const int begin = 3 * b.node_begin, len = 3 * b.num_nodes;
    r.segment(begin, len) = Mvi.segment(begin, len) +
                            h * (fem.gravity_force.segment(begin, len) + data.fem.f_int.segment(begin, len) +
                                 data.f_act.segment(begin, len)) -
                            (1 + h * b.rayleigh_mass) * data.Mv.segment(begin, len) -
                            h * b.rayleigh_stiffness * data.Kv.segment(begin, len);
  }
  project(model, r);
}

// ||Pi b|| (fixed dofs left out).
double projected_norm(const Model& model, const VecX& b) {
  double sum = 0;
  for (Eigen::Index k = 0; k < b.size(); ++k)
    if (!model.fem.fixed[static_cast<std::size_t>(k)]) sum += b[k] * b[k];
  return std::sqrt(sum);
}

// The incremental potential of the implicit Euler step, per body:
//   Phi(v) = 1/2 (1 + h alpha) v^T M v + h beta / 2 v^T K_i v - v^T M v_i + E(x_i + h v)
//            - h (P + f_act)^T v,
// whose gradient is R(v) = -r (newton_residual). Needs data.Mv, data.Kv of v (from
// newton_residual at v) and data.fem.energy at x_i + h v.
double incremental_potential(const Model& model, const Data& data, double h, const VecX& v) {
  const auto& fem = model.fem;
  double phi = data.fem.energy;
  for (const auto& b : fem.bodies) {
    const int begin = 3 * b.node_begin, len = 3 * b.num_nodes;
    const auto vb = v.segment(begin, len);
    phi += 0.5 * (1 + h * b.rayleigh_mass) * vb.dot(data.Mv.segment(begin, len)) +
           0.5 * h * b.rayleigh_stiffness * vb.dot(data.Kv.segment(begin, len)) -
           vb.dot(data.Mvi.segment(begin, len)) -
           h * vb.dot(fem.gravity_force.segment(begin, len) + data.f_act.segment(begin, len));
  }
  return phi;
}

}  // namespace

void project(const Model& model, VecX& b) {
  if (model.fem.num_fixed_dofs == 0) return;
  for (int k = 0; k < b.size(); ++k)
    if (model.fem.fixed[k]) b[k] = 0;
}

void assemble_system_matrix(const Model& model, double h, const VecX& K_damping, const VecX& K, Data& data) {
  assemble_system_matrix(model, h, K_damping, K, data.A);
  data.factor_is_current = false;
  data.A_h = h;
}

void assemble_system_matrix(const Model& model, double h, const VecX& K_damping, const VecX& K, SparseMatrix& matrix) {
  const auto& fem = model.fem;
  double* A = matrix.valuePtr();
  const double* M = fem.mass_values.data();
  for (const auto& b : fem.bodies) {
    const double cM = 1 + h * b.rayleigh_mass, cKd = h * b.rayleigh_stiffness, cK = h * h;
    if (&K_damping == &K) {
      const double c = cKd + cK;
      for (int k = b.value_begin; k < b.value_end; ++k) A[k] = cM * M[k] + c * K[k];
    } else {
      for (int k = b.value_begin; k < b.value_end; ++k) A[k] = cM * M[k] + cKd * K_damping[k] + cK * K[k];
    }
  }
  for (int k : fem.pattern.fixed_offdiagonal) A[k] = 0;
  for (int k : fem.pattern.fixed_diagonal) A[k] = 1;
}

StepStatus factorize(const Model& model, Data& data, long step_index) {
  (void)model;
  StepStatus s;
  if (!data.analyzed) {
    data.solver->analyze(data.A);
    data.analyzed = true;
  }
  const FactorStatus f = data.solver->factorize(data.A);
  ++data.factorizations;
  if (!f.ok) {
    s.code = StepStatus::Code::not_positive_definite;
    s.step = step_index;
    s.dof = f.column;
    s.detail = f.message;
    return s;
  }
  data.factor_is_current = true;
  return s;
}

StepStatus check_state(const Model& model, const State& state, long step_index) {
  StepStatus s;
  s.step = step_index;
  for (int k = 0; k < state.x.size(); ++k)
    if (!std::isfinite(state.x[k]) || !std::isfinite(state.v[k])) {
      s.code = StepStatus::Code::non_finite;
      s.dof = k;
      return s;
    }
  const auto& fem = model.fem;
  for (const auto& b : fem.bodies) {
    const double limit = model.step.divergence_factor * b.bbox_diagonal;
    for (int i = b.node_begin; i < b.node_begin + b.num_nodes; ++i) {
      const double d = (state.x.segment<3>(3 * i) - fem.X.col(i)).norm();
      if (d > limit) {
        s.code = StepStatus::Code::diverged;
        s.dof = 3 * i;
        s.value = d;
        return s;
      }
    }
  }
  double det = 0;
  const int e = fem::find_inverted_element(fem, state.x, &det);
  if (e >= 0) {
    s.code = StepStatus::Code::inverted_element;
    s.element = e;
    s.value = det;
  }
  return s;
}

StepStatus implicit_euler_step(const Model& model, Data& data, const State& in, State& out, long step_index,
                               const VecX* lambda_a) {
  data.h = model.step.dt;
  data.history_weight = 0;
  data.hat = in;
  return backward_euler_stage(model, data, in, out, step_index, lambda_a, model.step.dt, in.t + model.step.dt);
}

namespace {
StepStatus stage(const Model& model, Data& data, const State& in, State& out, long step_index, const VecX* lambda_a,
                 double h, double t_next);
}  // namespace

StepStatus backward_euler_stage(const Model& model, Data& data, const State& in, State& out, long step_index,
                                const VecX* lambda_a, double h, double t_next) {
  const StepStatus status = stage(model, data, in, out, step_index, lambda_a, h, t_next);
  // Factor reuse: the step after a failed one factorizes (linear_solver.hpp).
  if (!status.ok() && status.code != StepStatus::Code::not_converged) data.solver->refactorize_next();
  return status;
}

namespace {
StepStatus stage(const Model& model, Data& data, const State& in, State& out, long step_index, const VecX* lambda_a,
                 double h, double t_next) {
  const auto& fem = model.fem;
  data.timings = {};
  auto t0 = Clock::now();

  // 1. Linearization at x_i: f_int, K (the record the derivatives use). With a
  // constant system matrix (all bodies `linear`), K and the factor of A are kept
  // from the first step and f_int = -K (x_i - X).
  const bool reuse = model.constant_system_matrix() && data.factor_is_current && data.A_h == h;
  // Control's committed step after its prediction from the same x (data.hpp,
  // keep_linearization): K, f_int and the factor are already those of in.x.
  const bool same_linearization = !reuse && data.keep_linearization && model.step.newton_iterations == 1 &&
                                  data.factor_is_current && data.A_h == h && data.linearized_x.size() == in.x.size() &&
                                  data.linearized_x == in.x;
  if (reuse) {
    data.x_iter = in.x - Eigen::Map<const VecX>(fem.X.data(), 3 * fem.num_nodes);
    fem::symmetric_multiply(fem, data.fem.K_values, data.x_iter, data.fem.f_int);
    data.fem.f_int = -data.fem.f_int;
  } else if (!same_linearization) {
    if (!fem::evaluate(fem, in.x, {false, true, true}, data.fem)) return inverted(model, data, step_index);
    // 2. A = M + h D + h^2 K and b = h (P + f - D v_i) - h^2 K v_i, per body.
    assemble_system_matrix(model, h, data.fem.K_values, data.fem.K_values, data);
  }
  fem::symmetric_multiply(fem, fem.mass_values, in.v, data.Mv);
  fem::symmetric_multiply(fem, data.fem.K_values, in.v, data.Kv);
  for (const auto& b : fem.bodies) {
    const int begin = 3 * b.node_begin, len = 3 * b.num_nodes;
    const double alpha = b.rayleigh_mass, beta = b.rayleigh_stiffness;
    data.rhs.segment(begin, len) =
        h * (fem.gravity_force.segment(begin, len) + data.fem.f_int.segment(begin, len)) -
        (h * alpha) * data.Mv.segment(begin, len) - (h * beta + h * h) * data.Kv.segment(begin, len);
  }
  // Actuation: + h H_a(x_i)^T lambda_a, lambda_a at the end of the step (t_i + h).
  if (!model.actuation.empty()) {
    if (lambda_a) {
      SOFTDIFF_DEMAND(lambda_a->size() == data.lambda_a.size(),
                      "lambda_a: expected one value per actuator (" + std::to_string(data.lambda_a.size()) +
                          "), got " + std::to_string(lambda_a->size()));
      data.lambda_a = *lambda_a;
    } else {
      model.actuation.values(t_next, data.lambda_a);
    }
    data.f_act.setZero();
    model.actuation.add_forces(in.x, data.lambda_a, 1.0, data.f_act);
    data.rhs += h * data.f_act;
  }
  project(model, data.rhs);
  data.timings.assembly += seconds_since(t0);

  t0 = Clock::now();
  StepStatus status;
  if (!reuse && !same_linearization) {
    status = factorize(model, data, step_index);
    if (status.ok() && data.keep_linearization) data.linearized_x = in.x;
  }
  // Rigidified parts (integrator/rigidify.hpp): the Schur complement of the parts'
  // 6 m dofs on this step's factor (also when the factor is kept: T moves with x_i).
  const bool rigidified = !model.rigidify.empty();
  if (status.ok() && rigidified) status = prepare_rigidified(model, data, in.x, h, step_index);
  data.timings.factorization += seconds_since(t0);
  if (!status.ok()) return status;

  t0 = Clock::now();
  // data.dv holds the previous step's dv: with a kept factor (factor reuse) PCG starts
  // from it, the answer of a smooth trajectory's neighbour step.
  if (!(rigidified ? solve_rigidified(model, data, data.rhs, data.dv) : data.solver->solve_from(data.rhs, data.dv))) {
    status.step = step_index;
    const FactorStatus& f = data.solver->solve_factor_status();
    if (!f.ok) {
      // Factor reuse: PCG with the stale factor gave up and the factorization of this
      // step's A failed (linear_solver.hpp).
      status.code = StepStatus::Code::not_positive_definite;
      status.dof = f.column;
      status.detail = f.message;
      data.factor_is_current = false;
    } else {
      status.code = StepStatus::Code::solver_failed;
      status.detail = "iterative linear solver did not reach its tolerance";
    }
    return status;
  }
  out.v = in.v + data.dv;
  project(model, out.v);  // fixed dofs have v = 0
  data.timings.solve += seconds_since(t0);
  data.newton_iterations_used = 1;
  data.newton_residual = 0;

  // Contact (paper eq. 2): out.v = v_free on entry, v_f on return. With Newton this is
  // its first iteration; the contacts detected here stay for the whole step.
  if (model.contact.enabled) {
    // A moving plane (Obstacle::offset_schedule) at the step's end time: its gap
    // constraint n . x_{n+1} >= offset(t_{n+1}) is then exact (docs/method.md "Moving planes").
    data.contact.detector->set_time(t_next);
    status = contact::resolve_contacts(model, data, in, out.v, step_index, h);
    if (!status.ok()) return status;
  }

  // 3. Newton iterations on the nonlinear implicit Euler equations (optional).
  bool newton_converged = true;
  if (model.step.newton_iterations > 1) {
    t0 = Clock::now();
    data.K_i_values = data.fem.K_values;
    fem::symmetric_multiply(fem, fem.mass_values, in.v, data.Mvi);
    // Reference: ||R(0)|| = ||M v_i + h (P + f(x_i))|| (f(x_i) is still in data.fem).
    data.v_iter.setZero();
    newton_residual(model, data, h, data.Mvi, data.v_iter, data.rhs);
    // Rigidified parts: the residual of the reduced equations P^T R = 0, as nodal forces
    // (integrator/rigidify.hpp project_rigidified_residual), here and below.
    if (rigidified) project_rigidified_residual(model, data, data.rhs);
    const double r0 = data.rhs.norm();
    data.timings.other += seconds_since(t0);
    double r = 0, r_accepted = std::numeric_limits<double>::infinity();
    // Converged: ||R|| <= newton_tolerance max(||R(0)||, h ||P + f_act||, h ||f_int||)
    // (projected), or the last update was at most newton_tolerance relative to v (a
    // step criterion, as PETSc's SNES_CONVERGED_SNORM_RELATIVE). Near equilibrium
    // ||R(0)|| is small and ||R|| stops at its round-off floor, set by the forces that
    // cancel in R (f_int sums element forces much larger than their sum), not by R(0)
    // (docs/method.md).
    double load_scale = h * projected_norm(model, fem.gravity_force + data.f_act);
    if (rigidified) {  // the loads on the parts as the reduced step sees them (their resultant and moment)
      data.rigidify.f = fem.gravity_force + data.f_act;
      project(model, data.rigidify.f);
      project_rigidified_residual(model, data, data.rigidify.f);
      load_scale = h * data.rigidify.f.norm();
    }
    bool small_update = false;
    bool equations_converged_before = false;  // the previous accepted iterate's equations converged (with contact)
    newton_converged = false;
    // Contact (docs/method.md "Newton iterations with contact"): the contacts, H_c and
    // the gaps of the first iteration stay for the step. Every iteration k solves the
    // contact problem of its linearization, A_k dv = -R(v_k) + h H_c^T lambda with the
    // NCP on G_k = h H_c A_k^{-1} H_c^T and g_k = H_c (v_k + A_k^{-1}(-R(v_k))) + phi / h
    // (contact::solve_contact_problem), lambda the total force (not an increment).
    // contact_force = h H_c^T lambda of the last NCP (zero on fixed dofs: H_c is
    // projected). The residual is that of the equations with contact,
    // -R(v) + h H_c^T lambda, and the line search's merit is the incremental potential
    // less the work of the frozen contact forces, Phi(v) - (h H_c^T lambda) . v, whose
    // gradient is that residual: the Newton direction is a descent direction of it
    // (A_k positive definite), and Phi alone would reject the steps that contact forces
    // push uphill. The normal constraints H_n v + phi / h >= 0 are linear in v with H_c
    // fixed, so a halved step between two feasible iterates stays feasible.
    auto& cd = data.contact;
    const bool with_contact = model.contact.enabled && cd.contacts.size() > 0;
    VecX contact_force = VecX::Zero(with_contact ? out.v.size() : 0);
    if (with_contact) contact_force.noalias() = h * (cd.Ht * cd.lambda);
    if (with_contact && rigidified) project_rigidified_residual(model, data, contact_force);
    // ||f_int|| of the scale below, without the internal forces inside the parts.
    auto internal_norm = [&] {
      if (!rigidified) return projected_norm(model, data.fem.f_int);
      data.rigidify.f = data.fem.f_int;
      project(model, data.rigidify.f);
      project_rigidified_residual(model, data, data.rigidify.f);
      return data.rigidify.f.norm();
    };
    double phi_plain_accepted = 0;  // Phi(v_k) of the accepted iterate (without the contact work)
    // Line search: R is the gradient of the incremental potential Phi (see
    // incremental_potential). An iterate that inverts an element, or raises both Phi
    // and ||R||, is replaced by the one half as far from the previous iterate (at
    // most 30 halvings); undamped Newton cycles at large h without it. data.v_iter is
    // the previous accepted iterate (v = 0 before the first), data.dv the direction.
    double phi_accepted = std::numeric_limits<double>::infinity();
    double step = 1;
    int halvings = 0;
    data.dv = out.v;
    for (int it = 1;;) {
      t0 = Clock::now();
      data.x_iter = in.x + h * out.v;
      const bool valid = fem::evaluate(fem, data.x_iter, {true, true, true}, data.fem);
      double phi = std::numeric_limits<double>::infinity();
      r = std::numeric_limits<double>::infinity();
      double phi_plain = 0;
      if (valid) {
        newton_residual(model, data, h, data.Mvi, out.v, data.rhs);
        if (rigidified) project_rigidified_residual(model, data, data.rhs);
        phi_plain = incremental_potential(model, data, h, out.v);
        if (with_contact) {
          r = (data.rhs + contact_force).norm();
          phi = phi_plain - contact_force.dot(out.v);
        } else {
          r = data.rhs.norm();
          phi = phi_plain;
        }
      }
      data.timings.assembly += seconds_since(t0);
      const bool worse = !valid || !std::isfinite(r) ||
                         (phi > phi_accepted + 1e-12 * std::abs(phi_accepted) && r >= r_accepted);
      if (worse && halvings < 30) {
        step *= 0.5;
        ++halvings;
        out.v = data.v_iter + step * data.dv;
        project(model, out.v);
        continue;
      }
      if (!valid) return inverted(model, data, step_index);
      if (!(std::isfinite(r))) break;
      phi_accepted = phi;
      phi_plain_accepted = phi_plain;
      r_accepted = r;
      // With contact, a converged iterate is a full step: its velocity is the one the
      // last NCP's sigma = H_c v + phi / h belongs to (a halved step is not).
      const bool full_step = halvings == 0;
      step = 1;
      halvings = 0;
      // With contact the contact forces join the scale (as f_int: a resting body's
      // f_int balances its weight and the contact forces).
      const double scale = std::max({r0, load_scale, h * internal_norm(),
                                     with_contact ? contact_force.norm() : 0.0});
      const bool equations_converged = r <= model.step.newton_tolerance * scale || small_update;
      newton_converged = equations_converged;
      // With contact the last NCP must reach its tolerance too, unless it stalled twice
      // on the converged equations: the previous accepted iterate had converged already
      // and this iteration re-solved the same contact problem from that NCP's forces
      // (G_k, g_k change by Newton's converged update only), so more iterations repeat
      // it. The miss is then the NCP's own, reported as the linearized step reports it
      // (data.contact.result.converged false: the caller warns, --strict stops): e.g. a
      // rigid cube's redundant manifold on a soft slab (docs/method.md "Newton with rigid
      // contact"), where the linearized step's NCP stalls as well.
      if (with_contact)
        newton_converged = equations_converged && full_step && (cd.result.converged || equations_converged_before);
      equations_converged_before = equations_converged && full_step;
      if (newton_converged || it >= model.step.newton_iterations) {
        data.newton_iterations_used = it;
        break;
      }
      t0 = Clock::now();
      assemble_system_matrix(model, h, data.K_i_values, data.fem.K_values, data);
      data.timings.assembly += seconds_since(t0);
      t0 = Clock::now();
      status = factorize(model, data, step_index);
      // Rigidified parts: the Schur complement on this iteration's factor (T at x_i).
      if (status.ok() && rigidified) status = prepare_rigidified(model, data, in.x, h, step_index, &data.K_i_values);
      data.timings.factorization += seconds_since(t0);
      if (!status.ok()) return status;
      t0 = Clock::now();
      if (rigidified)
        solve_rigidified(model, data, data.rhs, data.dv);
      else
        data.solver->solve(data.rhs, data.dv);
      data.v_iter = out.v;
      out.v += data.dv;
      project(model, out.v);
      data.timings.solve += seconds_since(t0);
      if (with_contact) {
        // The free velocity v_k + dv_free -> the corrected v_{k+1}; the direction of the
        // line search is the whole update, and the accepted iterate's merit and
        // residual are re-evaluated with the new forces (the merit's frozen lambda).
        status = contact::solve_contact_problem(model, data, h, out.v, step_index);
        if (!status.ok()) return status;
        t0 = Clock::now();
        data.dv = out.v - data.v_iter;
        contact_force.noalias() = h * (cd.Ht * cd.lambda);
        if (rigidified) project_rigidified_residual(model, data, contact_force);
        phi_accepted = phi_plain_accepted - contact_force.dot(data.v_iter);
        r_accepted = (data.rhs + contact_force).norm();
        data.timings.other += seconds_since(t0);
      }
      small_update = data.dv.norm() <= model.step.newton_tolerance * out.v.norm();
      ++it;
    }
    data.newton_residual = r0 > 0 ? r / r0 : 0;
  }

  t0 = Clock::now();
  out.x = in.x + h * out.v;
  if (rigidified) place_rigidified(model, data, in, out, h);  // the parts' exact rigid motion
  out.t = t_next;
  status = check_state(model, out, step_index);
  data.timings.other += seconds_since(t0);
  if (status.ok() && !newton_converged) {
    status.code = StepStatus::Code::not_converged;
    status.step = step_index;
    status.iterations = data.newton_iterations_used;
    status.residual = data.newton_residual;
  }
  return status;
}
}  // namespace

}  // namespace integrator
}  // namespace softdiff
