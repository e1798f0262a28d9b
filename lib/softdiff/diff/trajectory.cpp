// Trajectory derivatives: see trajectory.hpp.
#include <softdiff/diff/trajectory.hpp>

#include <softdiff/core/assert.hpp>

#include <algorithm>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/bdf2_derivatives.hpp>

namespace softdiff::diff {

namespace {

Eigen::Index num_actuators(const Model& model) { return static_cast<Eigen::Index>(model.actuation.actuators.size()); }
Eigen::Index num_dofs(const Model& model) { return 3L * model.fem.num_nodes; }
// Rows of a sensitivity (and columns of x0, v0): the soft coordinates, then 6 per rigid body.
Eigen::Index num_rows(const Model& model) { return num_dofs(model) + 6L * static_cast<Eigen::Index>(model.rigid.size()); }

StepStatus derivative_failed(long k) {
  StepStatus s;
  s.code = StepStatus::Code::solver_failed;
  s.step = k;
  s.detail = "the derivative of the step failed (a linear solve did not succeed or produced non-finite values)";
  return s;
}

}  // namespace

namespace {
Eigen::Index basis_columns(bool on, const MatX& basis, const Model& model) {
  return !on ? 0 : basis.size() ? basis.cols() : num_rows(model);
}
void set_basis(MatX& block, const MatX& basis) {
  if (basis.size())
    block = basis;
  else
    block.setIdentity();
}
}  // namespace

Eigen::Index ThetaLayout::size(const Model& model) const {
  return static_cast<Eigen::Index>(parameters.size()) + (actuation ? num_actuators(model) : 0) +
         basis_columns(x0, x0_basis, model) + basis_columns(v0, v0_basis, model) +
         static_cast<Eigen::Index>(rigid_parameters.size());
}

Eigen::Index ThetaLayout::x0_offset(const Model& model) const {
  return actuation_offset() + (actuation ? num_actuators(model) : 0);
}

Eigen::Index ThetaLayout::v0_offset(const Model& model) const {
  return x0_offset(model) + basis_columns(x0, x0_basis, model);
}

Eigen::Index ThetaLayout::rigid_parameter_offset(const Model& model) const {
  return v0_offset(model) + basis_columns(v0, v0_basis, model);
}

std::vector<std::string> ThetaLayout::column_names(const Model& model) const {
  std::vector<std::string> names;
  for (const auto& p : parameters) {
    if (p.kind == Parameter::friction) {
      const auto& r = model.contact.detection.pairs[static_cast<std::size_t>(p.body)];
      const auto& n = model.contact.detection.names;
      names.push_back("friction[" + n[static_cast<std::size_t>(r.a)] + "-" + n[static_cast<std::size_t>(r.b)] + "]");
    } else {
      names.push_back(std::string(parameter_name(p.kind)) + "[" + model.fem.bodies[static_cast<std::size_t>(p.body)].name + "]");
    }
  }
  if (actuation)
    for (const auto& a : model.actuation.actuators) names.push_back("actuation[" + a.name + "]");
  if (x0) names.emplace_back("x0");
  if (v0) names.emplace_back("v0");
  for (const auto& p : rigid_parameters) {
    const std::string full = rigid::rigid_parameter_name(p.index), body = model.rigid[static_cast<std::size_t>(p.body)].name;
    const auto dot = full.find('.');
    names.push_back(dot == std::string::npos ? full + "[" + body + "]"
                                             : full.substr(0, dot) + "[" + body + "]" + full.substr(dot));
  }
  return names;
}

ForwardSensitivity::ForwardSensitivity(const Model& model, ThetaLayout theta)
    : theta_(std::move(theta)), step_(std::make_unique<integrator::StepDerivatives>(model, theta_.parameters)) {
  const Eigen::Index n = num_rows(model), k = theta_.size(model);
  rigid_jacobian_.resize(model.rigid.size());
  previous_rigid_.resize(model.rigid.size());
  for (const auto& p : theta_.rigid_parameters)
    SOFTDIFF_DEMAND(p.body >= 0 && p.body < static_cast<int>(model.rigid.size()) && p.index >= 0 &&
                        p.index < rigid::kRigidParameters,
                    "rigid parameter: no such body or index");
  dx_ = MatX::Zero(n, k);
  dv_ = MatX::Zero(n, k);
  for (const MatX* basis : {&theta_.x0_basis, &theta_.v0_basis})
    SOFTDIFF_DEMAND(basis->size() == 0 || basis->rows() == n, "x0/v0 basis: expected 3n + 6 n_rigid rows");
  if (theta_.x0) {
    const Eigen::Index cols = basis_columns(true, theta_.x0_basis, model);
    MatX block(n, cols);
    set_basis(block, theta_.x0_basis);
    dx_.middleCols(theta_.x0_offset(model), cols) = block;
  }
  if (theta_.v0) {
    const Eigen::Index cols = basis_columns(true, theta_.v0_basis, model);
    MatX block(n, cols);
    set_basis(block, theta_.v0_basis);
    dv_.middleCols(theta_.v0_offset(model), cols) = block;
  }
}

bool ForwardSensitivity::advance(const Model& model, const Data& data, const State& in, const State& out) {
  // The soft step's input as its derivative sees it is data.hat; the rigid bodies' is in.rigid.
  const Eigen::Index n3 = num_dofs(model), nr = static_cast<Eigen::Index>(model.rigid.size());
  // Rigid bodies in contact (model.contact.with_rigid()): the step's JVP carries their
  // rows through the one contact solve (contact/rigid_contact_derivatives.hpp). Otherwise
  // each body's 12 x 12 (and 12 x 7) step Jacobian, once per step.
  const bool coupled = model.contact.with_rigid();
  // BDF2 (data.history_weight != 0): the step also depends on the previous state, whose
  // sensitivities are kept (one more pair of 3n x k matrices), and the rigid bodies on
  // their previous states (kept from the last advance()).
  const bool multistep = data.history_weight != 0;
  if (multistep) SOFTDIFF_DEMAND(previous_dx_.cols() == dx_.cols(), "ForwardSensitivity: a BDF2 step without a previous step");
  // Each body's Jacobian (rigid_bdf2_derivatives.hpp; implicit Euler's when not
  // multistep). Coupled by contact, only the extrapolation's part is used: the step's JVP
  // takes the tangent of the extrapolated state.
  const bool rigid_bdf2 = model.step.integrator == IntegratorKind::bdf2;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    auto& J = rigid_jacobian_[r];
    const rigid::RigidState* prev = multistep ? &previous_rigid_[r] : nullptr;
    if (!coupled) {
      // The branch is the step's record (data.rigid[r].bdf2, rigid_bdf2.cpp): read, not decided again.
      rigid::bdf2_step_jacobian(model.rigid[r], in.rigid[r], rigid_bdf2 ? prev : nullptr,
                                data.hat.rigid.size() == model.rigid.size() ? data.hat.rigid[r] : in.rigid[r],
                                out.rigid[r], data.rigid[r], model.step.dt, model.step.gravity, J);
    } else if (prev) {
      // In contact the branch is the step's record (bdf2.cpp): a BDF2 step (history_weight
      // != 0) is BDF2 for every body (a limit restarts the whole step as implicit Euler,
      // whose record has history_weight 0), so nothing is decided again here.
      J.bdf2 = true;
      rigid::extrapolation_jacobian(model.rigid[r], in.rigid[r], *prev, data.hat.rigid[r], J.extrapolation);
    } else {
      J.bdf2 = false;
    }
  }
  const Eigen::Index nrp = static_cast<Eigen::Index>(theta_.rigid_parameters.size());
  const Eigen::Index rp0 = nrp ? theta_.rigid_parameter_offset(model) : 0;
  const Eigen::Index np = theta_.actuation_offset(), na = theta_.actuation ? num_actuators(model) : 0;
  next_dx_.resize(dx_.rows(), dx_.cols());
  next_dv_.resize(dv_.rows(), dv_.cols());
  for (Eigen::Index c = 0; c < dx_.cols(); ++c) {
    t_.x = dx_.col(c).head(n3);
    t_.v = dv_.col(c).head(n3);
    t_.p.resize(0);
    t_.lambda_a.resize(0);
    if (c < np)
      t_.p = VecX::Unit(np, c);
    else if (c < np + na)
      t_.lambda_a = VecX::Unit(num_actuators(model), c - np);
    if (coupled) {
      t_.rigid.resize(12 * nr);
      for (Eigen::Index r = 0; r < nr; ++r)
        t_.rigid.segment<12>(12 * r) << dx_.col(c).segment<6>(n3 + 6 * r), dv_.col(c).segment<6>(n3 + 6 * r);
      t_.rigid_p.resize(0);
      if (c >= rp0 && c < rp0 + nrp) {
        const auto& p = theta_.rigid_parameters[static_cast<std::size_t>(c - rp0)];
        t_.rigid_p = VecX::Unit(7 * nr, 7 * p.body + p.index);
      }
      if (multistep) {
        previous_.x = previous_dx_.col(c).head(n3);
        previous_.v = previous_dv_.col(c).head(n3);
        // BDF2: the tangent of the extrapolated rigid states (rigid_bdf2_derivatives.hpp).
        for (Eigen::Index r = 0; r < nr; ++r) {
          const auto& J = rigid_jacobian_[static_cast<std::size_t>(r)];
          if (!J.bdf2) continue;
          rigid::Vec12 d_prev, d_n = t_.rigid.segment<12>(12 * r);
          d_prev << previous_dx_.col(c).segment<6>(n3 + 6 * r), previous_dv_.col(c).segment<6>(n3 + 6 * r);
          rigid::Vec12 d_hat = J.extrapolation.in * d_n + J.extrapolation.previous * d_prev;
          if (t_.rigid_p.size()) d_hat += J.extrapolation.params * t_.rigid_p.segment<7>(7 * r);
          t_.rigid.segment<12>(12 * r) = d_hat;
        }
      } else {
        previous_.x.resize(0);
        previous_.v.resize(0);
      }
      if (!integrator::multistep_jvp(*step_, model, data, out, t_, previous_, r_, &in, &previous_state_)) return false;
      next_dx_.col(c).head(n3) = r_.x;
      next_dv_.col(c).head(n3) = r_.v;
      for (Eigen::Index r = 0; r < nr; ++r) {
        next_dx_.col(c).segment<6>(n3 + 6 * r) = r_.rigid.segment<6>(12 * r);
        next_dv_.col(c).segment<6>(n3 + 6 * r) = r_.rigid.segment<6>(12 * r + 6);
      }
      continue;
    }
    t_.rigid.resize(0);
    t_.rigid_p.resize(0);
    if (multistep) {
      previous_.x = previous_dx_.col(c).head(n3);
      previous_.v = previous_dv_.col(c).head(n3);
    } else {
      previous_.x.resize(0);
      previous_.v.resize(0);
    }
    // A column with no soft input (a rigid body's parameter or initial state while no
    // contact couples the bodies) keeps zero soft rows: the step's JVP is linear, so its
    // solve is skipped.
    const bool soft_zero = c >= np + na && t_.x.isZero(0) && t_.v.isZero(0) &&
                           (!multistep || (previous_.x.isZero(0) && previous_.v.isZero(0)));
    if (soft_zero) {
      next_dx_.col(c).head(n3).setZero();
      next_dv_.col(c).head(n3).setZero();
    } else {
      if (!integrator::multistep_jvp(*step_, model, data, out, t_, previous_, r_, &in, &previous_state_)) return false;
      next_dx_.col(c).head(n3) = r_.x;
      next_dv_.col(c).head(n3) = r_.v;
    }
    // The rigid rows: d out = J_state d in (+ J_params e_k for a rigid parameter column).
    for (Eigen::Index r = 0; r < nr; ++r) {
      const Eigen::Index row = n3 + 6 * r;
      rigid::Vec12 d_in;
      d_in << dx_.col(c).segment<6>(row), dv_.col(c).segment<6>(row);
      const auto& J = rigid_jacobian_[static_cast<std::size_t>(r)];
      rigid::Vec12 d_out = J.state * d_in;
      if (J.bdf2) {
        rigid::Vec12 d_prev;
        d_prev << previous_dx_.col(c).segment<6>(row), previous_dv_.col(c).segment<6>(row);
        d_out += J.previous * d_prev;
      }
      if (c >= rp0 && c < rp0 + nrp) {
        const auto& p = theta_.rigid_parameters[static_cast<std::size_t>(c - rp0)];
        if (p.body == r) d_out += J.params.col(p.index);
      }
      next_dx_.col(c).segment<6>(row) = d_out.head<6>();
      next_dv_.col(c).segment<6>(row) = d_out.tail<6>();
    }
  }
  for (std::size_t r = 0; r < model.rigid.size(); ++r) previous_rigid_[r] = in.rigid[r];
  if (!model.rigidify.empty()) {  // BDF2 with rigidified parts: the next step's x_{n-1}
    previous_state_.x = in.x;
    previous_state_.v = in.v;
  }
  previous_dx_.swap(dx_);
  previous_dv_.swap(dv_);
  dx_.swap(next_dx_);
  dv_.swap(next_dv_);
  return true;
}

