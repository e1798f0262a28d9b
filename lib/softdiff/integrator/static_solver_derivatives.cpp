// Derivatives of the static equilibrium: see static_solver_derivatives.hpp.
#include <softdiff/integrator/static_solver_derivatives.hpp>

#include <softdiff/contact/contact_step_derivatives.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/fem_derivatives.hpp>
#include <softdiff/integrator/implicit_euler.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <variant>

namespace softdiff::integrator {

namespace {

// The proximal factor of a body held by contact alone (its K is singular on the rigid
// motions): tau_b = c max_i |K_ii| over its free dofs, c from kProximalMin, grown
// tenfold up to kProximalMax until K + tau E factorizes (the static solver's schedule,
// static_solver.cpp). The refinement below removes tau's effect on the answer.
constexpr double kProximalMin = 1e-8;
constexpr double kProximalMax = 1e-3;
// The refinement stops when an iteration changes the solution by at most this much
// relative to its largest entry (it contracts by about tau / lambda_min per iteration,
// lambda_min the smallest stiffness left once the contacts hold the rigid motions, so
// a few iterations reach it; the solves' round-off is below), or fails after
// kMaxRefinements iterations. Without held bodies and geometry terms (fixed nodes,
// contact with planes or box faces) M = 0 and one pass is exact.
constexpr double kRefinementTolerance = 1e-13;
// Where a change stops decreasing, the refinement has reached its round-off floor: the
// rigid part of a held body's solves is ~1 / tau times the answer and cancels in it
// (measured: a change of 1e-7 of the solution on a cube that needs tau = 1e-3 max K_ii).
// Accepted up to this much of the solution, a failure above.
constexpr double kRefinementFloor = 1e-6;
constexpr int kMaxRefinements = 200;

// The linearized equilibrium at x* with the last NCP's contacts and modes held fixed
// (static_solver_derivatives.hpp, docs/method.md "Derivatives", "Static equilibrium"):
//   (K - dH^T lambda) dx - H_c^T dlambda = q,   mode rows on dsigma = H_c dx (dmu),
// solved as the refinement z <- Phi (q + M z) + Psi dmu with Phi, Psi the mode-fixed
// contact solve with K_tau = K + tau E (E: the free dofs of the bodies held by contact
// alone) and M z = tau E z + dH[z]^T lambda. Its fixed point solves the system above.
class EquilibriumSystem {
 public:
  EquilibriumSystem(const Model& model, Data& data) : model_(model), data_(data) {}

  void demand_supported() const {
    SOFTDIFF_DEMAND(model_.step.integrator == IntegratorKind::static_equilibrium,
                    "static derivatives: not a static scene");
    for (const auto& b : model_.fem.bodies)
      SOFTDIFF_DEMAND(!b.psd_projection, "static derivatives: psd_projection (body '" + b.name +
                                             "') is not differentiated in this version");
    for (const auto& a : model_.actuation.actuators) {
      const auto* servo = std::get_if<actuation::Servo>(&a.kind);
      SOFTDIFF_DEMAND(std::holds_alternative<actuation::Cable>(a.kind) || (servo && !servo->is_rotation()),
                      "static derivatives: actuator '" + a.name + "' (" + a.kind_name() +
                          ") is not differentiated in this version (cables and translation servos are)");
    }
  }

