// Derivatives of the static equilibrium: see static_solver_derivatives.hpp.
#include <softdiff/integrator/static_solver_derivatives.hpp>

#include <softdiff/contact/contact_step_derivatives.hpp>
#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/rigid/rigid_body.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/fem_derivatives.hpp>
#include <softdiff/integrator/empty_system.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/rigidify.hpp>
#include <softdiff/integrator/static_rigid.hpp>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdio>
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
// The rigid bodies' proximal block (they have no stiffness): tau_r diag(m I, I_w) with
// tau_r m = kRigidProximal max K_ii over the soft free dofs. Its effect on the answer is
// removed by the refinement, which contracts by ~ tau_r m / (the supports' stiffness on
// the body's motion, many K_ii): a few iterations; its round-off ~ eps / kRigidProximal
// (the rigid part of G is ~ 1 / tau_r and cancels in dlambda): ~ 2e-12 relative.
// 1e-4 since 2026-12-04 (branch ffric; 1e-6 before): a free body in frictional contact
// (static.friction load_step) has its mass column cancelled in the sticking contacts'
// tangential rows too, and at 1e-6 the refinement stalled at 1.4e-6 to 4.7e-5 of that
// column, above kRefinementFloor; at 1e-4 it converges (docs/method.md
// *Load-step-anchored friction*, the free body), the other static rigid tests unchanged
// within their tolerances (the frictionless corner's vjp agreement 1.9e-8 -> 1.6e-11).
constexpr double kRigidProximal = 1e-4;

// The largest |entry| (0 for an empty vector: Eigen's maxCoeff needs one entry).
template <typename V>
double max_abs(const V& v) {
  return v.size() > 0 ? v.cwiseAbs().maxCoeff() : 0.0;
}

// The linearized equilibrium at x* with the last NCP's contacts and modes held fixed
// (static_solver_derivatives.hpp, docs/method.md "Derivatives", "Static equilibrium"):
//   (K - dH^T lambda) dx - H_c^T dlambda = q,   mode rows on dsigma = H_c dx (dmu),
// solved as the refinement z <- Phi (q + M z) + Psi dmu with Phi, Psi the mode-fixed
// contact solve with K_tau = K + tau E (E: the free dofs of the bodies held by contact
// alone) and M z = tau E z + dH[z]^T lambda. Its fixed point solves the system above.
class EquilibriumSystem {
 public:
  EquilibriumSystem(const Model& model, Data& data, bool measure_free_body_friction = false)
      : model_(model), data_(data), measure_free_body_friction_(measure_free_body_friction) {}
  EquilibriumSystem(const EquilibriumSystem&) = delete;
  EquilibriumSystem& operator=(const EquilibriumSystem&) = delete;

  void demand_supported() const {
    SOFTDIFF_DEMAND(model_.step.integrator == IntegratorKind::static_equilibrium,
                    "static derivatives: not a static scene");
    for (const auto& b : model_.fem.bodies)
      SOFTDIFF_DEMAND(!b.psd_projection, "static derivatives: psd_projection (body '" + b.name +
                                             "') is not differentiated in this version");
    // Free bodies beside soft bodies (docs/method.md "Static equilibrium with rigid bodies",
    // *Free bodies beside soft bodies*). Frictionless: differentiated (2026-12-04, srfree)
    // where the contacts at x* hold all six dofs (demand_free_bodies_held, in prepare: a
    // flat support leaves sliding and spinning free, and the pose is then not determinate).
    // With friction refused: with static.friction iterate each Newton iteration's NCP sticks
    // relative to that iterate, so the tangential state is the stick accumulated along the
    // solver's path (2% to 20% off the differences on the cube on the slab, rstd), and
    // check-grad's path-dependence count (sgrad) reads the soft nodes' displacement only,
    // not the rigid body's share of a contact's slip, so it could not tell a body stuck
    // from the first iterate. With static.friction load_step (2026-12-04, branch sfric) the
    // equilibrium is a function of the parameters, but this derivative is not validated
    // there (docs/method.md *Load-step-anchored friction*): with the face terms in the mode
    // rows, kRigidProximal 1e-4 and the sticking contacts' tangential rows in
    // demand_free_bodies_held (ffric) it agrees with differences on the cube on the slab,
    // not in the soft corner with friction on its walls (below).
    const int nb = static_cast<int>(model_.fem.bodies.size());
    for (std::size_t r = 0; r < model_.rigid.size(); ++r) {
      const auto& b = model_.rigid[r];
      if (b.joint.kind != rigid::Joint::Kind::free || model_.fem.num_nodes == 0) continue;
      const double mu = model_.contact.detection.max_friction(nb + static_cast<int>(r));
      // static.friction load_step (2026-12-04, branch ffric): the derivative with the face
      // terms agrees with central differences on the free cube on the slab (1e-7) and in the
      // soft corner with friction on the slab alone, but not with friction on the corner's
      // walls (1.5e-2 at mu 0.5): there the edge-edge records are kinematically redundant
      // with the vertex-face records and, under sliding friction, the mode-fixed system's
      // null space moves the nodes, so the derivative is not unique (2026-12-04, session 20:
      // docs/method.md *Found*). Still refused; what would lift it: refuse exactly where J's
      // null space moves the nodes (dense path) and differentiate elsewhere.
      // StaticTheta::measure_free_body_friction computes it for those measurements (the
      // tests), never the CLI.
      if (model_.step.static_friction == StaticFriction::load_step && measure_free_body_friction_) continue;
      SOFTDIFF_DEMAND(mu == 0,
                      "static derivatives of a free rigid body with friction are not supported yet (issue 21; "
                      "rigid body '" + b.name + "'): with friction (" + std::to_string(mu) +
                          ") and static.friction iterate its static tangential state is the stick accumulated along "
                          "the solver's path, not a function of the parameters; with static.friction load_step it "
                          "is, but its derivative is not validated yet: it is not unique where redundant contact "
                          "records slide (docs/method.md \"Static equilibrium with contact\", *Found*), and those "
                          "places are not told apart yet (frictionless free bodies are differentiated: "
                          "docs/method.md \"Static equilibrium with rigid bodies\")");
    }
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
    // A scene of rigid bodies only (no soft dof): no soft system, every solve with it of size
    // 0 (empty_system.hpp, as the dynamic rigid-only derivative's).
    static EmptySystem no_soft;  // stateless
    solver_ = n > 0 ? data_.solver.get() : &no_soft;
    if (n > 0 && !fem::evaluate(fem, *x_, {false, true, true}, data_.fem)) return false;
    const auto& cd = data_.contact;
    contact_ = model_.contact.enabled && cd.contacts.size() > 0;
    if (!model_.rigid.empty()) prepare_rigid(equilibrium);
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
    demand_free_bodies_held();
    // First the augmented tangent (exact, no refinement for tau), then, where it does not
    // factorize or does not apply, the proximal one.
    bool factorized = false;
    // (With parts not: the augmentation would touch their identity rows, and their
    // coupling values are K's alone.)
    if (contact_ && rigid_bodies_ == 0 && model_.rigidify.empty() && augmentable()) {
      double diag_max = 0;
      for (int d = 0; d < static_cast<int>(fem.pattern.diagonal.size()); ++d)
        if (!fem.fixed[d]) diag_max = std::max(diag_max, std::abs(data_.fem.K_values[fem.pattern.diagonal[d]]));
      for (double rho = diag_max; rho <= 1e4 * diag_max && !factorized; rho *= 10) {
        assemble(0);
        augment(rho);
        factorized = factorize(model_, data_, 1).ok();
      }
    }
    if (n == 0) factorized = true;
    // With parts the reduced matrix S - Q must factorize too: on a body held by contact
    // alone (rstp) its proximal term is in S (prepare_parts), and c grows where either
    // factorization fails (under stress S - Q is indefinite along the body's rigid
    // rotations that the contacts hold, as K is).
    bool parts_ready = false;
    for (double c = held_.empty() ? 0.0 : kProximalMin; !factorized; c *= 10) {
      assemble(c);
      factorized = factorize(model_, data_, 1).ok();
      if (factorized && !model_.rigidify.empty()) factorized = parts_ready = prepare_parts();
      if (!factorized && (held_.empty() || c >= kProximalMax)) return false;
    }
    // Parts: every soft solve below is the reduced one (beside rigid bodies too, since
    // rstp: their rows W_r and the contacts' G are built on solver_, the parts' reduced
    // system then).
    if (!model_.rigidify.empty()) {
      if (!parts_ready && !prepare_parts()) return false;
      solver_ = &reduced_;
    }
    if (!model_.rigid.empty()) return prepare_rigid_contact() && prepare_slip_terms();
    // (With parts no A_upper: the operator path's preconditioner is built from the full A,
    // not the reduced one; without it the mode-fixed system is solved through solver_.)
    if (contact_ && !stage_.prepare(model_, contact_data(), *x_, *solver_, 1.0, false, &modes_, &sigma_,
                                    model_.rigidify.empty() ? &data_.A : nullptr))
      return false;
    return prepare_slip_terms();
  }