StepStatus forward_sensitivities(const Model& model, Data& data, const State& initial, long steps,
                                 const ThetaLayout& theta, State& final, MatX& dx_dtheta, MatX& dv_dtheta,
                                 const SensitivityObserver& observer) {
  ForwardSensitivity sensitivity(model, theta);
  State s = initial, next = initial, previous;
  for (long step = 1; step <= steps; ++step) {
    const StepStatus st = integrator::time_step(model, data, s, step > 1 ? &previous : nullptr, next, step);
    if (!st.ok()) return st;
    if (!sensitivity.advance(model, data, s, next)) return derivative_failed(step);
    std::swap(previous, s);
    std::swap(s, next);
    if (observer) observer(step, s, sensitivity.dx_dtheta(), sensitivity.dv_dtheta());
  }
  final = s;
  dx_dtheta = sensitivity.dx_dtheta();
  dv_dtheta = sensitivity.dv_dtheta();
  return {};
}

std::size_t Tape::bytes() const {
  std::size_t b = 0;
  for (const auto& f : frames) b += sizeof(double) * static_cast<std::size_t>(f.x.size() + f.v.size() + 1);
  for (const auto& l : lambda_a) b += sizeof(double) * static_cast<std::size_t>(l.size());
  for (const auto& w : warm_start)
    b += sizeof(w.keys[0]) * w.keys.size() +
         sizeof(double) * static_cast<std::size_t>(w.lambda.size() + w.limit_lambda.size());
  return b;
}

