// Derivatives of the contact stage: see contact_step_derivatives.hpp.
#include <softdiff/contact/contact_step_derivatives.hpp>

#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/contact/sparse_delassus.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>

#include <algorithm>
#include <sstream>
#include <utility>

namespace softdiff::contact {

namespace {
// Whether contact c belongs to pair rule r (its sides in either order).
bool in_rule(const collision::Contact& c, const collision::PairRule& r) {
  return (c.side_a == r.a && c.side_b == r.b) || (c.side_a == r.b && c.side_b == r.a);
}
// The contact's node components of a global vector (12; count nodes used).
Eigen::Matrix<double, 12, 1> gather_contact(const collision::Contact& c, const VecX& v) {
  Eigen::Matrix<double, 12, 1> u = Eigen::Matrix<double, 12, 1>::Zero();
  for (int k = 0; k < c.count; ++k) u.segment<3>(3 * k) = v.segment<3>(3 * c.nodes[k]);
  return u;
}
// The directional derivative along dx of the contact's frame components of a nodal field F
// read through its weights, C^T sum_k w_k F_k (C the frame, w the weights, both moving
// with dx; F held): dC^T V + C^T sum_k dw_k F_k with V = sum_k w_k F_k. The sigma rows
// (F the step's velocity) and the load-step slip rows (F the displacement since the load
// step's start, its tangential components) share it.
Vec3 frame_field_jvp(const collision::Contact& c, const collision::ContactGeometryDerivative& g, const VecX& F,
                     const VecX& dx) {
  const Eigen::Matrix<double, 12, 1> u = gather_contact(c, dx);
  const Mat3 dC = Eigen::Map<const Mat3>(Eigen::Matrix<double, 9, 1>(g.dframe * u).data());
  const Eigen::Vector4d dw = g.dweights * u;
  Vec3 V = Vec3::Zero(), dV = Vec3::Zero();
  for (int k = 0; k < c.count; ++k) {
    const Vec3 Fk = F.segment<3>(3 * c.nodes[k]);
    V += c.weights[k] * Fk;
    dV += dw[k] * Fk;
  }
  return dC.transpose() * V + c.frame.transpose() * dV;
}
}  // namespace

// The operator path beyond derivative_dense_max_active active contacts: every active
// contact sticking (J = G_AA), by CG preconditioned with (G_AA + c I)^{-1}; with sliding
// contacts, by GMRES with the reduced preconditioner (mode_system.hpp "Mixed sets") when
// A_upper is given. Without A_upper (no preconditioner can be factorized), mixed sets
// take the operator path only up to this many active contacts (unpreconditioned CGLS
// needs about kappa(J) iterations: on the slab's 4337 it did not converge in 3000) and
// keep the dense G_AA beyond.
constexpr int operator_unpreconditioned_mixed_max_active = 64;

bool ContactStageDerivative::prepare(const Model& model, const ContactData& cd, const VecX& x,
                                     integrator::LinearSolver& solver, double h, bool use_record_G,
                                     const std::vector<Mode>* modes_in, const VecX* sigma_in,
                                     const SparseMatrix* A_upper, const NcpSystem* extended) {
  const std::vector<Mode>& modes = modes_in ? *modes_in : cd.modes;
  const VecX& sigma = sigma_in ? *sigma_in : cd.sigma;
  const auto& det = model.contact.detection;
  const int nc = cd.contacts.size();
  geometry_.resize(static_cast<std::size_t>(nc));
  nondifferentiable_ = 0;
  smoothed_ = 0;
  for (int i = 0; i < nc; ++i) {
    const auto& c = cd.contacts.contacts[i];
    const collision::Obstacle* o = nullptr;
    if (c.kind == collision::ContactKind::vertex_obstacle)
      o = &det.obstacles[static_cast<std::size_t>(c.side_b) - det.surfaces.size()];
    auto& g = geometry_[static_cast<std::size_t>(i)];
    const auto kind = collision::contact_geometry_derivative(c, x, o, model.contact.smoothing, g);
    if (kind == collision::GeometryDerivativeKind::smoothed) ++smoothed_;
    if (kind == collision::GeometryDerivativeKind::none) {
      g.dn.setZero();
      g.dgap.setZero();
      g.dweights.setZero();
      g.dframe.setZero();
      ++nondifferentiable_;
    }
  }
  if (nc == 0) return true;
  if (extended && extended->G) {
    ncp_.compute(*extended->G, *extended->mu, *extended->lambda, *extended->sigma, *extended->modes);
  } else if (!extended && use_record_G && cd.G.rows() == 3 * nc) {
    ncp_.compute(cd.G, cd.mu, cd.lambda, sigma, modes);
  } else {
    // The system's rows: cd's, or an extended system's on the operator (NcpSystem without
    // G: the limit rows after the contacts, or a rigidified part's rows K_p).
    const SparseMatrix* Ht = extended && extended->Ht ? extended->Ht : &cd.Ht;
    const bool with_rigid = model.contact.with_rigid();
    const MatX* Kt = extended && extended->Kt ? extended->Kt : with_rigid ? &rigid_rows(model, cd) : &cd.rigid.Kt;
    const MatX* Kt_more = extended ? extended->Kt_more : nullptr;
    const VecX& mu = extended ? *extended->mu : cd.mu;
    const VecX& lambda = extended ? *extended->lambda : cd.lambda;
    const VecX& sys_sigma = extended ? *extended->sigma : sigma;
    const std::vector<Mode>& sys_modes = extended ? *extended->modes : modes;
    const int n_rows = static_cast<int>(sys_modes.size());  // nc, or nc + the limit rows
    const SparseMatrix* Ht_rows = Ht;  // before the padding (the preconditioner's bind pads itself)
    if (3L * n_rows > Ht->cols()) {  // rows without a soft dof (limit rows): zero columns
      Ht_padded_ = *Ht;
      Ht_padded_.conservativeResize(Ht_padded_.rows(), 3L * n_rows);
      Ht_padded_.makeCompressed();
      Ht = &Ht_padded_;
    }
    // The mode-fixed system needs G_AA of the active contacts only: one congruence
    // with the factorization of A (never the whole G).
    active_ids_.clear();
    for (int i = 0; i < n_rows; ++i)
      if (sys_modes[static_cast<std::size_t>(i)] != Mode::breaking) active_ids_.push_back(i);
    select_contact_columns(*Ht, active_ids_, Ht_active_);
    const int na = static_cast<int>(active_ids_.size());
    // Rigid bodies (issue 21): the step's G had their part h sum_r H_r W_r H_r^T = h Kt^T Kt
    // (Kt = L_r^T H_r^T stacked, k x 3 nc), so every G_AA below adds h Kt_A^T Kt_A, Kt_A =
    // Kt's columns of the active contacts. The sparse backend's record has Kt
    // (rigid_delassus_rows, SparseDelassus::set_rigid; an extended system's Kt has the limit
    // rows' columns too); the dense backend's has G instead, and a G_AA recomputed there
    // (Newton: with the converged tangent A_f, docs/method.md "Newton with rigid contact")
    // takes Kt from the record's H_r^T and L_r (rigid_rows).
    // Rigidified parts on the sparse backend (rpsp): their rank-6m part h K_p^T K_p is
    // rigid rows the same way (Kt_more, after the bodies' rows).
    Kt_active_.resize(0, 3 * na);
    if (with_rigid)
      SOFTDIFF_DEMAND(Kt->cols() == 3L * n_rows, "contact derivative: the rigid rows Kt have " +
                                                     std::to_string(Kt->cols()) + " columns, expected " +
                                                     std::to_string(3L * n_rows));
    const Eigen::Index k_bodies = with_rigid ? Kt->rows() : 0;
    const Eigen::Index k_more = Kt_more ? Kt_more->rows() : 0;
    // (the sparse backend's record, or with Newton the converged tangent's rows on either
    // backend: rigidify_derivatives.hpp newton_contact_rows)
    if (Kt_more)
      SOFTDIFF_DEMAND(Kt_more->cols() == 3 * static_cast<Eigen::Index>(nc),
                      "contact derivative: a rigidified part's rows K_p need 3 nc columns");
    if (k_bodies + k_more > 0) {
      Kt_active_.setZero(k_bodies + k_more, 3 * na);
      for (int b = 0; b < na; ++b) {
        const int id = active_ids_[static_cast<std::size_t>(b)];
        if (k_bodies > 0) Kt_active_.block(0, 3 * b, k_bodies, 3) = Kt->middleCols<3>(3 * id);
        if (k_more > 0 && id < nc) Kt_active_.block(k_bodies, 3 * b, k_more, 3) = Kt_more->middleCols<3>(3 * id);
      }
    }
    bool all_sticking = true;
    for (int i : active_ids_) all_sticking = all_sticking && sys_modes[static_cast<std::size_t>(i)] == Mode::sticking;
    const auto& ncp = model.contact.ncp;
    const int dense_max = all_sticking ? ncp.derivative_dense_max_active : ncp.derivative_mixed_dense_max_active;
    if (na > dense_max && (all_sticking || A_upper || na <= operator_unpreconditioned_mixed_max_active)) {
      // Beyond the crossover: the mode-fixed system on the operator (mode_system.hpp),
      // G_AA y = h H_A A^{-1} H_A^T y, one solve with `solver` per product (the caller
      // keeps its factorization until the last jvp / vjp).
      // Where no soft dof is in the active contacts (rigid bodies on obstacles only) the
      // soft part is 0: no solve.
      const bool soft_empty = Ht_active_.nonZeros() == 0;
      const auto G_AA = [this, &solver, h, soft_empty](const VecX& y, VecX& out) {
        if (soft_empty) {
          out.setZero(y.size());
          op_w_.setZero(Ht_active_.rows());
          add_rigid_product(h, y, out);
          return true;
        }
        op_u_.noalias() = Ht_active_ * y;
        if (!solver.solve(op_u_, op_w_)) return false;  // op_w_ is not defined then
        out.noalias() = h * (Ht_active_.transpose() * op_w_);
        add_rigid_product(h, y, out);
        return true;
      };
      // The scale L (docs/method.md "The derivative's scale"). Every active contact
      // sticking (J = G_AA, PCG): L only sets the preconditioner's shift c = 1e-4 L, whose
      // floor is the Woodbury solve's cancellation relative to the largest eigenvalue, so
      // L = lambda_max(G_AA) by power iteration, warm-started from the last system's
      // iterate carried in the nodes' space (scale_w_ = A^{-1} H_A^T y of the last
      // product: y_0 = H_A scale_w_ on this step's active set), else from a fixed start.
      // With sliding contacts L is also the row scale of J's local rows L (lambda_T + mu
      // lambda_N t), which must match the rows S G_AA beside them, i.e. G's diagonal:
      // lambda_max is far larger on a large set (76.8 against a largest diagonal entry of
      // 0.974 at 420 active contacts on the 13k-tet beam, where GMRES then did not reach
      // its tolerance in 4000 iterations; BM_StepDerivatives/6/1), so L = the largest
      // diagonal entry of G_AA over a sample of its contacts (sampled_max_diagonal).
      double L = 0;
      if (all_sticking) {
        if (scale_w_.size() == Ht_active_.rows()) scale_y_.noalias() = Ht_active_.transpose() * scale_w_;
        if (scale_y_.size() != 3 * na || !(scale_y_.norm() > 0) || !scale_y_.allFinite()) {
          scale_y_.resize(3 * na);
          for (int k = 0; k < 3 * na; ++k) scale_y_[k] = 1.0 + 0.01 * static_cast<double>(k % 7);
        }
        scale_ = power_iteration(G_AA, scale_y_, scale_gy_, ncp.derivative_scale_tolerance,
                                 ncp.derivative_scale_max_iterations);
        if (scale_.failed) return false;
        if (!scale_.converged) {
          std::ostringstream m;
          m.precision(3);
          m << "the scale of the contact derivative's mode-fixed system: the power iteration on G_AA (" << na
            << " active contacts) did not converge in " << scale_.iterations << " products (relative change "
            << scale_.change << " > derivative_scale_tolerance " << ncp.derivative_scale_tolerance << ")";
          throw ComputationError(m.str());
        }
        scale_w_ = op_w_;  // A^{-1} H_A^T y of the last product: the next system's start
        L = std::max(scale_.value, 1e-300);
      } else {
        scale_ = PowerIteration{};
        if (!sampled_max_diagonal(solver, h, L)) return false;
      }
      integrator::LinearSolver* A = &solver;
      // The preconditioner (G_AA + c I)^{-1}: one factorization of B = A + (h/c) H_A^T H_A.
      OperatorModeSystem::Precondition M, reduce_apply;
      OperatorModeSystem::FactorizeReduced reduce;
      if (A_upper) {
        // With rigid rows, bound to the system's unpadded Ht: set_rigid pads it to the
        // widest of Kt (the limit rows' columns) and Kt_more (a part's K_p: the contacts'
        // columns only), as the step's operator (contact_step.cpp) does.
        // B's storage (pattern, values, factorization) is the step's NCP's (cd.sparse): the
        // NCP has finished with its B, whose pattern contains this one (A's and the active
        // contacts' blocks); one CHOLMOD factor of B instead of two (docs/method.md "The
        // derivative's memory"). The next step's NCP overwrites it; a jvp after that (a
        // replay of the same step, whose cache key matches) refactorizes this B.
        shifted_.share_shifted_storage(cd.sparse);
        shifted_.bind(solver, *A_upper, Kt_active_.rows() > 0 ? *Ht_rows : *Ht, h, model.solver);
        if (Kt_active_.rows() > 0) {  // + h Kt^T Kt (bind clears it)
          static const MatX none;
          shifted_.set_rigid(k_bodies > 0 ? *Kt : none, Kt_more);
        }
        shifted_.restrict_to(active_ids_);
        // B is positive definite where A is; where it does not factorize (the static
        // solver's tangent need not be), the system is solved unpreconditioned.
        if (all_sticking) {
          if (shifted_.factorize_shifted(operator_shift_fraction * L))
            M = [this](VecX& r) { return shifted_.solve_shifted(r); };
        } else {
          // Mixed: the reduced preconditioner, factorized at the first solve.
          reduce = [this](const std::vector<Mat3>& frames, const VecX& s) {
            shifted_.set_frames(frames, s);
            return shifted_.factorize_shifted(1.0);
          };
          reduce_apply = [this](VecX& r) { return shifted_.solve_shifted(r); };
        }
      }
      ncp_.compute_operator(
          [this, A, h, soft_empty](const VecX& y, VecX& out) {
            if (soft_empty) {
              out.setZero(y.size());
              add_rigid_product(h, y, out);
              return true;
            }
            op_u_.noalias() = Ht_active_ * y;
            if (!A->solve(op_u_, op_w_)) return false;
            out.noalias() = h * (Ht_active_.transpose() * op_w_);
            add_rigid_product(h, y, out);
            return true;
          },
          L, mu, lambda, sys_sigma, sys_modes, std::move(M), std::move(reduce), std::move(reduce_apply));
    } else {
      if (!solver.inverse_congruence(Ht_active_, G_active_)) return false;
      G_active_ *= h;
      if (Kt_active_.rows() > 0) G_active_.noalias() += h * (Kt_active_.transpose() * Kt_active_);
      ncp_.compute_active(G_active_, mu, lambda, sys_sigma, sys_modes);
    }
  }
  return true;
}

const MatX& ContactStageDerivative::rigid_rows(const Model& model, const ContactData& cd) {
  const auto& rd = cd.rigid;
  const Eigen::Index cols = rd.Ht.cols();
  // The sparse backend's record: its Kt (the limit rows cut back, remove_limit_rows).
  if (cd.G.rows() == 0) {
    SOFTDIFF_DEMAND(rd.Kt.cols() == cols, "contact derivative: the sparse record's rigid rows Kt have " +
                                              std::to_string(rd.Kt.cols()) + " columns, expected " +
                                              std::to_string(cols));
    return rd.Kt;
  }
  // The dense backend's: Kt = L_r^T H_r^T of each body with dofs, as the sparse step
  // forms it (once per step's preparation, not per contact).
  rigid_body_rows(model, rd, Kt_record_);
  return Kt_record_;
}

bool ContactStageDerivative::full_G(const Model& model, const ContactData& cd, integrator::LinearSolver& solver,
                                    double h, MatX& G, const SparseMatrix* Ht, const MatX* Kt_more) {
  const SparseMatrix& H = Ht ? *Ht : cd.Ht;
  if (Kt_more)
    SOFTDIFF_DEMAND(Kt_more->cols() == H.cols(), "contact derivative: a rigidified part's rows K_f have " +
                                                     std::to_string(Kt_more->cols()) + " columns, expected " +
                                                     std::to_string(H.cols()));
  if (H.nonZeros() > 0) {
    if (!solver.inverse_congruence(H, G)) return false;
    G *= h;
  } else {
    G.setZero(H.cols(), H.cols());  // no free soft dof in the contacts (all in parts): no solve
  }
  if (model.contact.with_rigid()) {
    const MatX& Kt = rigid_rows(model, cd);
    if (Kt.rows() > 0) G.noalias() += h * (Kt.transpose() * Kt);
  }
  if (Kt_more && Kt_more->rows() > 0) G.noalias() += h * (Kt_more->transpose() * *Kt_more);
  return true;
}

// The largest diagonal entry of G_AA = h H_A A^{-1} H_A^T over a deterministic sample of
// at most scale_sample_contacts active contacts, evenly spaced in the active list (all of
// them on a smaller set, where it is the exact maximum): their 3 columns of A^{-1} H_A^T
// from one solve with several right-hand sides on `solver`'s factor. A row scale only:
// the mode-fixed system's answer does not depend on it, its conditioning does.
void ContactStageDerivative::add_rigid_product(double h, const VecX& y, VecX& out) {
  if (Kt_active_.rows() == 0) return;
  op_k_.noalias() = Kt_active_ * y;
  out.noalias() += h * (Kt_active_.transpose() * op_k_);
}

bool ContactStageDerivative::sampled_max_diagonal(integrator::LinearSolver& solver, double h, double& L) {
  const int na = static_cast<int>(active_ids_.size());
  const int ns = std::min(na, scale_sample_contacts);
  const Eigen::Index n = Ht_active_.rows();
  // In blocks of scale_sample_block_contacts contacts (3 columns each): the dense n x 3 s
  // right-hand sides, their solutions and the solver's workspaces of as many columns
  // (CHOLMOD's X, Y: 4 such matrices) were 4 x 26 MB at s = 32 on the slab of
  // configs/slab_on_plane.yaml (n = 34k), 100 of its 476 MB (docs/performance.md
  // "Contact at scale", "The derivative's memory"); per block they are 1/8 of that.
  const int block = std::min(ns, scale_sample_block_contacts);
  sample_B_.resize(n, 3 * block);
  L = 0;
  for (int j0 = 0; j0 < ns; j0 += block) {
    const int nb = std::min(block, ns - j0);
    sample_B_.setZero(n, 3 * nb);
    for (int j = 0; j < nb; ++j) {
      const int a = static_cast<int>((static_cast<long>(j0 + j) * na) / ns);
      for (int k = 0; k < 3; ++k) sample_B_.col(3 * j + k) = Ht_active_.col(3 * a + k);
    }
    if (!solver.solve(sample_B_, sample_X_)) return false;
    for (Eigen::Index c = 0; c < sample_B_.cols(); ++c) {
      double Gcc = h * sample_B_.col(c).dot(sample_X_.col(c));
      // + the rigid part's diagonal h |Kt_A's column|^2 (the same sampled column).
      if (Kt_active_.rows() > 0) {
        const int j = j0 + static_cast<int>(c / 3), k = static_cast<int>(c % 3);
        const int a = static_cast<int>((static_cast<long>(j) * na) / ns);
        Gcc += h * Kt_active_.col(3 * a + k).squaredNorm();
      }
      L = std::max(L, Gcc);
    }
  }
  if (!(L > 0) || !std::isfinite(L)) return false;
  return true;
}

void ContactStageDerivative::add_force_jvp(const ContactData& cd, double h, const VecX& dx, VecX& r) const {
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[i];
    const auto& g = geometry_[static_cast<std::size_t>(i)];
    const Eigen::Matrix<double, 12, 1> u = gather_contact(c, dx);
    const Vec3 l = cd.lambda.segment<3>(3 * i);
    const Vec3 Cl = c.frame * l;
    const Mat3 dC = Eigen::Map<const Mat3>(Eigen::Matrix<double, 9, 1>(g.dframe * u).data());
    const Vec3 dCl = dC * l;
    const Eigen::Vector4d dw = g.dweights * u;
    for (int k = 0; k < c.count; ++k) r.segment<3>(3 * c.nodes[k]) += h * (dw[k] * Cl + c.weights[k] * dCl);
  }
}