  // static.friction load_step (2026-12-04, branch ffric; docs/method.md *Load-step-anchored
  // friction*, the face terms): a frictional contact's slip s = t . sum_k w_k (X_k -
  // X_k^start) is measured through its current weights and frame, so its mode rows hold
  // H_T dx + e[dx] (contact_step_derivatives.hpp add_slip_jvp: dt . d + t . sum_k dw_k D_k),
  // not H_T dx alone. e depends on the whole dx (soft nodes and, with rigid bodies, the
  // pseudo-nodes' dp + dtheta x rho), so it enters the refinement as M does: the NCP's
  // right-hand side of iteration k carries e[z_{k-1}] (apply_m computes it, apply_phi adds
  // it); its fixed point solves the system with the full mode rows. The transpose: the
  // cotangent bar_b of the last Phi^T enters the next iterate through e^T (apply_m_transposed).
  // D = X* - X^start on the contacts' (extended) positions; without a recorded start, the
  // initial state's (as equilibrium_modes' fallback). Off (slip_terms_ false, e = 0)
  // under static.friction iterate and where no contact has friction: bit for bit as before.
  bool prepare_slip_terms() {
    slip_terms_ = false;
    e_.setZero(contact_ ? 3L * contact_data().contacts.size() : 0);
    if (!contact_ || model_.step.static_friction != StaticFriction::load_step || max_abs(contact_data().mu) == 0)
      return true;
    const VecX& now = rigid_bodies_ > 0 ? ext_x_ : *x_;
    if (data_.static_load_step_start_extended.size() == now.size()) {
      slip_D_ = now - data_.static_load_step_start_extended;
    } else {
      extended_positions(model_, model_.initial.x, model_.initial.rigid, slip_D_);
      SOFTDIFF_DEMAND(slip_D_.size() == now.size(), "static derivatives: the load step's start has " +
                                                        std::to_string(slip_D_.size()) + " extended positions, expected " +
                                                        std::to_string(now.size()));
      slip_D_ = now - slip_D_;
    }
    slip_terms_ = true;
    return true;
  }

  // The rigid unknowns' size (6R; 0 without rigid bodies).
  Eigen::Index rigid_size() const { return 6 * static_cast<Eigen::Index>(model_.rigid.size()); }

  // z = dx* for q (projected inside) and dmu (nc; empty: zero).
  // With rigid bodies, q_r and z_r are their parts (6R; q_r empty: zero).
  bool solve(const VecX& q, const VecX& dmu, VecX& z, const VecX& q_r = VecX(), VecX* z_r = nullptr) {
    z_.setZero();
    m_.setZero();
    e_.setZero();  // e[z_] of z_ = 0
    zr_.setZero(rigid_size());
    mr_.setZero(rigid_size());
    free_scale_ = 0;
    double previous = std::numeric_limits<double>::infinity();
    for (int it = 0;; ++it) {
      r_ = q + m_;
      rr_ = mr_;
      if (q_r.size()) rr_ += q_r;
      if (!apply_phi(r_, dmu, z_next_)) return false;
      // (max_abs: 0 for the empty soft part of a scene of rigid bodies only)
      double change = max_abs(z_next_ - z_), size = max_abs(z_next_);
      if (rigid_size()) {
        change = std::max(change, max_abs(zr_next_ - zr_));
        size = std::max(size, max_abs(zr_next_));
        zr_.swap(zr_next_);
      }
      z_.swap(z_next_);
      if (!apply_m(z_, m_)) return false;
      if (m_.isZero(0) && mr_.isZero(0) && e_.isZero(0)) break;
      const int verdict = converged(it, change, size, previous);
      if (verdict > 0) break;
      if (verdict < 0) return false;
    }
    z = z_;
    if (z_r) *z_r = zr_;
    return z.allFinite() && zr_.allFinite();
  }