StepStatus record(const Model& model, Data& data, const State& initial, long steps, Tape& tape, const MatX& actuation,
                  const AfterStep& after_step) {
  const Eigen::Index na = num_actuators(model);
  SOFTDIFF_DEMAND(actuation.size() == 0 || (actuation.rows() == na && actuation.cols() == steps),
                  "actuation: expected (" + std::to_string(na) + " x " + std::to_string(steps) + ") values, got (" +
                      std::to_string(actuation.rows()) + " x " + std::to_string(actuation.cols()) + ")");
  tape.frames.assign(1, initial);
  tape.frames.reserve(static_cast<std::size_t>(steps) + 1);
  tape.lambda_a.clear();
  tape.lambda_a.reserve(static_cast<std::size_t>(steps));
  tape.warm_start.clear();
  tape.rigid_at_limit.clear();
  tape.rigid_at_limit.reserve(static_cast<std::size_t>(steps) * model.rigid.size());
  State next = initial;
  VecX lambda;
  for (long step = 1; step <= steps; ++step) {
    const VecX* override_values = nullptr;
    if (actuation.size()) {
      lambda = actuation.col(step - 1);
      override_values = &lambda;
    }
    if (model.contact.enabled)
      tape.warm_start.push_back({data.contact.previous_keys, data.contact.previous_lambda, data.contact.rigid.limit_lambda});
    const State* previous = step > 1 ? &tape.frames[tape.frames.size() - 2] : nullptr;
    const StepStatus st = integrator::time_step(model, data, tape.frames.back(), previous, next, step, override_values);
    if (!st.ok()) return st;
    if (after_step)
      if (const StepStatus hook = after_step(step, data); !hook.ok()) return hook;
    tape.frames.push_back(next);
    tape.lambda_a.push_back(data.lambda_a);
    for (std::size_t r = 0; r < model.rigid.size(); ++r) tape.rigid_at_limit.push_back(data.rigid[r].at_limit ? 1 : 0);
  }
  return {};
}