  // Evaluates and factorizes at x*, prepares the contact derivative. False if an element
  // is inverted at x*, K + tau E is not positive definite, or a solve failed.
  bool prepare(const State& equilibrium) {
    const auto& fem = model_.fem;
    x_ = &equilibrium.x;
    const Eigen::Index n = 3L * fem.num_nodes;
    for (VecX* v : {&r_, &y_, &z_, &z_next_, &m_, &tmp_}) v->setZero(n);
    if (!model_.actuation.empty()) model_.actuation.values(1.0, data_.lambda_a);
    if (!fem::evaluate(fem, *x_, {false, true, true}, data_.fem)) return false;
    const auto& cd = data_.contact;
    contact_ = model_.contact.enabled && cd.contacts.size() > 0;
    // Bodies held by contact alone: no fixed dof (the static solver's rule).
    held_.clear();
    if (model_.contact.enabled)
      for (const auto& b : fem.bodies) {
        bool any_fixed = false;
        for (int d = 3 * b.node_begin; d < 3 * (b.node_begin + b.num_nodes); ++d) any_fixed = any_fixed || fem.fixed[d];
        if (!any_fixed) held_.push_back({3 * b.node_begin, 3 * b.num_nodes, 0.0});
      }
    if (contact_) {
      const VecX& start = data_.static_load_step_start.size() == n ? data_.static_load_step_start : model_.initial.x;
      equilibrium_modes(model_, cd, *x_, start, modes_, sigma_);
    }
    // First the augmented tangent (exact, no refinement for tau), then, where it does not
    // factorize or does not apply, the proximal one.
    bool factorized = false;
    if (contact_ && augmentable()) {
      double diag_max = 0;
      for (int d = 0; d < static_cast<int>(fem.pattern.diagonal.size()); ++d)
        if (!fem.fixed[d]) diag_max = std::max(diag_max, std::abs(data_.fem.K_values[fem.pattern.diagonal[d]]));
      for (double rho = diag_max; rho <= 1e4 * diag_max && !factorized; rho *= 10) {
        assemble(0);
        augment(rho);
        factorized = factorize(model_, data_, 1).ok();
      }
    }
    for (double c = held_.empty() ? 0.0 : kProximalMin; !factorized; c *= 10) {
      assemble(c);
      factorized = factorize(model_, data_, 1).ok();
      if (!factorized && (held_.empty() || c >= kProximalMax)) return false;
    }
    if (contact_ && !stage_.prepare(model_, cd, *x_, *data_.solver, 1.0, false, &modes_, &sigma_, &data_.A)) return false;
    return true;
  }

  // z = dx* for q (projected inside) and dmu (nc; empty: zero).
  bool solve(const VecX& q, const VecX& dmu, VecX& z) {
    z_.setZero();
    m_.setZero();
    double previous = std::numeric_limits<double>::infinity();
    for (int it = 0;; ++it) {
      r_ = q + m_;
      if (!apply_phi(r_, dmu, z_next_)) return false;
      const double change = (z_next_ - z_).cwiseAbs().maxCoeff(), size = z_next_.cwiseAbs().maxCoeff();
      z_.swap(z_next_);
      if (!apply_m(z_, m_)) return false;
      if (m_.isZero(0)) break;
      const int verdict = converged(it, change, size, previous);
      if (verdict > 0) break;
      if (verdict < 0) return false;
    }
    z = z_;
    return z.allFinite();
  }

  // The transpose: u = (I - Phi^T M^T)^{-1} Phi^T bar_z (the cotangent of q) and
  // bar_mu = Psi^T (bar_z + M^T u).
  bool solve_transposed(const VecX& bar_z, VecX& u, VecX& bar_mu) {
    z_.setZero();
    m_.setZero();
    double previous = std::numeric_limits<double>::infinity();
    for (int it = 0;; ++it) {
      r_ = bar_z + m_;
      if (!apply_phi_transposed(r_, z_next_, bar_mu)) return false;
      const double change = (z_next_ - z_).cwiseAbs().maxCoeff(), size = z_next_.cwiseAbs().maxCoeff();
      z_.swap(z_next_);
      if (!apply_m_transposed(z_, m_)) return false;
      if (m_.isZero(0)) break;
      const int verdict = converged(it, change, size, previous);
      if (verdict > 0) break;
      if (verdict < 0) return false;
    }
    u = z_;
    return u.allFinite() && bar_mu.allFinite();
  }

  bool contact() const { return contact_; }
  // The largest relative change of the last refinement's last iteration (its accuracy).
  double last_change() const { return last_change_; }

 private:
  struct Held {
    int begin, size;
    double tau;
  };

  // data.A = J + c max|K_ii| E per held body (c = 0: J); tau recorded for the refinement.
  void assemble(double c) {
    const auto& fem = model_.fem;
    double* A = data_.A.valuePtr();
    for (long k = 0; k < data_.A.nonZeros(); ++k) A[k] = data_.fem.K_values[k];
    if (!model_.actuation.empty()) model_.actuation.add_stiffness(*x_, data_.lambda_a, fem.pattern, A);
    for (int k : fem.pattern.fixed_offdiagonal) A[k] = 0;
    for (int k : fem.pattern.fixed_diagonal) A[k] = 1;
    for (auto& h : held_) {
      double diag_max = 0;
      for (int d = h.begin; d < h.begin + h.size; ++d)
        diag_max = std::max(diag_max, std::abs(data_.fem.K_values[fem.pattern.diagonal[d]]));
      h.tau = c * diag_max;
      for (int d = h.begin; d < h.begin + h.size; ++d) A[fem.pattern.diagonal[d]] += h.tau;
    }
    data_.factor_is_current = false;
  }