  // The transpose: u = (I - Phi^T M^T)^{-1} Phi^T bar_z (the cotangent of q) and
  // bar_mu = Psi^T (bar_z + M^T u).
  bool solve_transposed(const VecX& bar_z, VecX& u, VecX& bar_mu, const VecX& bar_zr = VecX(), VecX* u_r = nullptr) {
    z_.setZero();
    m_.setZero();
    zr_.setZero(rigid_size());
    mr_.setZero(rigid_size());
    free_scale_ = 0;
    double previous = std::numeric_limits<double>::infinity();
    for (int it = 0;; ++it) {
      r_ = bar_z + m_;
      rr_ = mr_;
      if (bar_zr.size()) rr_ += bar_zr;
      if (!apply_phi_transposed(r_, z_next_, bar_mu)) return false;
      // (max_abs: 0 for the empty soft part of a scene of rigid bodies only)
      double change = max_abs(z_next_ - z_), size = max_abs(z_next_);
      if (rigid_size()) {
        change = std::max(change, max_abs(zr_next_ - zr_));
        size = std::max(size, max_abs(zr_next_));
        zr_.swap(zr_next_);
      }
      z_.swap(z_next_);
      if (!apply_m_transposed(z_, m_)) return false;
      if (m_.isZero(0) && mr_.isZero(0)) break;
      const int verdict = converged(it, change, size, previous);
      if (verdict > 0) break;
      if (verdict < 0) return false;
    }
    u = z_;
    if (u_r) *u_r = zr_;
    return u.allFinite() && zr_.allFinite() && bar_mu.allFinite();
  }

  bool contact() const { return contact_; }

  // The contacts the derivative differentiates: the last NCP's (a vertex resting on an
  // edge or vertex of a flat region is recorded against the face's plane by detection:
  // collision/detection.cpp, docs/method.md "Contact normals at tiny gaps").
  const ContactData& contact_data() const { return data_.contact; }
  // The largest relative change of the last refinement's last iteration (its accuracy).
  double last_change() const { return last_change_; }

 private:
  // Rigidified parts (docs/method.md "Static equilibrium with rigidified parts",
  // *Derivatives*): the reduced equilibrium P(x)^T R(x) = 0, x on the parts' rigid motions
  // (x_i = c + dp + exp([dtheta]) a_i on part p, a_i = x_i - c). Its linearization at x*
  // in the reduced unknowns (soft dx, (dp, dtheta) per part) is
  //     (P^T K P - Q) du - P^T H_c^T dlambda - P^T dH^T lambda P du = P^T q,
  // the static derivative's system above on the parts' motions, plus the arms' rotation
  // in P^T: d(sum_i a_i x R_i) = sum_i (dtheta x a_i) x R_i = Q_p dtheta, Q_p =
  // sum_i [R_i]x [a_i]x (R_i = f_int + P + f_act + H_c^T lambda on the part's nodes: not
  // zero one by one, only their resultant and moment are). The centre's move adds
  // -dc x sum_i R_i = 0 at the equilibrium. Q_p is symmetric up to the converged moment
  // sum a_i x R_i (its antisymmetric part is [sum a_i x R_i]x / 2): its symmetric part is
  // taken. The solves are rigidify.hpp's Schur complement on the one factorization of
  // K (parts' dofs identity rows) with S - Q (ReducedSystem below).
  // Every scene with free or servo-attached parts is differentiated since rstp (rstat
  // refused three): beside rigid bodies (the bodies' rows W_r beside the parts' reduced
  // system: prepare; a free body beside soft bodies stays refused, as without parts), a
  // cable acting on a part's nodes (its stiffness in the parts' coupling: prepare_parts),
  // a part on a body held by contact alone (its proximal term in the coupling too).
  //
  // The parts' Schur complement at x* (prepare_rigidified, h = 1), less Q. Its coupling
  // values are the derivative's tangent's (2026-12-04, branch rstp): prepare_rigidified
  // reads a static model's coupling from data.fem.K_values alone, so while it reads them
  // K_values holds K + the cables' stiffness lambda d^2L/dx^2 (the cables' cliques are in
  // the pattern: ActuationModel::stiffness_cliques; the soft rows' factor, assemble, has
  // it already) + the held bodies' proximal term, and K again afterwards. (rstat read K
  // alone, as the static solve did then: modified Newton for a cable through a part,
  // whose converged answer does not depend on it, but not the derivative's tangent.)
  // A part on a body held by contact alone (rstp): the proximal term tau E of the
  // refinement (assemble, apply_m: tau on every dof of the body, the part's too) must be
  // the reduced system's as well, P^T (K + tau E) P: the factor has it on the soft dofs
  // (and on the part's identity rows, where it does nothing), the coupling gets it here,
  // T^T tau I T in S. The refinement's fixed point then solves the reduced equilibrium
  // without tau, as without parts (with tau on the soft dofs only, S would miss it: S is
  // then indefinite on the held body's rigid motions under stress, and the refinement's
  // M would not be the reduced system's term).
  bool prepare_parts() {
    const auto& rm = model_.rigidify;
    auto& w = data_.rigidify;
    const bool cables = !model_.actuation.empty();
    const bool modified = cables || !held_.empty();
    if (modified) {
      saved_K_ = data_.fem.K_values;
      double* K = data_.fem.K_values.data();
      if (cables) model_.actuation.add_stiffness(*x_, data_.lambda_a, model_.fem.pattern, K);
      for (const auto& h : held_)
        for (int d = h.begin; d < h.begin + h.size; ++d) K[model_.fem.pattern.diagonal[d]] += h.tau;
    }
    const bool prepared = prepare_rigidified(model_, data_, *x_, 1.0, -1).ok();
    if (modified) data_.fem.K_values.swap(saved_K_);
    if (!prepared || w.reduced_pcg) return false;
    // R = f_int + P + f_act + H_c^T lambda at x* (the final load factor 1).
    force_parts_ = data_.fem.f_int + model_.fem.gravity_force;
    if (!model_.actuation.empty()) model_.actuation.add_forces(*x_, data_.lambda_a, 1.0, force_parts_);
    // (lambda's head: the contacts' rows; with rigid bodies a joint limit's rows follow.)
    if (contact_) force_parts_.noalias() += contact_data().Ht * contact_data().lambda.head(contact_data().Ht.cols());
    for (int p = 0; p < rm.size(); ++p) {
      Mat3 Q = Mat3::Zero();
      for (int i : rm.parts[static_cast<std::size_t>(p)].nodes) {
        const Vec3 a = x_->segment<3>(3L * i) - w.centre[static_cast<std::size_t>(p)];
        Q.noalias() += skew(Vec3(force_parts_.segment<3>(3L * i))) * skew(a);
      }
      w.S.block<3, 3>(6 * p + 3, 6 * p + 3) -= 0.5 * (Q + Q.transpose());
    }
    w.S_factor.compute(w.S);
    return w.S_factor.info() == Eigen::Success;
  }