void ContactStageDerivative::add_sigma_jvp(const ContactData& cd, const VecX& u_sol, double h, const VecX& dx,
                                           VecX& b) const {
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[i];
    const auto& g = geometry_[static_cast<std::size_t>(i)];
    b.segment<3>(3 * i) += frame_field_jvp(c, g, u_sol, dx);
    b[3 * i + 2] += (g.dgap * gather_contact(c, dx))(0) / h;
  }
}

void ContactStageDerivative::add_geometry_vjp(const ContactData& cd, const VecX& u_sol, double h, const VecX& y,
                                              const VecX& bar_b, VecX& bar_x) const {
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[i];
    const auto& g = geometry_[static_cast<std::size_t>(i)];
    const Vec3 l = cd.lambda.segment<3>(3 * i), Cl = c.frame * l, bb = bar_b.segment<3>(3 * i), Cb = c.frame * bb;
    // d/du of  h sum_k y_k . (dw_k C l + w_k dC l)  +  bb . (dC^T V + C^T dV) + bb_N dgap / h.
    Eigen::Matrix<double, 4, 1> gw = Eigen::Matrix<double, 4, 1>::Zero();
    Mat3 gC = Mat3::Zero();  // the gradient with respect to the entries of C
    Vec3 V = Vec3::Zero();
    for (int k = 0; k < c.count; ++k) {
      const Vec3 yk = y.segment<3>(3 * c.nodes[k]), vk = u_sol.segment<3>(3 * c.nodes[k]);
      gw[k] += h * yk.dot(Cl) + Cb.dot(vk);
      gC += h * c.weights[k] * yk * l.transpose();
      V += c.weights[k] * vk;
    }
    gC += V * bb.transpose();  // bb . dC^T V = V . dC bb
    const Eigen::Matrix<double, 12, 1> gu = g.dweights.transpose() * gw +
                                            g.dframe.transpose() * Eigen::Map<const Eigen::Matrix<double, 9, 1>>(gC.data()) +
                                            g.dgap.transpose() * (bb[2] / h);
    for (int k = 0; k < c.count; ++k) bar_x.segment<3>(3 * c.nodes[k]) += gu.segment<3>(3 * k);
  }
}