  // The augmented tangent applies when every active contact is a single node's (a
  // vertex against an obstacle): its rows' H_i^T H_i is that node's 3x3 block, in the
  // pattern.
  bool augmentable() const {
    const auto& cd = data_.contact;
    for (int i = 0; i < cd.contacts.size(); ++i)
      if (modes_[static_cast<std::size_t>(i)] != contact::Mode::breaking && cd.contacts.contacts[i].count != 1)
        return false;
    return true;
  }

  // data.A += rho sum over the equality rows r (a sticking contact's three, a sliding
  // one's normal row) of r^T r. With those rows held (H_E dx = 0 at the solution),
  // (J + rho H_E^T H_E) dx - H_c^T dlambda = q is the same system, and J + rho H_E^T
  // H_E is positive definite where the contacts hold the bodies (an augmented
  // Lagrangian); rho from max |K_ii|, grown tenfold where it does not factorize.
  void augment(double rho) {
    const auto& cd = data_.contact;
    const SparseMatrix& A = data_.A;
    double* values = data_.A.valuePtr();
    auto value_index = [&](int row, int col) {
      const int* begin = A.innerIndexPtr() + A.outerIndexPtr()[col];
      const int* end = A.innerIndexPtr() + A.outerIndexPtr()[col + 1];
      const int* it = std::lower_bound(begin, end, row);
      SOFTDIFF_DEMAND(it != end && *it == row, "static derivatives: a node block is missing from the pattern");
      return static_cast<int>(A.outerIndexPtr()[col] + (it - A.innerIndexPtr() - A.outerIndexPtr()[col]));
    };
    for (int i = 0; i < cd.contacts.size(); ++i) {
      const auto mode = modes_[static_cast<std::size_t>(i)];
      if (mode == contact::Mode::breaking) continue;
      const int node = cd.contacts.contacts[i].nodes[0];
      Mat3 B = Mat3::Zero();
      for (int r = mode == contact::Mode::sticking ? 0 : 2; r < 3; ++r) {
        Vec3 col = Vec3::Zero();
        for (SparseMatrix::InnerIterator it(cd.Ht, 3 * i + r); it; ++it) {
          SOFTDIFF_DEMAND(it.row() / 3 == node, "static derivatives: a vertex contact's row spans another node");
          col[it.row() % 3] = it.value();
        }
        B += col * col.transpose();
      }
      for (int a = 0; a < 3; ++a)
        for (int b = a; b < 3; ++b)
          if (B(a, b) != 0) values[value_index(3 * node + a, 3 * node + b)] += rho * B(a, b);
    }
    data_.factor_is_current = false;
  }

  // 1: the refinement has converged (a change of at most kRefinementTolerance of the
  // solution, or a change that no longer decreases, the round-off floor, within
  // kRefinementFloor); -1: it fails (no contraction above that floor, too many
  // iterations, not finite); 0: go on.
  int converged(int it, double change, double size, double& previous) {
    last_change_ = size > 0 ? change / size : 0.0;
    if (!std::isfinite(change)) return -1;
    if (change <= kRefinementTolerance * size) return 1;
    if (change >= previous) return change <= kRefinementFloor * size ? 1 : -1;
    previous = change;
    return it >= kMaxRefinements ? -1 : 0;
  }

  // out = K_tau^{-1} Pi r + K_tau^{-1} H_c^T dlambda, dlambda the mode-fixed NCP's
  // answer to dsigma = H_c K_tau^{-1} Pi r at fixed lambda (and dmu).
  bool apply_phi(const VecX& r, const VecX& dmu, VecX& out) {
    tmp_ = r;
    project(model_, tmp_);
    if (!data_.solver->solve(tmp_, out)) return false;
    project(model_, out);
    if (!contact_) return true;
    const auto& cd = data_.contact;
    b_.noalias() = cd.Ht.transpose() * out;
    stage_.ncp().jvp(b_, dmu, dlambda_);
    tmp_.noalias() = cd.Ht * dlambda_;
    project(model_, tmp_);
    if (!data_.solver->solve(tmp_, y_)) return false;
    project(model_, y_);
    out += y_;
    return true;
  }