  // The reduced solves as a LinearSolver (the contact stage's derivative and the
  // refinement call it): v = P (P^T K P - Q)^{-1} P^T b, G = H P (...)^{-1} P^T H^T.
  class ReducedSystem final : public LinearSolver {
   public:
    ReducedSystem(const Model& model, Data& data) : model_(model), data_(data) {}
    std::string name() const override { return "rigidified parts' reduced system"; }
    void analyze(const SparseMatrix&) override {}
    FactorStatus factorize(const SparseMatrix&) override { return {}; }
    bool solve(const VecX& b, VecX& x) override { return solve_rigidified(model_, data_, b, x); }
    bool solve(const MatX& B, MatX& X) override {
      X.resize(B.rows(), B.cols());
      for (Eigen::Index j = 0; j < B.cols(); ++j) {
        col_b_ = B.col(j);
        if (!solve_rigidified(model_, data_, col_b_, col_x_)) return false;
        X.col(j) = col_x_;
      }
      return true;
    }
    bool inverse_congruence(const SparseMatrix& B, MatX& G) override {
      return rigidified_congruence(model_, data_, B, G);
    }

   private:
    const Model& model_;
    Data& data_;
    VecX col_b_, col_x_;
  };

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
    const auto& cd = contact_data();
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
    const auto& cd = contact_data();
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
  // Where the contacts hold everything the answer is zero and the refinement's changes
  // are the round-off of the free response (the first solve's answer before the
  // contacts' correction, free_scale_) cancelled by the contacts' (measured: 6e-15 of it on
  // a scene of rigid bodies only on rigid supports, every column zero). A change that no
  // longer decreases is accepted below kRoundOff of the free response too.
  static constexpr double kRoundOff = 1e-12;
  int converged(int it, double change, double size, double& previous) {
    last_change_ = size > 0 ? change / size : 0.0;
    if (!std::isfinite(change)) return -1;
    if (change <= kRefinementTolerance * size) return 1;
    if (change >= previous)
      return change <= std::max(kRefinementFloor * size, kRoundOff * free_scale_) ? 1 : -1;
    previous = change;
    return it >= kMaxRefinements ? -1 : 0;
  }

  // out = K_tau^{-1} Pi r + K_tau^{-1} H_c^T dlambda, dlambda the mode-fixed NCP's
  // answer to dsigma = H_c K_tau^{-1} Pi r at fixed lambda (and dmu).
  bool apply_phi(const VecX& r, const VecX& dmu, VecX& out) {
    tmp_ = r;
    project(model_, tmp_);
    if (!solver_->solve(tmp_, out)) return false;
    project(model_, out);
    apply_w(rr_, zr_next_);  // the rigid part (rr_: its right-hand side)
    free_scale_ = std::max({free_scale_, max_abs(out), max_abs(zr_next_)});
    if (!contact_) return true;
    const auto& cd = contact_data();
    b_.noalias() = cd.Ht.transpose() * out;
    if (rigid_size()) b_.noalias() += Ht_r_.transpose() * zr_next_;
    if (slip_terms_) b_.head(e_.size()) += e_;  // the face terms of the previous iterate
    stage_.ncp().jvp(b_, dmu, dlambda_);
    tmp_.noalias() = cd.Ht * dlambda_;
    project(model_, tmp_);
    if (!solver_->solve(tmp_, y_)) return false;
    project(model_, y_);
    out += y_;
    if (rigid_size()) {
      yr_.noalias() = Ht_r_ * dlambda_;
      apply_w(yr_, wr_);
      zr_next_ += wr_;
    }
    return true;
  }

  // out = W_r v per rigid body (W_r = (tau_r A_r)^{-1}, T T^T / a on a joint, 0 fixed).
  void apply_w(const VecX& v, VecX& out) const {
    out.setZero(rigid_size());
    for (std::size_t r = 0; r < model_.rigid.size(); ++r)
      out.segment<6>(6 * static_cast<Eigen::Index>(r)) = W_[r] * v.segment<6>(6 * static_cast<Eigen::Index>(r));
  }

  // The rigid record at the equilibrium: the extended positions (pseudo-nodes at the
  // final poses), their lever arms rho_k, H_r^T at the final poses, W_r, A_r (tau_r's
  // block), each body's total force (weight + contacts: a hinge basis' term), and the
  // forces F_k on the pseudo-nodes (the lever arms' rotation term Q_r).
  void prepare_rigid(const State& equilibrium) {
    const auto& fem = model_.fem;
    const int n = fem.num_nodes;
    const auto R = static_cast<Eigen::Index>(model_.rigid.size());
    const auto& cd = contact_data();
    rigid_bodies_ = static_cast<int>(R);
    poses_ = equilibrium.rigid;
    const Eigen::Index pseudo = static_cast<Eigen::Index>(model_.contact.rigid_node_body.size());
    ext_x_.setZero(3 * (n + pseudo));
    ext_x_.head(3L * n) = equilibrium.x;
    rho_.setZero(3 * pseudo);
    for (Eigen::Index k = 0; k < pseudo; ++k) {
      const int r = model_.contact.rigid_node_body[static_cast<std::size_t>(k)];
      const auto& body = model_.rigid[static_cast<std::size_t>(r)];
      const auto& s = poses_[static_cast<std::size_t>(r)];
      const int j = static_cast<int>(n + k) - model_.contact.rigid_node_begin[static_cast<std::size_t>(r)];
      rho_.segment<3>(3 * k) = s.orientation * body.surface.vertices.col(j);
      ext_x_.segment<3>(3 * (n + k)) = s.position + rho_.segment<3>(3 * k);
    }
    if (contact_) contact::rigid_jacobian_transpose(model_, cd.contacts, poses_, Ht_r_);
    else Ht_r_.setZero(6 * R, 0);
    // tau_r from the soft tangent's diagonal.
    double diag_max = 0;
    for (int d = 0; d < static_cast<int>(fem.pattern.diagonal.size()); ++d)
      if (!fem.fixed[d]) diag_max = std::max(diag_max, std::abs(data_.fem.K_values[fem.pattern.diagonal[d]]));
    W_.assign(static_cast<std::size_t>(R), rigid::Mat6::Zero());
    A_.assign(static_cast<std::size_t>(R), rigid::Mat6::Zero());
    force_.assign(static_cast<std::size_t>(R), rigid::Vec6::Zero());
    Q_.assign(static_cast<std::size_t>(R), Mat3::Zero());
    for (Eigen::Index r = 0; r < R; ++r) {
      const auto& body = model_.rigid[static_cast<std::size_t>(r)];
      const auto& s = poses_[static_cast<std::size_t>(r)];
      if (body.joint.kind == rigid::Joint::Kind::fixed) continue;
      // Without soft bodies (diag_max 0) W_r is the only compliance in G: the mode-fixed
      // solve does not depend on its scale in the directions the contacts hold, and the
      // refinement leaves the others as they are; tau_r = |g| / s (s the body's surface
      // box diagonal: the static solver's proximal scale, without its 0.01) keeps G's
      // entries ~ 1 / (m |g| / s).
      const double tau = diag_max > 0 ? kRigidProximal * diag_max / body.mass : rigid_only_tau(body);
      rigid::Mat6 A = rigid::Mat6::Zero();
      A.topLeftCorner<3, 3>() = tau * body.mass * Mat3::Identity();
      A.bottomRightCorner<3, 3>() = tau * rigid::world_inertia(body, s.orientation);
      A_[static_cast<std::size_t>(r)] = A;
      if (body.joint.kind == rigid::Joint::Kind::free) {
        W_[static_cast<std::size_t>(r)] = A.inverse();
      } else {
        const rigid::Vec6 T = rigid::joint_motion_basis(body, s).col(0);
        W_[static_cast<std::size_t>(r)] = T * T.transpose() / T.dot(A * T);
      }
      force_[static_cast<std::size_t>(r)].head<3>() = body.mass * model_.step.gravity;
      if (contact_) force_[static_cast<std::size_t>(r)] += Ht_r_.middleRows<6>(6 * r) * cd.lambda.head(Ht_r_.cols());
    }
    hold_limited_bodies();
    if (contact_) {
      for (int i = 0; i < cd.contacts.size(); ++i) {
        const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
        const Vec3 f = c.frame * cd.lambda.segment<3>(3 * i);
        for (int a = 0; a < c.count; ++a) {
          const int node = c.nodes[static_cast<std::size_t>(a)];
          const double w = c.weights[static_cast<std::size_t>(a)];
          if (node < n || w == 0) continue;
          const Eigen::Index k = node - n;
          const int r = model_.contact.rigid_node_body[static_cast<std::size_t>(k)];
          if (model_.rigid[static_cast<std::size_t>(r)].joint.kind == rigid::Joint::Kind::fixed) continue;
          // d(rho x F) = (dtheta x rho) x F = [F]x [rho]x dtheta.
          Q_[static_cast<std::size_t>(r)] += w * skew(f) * skew(Vec3(rho_.segment<3>(3 * k)));
        }
      }
    }
  }