void ContactStageDerivative::add_slip_jvp(const ContactData& cd, const VecX& D, const VecX& dx, VecX& b) const {
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[i];
    b.segment<2>(3 * i) += frame_field_jvp(c, geometry_[static_cast<std::size_t>(i)], D, dx).head<2>();
  }
}

void ContactStageDerivative::add_slip_vjp(const ContactData& cd, const VecX& D, const VecX& bar_b,
                                          VecX& bar_x) const {
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[i];
    const auto& g = geometry_[static_cast<std::size_t>(i)];
    const double b0 = bar_b[3 * i], b1 = bar_b[3 * i + 1];
    if (b0 == 0 && b1 == 0) continue;
    // d/du of  sum_r b_r (dC_r . d + C_r . sum_k dw_k D_k).
    const Vec3 t = b0 * c.frame.col(0) + b1 * c.frame.col(1);
    Eigen::Matrix<double, 4, 1> gw = Eigen::Matrix<double, 4, 1>::Zero();
    Vec3 d = Vec3::Zero();
    for (int k = 0; k < c.count; ++k) {
      const Vec3 Dk = D.segment<3>(3 * c.nodes[k]);
      gw[k] = t.dot(Dk);
      d += c.weights[k] * Dk;
    }
    Mat3 gC = Mat3::Zero();  // the gradient with respect to the entries of C (column-major, as dframe)
    gC.col(0) = b0 * d;
    gC.col(1) = b1 * d;
    const Eigen::Matrix<double, 12, 1> gu =
        g.dweights.transpose() * gw + g.dframe.transpose() * Eigen::Map<const Eigen::Matrix<double, 9, 1>>(gC.data());
    for (int k = 0; k < c.count; ++k) bar_x.segment<3>(3 * c.nodes[k]) += gu.segment<3>(3 * k);
  }
}

