// Derivatives of the implicit Euler step: see implicit_euler_derivatives.hpp.
#include <softdiff/integrator/implicit_euler_derivatives.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/fem_derivatives.hpp>
#include <softdiff/integrator/empty_system.hpp>
#include <softdiff/integrator/implicit_euler.hpp>

#include <string>

namespace softdiff::integrator {

namespace {

void demand_supported(const Model& model) {
  SOFTDIFF_DEMAND(model.step.integrator == IntegratorKind::implicit_euler || model.step.integrator == IntegratorKind::bdf2,
                  "step derivatives: only the implicit_euler and bdf2 integrators are differentiated in this version");
  if (model.step.newton_iterations > 1)
    for (const auto& b : model.fem.bodies)
      SOFTDIFF_DEMAND(!b.psd_projection, "step derivatives: newton_iterations > 1 with psd_projection (body '" +
                                             b.name + "') is not differentiated in this version");
}

// A scene of rigid bodies only (fem.num_nodes == 0) has no soft stage: its step is linear
// in the contact impulse whatever newton_iterations says (bdf2.cpp time_step_rigid_only).
bool is_newton(const Model& model) { return model.step.newton_iterations > 1 && model.fem.num_nodes > 0; }

// Rigidified parts: what rigidify_derivatives.hpp covers (the rest is issue 21).
void demand_parts_supported(const Model& model) {
  const std::string part = model.rigidify.parts.front().name;
  // BDF2: the stage from the extrapolated state (the record's hat) is this step; the
  // extrapolation's derivative is multistep_jvp / multistep_vjp's (rigidify_bdf2_derivatives.hpp).
  // Newton (newton_iterations > 1): the implicit function theorem on the converged
  // reduced equations, A_f's own Schur complement (RigidifiedStepDerivative::prepare_newton),
  // with contact the reduced Delassus rows at A_f (prepare_contact).
  SOFTDIFF_DEMAND(model.step.integrator == IntegratorKind::implicit_euler || model.step.integrator == IntegratorKind::bdf2,
                  "step derivatives with rigidified parts (" + part + "): implicit_euler or bdf2 only (issue 21)");
  // In contact: the dense record's G (it holds the parts' rank-6m term, and with rigid
  // bodies in contact their blocks too: rpint; the extended pseudo-node vectors take the
  // soft rows' cotangents and tangents from the parts' reduced solves), or on the sparse
  // backend the operator's rows (H_f^T, K_p: data.rigidify.Ht_soft, SW; rpsp), or with
  // Newton the rows at the converged tangent (H_f^T, K_f: newton_contact_rows; rnewtp),
  // rigid bodies in contact beside them on the sparse backend and under Newton (their rows
  // L_r^T H_r^T, contact::rigid_body_rows, do not depend on A: rpsn), joint limits in the
  // contact solve too (rplim): on the dense backend with one Newton iteration the record's
  // G in the extended G (prepare_limits); on the sparse one the extended rows with the
  // parts' H_f^T and K_p (prepare_contact); under Newton the extended G on the contacts'
  // reduced G at A_f (prepare_rigid, full_G with newton_contact_rows).
}

// The step size of the record: data.h (dt for implicit Euler, 2 dt / 3 for BDF2), or
// dt before any step.
double step_size(const Model& model, const Data& data) { return data.h > 0 ? data.h : model.step.dt; }

// Newton with parts (v~ = v_i + P z: the step's v_i enters R directly and through v~):
// out = (A_f - M) w = h alpha M w + h beta K~(x_i) w + h^2 K(x_f) w per body.
void newton_damped_product(const Model& model, const Data& data, double h, const VecX& w, VecX& out, VecX& work) {
  const auto& fem = model.fem;
  fem::symmetric_multiply(fem, fem.mass_values, w, out);
  fem::symmetric_multiply(fem, data.K_i_values, w, work);
  for (const auto& b : fem.bodies) {
    const int begin = 3 * b.node_begin, len = 3 * b.num_nodes;
    out.segment(begin, len) = h * b.rayleigh_mass * out.segment(begin, len) + h * b.rayleigh_stiffness * work.segment(begin, len);
  }
  fem::symmetric_multiply(fem, data.fem.K_values, w, work);
  out += h * h * work;
}

void demand_size(const VecX& v, Eigen::Index n, const char* name) {
  SOFTDIFF_DEMAND(v.size() == 0 || v.size() == n, std::string(name) + ": expected size " + std::to_string(n) +
                                                      " (or empty for zero), got " + std::to_string(v.size()));
}

}  // namespace

StepDerivatives::StepDerivatives(const Model& model, std::vector<ParameterId> parameters)
    : parameters_(std::move(parameters)) {
  const auto nb = static_cast<Eigen::Index>(model.fem.bodies.size());
  set_step_size(model, model.step.dt);
  for (const auto& p : parameters_) {
    if (p.kind == Parameter::friction) {
      SOFTDIFF_DEMAND(model.contact.enabled && p.body >= 0 &&
                          p.body < static_cast<int>(model.contact.detection.pairs.size()),
                      "parameter friction: pair rule " + std::to_string(p.body) + " does not exist");
      continue;
    }
    SOFTDIFF_DEMAND(p.body >= 0 && p.body < nb, "parameter " + std::string(parameter_name(p.kind)) + ": body " +
                                                    std::to_string(p.body) + " does not exist");
  }
  const Eigen::Index n = 3L * model.fem.num_nodes;
  for (VecX* v : {&r_, &y_, &q_, &w_, &delta_, &tmp_, &tmp2_, &zero_, &q_extra_, &work_, &newton_work_}) *v = VecX::Zero(n);
  zero_bodies_ = VecX::Zero(nb);
}

void StepDerivatives::set_step_size(const Model& model, double h) {
  if (h == coef_h_) return;
  coef_h_ = h;
  const auto nb = static_cast<Eigen::Index>(model.fem.bodies.size());
  h_alpha_.resize(nb);
  k_coef_.resize(nb);
  for (Eigen::Index b = 0; b < nb; ++b) {
    h_alpha_[b] = h * model.fem.bodies[b].rayleigh_mass;
    k_coef_[b] = h * model.fem.bodies[b].rayleigh_stiffness + h * h;
  }
  minus_h_ = VecX::Constant(nb, -h);
  // The coefficient of dK~(x_i)[dx_i] w: -(h beta + h^2) in the linearized step (K(x_i)
  // is both the damping's and the elastic stiffness), -h beta with Newton (only the
  // damping D = alpha M + beta K(x_i) depends on x_i through K; the elastic force is at x_f).
  minus_k_coef_ = -k_coef_;
  if (model.step.newton_iterations > 1)
    for (Eigen::Index b = 0; b < nb; ++b) minus_k_coef_[b] = -h * model.fem.bodies[b].rayleigh_stiffness;
}

void StepDerivatives::body_scaled_product(const Model& model, const VecX& values, const VecX& w, const VecX& scale,
                                          VecX& out) {
  fem::symmetric_multiply(model.fem, values, w, out);  // bodies share no node: S is block diagonal per body
  for (std::size_t b = 0; b < model.fem.bodies.size(); ++b) {
    const auto& body = model.fem.bodies[b];
    out.segment(3 * body.node_begin, 3 * body.num_nodes) *= scale[static_cast<Eigen::Index>(b)];
  }
}

// The damping stiffness K~(x_i): the record's K in the linearized step, the one kept
// for the damping with Newton (data.fem then holds the last iterate, x_f).
const VecX& damping_stiffness(const Model& model, const Data& data) {
  return is_newton(model) ? data.K_i_values : data.fem.K_values;
}

bool StepDerivatives::parameter_column(const Model& model, const Data& data, const State& in, const State& out,
                                       int j, VecX& q) {
  const ParameterId& id = parameters_[static_cast<std::size_t>(j)];
  q.setZero();
  if (id.kind == Parameter::friction) return true;  // acts through the NCP only (friction_dmu)
  const auto& fem = model.fem;
  const auto& body = fem.bodies[static_cast<std::size_t>(id.body)];
  const double h = step_size(model, data);
  const Eigen::Index begin = 3 * body.node_begin, len = 3 * body.num_nodes;
  // The coefficient of the stiffness that multiplies w: h beta + h^2 (linearized: K(x_i)
  // in A and b), h beta (Newton: the elastic force is f(x_f), only D has K(x_i)).
  const double kw = -minus_k_coef_[id.body];
  q.setZero();
  switch (id.kind) {
    case Parameter::young: {
      // f_int and K~ are proportional to E (mu, lambda are; the projection commutes
      // with a positive scale): df/dE = f/E and dK~/dE = K~/E, from the step's record
      // (f_int at x_i, or at x_f with Newton).
      fem::symmetric_multiply(fem, damping_stiffness(model, data), out.v, tmp_);
      q.segment(begin, len) = (h * data.fem.f_int.segment(begin, len) - kw * tmp_.segment(begin, len)) / body.young;
      return true;
    }
    case Parameter::poisson: {
      tmp_.setZero();
      tmp2_.setZero();
      // df/dnu at the elastic force's positions, dK~/dnu w at x_i.
      if (is_newton(model)) {
        q_extra_.setZero();
        if (fem::add_elastic_parameter_derivative(fem, out.x, id.body, fem::ElasticParameter::poisson, out.v, tmp_,
                                                  q_extra_) >= 0 ||
            fem::add_elastic_parameter_derivative(fem, in.x, id.body, fem::ElasticParameter::poisson, out.v, q_extra_,
                                                  tmp2_) >= 0)
          return false;
      } else if (fem::add_elastic_parameter_derivative(fem, in.x, id.body, fem::ElasticParameter::poisson, out.v,
                                                       tmp_, tmp2_) >= 0) {
        return false;
      }
      q = h * tmp_ - kw * tmp2_;
      return true;
    }
    case Parameter::density: {
      // M and P = M g are proportional to rho.
      w_ = h_alpha_[id.body] * out.v + delta_;
      fem::symmetric_multiply(fem, fem.mass_values, w_, tmp_);
      q.segment(begin, len) = (h * fem.gravity_force.segment(begin, len) - tmp_.segment(begin, len)) / body.density;
      return true;
    }
    case Parameter::rayleigh_mass:
      fem::symmetric_multiply(fem, fem.mass_values, out.v, tmp_);
      q.segment(begin, len) = -h * tmp_.segment(begin, len);
      return true;
    case Parameter::rayleigh_stiffness:
      fem::symmetric_multiply(fem, damping_stiffness(model, data), out.v, tmp_);
      q.segment(begin, len) = -h * tmp_.segment(begin, len);
      return true;
    case Parameter::friction: return false;
  }
  return false;
}

bool StepDerivatives::prepare_contact(const Model& model, const Data& data, const State& in, const State& out,
                                      LinearSolver& solver) {
  // The cache key: v_f, and with rigid bodies their corrected velocities too (a scene whose
  // soft nodes are all fixed has the same v_f = 0 at every step).
  const bool with_rigid = model.contact.with_rigid();
  const Eigen::Index key_size = out.v.size() + (with_rigid ? data.contact.rigid.u.size() : 0);
  if (contact_v_.size() == key_size && contact_v_.head(out.v.size()) == out.v &&
      (!with_rigid || contact_v_.tail(data.contact.rigid.u.size()) == data.contact.rigid.u))
    return true;
  // Newton (docs/method.md "Newton iterations with contact"): the record's G is that of
  // the last Newton factorization, one iterate before the converged v_f; the implicit
  // function theorem at v_f needs G with the converged tangent A_f (`solver`, this
  // object's factorization), so the record's G is not used and G_AA is formed with A_f.
  // (none in a scene of rigid bodies only: no preconditioner for the operator path, whose
  // products have no soft part there)
  const SparseMatrix* A = model.fem.num_nodes == 0 ? nullptr : is_newton(model) ? &newton_A_ : &data.A;
  // A failed solve (a PCG that misses its tolerance with a kept factor, an operator
  // product that fails) is the derivative's failure, reported by the caller with its step
  // (diff/trajectory.cpp), not a programming error.
  contact_v_.resize(0);
  // With rigid bodies the geometry is that of the extended positions (soft nodes, then the
  // rigid pseudo-nodes posed at the start of the step) that detection used.
  const VecX& x = model.contact.with_rigid() ? data.contact.rigid.x : in.x;
  // Joint limits in the step's NCP (rigid_contact_derivatives.hpp): the NCP derivative on
  // the extended system (the contacts' rows, then the limit rows).
  // On the sparse backend (no G in the record) the extended system is the operator's rows
  // (rpsp): the limit rows' extended Kt; a rigidified part's H_f^T and K_p (the step's
  // rigidified_rows, data.rigidify) beside the contacts' rows.
  contact::ContactStageDerivative::NcpSystem extended;
  if (with_rigid && rigid_.limit_rows() > 0) {
    extended = {&rigid_.extended_G(), &rigid_.extended_mu(), &rigid_.extended_lambda(), &rigid_.extended_sigma(),
                &rigid_.extended_modes()};
    if (rigid_.extended_on_operator()) {
      extended.G = nullptr;
      extended.Kt = &rigid_.extended_Kt();
      // Rigidified parts on the sparse backend (rplim): the operator's soft rows H_f^T and
      // the parts' K_p (the step's rigidified_rows, formed before the limit columns were
      // appended: 3 nc columns, zero on the limit rows, which have no soft dof) beside the
      // bodies' and limits' extended rows. (Newton: the extended G, whose contacts' block
      // prepare_rigid formed from the parts' rows at A_f.)
      if (!model.rigidify.empty()) {
        extended.Ht = &data.rigidify.Ht_soft;
        extended.Kt_more = &data.rigidify.SW;
      }
    }
  } else if (!model.rigidify.empty() && is_newton(model)) {
    // Newton with parts (rnewtp): the reduced Delassus rows at the converged tangent A_f
    // (H_f^T and K_f = L_{S_f}^{-1} W_f on A_f's Schur complement, prepare_newton), on
    // either backend: the record's G or rows are the last iteration's, one iterate earlier.
    const auto& cd = data.contact;
    parts_.newton_contact_rows(model, data, cd.Ht);
    extended = {nullptr, &cd.mu, &cd.lambda, &cd.sigma, &cd.modes};
    extended.Ht = &parts_.newton_Ht_soft();
    extended.Kt_more = &parts_.newton_K();
  } else if (!model.rigidify.empty() && data.contact.G.rows() == 0) {
    const auto& cd = data.contact;
    extended = {nullptr, &cd.mu, &cd.lambda, &cd.sigma, &cd.modes};
    extended.Ht = &data.rigidify.Ht_soft;
    extended.Kt_more = &data.rigidify.SW;
  }
  if (!contact_.prepare(model, data.contact, x, solver, step_size(model, data), !is_newton(model), nullptr, nullptr, A,
                        extended.modes ? &extended : nullptr))
    return false;
  contact_v_.resize(key_size);
  contact_v_.head(out.v.size()) = out.v;
  if (with_rigid) contact_v_.tail(data.contact.rigid.u.size()) = data.contact.rigid.u;
  return true;
}

void StepDerivatives::add_contact_force_jvp(const Model& model, const Data& data, const VecX& dx, VecX& r) const {
  contact_.add_force_jvp(data.contact, step_size(model, data), dx, r);
}

void StepDerivatives::contact_sigma_jvp(const Model& model, const Data& data, const State& out, const VecX& dx,
                                        const VecX& dv0, VecX& b) const {
  b.noalias() = data.contact.Ht.transpose() * dv0;  // H dv0 (projected H)
  contact_.add_sigma_jvp(data.contact, out.v, step_size(model, data), dx, b);
}

void StepDerivatives::add_contact_geometry_vjp(const Model& model, const Data& data, const State& out, const VecX& y,
                                               const VecX& bar_b, VecX& bar_x) const {
  contact_.add_geometry_vjp(data.contact, out.v, step_size(model, data), y, bar_b, bar_x);
}

LinearSolver* StepDerivatives::system(const Model& model, const Data& data, const State& out) {
  if (model.fem.num_nodes == 0) {
    static EmptySystem empty;  // stateless
    return &empty;
  }
  if (!is_newton(model)) return data.solver.get();
  // Newton: the implicit function theorem on the converged residual R(v_f) = 0 needs
  // dR/dv = (1 + h alpha) M + h beta K~(x_i) + h^2 K(x_f), the system matrix at the
  // last iterate (Newton's own last factorization is one iterate earlier). Assembled
  // and factorized once per step (cached by v_f), into this object's workspace.
  const double h = step_size(model, data);
  if (newton_v_.size() == out.v.size() && newton_v_ == out.v && newton_h_ == h) return newton_solver_.get();
  if (!newton_solver_) {
    newton_A_ = model.fem.pattern.structure;
    newton_solver_ = make_linear_solver(model.solver);
    newton_solver_->analyze(newton_A_);
  }
  assemble_system_matrix(model, h, data.K_i_values, data.fem.K_values, newton_A_);
  if (!newton_solver_->factorize(newton_A_).ok) return nullptr;
  ++newton_serial_;
  newton_v_ = out.v;
  newton_h_ = h;
  return newton_solver_.get();
}

bool StepDerivatives::prepare_rigid(const Model& model, const Data& data, const State& out, double h,
                                    const VecX& rigid, const VecX& rigid_p) {
  if (!model.contact.with_rigid()) return false;
  const auto R = static_cast<Eigen::Index>(model.rigid.size());
  // BDF2 (data.history_weight != 0): the stage from the extrapolated states with h' = data.h
  // (rigid/rigid_bdf2_derivatives.hpp), with Newton too: the stage is implicit Euler's from
  // (x^, v^, s^) (the rigid record's `in`), so its derivative is the same.
  demand_size(rigid, 12 * R, "rigid tangent");
  demand_size(rigid_p, 7 * R, "rigid parameter tangent");
  // Once per step, not per tangent: the record's serial number (ContactData::serial, a
  // new one each time the contact stage writes the record, unique in the process), an
  // O(1) test; the JVP / VJP columns of one step share it (prepare_limits' extended G
  // is rebuilt only for a new record).
  if (rigid_serial_ != 0 && rigid_serial_ == data.contact.serial) return true;
  const auto& rd = data.contact.rigid;
  // Newton (docs/method.md "Newton with rigid contact"): the implicit function theorem at
  // v_f needs G with the converged tangent A_f. G_AA is recomputed with it in
  // prepare_contact (with the rigid rows h Kt_A^T Kt_A, from the record's Kt or, on the
  // dense backend, from its H_r^T and L_r); joint limits in the contact solve take the
  // contacts' whole G with A_f (newton_solver_, factorized by system() for this v_f) in
  // their extended G, the dense record's G being the last Newton factorization's, one
  // iterate earlier.
  const bool limits = data.contact.contacts.size() > 0 && !rd.limit_rows.empty();
  const MatX* G_contacts = nullptr;
  if (is_newton(model) && limits) {
    SOFTDIFF_DEMAND(newton_solver_ && newton_v_.size() == out.v.size() && newton_v_ == out.v,
                    "step derivatives: the Newton system is not factorized for this step's v_f");
    // (A solve with the factor just made failing is a computation failure, not "no rigid
    // bodies", which false means here.)
    // Rigidified parts (rplim): the contacts' G is the reduced one at A_f, h H_f A_f,ff^-1
    // H_f^T + h K_f^T K_f (+ the bodies' rows), from the parts' rows at the converged
    // tangent (newton_contact_rows, on the Schur complement prepare_newton formed before
    // this call in jvp / vjp), as prepare_contact uses them without limits.
    const bool parts = !model.rigidify.empty();
    if (parts) parts_.newton_contact_rows(model, data, data.contact.Ht);
    if (!contact_.full_G(model, data.contact, *newton_solver_, h, newton_G_,
                         parts ? &parts_.newton_Ht_soft() : nullptr, parts ? &parts_.newton_K() : nullptr))
      throw ComputationError("step derivatives: the contacts' Delassus matrix with Newton's converged tangent "
                             "(joint limits in contact) failed: a solve with its factorization failed");
    G_contacts = &newton_G_;
  }
  rigid_.prepare(model, data, out.rigid, h, G_contacts);
  rigid_serial_ = data.contact.serial;
  return true;
}

bool StepDerivatives::jvp(const Model& model, const Data& data, const State& in, const State& step_out,
                          const StepTangent& d, StateTangent& d_out) {
  demand_supported(model);
  const auto& fem = model.fem;
  const Eigen::Index n = 3L * fem.num_nodes;
  const auto na = static_cast<Eigen::Index>(model.actuation.actuators.size());
  demand_size(d.x, n, "tangent x");
  demand_size(d.v, n, "tangent v");
  demand_size(d.lambda_a, na, "tangent lambda_a");
  demand_size(d.p, static_cast<Eigen::Index>(parameters_.size()), "tangent p");
  const double h = step_size(model, data);
  set_step_size(model, h);
  // Rigidified parts: the terms below at the solve's velocity v~ (before the placement).
  const bool parts = !model.rigidify.empty();
  if (parts) {
    demand_parts_supported(model);
    parts_.prepare(model, data, in, step_out, h);
  }
  const State& out = parts ? parts_.solve_state() : step_out;
  const bool newton = is_newton(model);
  const VecX& dx = d.x.size() ? d.x : zero_;
  const VecX& dv = d.v.size() ? d.v : zero_;
  delta_ = out.v - in.v;
  LinearSolver* solver = system(model, data, out);
  if (!solver) return false;
  // Newton with parts: the reduced solves on A_f (its Schur complement, once per step).
  if (parts && newton && !parts_.prepare_newton(model, data, *solver, newton_serial_)) return false;

  r_.setZero();
  if (d.x.size()) {
    if (newton) {
      // -h K(x_f) dx (the elastic force at x_f = x_i + h v_f), - h beta dK~(x_i)[dx] w
      fem::symmetric_multiply(fem, data.fem.K_values, dx, tmp_);
      r_ = -h * tmp_;
      if (fem::add_stiffness_jvp(fem, in.x, dx, out.v, zero_bodies_, minus_k_coef_, r_) >= 0) return false;
    } else if (fem::add_stiffness_product(fem, data.fem, in.x, fem::StiffnessProduct::jvp, dx, out.v, minus_h_,
                                          minus_k_coef_, r_, work_) >= 0) {
      // -h K dx - (h beta + h^2) dK~[dx] w, from the step's record at x_i: K dx with the
      // assembled K, dK~[dx] w from the kept polar decompositions (fem_derivatives.hpp)
      return false;
    }
  }
  if (na > 0 && n > 0) {
    if (d.x.size()) model.actuation.add_force_derivatives(in.x, data.lambda_a, dx, h, r_);
    if (d.lambda_a.size()) model.actuation.add_forces(in.x, d.lambda_a, h, r_);
  }
  if (d.v.size()) {
    if (newton && parts) {
      // v~ = Pi v_i + P z (Newton's iterates are projected: v_i's fixed dofs do not enter
      // R): -dR/dv_i dv_i = M dv_i - A_f Pi dv_i, and dv~ = Pi dv_i + the solve's terms below.
      tmp2_ = dv;
      project(model, tmp2_);
      newton_damped_product(model, data, h, tmp2_, tmp_, newton_work_);
      r_ -= tmp_;
    } else if (newton) {
      fem::symmetric_multiply(fem, fem.mass_values, dv, tmp_);  // -dR/dv_i dv_i = M dv_i
      r_ += tmp_;
    } else {
      body_scaled_product(model, fem.mass_values, dv, h_alpha_, tmp_);
      r_ -= tmp_;
      body_scaled_product(model, data.fem.K_values, dv, k_coef_, tmp_);
      r_ -= tmp_;
    }
  }
  for (int j = 0; j < static_cast<int>(parameters_.size()); ++j) {
    if (!d.p.size() || d.p[j] == 0) continue;
    if (!parameter_column(model, data, in, out, j, q_)) return false;
    r_ += d.p[j] * q_;
  }
  const bool contact = model.contact.enabled && !data.contact.contacts.empty();
  const bool with_rigid = prepare_rigid(model, data, out, h, d.rigid, d.rigid_p);
  const auto& cd = data.contact;
  if (contact) {
    if (!prepare_contact(model, data, in, out, *solver)) return false;
    if (with_rigid) {
      // h dH^T lambda on the extended positions: the soft nodes' share joins r, the
      // pseudo-nodes' moves the rigid impulses (impulse_jvp).
      ext_dx_.resize(cd.rigid.x.size());
      ext_dx_.head(n) = dx;
      rigid_.pseudo_position_jvp(model, d.rigid, ext_dx_);
      ext_r_.setZero(cd.rigid.x.size());
      contact_.add_force_jvp(cd, h, ext_dx_, ext_r_);
      r_ += ext_r_.head(n);
    } else if (d.x.size()) {
      add_contact_force_jvp(model, data, dx, r_);  // h dH^T lambda
    }
  }
  if (parts) parts_.add_rhs_jvp(model, data, d.x, r_);  // - A dP z; keeps dP^T r_res
  project(model, r_);
  if (!(parts ? parts_.solve(model, data, r_, true, y_) : solver->solve(r_, y_))) return false;
  // Linearized: y = dDelta, dv_f = dv_i + dDelta; Newton: y = dv_f.
  d_out.v = newton && !parts ? y_ : VecX(dv + y_);
  if (parts) parts_.add_dPz(d_out.v);
  project(model, d_out.v);
  if (contact) {
    // dv_f at fixed lambda is d_out.v; sigma moves by b; the forces by dlambda (the
    // implicit function theorem, modes fixed); then h A^{-1} H^T dlambda.
    if (with_rigid) {
      // b = H_s dv0 + the geometry terms on the extended velocities + the rigid rows'.
      // With joint limits in the NCP, b has their rows after the contacts' (limit_sigma_jvp).
      b_.resize(cd.Ht.cols() + 3 * rigid_.limit_rows());
      b_.head(cd.Ht.cols()).noalias() = cd.Ht.transpose() * d_out.v;
      rigid_.extended_velocities(model, cd, out.v, ext_u_);
      contact_.add_sigma_jvp(cd, ext_u_, h, ext_dx_, b_);
      rigid_.impulse_jvp(model, d.rigid, d.rigid_p, ext_r_, du0_);
      rigid_.add_sigma_jvp(model, cd, du0_, d.rigid, b_);
      if (rigid_.limit_rows() > 0) rigid_.limit_sigma_jvp(d.rigid, du0_, b_);
    } else {
      contact_sigma_jvp(model, data, out, dx, d_out.v, b_);
    }
    // Friction parameters: dmu_i = dp_j for the contacts of pair rule j.
    VecX dmu;
    contact::ContactStageDerivative::friction_tangent(model, data.contact, parameters_, d.p, dmu);
    if (dmu.size() && with_rigid && rigid_.limit_rows() > 0) {
      dmu.conservativeResize(dmu.size() + rigid_.limit_rows());  // the limit rows: mu = 0
      dmu.tail(rigid_.limit_rows()).setZero();
    }
    contact_.ncp().jvp(b_, dmu, dlambda_);
    tmp_.noalias() = h * (data.contact.Ht * dlambda_.head(data.contact.Ht.cols()));
    project(model, tmp_);
    if (!(parts ? parts_.solve(model, data, tmp_, false, y_) : solver->solve(tmp_, y_))) return false;
    project(model, y_);
    d_out.v += y_;
  }
  if (with_rigid)
    rigid_.out_jvp(model, cd, d.rigid, d.rigid_p, du0_, dlambda_, d_out.rigid);
  else
    d_out.rigid.resize(0);
  d_out.x = dx + h * d_out.v;
  if (parts) parts_.place_jvp(model, dx, d_out.x, d_out.v);  // the parts' exact placement
  return d_out.x.allFinite() && d_out.v.allFinite() && d_out.rigid.allFinite();
}

bool StepDerivatives::actuation_jvps(const Model& model, const Data& data, const State& in, const State& out,
                                     const MatX& dlambda, MatX& dx_out) {
  demand_supported(model);
  const Eigen::Index n = 3L * model.fem.num_nodes;
  const auto na = static_cast<Eigen::Index>(model.actuation.actuators.size());
  SOFTDIFF_DEMAND(dlambda.rows() == na, "actuation tangents: expected " + std::to_string(na) + " rows, got " +
                                            std::to_string(dlambda.rows()));
  SOFTDIFF_DEMAND(!(model.contact.enabled && !data.contact.contacts.empty()),
                  "actuation_jvps: the step has contacts (their tangent goes through the NCP's modes: jvp() per column)");
  const double h = step_size(model, data);
  set_step_size(model, h);
  const bool parts = !model.rigidify.empty();
  if (parts) {
    // Rigidified parts: per column the reduced solve (one solve with the step's factor,
    // rigidify_derivatives.hpp; dx_i = 0, so no dP terms) and the placement's tangent.
    demand_parts_supported(model);
    parts_.prepare(model, data, in, out, h);
  }
  LinearSolver* solver = system(model, data, parts ? parts_.solve_state() : out);
  if (!solver) return false;
  if (parts && is_newton(model) && !parts_.prepare_newton(model, data, *solver, newton_serial_)) return false;
  const Eigen::Index k = dlambda.cols();
  if (parts) {
    dx_out.resize(n, k);
    for (Eigen::Index j = 0; j < k; ++j) {
      lambda_column_ = dlambda.col(j);
      r_.setZero();
      model.actuation.add_forces(in.x, lambda_column_, h, r_);
      project(model, r_);
      if (!parts_.solve(model, data, r_, false, y_)) return false;
      project(model, y_);  // dv~ (dv_i = 0)
      tmp_ = h * y_;
      parts_.place_jvp(model, zero_, tmp_, y_);  // the parts' rows of dx_f
      dx_out.col(j) = tmp_;
    }
    return dx_out.allFinite();
  }
  rhs_columns_.resize(n, k);  // no allocation when k and n are those of the last call
  for (Eigen::Index j = 0; j < k; ++j) {
    // jvp()'s right-hand side with only d.lambda_a: Pi h H_a(x_i)^T dlambda_j.
    lambda_column_ = dlambda.col(j);
    r_.setZero();
    model.actuation.add_forces(in.x, lambda_column_, h, r_);
    project(model, r_);
    rhs_columns_.col(j) = r_;
  }
  if (!solver->solve(rhs_columns_, y_columns_)) return false;
  // Linearized: dv_f = dv_i + dDelta = y; Newton: dv_f = y. dx_f = dx_i + h dv_f = h y.
  dx_out.resize(n, k);
  for (Eigen::Index j = 0; j < k; ++j) {
    y_ = y_columns_.col(j);
    project(model, y_);
    dx_out.col(j) = h * y_;
  }
  return dx_out.allFinite();
}

bool StepDerivatives::vjp(const Model& model, const Data& data, const State& in, const State& step_out,
                          const StateTangent& bar_out, StepCotangent& bar_in) {
  demand_supported(model);
  const auto& fem = model.fem;
  const Eigen::Index n = 3L * fem.num_nodes;
  const auto na = static_cast<Eigen::Index>(model.actuation.actuators.size());
  demand_size(bar_out.x, n, "cotangent x");
  demand_size(bar_out.v, n, "cotangent v");
  const double h = step_size(model, data);
  set_step_size(model, h);
  const bool parts = !model.rigidify.empty();
  if (parts) {
    demand_parts_supported(model);
    parts_.prepare(model, data, in, step_out, h);
  }
  const State& out = parts ? parts_.solve_state() : step_out;
  const bool newton = is_newton(model);
  delta_ = out.v - in.v;
  LinearSolver* solver = system(model, data, out);
  if (!solver) return false;
  if (parts && newton && !parts_.prepare_newton(model, data, *solver, newton_serial_)) return false;

  // v~ = Pi (bar_v_f + h bar_x_f), y = A^{-1} v~.
  tmp_ = bar_out.v.size() ? bar_out.v : zero_;
  if (bar_out.x.size()) tmp_ += h * bar_out.x;
  if (parts) {
    // The placement's transpose: the parts' rows of v~'s and x_i's cotangents.
    bar_in.x = bar_out.x.size() ? bar_out.x : zero_;
    parts_.place_vjp(model, bar_out.x.size() ? bar_out.x : zero_, bar_out.v.size() ? bar_out.v : zero_, tmp_,
                     bar_in.x);
  }
  project(model, tmp_);
  if (!(parts ? parts_.solve(model, data, tmp_, false, y_) : solver->solve(tmp_, y_))) return false;
  project(model, y_);
  VecX* v_direct = &tmp_;  // the cotangent of dv_f's direct dependence on dv_i
  const bool with_rigid = prepare_rigid(model, data, out, h, bar_out.rigid, VecX());
  const auto& cd = data.contact;
  if (with_rigid && !(model.contact.enabled && !cd.contacts.empty()))
    rigid_.out_vjp(model, cd, bar_out.rigid, bar_in.rigid, bar_in.rigid_p, bar_du0_, bar_lambda_);
  if (model.contact.enabled && !data.contact.contacts.empty()) {
    // Contact: lambda's cotangent h H A^{-1} v~, the NCP derivative's transpose gives
    // bar_b; b = H dv0 + ... adds z = H^T bar_b to dv0's cotangent, so the right-hand
    // side's cotangent is y + A^{-1} z.
    if (!prepare_contact(model, data, in, out, *solver)) return false;
    const int limit_rows = with_rigid ? rigid_.limit_rows() : 0;  // joint limits' rows after the contacts'
    bar_lambda_.resize(cd.Ht.cols() + 3 * limit_rows);
    bar_lambda_.head(cd.Ht.cols()).noalias() = h * (data.contact.Ht.transpose() * y_);
    bar_lambda_.tail(3 * limit_rows).setZero();
    if (with_rigid) rigid_.out_vjp(model, cd, bar_out.rigid, bar_in.rigid, bar_in.rigid_p, bar_du0_, bar_lambda_);
    contact_.ncp().vjp(bar_lambda_, bar_b_, bar_mu_);
    if (with_rigid) rigid_.add_sigma_vjp(model, cd, bar_b_, bar_du0_, bar_in.rigid);
    if (limit_rows > 0) rigid_.add_limit_sigma_vjp(bar_b_, bar_du0_, bar_in.rigid);
    tmp2_.noalias() = data.contact.Ht * bar_b_.head(cd.Ht.cols());
    project(model, tmp2_);
    if (!(parts ? parts_.solve(model, data, tmp2_, false, y2_) : solver->solve(tmp2_, y2_))) return false;
    project(model, y2_);
    y_ += y2_;
    tmp_ += tmp2_;
    v_direct = &tmp_;
  }

  if (n == 0) {
    bar_in.v.resize(0);  // a scene of rigid bodies only: no soft term below
  } else if (newton && parts) {
    bar_in.v = *v_direct;  // dv~ = Pi dv_i + ..., minus (A_f - M) Pi dv_i through the solve
    newton_damped_product(model, data, h, y_, tmp2_, newton_work_);
    project(model, tmp2_);
    bar_in.v -= tmp2_;
  } else if (newton) {
    fem::symmetric_multiply(fem, fem.mass_values, y_, bar_in.v);
  } else {
    bar_in.v = *v_direct;
    body_scaled_product(model, fem.mass_values, y_, h_alpha_, tmp2_);
    bar_in.v -= tmp2_;
    body_scaled_product(model, data.fem.K_values, y_, k_coef_, tmp2_);
    bar_in.v -= tmp2_;
  }

  if (parts)
    parts_.add_solve_vjp(model, data, tmp_, y_, bar_in.x);  // the dP terms (bar_in.x holds the placement's)
  else
    bar_in.x = bar_out.x.size() ? bar_out.x : zero_;
  if (n == 0) {
    // no soft dof: no stiffness term
  } else if (newton) {
    fem::symmetric_multiply(fem, data.fem.K_values, y_, tmp2_);
    bar_in.x -= h * tmp2_;
    if (fem::add_stiffness_vjp(fem, in.x, y_, out.v, zero_bodies_, minus_k_coef_, bar_in.x) >= 0) return false;
  } else if (fem::add_stiffness_product(fem, data.fem, in.x, fem::StiffnessProduct::vjp, y_, out.v, minus_h_,
                                        minus_k_coef_, bar_in.x, work_) >= 0) {
    return false;
  }
  if (model.contact.enabled && !data.contact.contacts.empty()) {
    if (with_rigid) {
      // The extended cotangents: y on the soft nodes, the impulses' on the pseudo-nodes.
      ext_y_.resize(cd.rigid.x.size());
      ext_y_.head(n) = y_;
      rigid_.impulse_vjp(model, bar_du0_, bar_in.rigid, bar_in.rigid_p, ext_y_);
      rigid_.extended_velocities(model, cd, out.v, ext_u_);
      ext_bar_x_.setZero(cd.rigid.x.size());
      contact_.add_geometry_vjp(cd, ext_u_, h, ext_y_, bar_b_, ext_bar_x_);
      bar_in.x += ext_bar_x_.head(n);
      rigid_.add_pseudo_position_vjp(model, ext_bar_x_, bar_in.rigid);
    } else {
      add_contact_geometry_vjp(model, data, out, y_, bar_b_, bar_in.x);
    }
  }
  if (!with_rigid) {
    bar_in.rigid.resize(0);
    bar_in.rigid_p.resize(0);
  }
  bar_in.lambda_a = VecX::Zero(na);
  if (na > 0 && n > 0) {
    model.actuation.add_force_derivatives_transpose(in.x, data.lambda_a, y_, h, bar_in.x);
    model.actuation.add_jacobian_product(in.x, y_, h, bar_in.lambda_a);
  }
  bar_in.p = VecX::Zero(static_cast<Eigen::Index>(parameters_.size()));
  if (model.contact.enabled && !data.contact.contacts.empty())
    contact::ContactStageDerivative::add_friction_cotangent(model, data.contact, parameters_, bar_mu_, bar_in.p);
  for (int j = 0; j < static_cast<int>(parameters_.size()); ++j) {
    if (parameters_[static_cast<std::size_t>(j)].kind == Parameter::friction) continue;
    if (!parameter_column(model, data, in, out, j, q_)) return false;
    bar_in.p[j] = y_.dot(q_);
  }
  return bar_in.x.allFinite() && bar_in.v.allFinite() && bar_in.lambda_a.allFinite() && bar_in.p.allFinite() &&
         bar_in.rigid.allFinite() && bar_in.rigid_p.allFinite();
}

}  // namespace softdiff::integrator