  // A free body beside soft bodies (frictionless: demand_supported) must be held in all six
  // dofs by the normals of the contacts the derivative keeps (modes not breaking): else its
  // pose is not determinate (a cube flat on a slab slides and spins freely) and the
  // refinement, whose proximal block tau_r is then the only stiffness on those motions,
  // does not converge. Each kept contact's normal wrench on the body, h = (n, rho x n / L)
  // (L the body's reach: forces and moments on one scale), enters S = sum h h^T; an
  // eigenvalue of S below kHeldRatio = 1e-4 of its largest is a direction the contacts do
  // not hold: their normals' components along it are below ~1e-2, i.e. at most the tilt
  // of a support's surface by its deformation (a held direction that only this tilt
  // holds has a stiffness ~ tilt^2 of the support's: the static solve does not converge
  // there either). Measured: the frictionless cube flat on the slab 8.6e-9, 1.5e-8, 2.9e-8
  // (x, y, yaw; the slab's dimple tilts the normals by ~1e-4), then 0.17; the cube in the
  // soft corner's smallest 0.20. Refused as bad input (exit 2), naming those directions.
  static constexpr double kHeldRatio = 1e-4;
  void demand_free_bodies_held() const {
    if (model_.fem.num_nodes == 0) return;  // rigid-only scenes: RigidOnlyStack's path
    const auto& cd = contact_data();
    for (std::size_t r = 0; r < model_.rigid.size(); ++r) {
      const auto& body = model_.rigid[r];
      if (body.joint.kind != rigid::Joint::Kind::free) continue;
      double reach = 0;
      for (Eigen::Index k = 0; k < body.surface.vertices.cols(); ++k)
        reach = std::max(reach, body.surface.vertices.col(k).norm());
      reach = std::max(reach, 1e-12);
      rigid::Mat6 S = rigid::Mat6::Zero();
      int kept = 0;
      if (contact_)
        for (int i = 0; i < cd.contacts.size(); ++i) {
          const auto mode = modes_[static_cast<std::size_t>(i)];
          if (mode == contact::Mode::breaking) continue;
          // A sticking contact (friction, static.friction load_step) holds its tangential
          // directions too: its three rows (the normal's alone otherwise).
          bool any = false;
          for (int row = mode == contact::Mode::sticking ? 0 : 2; row < 3; ++row) {
            rigid::Vec6 h = Ht_r_.block<6, 1>(6 * static_cast<Eigen::Index>(r), 3L * i + row);
            if (h.squaredNorm() == 0) continue;
            h.tail<3>() /= reach;
            S.noalias() += h * h.transpose();
            any = true;
          }
          kept += any;
        }
      const Eigen::SelfAdjointEigenSolver<rigid::Mat6> eig(S);
      const double largest = eig.eigenvalues().maxCoeff();
      // The unheld subspace (eigenvectors below kHeldRatio of the largest), named by the
      // world axes it contains where it is spanned by them (a flat support: "translation
      // along x", "translation along y", "rotation about z"), else by its eigenvectors.
      Eigen::Matrix<double, 6, Eigen::Dynamic> V(6, 0);
      for (int k = 0; k < 6; ++k)
        if (!(largest > 0 && eig.eigenvalues()[k] > kHeldRatio * largest)) {
          V.conservativeResize(Eigen::NoChange, V.cols() + 1);
          V.col(V.cols() - 1) = eig.eigenvectors().col(k);
        }
      std::string unheld, axes;
      int on_axes = 0;
      for (int a = 0; a < 6; ++a)
        if ((V.transpose() * rigid::Vec6::Unit(a)).squaredNorm() > 0.99) {
          axes += (axes.empty() ? "" : ", ") + std::string(a < 3 ? "translation along " : "rotation about ") +
                  "xyz"[a % 3];
          ++on_axes;
        }
      if (on_axes == V.cols()) unheld = axes;
      else
        for (Eigen::Index k = 0; k < V.cols(); ++k) {
          const rigid::Vec6 v = V.col(k);
          char buf[160];
          if (v.head<3>().norm() >= v.tail<3>().norm())
            std::snprintf(buf, sizeof buf, "translation along (%.3g, %.3g, %.3g)", v[0], v[1], v[2]);
          else
            std::snprintf(buf, sizeof buf, "rotation about (%.3g, %.3g, %.3g)", v[3], v[4], v[5]);
          unheld += (unheld.empty() ? "" : ", ") + std::string(buf);
        }
      if (!unheld.empty())
        throw InputError("static derivatives of free rigid body '" + body.name + "': the " + std::to_string(kept) +
                         " contacts that hold it at the equilibrium leave " + unheld +
                         " free, so its pose is not determinate and has no derivative (issue 21; frictionless, a "
                         "free body beside soft bodies is differentiated where its contacts' normals hold all six "
                         "dofs, e.g. a cube leaning into a corner: docs/method.md \"Static equilibrium with rigid "
                         "bodies\")");
    }
  }

