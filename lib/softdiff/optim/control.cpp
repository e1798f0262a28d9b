// Inverse dynamics: see control.hpp.
#include <softdiff/optim/control.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/optim/box_qp.hpp>

#include <limits>

namespace softdiff::optim {

InverseDynamics::InverseDynamics(const Model& model, const ControlOptions& options)
    : options_(options), data_(model) {
  data_.keep_linearization = true;
  const auto& eff = model.actuation.effectors;
  SOFTDIFF_DEMAND(options.effector >= 0 && options.effector < static_cast<int>(eff.size()), "control: no such effector");
  SOFTDIFF_DEMAND(!model.actuation.actuators.empty(), "control: the scene has no actuators");
  SOFTDIFF_DEMAND(options.filter > 0 && options.filter <= 1, "control: filter must be in (0, 1]");
  SOFTDIFF_DEMAND(model.step.integrator == IntegratorKind::implicit_euler || model.step.integrator == IntegratorKind::bdf2,
                  "control: needs the implicit Euler or BDF2 integrator");
  derivatives_ = std::make_unique<integrator::StepDerivatives>(model, std::vector<ParameterId>{});
  const Eigen::Index na = static_cast<Eigen::Index>(model.actuation.actuators.size());
  const double inf = std::numeric_limits<double>::infinity();
  lo_ = VecX::Constant(na, -inf);
  hi_ = VecX::Constant(na, inf);
  for (Eigen::Index j = 0; j < na; ++j) {
    const auto& a = model.actuation.actuators[static_cast<std::size_t>(j)];
    if (a.has_limits) {
      lo_[j] = a.limits[0];
      hi_[j] = a.limits[1];
    }
  }
  const auto& b = model.fem.bodies[static_cast<std::size_t>(eff[static_cast<std::size_t>(options.effector)].body)];
  body_begin_ = b.node_begin;
  body_nodes_ = b.num_nodes;
}

namespace {
// lambda with the self-contacts' rows zeroed (their forces are internal to a body).
VecX external(const Data& data, const VecX& lambda) {
  VecX out = lambda;
  const auto& contacts = data.contact.contacts.contacts;
  for (std::size_t i = 0; i < contacts.size(); ++i)
    if (contacts[i].side_a == contacts[i].side_b) out.segment<3>(3 * static_cast<Eigen::Index>(i)).setZero();
  return out;
}
}  // namespace

VecX InverseDynamics::nodal_contact_forces(const Data& data, const VecX& lambda) const {
  return (data.contact.Ht * external(data, lambda)).segment(3L * body_begin_, 3L * body_nodes_);
}

double InverseDynamics::contact_force_norm(const Model& model, const Data& data) const {
  if (!model.contact.enabled || data.contact.contacts.empty()) return 0;
  return nodal_contact_forces(data, data.contact.lambda).norm();
}

StepStatus InverseDynamics::compute(const Model& model, const State& s, long k, const Vec3& goal, const VecX& previous,
                                    VecX& lambda_out, ControlStep& info, const State* history) {
  const Eigen::Index na = previous.size();
  SOFTDIFF_DEMAND(na == lo_.size(), "control: one actuation value per actuator");
  const StepStatus st = integrator::time_step(model, data_, s, k > 1 ? history : nullptr, prediction_, k, &previous);
  if (!st.ok() && st.code != StepStatus::Code::not_converged) return st;
  const auto& e = model.actuation.effectors[static_cast<std::size_t>(options_.effector)].effector;
  info.predicted = e.position(prediction_.x);
  const bool contact = model.contact.enabled && !data_.contact.contacts.empty() && options_.beta > 0;
  const Eigen::Index nd = options_.shared ? 1 : na;  // QP variables
  Eigen::Matrix<double, 3, Eigen::Dynamic> Ja(3, nd);  // fixed 3 rows: its columns are Vec3
  MatX Jc;
  VecX F;
  if (contact) {
    F = nodal_contact_forces(data_, data_.contact.lambda);
    Jc.resize(F.size(), nd);
  }
  StepStatus failed;
  failed.code = StepStatus::Code::solver_failed;
  failed.step = k;
  failed.detail = "control: the derivative of the step with respect to the actuation failed";
  // The actuation directions: the unit vectors, or all ones (shared).
  if (options_.shared)
    directions_.setOnes(na, 1);
  else
    directions_.setIdentity(na, na);
  if (!(model.contact.enabled && !data_.contact.contacts.empty())) {
    // No contact in the record: all nd columns in one solve with nd right-hand sides
    // (StepDerivatives::actuation_jvps), BDF2 at (x^, v^); rigidified parts included (the
    // reduced solve and the placement's tangent per column, rigidify_derivatives.hpp).
    if (!derivatives_->actuation_jvps(model, data_, data_.hat, prediction_, directions_, dx_columns_)) return failed;
    for (Eigen::Index j = 0; j < nd; ++j) {
      column_ = dx_columns_.col(j);
      Ja.col(j) = e.point().position(column_);  // W dx (p is linear in x)
    }
  } else {
    // Contact: the tangent goes through the NCP's modes (the mode-fixed system, the
    // contact forces' tangent for J_c), one jvp() per column; rigidified parts too.
    integrator::StepTangent t;
    integrator::StateTangent r;
    for (Eigen::Index j = 0; j < nd; ++j) {
      t.lambda_a = directions_.col(j);
      if (!derivatives_->jvp(model, data_, data_.hat, prediction_, t, r)) return failed;  // BDF2: at (x^, v^)
      Ja.col(j) = e.point().position(r.x);  // W dx (p is linear in x)
      if (contact) Jc.col(j) = nodal_contact_forces(data_, derivatives_->contact_force_tangent());
    }
  }
  info.contact_force_norm = F.size() ? F.norm() : contact_force_norm(model, data_);
  info.Ja = Ja;
  info.F = F;
  info.Jc = Jc;
  // The QP.
  Vec3 err = info.predicted - goal;
  for (int c = 0; c < 3; ++c)
    if (!options_.axes[static_cast<std::size_t>(c)]) {
      err[c] = 0;
      Ja.row(c).setZero();
    }
  MatX H = options_.alpha * Ja.transpose() * Ja;
  VecX g = options_.alpha * Ja.transpose() * err;
  double scale = options_.alpha * Ja.squaredNorm();
  if (contact) {
    H += options_.beta * Jc.transpose() * Jc;
    g += options_.beta * Jc.transpose() * F;
    scale += options_.beta * Jc.squaredNorm();
  }
  const double rho = options_.regularization * std::max(scale, 1e-300) / static_cast<double>(nd);
  H += rho * MatX::Identity(nd, nd);
  VecX lo = lo_ - previous, hi = hi_ - previous;
  if (options_.shared) {
    lo = VecX::Constant(1, lo.maxCoeff());
    hi = VecX::Constant(1, std::max(hi.minCoeff(), lo[0]));
  }
  const BoxQpResult qp = solve_box_qp(H, g, lo, hi);
  info.delta = options_.shared ? VecX(VecX::Constant(na, qp.d[0])) : qp.d;
  info.kkt = qp.kkt;
  info.qp_iterations = qp.iterations;
  info.qp_converged = qp.converged;
  lambda_out = previous + options_.filter * info.delta;
  // Round-off must not leave the limits.
  lambda_out = lambda_out.cwiseMax(lo_).cwiseMin(hi_);
  return {};
}

}  // namespace softdiff::optim
