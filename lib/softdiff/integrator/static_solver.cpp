#include <softdiff/integrator/static_solver.hpp>

#include <softdiff/contact/contact_step.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/rigidify.hpp>
#include <softdiff/integrator/static_rigid.hpp>

#include <algorithm>
#include <softdiff/core/assert.hpp>
#include <softdiff/core/timer.hpp>

#include <chrono>
#include <cmath>
#include <limits>

namespace softdiff::integrator {
namespace {

// Tangent regularization (see the Newton loop): the first shift relative to the
// largest diagonal entry of K on the free dofs, and the number of times it may grow
// tenfold (1e-3 * 10^16: far beyond any diagonal).
constexpr double kShiftMin = 1e-3;
constexpr int kMaxShifts = 16;
// Contact: a body without fixed dofs is held by its contacts alone, and its K has the
// rigid motions in its null space. Its free dofs get the proximal term tau_p I with
// tau_p = kProximal max_i |K_ii| over the body's free dofs (docs/method.md "Static
// equilibrium"): small enough that its elastic modes converge at a rate ~ tau_p /
// lambda_min per Newton iteration, large enough for a Cholesky factorization
// (condition ~ 1 / kProximal).
constexpr double kProximal = 1e-8;

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
  // A scene of rigid bodies only: no soft stage (static_rigid.hpp).
  if (model.fem.num_nodes == 0) return solve_static_rigid_only(model, data, in, out, on_load_step);
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
  // Rotation servos (follower torques, no potential): the line search works on the
  // potential of the rest with the servos' forces frozen at x_k, Pi_k(x) = E(x) - P.x +
  // U_cons(x) - f_rot(x_k).x (docs/method.md "Static equilibrium with rotation servos").
  // Its gradient at x_k is minus the full residual, and the tangent (without the servos'
  // derivative) is its Hessian, so the step is a descent direction of Pi_k. Open
  // pressure faces keep the residual-norm search.
  bool frozen_followers = actuated && !conservative;
  VecX lambda_conservative, follower_force;
  for (const auto& a : model.actuation.actuators)
    if (const auto* cavity = std::get_if<actuation::Cavity>(&a.kind); cavity && !cavity->closed()) frozen_followers = false;
  bool constant_values = true;
  for (const auto& a : model.actuation.actuators) constant_values = constant_values && a.value.points.empty();
  double shift = 0;  // the last diagonal shift of the tangent (0: the exact tangent)
  data.static_shifted_iterations = 0;
  double size_scale = 0;
  for (const auto& b : fem.bodies) size_scale = std::max(size_scale, b.bbox_diagonal);
  // Rigid bodies (static_rigid.hpp): their pose increments join each iteration's contact
  // solve, with the proximal factor k_rigid; the rigid equations join the convergence test.
  const bool with_rigid = !model.rigid.empty();
  SOFTDIFF_DEMAND(!with_rigid || model.contact.with_rigid() ||
                      std::all_of(model.rigid.begin(), model.rigid.end(),
                                  [](const auto& b) { return b.joint.kind == rigid::Joint::Kind::fixed; }),
                  "solve_static: rigid bodies with dofs need contact (the scene reader refuses the rest)");
  const double k_first = with_rigid ? static_rigid_stiffness(model, size_scale, true) : 0.0;
  const double k_rigid = with_rigid ? static_rigid_stiffness(model, size_scale, false) : 0.0;
  // Rigidified parts (static_rigid.hpp, rigidify.hpp): the reduced Newton P^T R(P u) = 0;
  // residuals projected on the parts' rigid motions, increments by the reduced solve,
  // the parts' nodes placed exactly.
  const bool rigidified = !model.rigidify.empty();
  double rigid_rel = 0;
  std::string rigid_worst;
  // Contact (docs/method.md "Static equilibrium"): per Newton iteration, the NCP of the
  // linearized problem at x_k with the same contact stage as the dynamic step, h = 1:
  // G = H K^{-1} H^T, g = H dx_free + phi, dx = dx_free + K^{-1} H^T lambda. lambda is
  // the total contact force (not an increment); the residual that decides convergence
  // is f_int + P + f_act + H_c^T lambda with the last NCP's H_c and lambda.
  const bool with_contact = model.contact.enabled;
  auto& cd = data.contact;
  // Bodies held by contact alone (no fixed dof): their diagonal offsets and free dofs.
  std::vector<std::vector<int>> proximal_dofs;
  if (with_contact)
    for (const auto& b : fem.bodies) {
      bool any_fixed = false;
      for (int d = 3 * b.node_begin; d < 3 * (b.node_begin + b.num_nodes); ++d) any_fixed = any_fixed || fem.fixed[d];
      if (any_fixed) continue;
      proximal_dofs.emplace_back();
      for (int d = 3 * b.node_begin; d < 3 * (b.node_begin + b.num_nodes); ++d) proximal_dofs.back().push_back(d);
    }
  double proximal = kProximal;  // the proximal factor of the last iteration (grown where K + tau_p I is indefinite)
  VecX dx_previous = VecX::Zero(3L * fem.num_nodes);  // the last corrected increment (widens the margin)
  VecX contact_force = VecX::Zero(with_contact ? 3L * fem.num_nodes : 0);  // H_c^T lambda of the last NCP
  bool contact_solved = false;  // an NCP was solved in this load step
  if (with_contact) contact::clear_contact_record(cd);
  const SlipOffsetGuard slip_guard{cd};  // static.friction load_step's offsets are this solve's
  // Parts (rigidify.hpp prepare_rigidified, h = 1: its coupling values are K's, read from
  // data.fem.K_values): with cables, a diagonal shift or a body held by contact alone,
  // K_values holds K + the cables' stiffness + shift (free dofs) + tau_p (the held bodies'
  // dofs) while the coupling is read, K again afterwards (k_saved: one buffer, sized
  // once). The coupling is then A's own (since rstp; before, the cables' blocks on a
  // part's dofs were left out: modified Newton for a cable through a part).
  VecX k_saved;
  auto prepare_parts = [&](const VecX& x, long load_step, double diagonal_shift) {
    const bool modified = actuated || diagonal_shift != 0 || !proximal_dofs.empty();
    if (modified) {
      k_saved = data.fem.K_values;
      double* K = data.fem.K_values.data();
      if (actuated) model.actuation.add_stiffness(x, data.lambda_a, fem.pattern, K);
      if (diagonal_shift != 0)
        for (int d = 0; d < static_cast<int>(fem.pattern.diagonal.size()); ++d)
          if (!fem.fixed[d]) K[fem.pattern.diagonal[d]] += diagonal_shift;
      for (const auto& dofs : proximal_dofs) {
        double diag_max = 0;
        for (int d : dofs) diag_max = std::max(diag_max, std::abs(k_saved[fem.pattern.diagonal[d]]));
        for (int d : dofs) K[fem.pattern.diagonal[d]] += proximal * diag_max;
      }
    }
    const StepStatus st = prepare_rigidified(model, data, x, 1.0, load_step);
    if (modified) data.fem.K_values.swap(k_saved);
    return st;
  };