  // Joint limits (docs/method.md "Static equilibrium with joint limits", derivatives): a
  // limit row of the last solve with a positive reaction (above 10 times the NCP's
  // tolerance of the largest force: the equilibrium_modes rule) is held active, a
  // bilateral row j dz_r = 0 (j = s T / |T|^2), as the dynamic derivative holds it
  // (rigid_contact_derivatives.cpp prepare_limits). On a hinge or slider T spans the
  // body's only dof, so the row fixes it: dc = 0, z_r = 0, and the body enters the rest
  // of the system as a fixed one (its contacts' rows have no rigid part). Its own equation
  // only gives the limit's reaction, which is not an output. So W_r = 0 (and A_r = 0: no
  // proximal term to remove). The limit's force s lambda T / |T|^2 has T^T of it
  // constant (s lambda), so it adds no basis term to the joint's equation. An inactive
  // limit row (no reaction) drops, as a breaking contact.
  void hold_limited_bodies() {
    const auto& rd = data_.contact.rigid;
    limited_ = 0;
    if (rd.limit_rows.empty() || rd.limit_lambda.size() != contact::num_limit_slots(model_)) return;
    double scale = max_abs(rd.limit_lambda);
    if (contact_) scale = std::max(scale, max_abs(data_.contact.lambda));
    const double tol = 10 * model_.contact.ncp.tolerance * scale;
    for (const auto& row : rd.limit_rows) {
      if (!(rd.limit_lambda[row.slot] > tol)) continue;
      W_[static_cast<std::size_t>(row.body)].setZero();
      A_[static_cast<std::size_t>(row.body)].setZero();
      ++limited_;
    }
  }

  double rigid_only_tau(const rigid::RigidBody& body) const {
    const auto& V = body.surface.vertices;
    const double size = V.cols() > 0 ? (V.rowwise().maxCoeff() - V.rowwise().minCoeff()).norm() : 0.0;
    const double g = model_.step.gravity.norm();
    return size > 0 && g > 0 ? g / size : 1.0;
  }

  static Mat3 skew(const Vec3& v) {
    Mat3 m;
    m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
    return m;
  }

  // The NCP derivative on the dense G of all contacts: H_s K_tau^{-1} H_s^T + sum_r H_r
  // W_r H_r^T (the extended system of ContactStageDerivative::prepare, which then keeps
  // the contacts' geometry derivatives at the extended positions).
  bool prepare_rigid_contact() {
    if (!contact_) return true;
    const auto& cd = contact_data();
    const Eigen::Index m = cd.Ht.cols();
    if (cd.Ht.nonZeros() > 0) {
      if (!solver_->inverse_congruence(cd.Ht, G_ext_)) return false;
    } else {
      G_ext_.setZero(m, m);
    }
    for (std::size_t r = 0; r < model_.rigid.size(); ++r) {
      const auto B = Ht_r_.middleRows<6>(6 * static_cast<Eigen::Index>(r));
      if (B.squaredNorm() == 0) continue;
      G_ext_.noalias() += B.transpose() * (W_[r] * B);
    }
    lambda_ext_ = cd.lambda.head(m);
    mu_ext_ = cd.mu;
    contact::ContactStageDerivative::NcpSystem system{&G_ext_, &mu_ext_, &lambda_ext_, &sigma_, &modes_};
    return stage_.prepare(model_, cd, ext_x_, *solver_, 1.0, false, &modes_, &sigma_,
                          model_.rigidify.empty() ? &data_.A : nullptr, &system);
  }

  bool apply_phi_transposed(const VecX& v, VecX& out, VecX& bar_mu) {
    tmp_ = v;
    project(model_, tmp_);
    if (!solver_->solve(tmp_, out)) return false;
    project(model_, out);
    apply_w(rr_, zr_next_);
    free_scale_ = std::max({free_scale_, max_abs(out), max_abs(zr_next_)});
    if (!contact_) return true;
    const auto& cd = contact_data();
    bar_lambda_.noalias() = cd.Ht.transpose() * out;
    if (rigid_size()) bar_lambda_.noalias() += Ht_r_.transpose() * zr_next_;
    stage_.ncp().vjp(bar_lambda_, bar_b_, bar_mu);
    tmp_.noalias() = cd.Ht * bar_b_;
    project(model_, tmp_);
    if (!solver_->solve(tmp_, y_)) return false;
    project(model_, y_);
    out += y_;
    if (rigid_size()) {
      yr_.noalias() = Ht_r_ * bar_b_;
      apply_w(yr_, wr_);
      zr_next_ += wr_;
    }
    return true;
  }

  // m = Pi (tau E z + dH[z]^T lambda).
  bool apply_m(const VecX& z, VecX& m) {
    m.setZero();
    if (slip_terms_) e_.setZero();
    for (const auto& h : held_) m.segment(h.begin, h.size) = h.tau * z.segment(h.begin, h.size);
    if (rigid_size()) {
      apply_m_rigid(z, m);
      project(model_, m);
      return m.allFinite() && mr_.allFinite() && e_.allFinite();
    }
    if (contact_) stage_.add_force_jvp(contact_data(), 1.0, z, m);
    if (slip_terms_) stage_.add_slip_jvp(contact_data(), slip_D_, z, e_);
    project(model_, m);
    return m.allFinite() && e_.allFinite();
  }