  bool apply_phi_transposed(const VecX& v, VecX& out, VecX& bar_mu) {
    tmp_ = v;
    project(model_, tmp_);
    if (!data_.solver->solve(tmp_, out)) return false;
    project(model_, out);
    if (!contact_) return true;
    const auto& cd = data_.contact;
    bar_lambda_.noalias() = cd.Ht.transpose() * out;
    stage_.ncp().vjp(bar_lambda_, bar_b_, bar_mu);
    tmp_.noalias() = cd.Ht * bar_b_;
    project(model_, tmp_);
    if (!data_.solver->solve(tmp_, y_)) return false;
    project(model_, y_);
    out += y_;
    return true;
  }

  // m = Pi (tau E z + dH[z]^T lambda).
  bool apply_m(const VecX& z, VecX& m) {
    m.setZero();
    for (const auto& h : held_) m.segment(h.begin, h.size) = h.tau * z.segment(h.begin, h.size);
    if (contact_) stage_.add_force_jvp(data_.contact, 1.0, z, m);
    project(model_, m);
    return m.allFinite();
  }

  bool apply_m_transposed(const VecX& z, VecX& m) {
    m.setZero();
    for (const auto& h : held_) m.segment(h.begin, h.size) = h.tau * z.segment(h.begin, h.size);
    if (contact_) {
      zero_b_.setZero(data_.contact.lambda.size());
      tmp_.setZero();
      stage_.add_geometry_vjp(data_.contact, tmp_, 1.0, z, zero_b_, m);
    }
    project(model_, m);
    return m.allFinite();
  }