StepStatus adjoint(const Model& model, Data& data, const Tape& tape, const ThetaLayout& theta,
                   const LossCotangent& loss, AdjointResult& result, const RigidLossCotangent& rigid_loss) {
  const long T = tape.steps();
  SOFTDIFF_DEMAND(T >= 0 && static_cast<long>(tape.lambda_a.size()) == T, "adjoint: the tape is inconsistent");
  const Eigen::Index n = num_dofs(model), np = theta.actuation_offset(), na = num_actuators(model);
  const Eigen::Index nr = static_cast<Eigen::Index>(model.rigid.size());
  const Eigen::Index rp0 = theta.rigid_parameter_offset(model);
  for (const auto& p : theta.rigid_parameters)
    SOFTDIFF_DEMAND(p.body >= 0 && p.body < nr && p.index >= 0 && p.index < rigid::kRigidParameters,
                    "rigid parameter: no such body or index");
  // The rigid bodies' cotangents (12 per body), their parameters' (7 per body, scattered
  // to theta's columns at the end) and each step's Jacobian of one body. With rigid bodies
  // in contact the step's VJP carries them (contact/rigid_contact_derivatives.hpp).
  const bool coupled = model.contact.with_rigid();
  VecX bar_rigid = VecX::Zero(12 * nr), bar_rigid_p = VecX::Zero(7 * nr);
  rigid::Bdf2StepJacobian rigid_J;
  // BDF2: the rigid cotangent of frame s-1 that step s+1 sent back through its history.
  VecX pending_rigid = VecX::Zero(12 * nr), bar_rigid_previous = VecX::Zero(12 * nr);
  const bool rigid_bdf2 = model.step.integrator == IntegratorKind::bdf2;
  const bool restarts = static_cast<long>(tape.rigid_at_limit.size()) == T * nr;
  integrator::StepDerivatives derivatives(model, theta.parameters);
  result.theta = VecX::Zero(theta.size(model));
  result.lambda_a = MatX::Zero(na, T);
  integrator::StateTangent bar;
  bar.x = VecX::Zero(n);
  bar.v = VecX::Zero(n);
  if (loss) loss(T, tape.frames[static_cast<std::size_t>(T)], bar.x, bar.v);
  if (rigid_loss && nr) rigid_loss(T, tape.frames[static_cast<std::size_t>(T)], bar_rigid);
  integrator::StepCotangent cot;
  // BDF2: step s depends on frames s-1 and s-2; `pending` holds the cotangent of frame
  // s-1 that step s+1 sent back through its history (zero for implicit Euler).
  integrator::StateTangent pending, bar_previous;
  pending.x = VecX::Zero(n);
  pending.v = VecX::Zero(n);
  State out;
  for (long step = T; step >= 1; --step) {
    const State& in = tape.frames[static_cast<std::size_t>(step - 1)];
    const State* previous = step > 1 ? &tape.frames[static_cast<std::size_t>(step - 2)] : nullptr;
    // Recompute the step's record (linearization, factorization) from its input state,
    // with the NCP warm start it had.
    if (model.contact.enabled && static_cast<long>(tape.warm_start.size()) == T) {
      const auto& w = tape.warm_start[static_cast<std::size_t>(step - 1)];
      data.contact.previous_keys = w.keys;
      data.contact.previous_lambda = w.lambda;
      data.contact.rigid.limit_lambda = w.limit_lambda;  // the limit rows' warm start (rigid_contact.hpp)
    }
    // BDF2 with rigid bodies: the restart flags the step began with (the previous step's
    // at_limit, rigid_bdf2.hpp), as recorded.
    if (rigid_bdf2 && nr) {
      data.rigid.resize(static_cast<std::size_t>(nr));
      for (std::size_t r = 0; r < static_cast<std::size_t>(nr); ++r)
        data.rigid[r].at_limit = step > 1 && restarts && tape.rigid_at_limit[static_cast<std::size_t>(step - 2) * static_cast<std::size_t>(nr) + r];
    }
    const StepStatus st =
        integrator::time_step(model, data, in, previous, out, step, &tape.lambda_a[static_cast<std::size_t>(step - 1)]);
    if (!st.ok()) return st;
    const State& recorded = tape.frames[static_cast<std::size_t>(step)];
    // (A scene of rigid bodies only has no soft coordinate: x, v empty, nothing compared.
    // The rigid states are not compared: doing so showed 2.7e-16 on the operator backend's
    // sliding wedge, test_contact_derivatives.cpp; not bit for bit there, not pursued yet.)
    if (out.x.size() > 0)
      result.recompute_mismatch = std::max({result.recompute_mismatch, (out.x - recorded.x).cwiseAbs().maxCoeff(),
                                            (out.v - recorded.v).cwiseAbs().maxCoeff()});
    if (coupled)
      bar.rigid = bar_rigid;
    else
      bar.rigid.resize(0);
    if (!integrator::multistep_vjp(derivatives, model, data, out, bar, cot, bar_previous, &in, previous)) return derivative_failed(step);
    result.theta.head(np) += cot.p;
    result.lambda_a.col(step - 1) = cot.lambda_a;
    if (theta.actuation) result.theta.segment(np, na) += cot.lambda_a;
    bar.x = cot.x + pending.x;
    bar.v = cot.v + pending.v;
    pending.x = bar_previous.x;
    pending.v = bar_previous.v;
    bar_rigid_previous.setZero();
    const bool multistep = data.history_weight != 0 && previous;
    if (coupled) {
      bar_rigid = cot.rigid;
      bar_rigid_p += cot.rigid_p;
      // BDF2: cot.rigid is the cotangent of the extrapolated states: split it onto the
      // step's input and previous states and the parameters (rigid_bdf2_derivatives.hpp).
      // The branch is the step's record (history_weight, bdf2.cpp): every body is BDF2 on
      // a BDF2 step in contact (a limit restarts the whole step as implicit Euler).
      for (Eigen::Index r = 0; multistep && r < nr; ++r) {
        const auto i = static_cast<std::size_t>(r);
        rigid::extrapolation_jacobian(model.rigid[i], in.rigid[i], previous->rigid[i], data.hat.rigid[i],
                                      rigid_J.extrapolation);
        const rigid::Vec12 bar_hat = cot.rigid.segment<12>(12 * r);
        bar_rigid.segment<12>(12 * r) = rigid_J.extrapolation.in.transpose() * bar_hat;
        bar_rigid_previous.segment<12>(12 * r) = rigid_J.extrapolation.previous.transpose() * bar_hat;
        bar_rigid_p.segment<7>(7 * r) += rigid_J.extrapolation.params.transpose() * bar_hat;
      }
    }
    // The rigid bodies without contact: bar_in = J_state^T bar_out, bar_params += J_params^T
    // bar_out (BDF2: bar_previous = J_previous^T bar_out too). The branch is the recomputed
    // step's record (data.rigid[i].bdf2), as in the forward mode.
    for (Eigen::Index r = 0; !coupled && r < nr; ++r) {
      const auto i = static_cast<std::size_t>(r);
      rigid::bdf2_step_jacobian(model.rigid[i], in.rigid[i], multistep && rigid_bdf2 ? &previous->rigid[i] : nullptr,
                                rigid_bdf2 ? data.hat.rigid[i] : in.rigid[i], out.rigid[i],
                                data.rigid[i], model.step.dt, model.step.gravity, rigid_J);
      const rigid::Vec12 bar_out_r = bar_rigid.segment<12>(12 * r);
      bar_rigid.segment<12>(12 * r) = rigid_J.state.transpose() * bar_out_r;
      bar_rigid_p.segment<7>(7 * r) += rigid_J.params.transpose() * bar_out_r;
      if (rigid_J.bdf2) bar_rigid_previous.segment<12>(12 * r) = rigid_J.previous.transpose() * bar_out_r;
    }
    bar_rigid += pending_rigid;
    pending_rigid.swap(bar_rigid_previous);
    if (loss) loss(step - 1, in, bar.x, bar.v);
    if (rigid_loss && nr) rigid_loss(step - 1, in, bar_rigid);
  }
  for (std::size_t j = 0; j < theta.rigid_parameters.size(); ++j) {
    const auto& p = theta.rigid_parameters[j];
    result.theta[rp0 + static_cast<Eigen::Index>(j)] = bar_rigid_p[7 * p.body + p.index];
  }
  result.x0 = bar.x;
  result.v0 = bar.v;
  result.rigid0 = bar_rigid;
  // x0, v0 with rigid bodies: the soft coordinates, then 6 per rigid body.
  VecX full_x(n + 6 * nr), full_v(n + 6 * nr);
  full_x.head(n) = bar.x;
  full_v.head(n) = bar.v;
  for (Eigen::Index r = 0; r < nr; ++r) {
    full_x.segment<6>(n + 6 * r) = bar_rigid.segment<6>(12 * r);
    full_v.segment<6>(n + 6 * r) = bar_rigid.segment<6>(12 * r + 6);
  }
  if (theta.x0)
    result.theta.segment(theta.x0_offset(model), basis_columns(true, theta.x0_basis, model)) =
        theta.x0_basis.size() ? VecX(theta.x0_basis.transpose() * full_x) : full_x;
  if (theta.v0)
    result.theta.segment(theta.v0_offset(model), basis_columns(true, theta.v0_basis, model)) =
        theta.v0_basis.size() ? VecX(theta.v0_basis.transpose() * full_v) : full_v;
  return {};
}

}  // namespace softdiff::diff