  // The rigid share of M (z_r = zr_ into mr_; the soft nodes' geometry share into m):
  // tau_r A_r z_r, the contact forces' change with the extended positions (soft nodes and
  // pseudo-nodes dX_k = dp + dtheta x rho_k) as wrenches on the bodies, the lever arms'
  // rotation Q_r dtheta, and on a hinge the basis' change (n x dp).f on its axis.
  void apply_m_rigid(const VecX& z, VecX& m) {
    const int n = model_.fem.num_nodes;
    mr_.setZero(rigid_size());
    for (std::size_t r = 0; r < model_.rigid.size(); ++r) {
      const auto o = 6 * static_cast<Eigen::Index>(r);
      mr_.segment<6>(o) = A_[r] * zr_.segment<6>(o);
      const auto& body = model_.rigid[r];
      if (body.joint.kind == rigid::Joint::Kind::hinge) {
        const Vec3 axis = body.joint.axis;
        const double t = axis.cross(Vec3(zr_.segment<3>(o))).dot(force_[r].head<3>());
        mr_.segment<3>(o + 3) += axis * (t / axis.squaredNorm());
      }
    }
    if (!contact_) return;
    const Eigen::Index pseudo = static_cast<Eigen::Index>(model_.contact.rigid_node_body.size());
    ext_dx_.resize(ext_x_.size());
    ext_dx_.head(3L * n) = z;
    for (Eigen::Index k = 0; k < pseudo; ++k) {
      const auto o = 6 * static_cast<Eigen::Index>(model_.contact.rigid_node_body[static_cast<std::size_t>(k)]);
      ext_dx_.segment<3>(3 * (n + k)) =
          zr_.segment<3>(o) + Vec3(zr_.segment<3>(o + 3)).cross(Vec3(rho_.segment<3>(3 * k)));
    }
    ext_m_.setZero(ext_x_.size());
    stage_.add_force_jvp(contact_data(), 1.0, ext_dx_, ext_m_);
    if (slip_terms_) stage_.add_slip_jvp(contact_data(), slip_D_, ext_dx_, e_);
    m += ext_m_.head(3L * n);
    for (Eigen::Index k = 0; k < pseudo; ++k) {
      const int r = model_.contact.rigid_node_body[static_cast<std::size_t>(k)];
      if (model_.rigid[static_cast<std::size_t>(r)].joint.kind == rigid::Joint::Kind::fixed) continue;
      const auto o = 6 * static_cast<Eigen::Index>(r);
      const Vec3 f = ext_m_.segment<3>(3 * (n + k));
      mr_.segment<3>(o) += f;
      mr_.segment<3>(o + 3) += Vec3(rho_.segment<3>(3 * k)).cross(f);
    }
    for (std::size_t r = 0; r < model_.rigid.size(); ++r) {
      const auto o = 6 * static_cast<Eigen::Index>(r);
      mr_.segment<3>(o + 3) += Q_[r] * zr_.segment<3>(o + 3);
    }
  }

  // Its transpose (zr_ the cotangent's rigid part).
  void apply_m_rigid_transposed(const VecX& z, VecX& m) {
    const int n = model_.fem.num_nodes;
    mr_.setZero(rigid_size());
    for (std::size_t r = 0; r < model_.rigid.size(); ++r) {
      const auto o = 6 * static_cast<Eigen::Index>(r);
      mr_.segment<6>(o) = A_[r].transpose() * zr_.segment<6>(o);
      const auto& body = model_.rigid[r];
      if (body.joint.kind == rigid::Joint::Kind::hinge) {
        const Vec3 axis = body.joint.axis;
        const double s = axis.dot(Vec3(zr_.segment<3>(o + 3))) / axis.squaredNorm();
        // (n x dp).f = dp.(f x n)
        mr_.segment<3>(o) += s * Vec3(force_[r].head<3>()).cross(axis);
      }
      mr_.segment<3>(o + 3) += Q_[r].transpose() * zr_.segment<3>(o + 3);
    }
    if (!contact_) return;
    const Eigen::Index pseudo = static_cast<Eigen::Index>(model_.contact.rigid_node_body.size());
    ext_dx_.resize(ext_x_.size());  // the cotangent of the force change on the extended nodes
    ext_dx_.head(3L * n) = z;
    for (Eigen::Index k = 0; k < pseudo; ++k) {
      const int r = model_.contact.rigid_node_body[static_cast<std::size_t>(k)];
      const auto o = 6 * static_cast<Eigen::Index>(r);
      if (model_.rigid[static_cast<std::size_t>(r)].joint.kind == rigid::Joint::Kind::fixed) {
        ext_dx_.segment<3>(3 * (n + k)).setZero();
        continue;
      }
      // (f, rho x f) . (a, b) = f . (a + b x rho)
      ext_dx_.segment<3>(3 * (n + k)) =
          zr_.segment<3>(o) + Vec3(zr_.segment<3>(o + 3)).cross(Vec3(rho_.segment<3>(3 * k)));
    }
    ext_m_.setZero(ext_x_.size());
    ext_u_.setZero(ext_x_.size());
    zero_b_.setZero(contact_data().lambda.size());
    stage_.add_geometry_vjp(contact_data(), ext_u_, 1.0, ext_dx_, zero_b_, ext_m_);
    if (slip_terms_) stage_.add_slip_vjp(contact_data(), slip_D_, bar_b_, ext_m_);  // e^T bar_b
    m += ext_m_.head(3L * n);
    for (Eigen::Index k = 0; k < pseudo; ++k) {
      const auto o = 6 * static_cast<Eigen::Index>(model_.contact.rigid_node_body[static_cast<std::size_t>(k)]);
      const Vec3 v = ext_m_.segment<3>(3 * (n + k));
      mr_.segment<3>(o) += v;
      mr_.segment<3>(o + 3) += Vec3(rho_.segment<3>(3 * k)).cross(v);  // (dtheta x rho).v = dtheta.(rho x v)
    }
  }

  bool apply_m_transposed(const VecX& z, VecX& m) {
    m.setZero();
    for (const auto& h : held_) m.segment(h.begin, h.size) = h.tau * z.segment(h.begin, h.size);
    if (rigid_size()) {
      apply_m_rigid_transposed(z, m);
      project(model_, m);
      return m.allFinite() && mr_.allFinite();
    }
    if (contact_) {
      zero_b_.setZero(contact_data().lambda.size());
      tmp_.setZero();
      stage_.add_geometry_vjp(contact_data(), tmp_, 1.0, z, zero_b_, m);
      if (slip_terms_) stage_.add_slip_vjp(contact_data(), slip_D_, bar_b_, m);  // e^T bar_b
    }
    project(model_, m);
    return m.allFinite();
  }