  for (long s = 1; s <= L; ++s) {
    const double factor = static_cast<double>(s) / L;
    // The load step's start: x, the rigid poses and their surface points (static.friction
    // load_step measures each contact's slip from there: static_rigid.hpp static_slip_offset).
    record_load_step_start(model, data, out.x, out.rigid);
    // A moving plane at this load step's time (the actuators' schedules are read at
    // `factor` as well): docs/method.md "Moving planes".
    if (with_contact) cd.detector->set_time(factor);
    double rel = 0;
    int it = 0;
    contact_solved = false;
    double dx_norm_previous = std::numeric_limits<double>::infinity();  // the answer criterion's |dx_{k-1}|
    // Each load step starts with the proximal factor kShiftMin (divided by 10 per
    // iteration down to kProximal): the first free increment carries the whole
    // unbalanced load of a body held by contact, and its rigid part R / tau_p enters g;
    // the NCP's accuracy on sigma is relative to |g|, so a small first tau_p would cost
    // slip (the contacts stick to what that accuracy allows, ~1e-5 m on a 0.1 m cube
    // with 1e-8 from the start).
    proximal = kShiftMin * 10;
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
      // With contact: the last NCP's forces H_c^T lambda (projected already).
      if (with_contact) residual += contact_force;
      // With parts: ||f_int|| without the internal forces inside them (they do no work on
      // the parts' rigid motions), as the dynamic Newton's scale.
      double internal_norm = data.fem.f_int.norm();
      if (rigidified) {
        rigidified_static_pose(model, data, out.x);
        data.rigidify.f = data.fem.f_int;
        project(model, data.rigidify.f);
        project_rigidified_residual(model, data, data.rigidify.f);
        internal_norm = data.rigidify.f.norm();
      }
      const double reference = std::max({factor * load_norm, internal_norm, actuated ? data.f_act.norm() : 0.0,
                                         with_contact ? contact_force.norm() : 0.0});
      project(model, residual);
      if (rigidified) project_rigidified_residual(model, data, residual);
      rel = reference > 0 ? residual.norm() / reference : 0.0;
      // Rigid bodies: T^T (w_r + H_r^T lambda) relative to the weight (static_rigid.hpp).
      if (with_rigid) {
        rigid_rel = static_rigid_residual(model, data, out.rigid, factor, with_contact && contact_solved, &rigid_worst);
        rel = std::max(rel, rigid_rel);
      }
      data.timings.assembly += seconds_since(t0);
      if (!std::isfinite(rel)) {
        status.code = StepStatus::Code::non_finite;
        status.step = s;
        return status;
      }
      // With contact, an equilibrium also needs this load step's contact forces, from
      // an NCP solved to its tolerance.
      const bool contact_ok = !with_contact || (contact_solved && cd.result.converged);
      if (rel <= settings.static_tolerance && contact_ok) break;
      if (it >= settings.static_max_iterations && with_rigid && rigid_rel >= rel) {
        StepStatus ns = not_converged(s, it, rel, "");
        ns.detail = "static equilibrium not reached: rigid body '" + rigid_worst +
                    "' is out of balance (increase static.max_iterations or static.load_steps)";
        return ns;
      }
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
      bool proximal_grown = false;  // the proximal factor had to grow (counted as shifted)
      proximal = std::max(kProximal, proximal / 10);
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
        for (const auto& dofs : proximal_dofs) {
          double diag_max = 0;
          for (int d : dofs) diag_max = std::max(diag_max, std::abs(data.fem.K_values[fem.pattern.diagonal[d]]));
          for (int d : dofs) A[fem.pattern.diagonal[d]] += proximal * diag_max;
        }
        data.timings.assembly += seconds_since(t0);
        t0 = Clock::now();
        status = factorize(model, data, s);
        // Parts: the Schur complement of their 6 m dofs on this factor. On a body held by
        // contact alone (2026-12-04, rstp) the proximal term of its free dofs, the parts'
        // too, enters their coupling (as the diagonal shift does): S = P^T (K + tau_p E) P
        // on the parts, otherwise S lacks it on the body's rigid motions and is indefinite
        // under stress (the static solve stopped with "not positive definite"). S not
        // positive definite grows the proximal factor or the shift as A's factorization does.
        if (status.ok() && rigidified) status = prepare_parts(out.x, s, shifted ? shift : 0.0);
        data.timings.factorization += seconds_since(t0);
        if (status.ok()) break;
        if (status.code != StepStatus::Code::not_positive_definite || attempt >= kMaxShifts) return status;
        // A body held by contact alone: under stress its K is indefinite along some
        // rigid rotations (the geometric stiffness of the prestress), which the contacts
        // constrain. The proximal factor grows tenfold first (on that body only, the
        // smallest that factorizes), the global shift only beyond kShiftMin.
        if (!proximal_dofs.empty() && proximal < kShiftMin) {
          proximal *= 10;
          proximal_grown = true;
          continue;
        }
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
      if (shifted || proximal_grown) ++data.static_shifted_iterations;
      else shift = 0;
      t0 = Clock::now();
      double rigid_moved = 0;  // the rigid bodies' largest vertex move in this iteration (static_rigid.hpp)
      // Without contact forces in the free solve: the NCP's lambda is the total force.
      if (with_contact) residual -= contact_force;
      if (rigidified ? !solve_rigidified(model, data, residual, dx) : !data.solver->solve(residual, dx)) {
        status.code = StepStatus::Code::solver_failed;
        status.step = s;
        status.detail = "the linear solver failed on the static Newton increment";
        return status;
      }
      project(model, dx);
      data.timings.solve += seconds_since(t0);
      if (with_contact) {
        // Rigid bodies: their free increments and compliances for this solve.
        if (with_rigid) begin_static_rigid(model, data, out.rigid, it == 0 ? k_first : k_rigid, factor);
        // The contact stage with h = 1: dx <- dx_free + K^{-1} H_c^T lambda.
        // static.friction load_step (docs/method.md "Static equilibrium with contact",
        // *Load-step-anchored friction*): after detection, the NCP's tangential rows offset
        // by each contact's slip since the load step's start (static_slip_offset); iterate:
        // no offset (resolve_contacts as before).
        contact::detect_contacts(model, data, out.x, dx_previous, 1.0, dx, false);
        static_slip_offset(model, data, out.x);
        const StepStatus cs = contact::solve_contact_problem(model, data, 1.0, dx, s);
        if (!cs.ok()) return cs;
        // No contact detected: no NCP ran; the joint limits' own LCPs (static_rigid.hpp).
        if (with_rigid && cd.contacts.size() == 0) static_limits_without_contact(model, data);
        // The rigid poses move by their corrected increments; a body that no contact
        // holds moves by ~10 x the scene's size (its free increment): no support.
        if (with_rigid) {
          const int unsupported = static_rigid_unsupported(model, data);
          if (unsupported >= 0) {
            StepStatus ns = not_converged(s, it, rel, "");
            ns.detail = "rigid body '" + model.rigid[static_cast<std::size_t>(unsupported)].name +
                        "' touches no support within contact.margin: no equilibrium under its load (rest it on a "
                        "soft body, an obstacle or another body, or fix its joint)";
            return ns;
          }
          int rigid_body = -1;
          const StepStatus rs = end_static_rigid(model, data, out.rigid, s, rigid_moved, rigid_body);
          if (!rs.ok()) return rs;
          if (!(rigid_moved <= size_scale)) {
            StepStatus ns = not_converged(s, it, rel, "");
            ns.detail = "rigid body '" + model.rigid[static_cast<std::size_t>(rigid_body)].name +
                        "' moved by more than the scene's size in one Newton iteration: its contacts do not hold it (it "
                        "rests on no support within contact.margin, or the load exceeds what friction holds: no "
                        "equilibrium)";
            return ns;
          }
        }
        contact_solved = true;
        // (No contact detected: no force; cd.Ht may be unsized, never built in this run.)
        if (cd.contacts.size() > 0)
          contact_force.noalias() = cd.Ht * cd.lambda;
        else
          contact_force.setZero();
        if (rigidified) project_rigidified_residual(model, data, contact_force);
        // A body held by contact alone moves rigidly (by its weight over tau_p) unless a
        // contact stops it: a move beyond the scene's size means it rests on nothing.
        const double moved = dx.cwiseAbs().maxCoeff();
        if (!proximal_dofs.empty() && !(moved <= size_scale))
          return not_converged(s, it, rel,
                               "a body without fixed nodes moved by more than the scene's size in one Newton iteration: "
                               "its contacts do not hold it (it rests on no support within contact.margin, or the load "
                               "exceeds what friction holds: no equilibrium)");
        dx_previous = dx;
      }
      // The answer criterion (static.convergence: answer; method.md "Static
      // equilibrium"): stop where the answer stops changing. With rho = |dx_k| /
      // |dx_{k-1}| (max norms, Newton directions) the observed contraction, the change
      // of the answer still to come after x_k + dx_k is at most |dx_k| rho / (1 - rho)
      // for linear convergence at rate rho (Newton's quadratic convergence makes it
      // far smaller). Accept x_k + dx_k (without a line search) when that bound is
      // below displacement_tolerance of the displacement from the start of the solve
      // and the residual at x_k below residual_tolerance of its reference. Not with a
      // shifted tangent (not Newton's step) or an NCP that missed its tolerance.
      {
        const double dx_norm = dx.cwiseAbs().maxCoeff();
        const double rho = dx_norm / dx_norm_previous;
        dx_norm_previous = shifted ? std::numeric_limits<double>::infinity() : dx_norm;
        if (settings.static_displacement_tolerance > 0 && !shifted && (!with_contact || cd.result.converged) &&
            rel <= settings.static_residual_tolerance && rho < 1 && rigid_moved <= 1e-13 * size_scale) {
          trial = out.x + dx - in.x;
          if (dx_norm * rho / (1 - rho) <= settings.static_displacement_tolerance * trial.cwiseAbs().maxCoeff()) {
            if (rigidified) {
              place_rigidified_static(model, data, out.x, dx, 1.0, trial);
              out.x = trial;
            } else {
              out.x += dx;
            }
            ++total_iterations;
            break;
          }
        }
      }
      // Stagnation at round-off: the residual of f_int + P cannot drop below ~eps
      // times the element forces that cancel in it; once the Newton correction is
      // below 1e-13 of the model's size, the equilibrium is as exact as doubles allow.
      // (Not with a shifted tangent: its step is not Newton's and may be small far from
      // the equilibrium.)
      if (!shifted && (!with_contact || cd.result.converged) && dx.cwiseAbs().maxCoeff() <= 1e-13 * size_scale &&
          rigid_moved <= 1e-13 * size_scale) {
        if (rigidified) {
          place_rigidified_static(model, data, out.x, dx, 1.0, trial);
          out.x = trial;
        } else {
          out.x += dx;
        }
        break;
      }

      // Backtracking (Armijo) on Pi(x) = E(x) - factor P.x along dx, a descent
      // direction when K is positive definite: dPi/dalpha = -(f + P).dx < 0. With
      // actuators: backtracking on the residual norm.
      t0 = Clock::now();
      const double load_work = factor * fem.gravity_force.dot(out.x);
      // Frozen followers: lambda of the conservative actuators (rotation servos zeroed)
      // and the rotation servos' forces at x_k.
      if (frozen_followers) {
        lambda_conservative = data.lambda_a;
        follower_force.setZero(out.x.size());
        for (std::size_t a = 0; a < model.actuation.actuators.size(); ++a) {
          const auto& act = model.actuation.actuators[a];
          const auto* servo = std::get_if<actuation::Servo>(&act.kind);
          if (!servo || !servo->is_rotation()) continue;
          const double l = data.lambda_a[static_cast<Eigen::Index>(a)];
          if (l != 0) act.add_force(out.x, l, 1.0, follower_force);
          lambda_conservative[static_cast<Eigen::Index>(a)] = 0;
        }
      }
      const double actuation_potential =
          actuated && conservative ? model.actuation.potential(out.x, data.lambda_a)
          : frozen_followers       ? model.actuation.potential(out.x, lambda_conservative) - follower_force.dot(out.x)
                                   : 0.0;
      const double pi0 = data.fem.energy - load_work + actuation_potential;
      // The round-off of Pi is that of its terms, not of their sum: near an equilibrium
      // the strain energy and the load's work nearly cancel (the quadratic beam of
      // configs/beam_cantilever_p2.yaml at load step 3: E 5.4e-3, P.x 4.8e-3, Pi 6.6e-4),
      // and a Newton step whose exact decrease is below that round-off (1e-18 there) reads
      // as an increase of 3e-17 to 9e-17, which a tolerance relative to Pi (7e-18) took
      // for a failure: the search then halved the step down to 1e-7 and Newton stalled at
      // a relative residual of 1e-8 (seen with OpenBLAS's Haswell kernels).
      const double pi_roundoff = 1e-14 * (std::abs(data.fem.energy) + std::abs(load_work) + std::abs(actuation_potential));
      const double slope = -residual.dot(dx);
      const double r0 = residual.norm();
      double alpha = 1;
      bool accepted = false;
      for (int ls = 0; ls < 40; ++ls, alpha *= 0.5) {
        if (rigidified)
          place_rigidified_static(model, data, out.x, dx, alpha, trial);
        else
          trial = out.x + alpha * dx;
        if (with_contact) {
          // Contact forces have no potential (friction): the full step, shortened only
          // where it inverts an element (x_k and x_k + dx both satisfy the linearized
          // contact constraints, so every point between does).
          if (!fem::evaluate(fem, trial, {true, false, false}, data.fem)) continue;
          accepted = true;
          break;
        }
        if (!actuated || conservative || frozen_followers) {
          if (!fem::evaluate(fem, trial, {true, false, false}, data.fem)) continue;  // inverted: shorter step
          const double pi =
              data.fem.energy - factor * fem.gravity_force.dot(trial) +
              (!actuated ? 0.0
               : frozen_followers
                   ? model.actuation.potential(trial, lambda_conservative) - follower_force.dot(trial)
                   : model.actuation.potential(trial, data.lambda_a));
          if (pi <= pi0 + 1e-4 * alpha * slope || std::abs(pi - pi0) <= pi_roundoff) {
            accepted = true;
            break;
          }
        } else {
          if (!fem::evaluate(fem, trial, {false, true, false}, data.fem)) continue;
          data.Kv = data.fem.f_int + factor * fem.gravity_force;
          model.actuation.add_forces(trial, data.lambda_a, 1.0, data.Kv);
          project(model, data.Kv);
          if (rigidified) project_rigidified_residual(model, data, data.Kv);  // as the residual r0
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
                             actuated && !conservative && !frozen_followers
                                 ? "line search found no decrease of the residual norm"
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