void ContactStageDerivative::friction_tangent(const Model& model, const ContactData& cd,
                                              const std::vector<ParameterId>& parameters, const VecX& dp, VecX& dmu) {
  dmu.resize(0);
  for (std::size_t j = 0; j < parameters.size(); ++j) {
    const ParameterId& id = parameters[j];
    const auto jj = static_cast<Eigen::Index>(j);
    if (id.kind != Parameter::friction || !dp.size() || dp[jj] == 0) continue;
    if (!dmu.size()) dmu = VecX::Zero(cd.contacts.size());
    const auto& rule = model.contact.detection.pairs[static_cast<std::size_t>(id.body)];
    for (int i = 0; i < cd.contacts.size(); ++i)
      if (in_rule(cd.contacts.contacts[i], rule)) dmu[i] += dp[jj];
  }
}

void ContactStageDerivative::add_friction_cotangent(const Model& model, const ContactData& cd,
                                                    const std::vector<ParameterId>& parameters, const VecX& bar_mu,
                                                    VecX& bar_p) {
  for (std::size_t j = 0; j < parameters.size(); ++j) {
    const ParameterId& id = parameters[j];
    if (id.kind != Parameter::friction) continue;
    const auto& rule = model.contact.detection.pairs[static_cast<std::size_t>(id.body)];
    for (int i = 0; i < cd.contacts.size(); ++i)
      if (in_rule(cd.contacts.contacts[i], rule)) bar_p[static_cast<Eigen::Index>(j)] += bar_mu[i];
  }
}

}  // namespace softdiff::contact