  const Model& model_;
  Data& data_;
  ReducedSystem reduced_{model_, data_};
  VecX force_parts_;  // R at x* (prepare_parts)
  VecX saved_K_;      // K_values while prepare_parts reads K + the cables' stiffness
  const VecX* x_ = nullptr;
  LinearSolver* solver_ = nullptr;  // data's, or EmptySystem without soft dofs
  int limited_ = 0;                  // bodies held on an active limit (hold_limited_bodies)
  double free_scale_ = 0;            // the refinement's free response (converged)
  bool contact_ = false;
  bool measure_free_body_friction_ = false;  // StaticTheta::measure_free_body_friction
  bool slip_terms_ = false;  // load_step's face terms in the mode rows (prepare_slip_terms)
  VecX slip_D_, e_;          //   D = X* - X^start (extended), e[z] of the last apply_m
  std::vector<Held> held_;
  contact::ContactStageDerivative stage_;
  std::vector<contact::Mode> modes_;  // the modes held (equilibrium_modes)
  VecX sigma_;
  double last_change_ = 0;
  VecX r_, y_, z_, z_next_, m_, tmp_, b_, dlambda_, bar_lambda_, bar_b_, zero_b_;
  // Rigid bodies (6R vectors; prepare_rigid).
  int rigid_bodies_ = 0;
  std::vector<rigid::RigidState> poses_;
  VecX ext_x_, rho_, ext_dx_, ext_m_, ext_u_, zr_, zr_next_, mr_, rr_, yr_, wr_, lambda_ext_, mu_ext_;
  MatX Ht_r_, G_ext_;
  std::vector<rigid::Mat6> W_, A_;
  std::vector<rigid::Vec6> force_;
  std::vector<Mat3> Q_;
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

// q_r (6R) of rigid parameter column c: the mass's weight g on its body (the final load
// step's factor 1), zero for the inertia (the equilibrium does not depend on it).
void rigid_parameter_column(const Model& model, const StaticTheta& theta, Eigen::Index c, VecX& q_r) {
  q_r.setZero(6 * static_cast<Eigen::Index>(model.rigid.size()));
  const auto [body, k] = theta.rigid_parameters[static_cast<std::size_t>(c)];
  SOFTDIFF_DEMAND(body >= 0 && body < static_cast<int>(model.rigid.size()), "static derivatives: rigid parameter of body " +
                                                                                 std::to_string(body) + " out of range");
  if (k == 0 && model.rigid[static_cast<std::size_t>(body)].joint.kind != rigid::Joint::Kind::fixed)
    q_r.segment<3>(6 * static_cast<Eigen::Index>(body)) = model.step.gravity;
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
  // static.friction load_step: the last NCP's tangential sigma is the load step's total
  // slip H_T (x - x_start) (its rigid bodies' share included: static_rigid.hpp
  // static_slip_offset), to the last increment's round-off at convergence.
  const bool load_step = model.step.static_friction == StaticFriction::load_step && cd.sigma.size() >= 3L * nc;
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
      for (int r = 0; r < 2; ++r) s[r] = load_step ? cd.sigma[3 * i + r] : cd.Ht.col(3 * i + r).dot(u);
      if (s.norm() > 1e-9 * size) sigma.segment<2>(3 * i) = s;
      else sigma.segment<2>(3 * i) = -l.head<2>() / lT * (1e100 * std::max(scale, 1.0));
    } else {
      m = contact::Mode::sticking;
    }
  }
}

bool static_sensitivities(const Model& model, Data& data, const State& equilibrium, const StaticTheta& theta,
                          MatX& dx_dtheta) {
  EquilibriumSystem system(model, data, theta.measure_free_body_friction);
  system.demand_supported();
  const Eigen::Index n = 3L * model.fem.num_nodes, np = static_cast<Eigen::Index>(theta.parameters.size());
  const Eigen::Index na = theta.actuation ? static_cast<Eigen::Index>(model.actuation.actuators.size()) : 0;
  const Eigen::Index nrp = static_cast<Eigen::Index>(theta.rigid_parameters.size()), nr = system.rigid_size();
  if (!system.prepare(equilibrium)) return false;
  dx_dtheta = MatX::Zero(n + nr, np + na + nrp);
  VecX q(n), z(n), dmu, q_r(nr), z_r(nr);
  for (Eigen::Index c = 0; c < np + na + nrp; ++c) {
    bool friction = false;
    q_r.setZero();
    if (c < np + na) {
      if (!parameter_column(model, data, equilibrium.x, theta, c, q, friction)) return false;
    } else {
      q.setZero();
      rigid_parameter_column(model, theta, c - np - na, q_r);
      if (q_r.isZero(0)) continue;  // inertia: no effect on the equilibrium
    }
    dmu.resize(0);
    if (friction) {
      if (!system.contact()) continue;  // no contact at the equilibrium: no effect
      friction_direction(model, data, theta, c, dmu);
    }
    if (!system.solve(q, dmu, z, q_r, &z_r)) return false;
    dx_dtheta.col(c).head(n) = z;
    if (nr) dx_dtheta.col(c).tail(nr) = z_r;
  }
  return dx_dtheta.allFinite();
}

bool static_vjp(const Model& model, Data& data, const State& equilibrium, const StaticTheta& theta, const VecX& bar_x,
                VecX& bar_theta) {
  EquilibriumSystem system(model, data, theta.measure_free_body_friction);
  system.demand_supported();
  const Eigen::Index n = 3L * model.fem.num_nodes, np = static_cast<Eigen::Index>(theta.parameters.size());
  const Eigen::Index na = theta.actuation ? static_cast<Eigen::Index>(model.actuation.actuators.size()) : 0;
  const Eigen::Index nrp = static_cast<Eigen::Index>(theta.rigid_parameters.size()), nr = system.rigid_size();
  SOFTDIFF_DEMAND(bar_x.size() == n + nr, "static_vjp: bar_x must have size 3n (+ 6R) = " + std::to_string(n + nr));
  if (!system.prepare(equilibrium)) return false;
  VecX u(n), bar_mu, q(n), u_r(nr), q_r(nr);
  const VecX bar_s = bar_x.head(n), bar_r = bar_x.tail(nr);
  if (!system.solve_transposed(bar_s, u, bar_mu, bar_r, &u_r)) return false;
  bar_theta = VecX::Zero(np + na + nrp);
  for (Eigen::Index c = 0; c < np + na; ++c) {
    bool friction = false;
    if (!parameter_column(model, data, equilibrium.x, theta, c, q, friction)) return false;
    if (!friction) bar_theta[c] = u.dot(q);
  }
  for (Eigen::Index c = 0; c < nrp; ++c) {
    rigid_parameter_column(model, theta, c, q_r);
    bar_theta[np + na + c] = u_r.dot(q_r);
  }
  if (system.contact() && bar_mu.size()) {
    VecX bar_p = VecX::Zero(np);
    contact::ContactStageDerivative::add_friction_cotangent(model, data.contact, theta.parameters, bar_mu, bar_p);
    bar_theta.head(np) += bar_p;
  }
  return bar_theta.allFinite();
}

}  // namespace softdiff::integrator