  const Model& model_;
  Data& data_;
  const VecX* x_ = nullptr;
  bool contact_ = false;
  std::vector<Held> held_;
  contact::ContactStageDerivative stage_;
  std::vector<contact::Mode> modes_;  // the modes held (equilibrium_modes)
  VecX sigma_;
  double last_change_ = 0;
  VecX r_, y_, z_, z_next_, m_, tmp_, b_, dlambda_, bar_lambda_, bar_b_, zero_b_;
};

// q = Pi dR/dtheta_c for column c (parameters, then actuators); false on failure. A
// friction column has q = 0 (it acts through the NCP): *friction is then set.
bool parameter_column(const Model& model, Data& data, const VecX& x, const StaticTheta& theta, Eigen::Index c,
                      VecX& q, bool& friction) {
  const auto& fem = model.fem;
  const auto np = static_cast<Eigen::Index>(theta.parameters.size());
  q.setZero();
  friction = false;
  if (c >= np) {
    model.actuation.add_forces(x, VecX::Unit(static_cast<Eigen::Index>(model.actuation.actuators.size()), c - np), 1.0,
                               q);
    project(model, q);
    return true;
  }
  const ParameterId& id = theta.parameters[static_cast<std::size_t>(c)];
  if (id.kind == Parameter::friction) {
    friction = true;
    return true;
  }
  const auto& body = fem.bodies[static_cast<std::size_t>(id.body)];
  const Eigen::Index begin = 3L * body.node_begin, len = 3L * body.num_nodes;
  switch (id.kind) {
    case Parameter::young: q.segment(begin, len) = data.fem.f_int.segment(begin, len) / body.young; break;
    case Parameter::poisson: {
      VecX dKw = VecX::Zero(q.size());
      const VecX zero = VecX::Zero(q.size());
      if (fem::add_elastic_parameter_derivative(fem, x, id.body, fem::ElasticParameter::poisson, zero, q, dKw) >= 0)
        return false;
      break;
    }
    case Parameter::density: q.segment(begin, len) = fem.gravity_force.segment(begin, len) / body.density; break;
    case Parameter::rayleigh_mass:
    case Parameter::rayleigh_stiffness:
    case Parameter::friction: break;  // no effect on the equilibrium (friction: above)
  }
  project(model, q);
  return true;
}

// dmu of a unit friction column c (its pair rule's contacts).
void friction_direction(const Model& model, const Data& data, const StaticTheta& theta, Eigen::Index c, VecX& dmu) {
  VecX dp = VecX::Unit(static_cast<Eigen::Index>(theta.parameters.size()), c);
  contact::ContactStageDerivative::friction_tangent(model, data.contact, theta.parameters, dp, dmu);
}

}  // namespace

void equilibrium_modes(const Model& model, const ContactData& cd, const VecX& x, const VecX& x_start,
                       std::vector<contact::Mode>& modes, VecX& sigma) {
  const int nc = cd.contacts.size();
  modes.assign(static_cast<std::size_t>(nc), contact::Mode::breaking);
  sigma = VecX::Zero(3L * nc);
  const double scale = nc > 0 ? cd.lambda.cwiseAbs().maxCoeff() : 0.0;
  const double tol = 10 * model.contact.ncp.tolerance * scale;
  double size = 0;
  for (const auto& b : model.fem.bodies) size = std::max(size, b.bbox_diagonal);
  const VecX u = x - x_start;
  for (int i = 0; i < nc; ++i) {
    const Vec3 l = cd.lambda.segment<3>(3 * i);
    const double mu = cd.mu[i], lT = l.head<2>().norm();
    auto& m = modes[static_cast<std::size_t>(i)];
    if (l[2] <= tol) {
      m = contact::Mode::breaking;
      sigma[3 * i + 2] = std::max(cd.sigma[3 * i + 2], 0.0);
    } else if (mu == 0 || mu * l[2] - lT <= tol) {
      m = contact::Mode::sliding;
      if (mu == 0 || lT == 0) continue;
      Eigen::Vector2d s;
      for (int r = 0; r < 2; ++r) s[r] = cd.Ht.col(3 * i + r).dot(u);
      if (s.norm() > 1e-9 * size) sigma.segment<2>(3 * i) = s;
      else sigma.segment<2>(3 * i) = -l.head<2>() / lT * (1e100 * std::max(scale, 1.0));
    } else {
      m = contact::Mode::sticking;
    }
  }
}

bool static_sensitivities(const Model& model, Data& data, const State& equilibrium, const StaticTheta& theta,
                          MatX& dx_dtheta) {
  EquilibriumSystem system(model, data);
  system.demand_supported();
  const Eigen::Index n = 3L * model.fem.num_nodes, np = static_cast<Eigen::Index>(theta.parameters.size());
  const Eigen::Index na = theta.actuation ? static_cast<Eigen::Index>(model.actuation.actuators.size()) : 0;
  if (!system.prepare(equilibrium)) return false;
  dx_dtheta = MatX::Zero(n, np + na);
  VecX q(n), z(n), dmu;
  for (Eigen::Index c = 0; c < np + na; ++c) {
    bool friction = false;
    if (!parameter_column(model, data, equilibrium.x, theta, c, q, friction)) return false;
    dmu.resize(0);
    if (friction) {
      if (!system.contact()) continue;  // no contact at the equilibrium: no effect
      friction_direction(model, data, theta, c, dmu);
    }
    if (!system.solve(q, dmu, z)) return false;
    dx_dtheta.col(c) = z;
  }
  return dx_dtheta.allFinite();
}

bool static_vjp(const Model& model, Data& data, const State& equilibrium, const StaticTheta& theta, const VecX& bar_x,
                VecX& bar_theta) {
  EquilibriumSystem system(model, data);
  system.demand_supported();
  const Eigen::Index n = 3L * model.fem.num_nodes, np = static_cast<Eigen::Index>(theta.parameters.size());
  const Eigen::Index na = theta.actuation ? static_cast<Eigen::Index>(model.actuation.actuators.size()) : 0;
  SOFTDIFF_DEMAND(bar_x.size() == n, "static_vjp: bar_x must have size 3n = " + std::to_string(n));
  if (!system.prepare(equilibrium)) return false;
  VecX u(n), bar_mu, q(n);
  if (!system.solve_transposed(bar_x, u, bar_mu)) return false;
  bar_theta = VecX::Zero(np + na);
  for (Eigen::Index c = 0; c < np + na; ++c) {
    bool friction = false;
    if (!parameter_column(model, data, equilibrium.x, theta, c, q, friction)) return false;
    if (!friction) bar_theta[c] = u.dot(q);
  }
  if (system.contact() && bar_mu.size()) {
    VecX bar_p = VecX::Zero(np);
    contact::ContactStageDerivative::add_friction_cotangent(model, data.contact, theta.parameters, bar_mu, bar_p);
    bar_theta.head(np) += bar_p;
  }
  return bar_theta.allFinite();
}

}  // namespace softdiff::integrator
