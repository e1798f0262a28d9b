// Derivatives of the implicit Euler step with rigidified parts: see rigidify_derivatives.hpp.
#include <softdiff/integrator/rigidify_derivatives.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/integrator/rigidify.hpp>
#include <softdiff/integrator/rigidify_pcg.hpp>
#include <softdiff/rigid/rotation.hpp>

namespace softdiff::integrator {

namespace {
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

// N = sum_i m_i T_i^T T_i and f = sum_i m_i T_i^T v_i for the part's nodes at x about c.
void fit_system(const Model& model, const RigidifiedPart& part, const VecX& x, const Vec3& c, const VecX& v, Mat6& N,
                Vec6& f) {
  N.setZero();
  f.setZero();
  for (int i : part.nodes) {
    const double mi = model.fem.mass_diagonal[3 * i];
    const Vec3 a = x.segment<3>(3 * i) - c;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Matrix<double, 1, 6> t = rigid_row(a, k);
      N.noalias() += mi * t.transpose() * t;
      f.noalias() += (mi * v[3 * i + k]) * t.transpose();
    }
  }
}
}  // namespace

void RigidifiedStepDerivative::prepare(const Model& model, const Data& data, const State& in, const State& out,
                                       double h) {
  const auto& fem = model.fem;
  const RigidifyModel& rm = model.rigidify;
  const Eigen::Index n = 3L * fem.num_nodes, m6 = 6L * rm.size();
  h_ = h;
  newton_ = model.step.newton_iterations > 1 && fem.num_nodes > 0;
  newton_solver_ = nullptr;  // prepare_newton's (a Newton step's solves need it)
  parts_.resize(rm.parts.size());
  for (VecX* v : {&r_res_, &da_, &dpz_, &w_, &Mw_, &Kw_, &Aw_, &bar_a_, &b_soft_, &y_, &Kiw_})
    if (v->size() != n) v->setZero(n);
  if (g_extra_.size() != m6) {
    g_extra_.setZero(m6);
    g_.setZero(m6);
    u_.setZero(m6);
  }
  x_ = in.x;
  solve_ = out;
  for (std::size_t p = 0; p < rm.parts.size(); ++p) {
    const auto& part = rm.parts[p];
    Part& q = parts_[p];
    q.c = part_centre(model, part, in.x);
    q.m = 0;
    for (int i : part.nodes) q.m += fem.mass_diagonal[3 * i];
    Vec6 f;
    fit_system(model, part, in.x, q.c, in.v, q.N, f);
    q.N_factor.compute(q.N);
    const Vec6 u_i = q.N_factor.solve(f);  // the fit of v_i (exact for a rigid field)
    q.I = q.N.bottomRightCorner<3, 3>();
    q.I_factor.compute(q.I);
    // The placed pose: its rigid field gives v_p and omega', and L = I' omega' = I omega.
    Mat6 N1;
    Vec6 f1;
    fit_system(model, part, out.x, part_centre(model, part, out.x), out.v, N1, f1);
    const Vec6 u1 = N1.ldlt().solve(f1);
    q.u_f.head<3>() = u1.head<3>();
    q.u_f.tail<3>() = q.I_factor.solve(Vec3(N1.bottomRightCorner<3, 3>() * u1.tail<3>()));
    q.u_z = q.u_f - u_i;
    const Vec3 omega = q.u_f.tail<3>();
    q.L = q.I * omega;
    q.R = rigid::quaternion_exp(h * omega).toRotationMatrix();
    q.Jr = rigid::right_jacobian(h * omega);
    q.s = q.I_factor.solve(Vec3(q.R.transpose() * q.L));
    q.omega_next = q.R * q.s;
    for (int i : part.nodes) {
      const Vec3 a = in.x.segment<3>(3 * i) - q.c;
      solve_.v.segment<3>(3 * i) = in.v.segment<3>(3 * i) + q.u_z.head<3>() + q.u_z.tail<3>().cross(a);
    }
  }
  // Newton: the elastic force's positions are the straight-line iterate x_i + h v~ (not the
  // placed pose): the parameter columns (poisson's df/dnu) evaluate there.
  if (newton_) solve_.x = in.x + h * solve_.v;
  // r_res = h (P + f_int + f_act) - h alpha M v~ - (h beta + h^2) K~ v~ - M Delta + h H^T lambda,
  // the parts' rows (zero resultant and moment on each part). Newton: -R(v~) = h (P +
  // f_int(x_i + h v~) + f_act) - h alpha M v~ - h beta K~(x_i) v~ - M Delta + h H^T lambda
  // (data.fem holds the converged iterate's f_int, data.K_i_values K~(x_i)).
  fem::symmetric_multiply(fem, fem.mass_values, solve_.v, Mw_);
  fem::symmetric_multiply(fem, newton_ ? data.K_i_values : data.fem.K_values, solve_.v, Kw_);
  w_ = solve_.v - in.v;
  fem::symmetric_multiply(fem, fem.mass_values, w_, Aw_);
  const bool contact = model.contact.enabled && !data.contact.contacts.empty();
  if (contact) w_.noalias() = h * (data.contact.Ht * data.contact.lambda);
  r_res_.setZero();
  for (const auto& part : rm.parts) {
    const auto& b = fem.bodies[static_cast<std::size_t>(part.body)];
    const double ha = h * b.rayleigh_mass, k = h * b.rayleigh_stiffness + (newton_ ? 0.0 : h * h);
    for (int i : part.nodes)
      for (int c = 3 * i; c < 3 * i + 3; ++c) {
        double r = h * (fem.gravity_force[c] + data.fem.f_int[c]) - ha * Mw_[c] - k * Kw_[c] - Aw_[c];
        if (!model.actuation.empty()) r += h * data.f_act[c];
        if (contact) r += w_[c];
        r_res_[c] = r;
      }
  }
}

bool RigidifiedStepDerivative::prepare_newton(const Model& model, const Data& data, LinearSolver& solver, long serial) {
  newton_solver_ = &solver;
  if (serial == newton_serial_) return true;
  newton_serial_ = -1;
  const Eigen::Index n = 3L * model.fem.num_nodes, m6 = 6L * model.rigidify.size();
  if (C_.rows() != n || C_.cols() != m6) {
    C_.resize(n, m6);
    Y_.resize(n, m6);
    S_.resize(m6, m6);
    S_factor_ = Eigen::LLT<MatX>(m6);
  }
  // C = A_f,fr T and S = T^T A_f,rr T - C^T A_f,ff^{-1} C at the step's arms (x_i): the
  // step's prepare_rigidified on A_f instead of the last iteration's A_k.
  rigidified_coupling(model, data, h_, &data.K_i_values, C_, S_);
  if (!solver.solve(C_, Y_)) return false;
  S_.noalias() -= C_.transpose() * Y_;
  for (Eigen::Index j = 0; j < m6; ++j)
    for (Eigen::Index i = 0; i < j; ++i) S_(i, j) = S_(j, i) = 0.5 * (S_(i, j) + S_(j, i));
  S_factor_.compute(S_);
  if (S_factor_.info() != Eigen::Success) return false;
  newton_serial_ = serial;
  return true;
}

void RigidifiedStepDerivative::newton_contact_rows(const Model& model, const Data& data, const SparseMatrix& Ht) {
  const RigidifyModel& rm = model.rigidify;
  const RigidifyData& w = data.rigidify;  // the arms (x_i, centres)
  const Eigen::Index ncols = Ht.cols(), m6 = 6L * rm.size();
  Ht_soft_ = Ht;
  Ht_soft_.prune([&](Eigen::Index row, Eigen::Index, double) { return rm.dof_part[static_cast<std::size_t>(row)] < 0; });
  K_.resize(m6, ncols);
  K_.noalias() = -(Y_.transpose() * Ht_soft_);
  for (Eigen::Index col = 0; col < ncols; ++col)
    for (SparseMatrix::InnerIterator it(Ht, col); it; ++it) {
      const int dof = static_cast<int>(it.row()), p = rm.dof_part[static_cast<std::size_t>(dof)];
      if (p < 0) continue;
      const Vec3 r = w.x.segment<3>(3 * (dof / 3)) - w.centre[static_cast<std::size_t>(p)];
      K_.block<6, 1>(6 * p, col).noalias() += it.value() * rigid_row(r, dof % 3).transpose();
    }
  S_factor_.matrixL().solveInPlace(K_);  // W_f^T S_f^{-1} W_f = K_f^T K_f
}

void RigidifiedStepDerivative::system_product(const Model& model, const Data& data, const VecX& w, VecX& out) {
  const auto& fem = model.fem;
  fem::symmetric_multiply(fem, fem.mass_values, w, Mw_);
  fem::symmetric_multiply(fem, data.fem.K_values, w, Kw_);
  if (newton_) {
    // A_f = (1 + h alpha) M + h beta K~(x_i) + h^2 K(x_f)
    fem::symmetric_multiply(fem, data.K_i_values, w, Kiw_);
    for (const auto& b : fem.bodies) {
      const int begin = 3 * b.node_begin, len = 3 * b.num_nodes;
      out.segment(begin, len) = (1 + h_ * b.rayleigh_mass) * Mw_.segment(begin, len) +
                                h_ * b.rayleigh_stiffness * Kiw_.segment(begin, len) +
                                h_ * h_ * Kw_.segment(begin, len);
    }
    return;
  }
  for (const auto& b : fem.bodies) {
    const int begin = 3 * b.node_begin, len = 3 * b.num_nodes;
    out.segment(begin, len) = (1 + h_ * b.rayleigh_mass) * Mw_.segment(begin, len) +
                              (h_ * b.rayleigh_stiffness + h_ * h_) * Kw_.segment(begin, len);
  }
}

Eigen::Matrix<double, 6, 1> RigidifiedStepDerivative::fit(const Model& model, int p, const VecX& w) const {
  const Part& q = parts_[static_cast<std::size_t>(p)];
  Vec6 f = Vec6::Zero();
  for (int i : model.rigidify.parts[static_cast<std::size_t>(p)].nodes) {
    const double mi = model.fem.mass_diagonal[3 * i];
    const Vec3 a = x_.segment<3>(3 * i) - q.c, wi = w.segment<3>(3 * i);
    f.head<3>() += mi * wi;
    f.tail<3>() += mi * a.cross(wi);
  }
  return q.N_factor.solve(f);
}

void RigidifiedStepDerivative::arms_to_positions(const Model& model, int p, const VecX& bar_a, const Vec3& bar_c,
                                                 VecX& bar_x) const {
  const Part& q = parts_[static_cast<std::size_t>(p)];
  const auto& nodes = model.rigidify.parts[static_cast<std::size_t>(p)].nodes;
  Vec3 sum = Vec3::Zero();
  for (int i : nodes) sum += bar_a.segment<3>(3 * i);
  const Vec3 centre = (bar_c - sum) / q.m;  // a_i = x_i - c, c = sum m_j x_j / m
  for (int i : nodes) bar_x.segment<3>(3 * i) += bar_a.segment<3>(3 * i) + model.fem.mass_diagonal[3 * i] * centre;
}

void RigidifiedStepDerivative::add_rhs_jvp(const Model& model, const Data& data, const VecX& dx, VecX& r) {
  const RigidifyModel& rm = model.rigidify;
  g_extra_.setZero();
  dpz_.setZero();
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    const Part& q = parts_[static_cast<std::size_t>(p)];
    if (dx.size() == 0) {
      for (int i : part.nodes) da_.segment<3>(3 * i).setZero();
      continue;
    }
    Vec3 dc = Vec3::Zero();
    for (int i : part.nodes) dc += model.fem.mass_diagonal[3 * i] * dx.segment<3>(3 * i);
    dc /= q.m;
    const Vec3 omega_z = q.u_z.tail<3>();
    for (int i : part.nodes) {
      const Vec3 da = dx.segment<3>(3 * i) - dc;
      da_.segment<3>(3 * i) = da;
      dpz_.segment<3>(3 * i) = omega_z.cross(da);                              // dP z
      g_extra_.segment<3>(6 * p + 3) += da.cross(Vec3(r_res_.segment<3>(3 * i)));  // dP^T r_res
    }
  }
  if (dx.size() == 0) return;
  system_product(model, data, dpz_, Aw_);
  r -= Aw_;
}

bool RigidifiedStepDerivative::solve(const Model& model, const Data& data, const VecX& b, bool with_extra, VecX& v) {
  // rigidify.cpp's solve_rigidified with this object's workspace (data is the record).
  const RigidifyModel& rm = model.rigidify;
  const RigidifyData& w = data.rigidify;
  b_soft_ = b;
  for (const auto& part : rm.parts)
    for (int i : part.nodes) b_soft_.segment<3>(3 * i).setZero();
  auto add_part_loads = [&] {  // g += T^T b_r
    for (int p = 0; p < rm.size(); ++p)
      for (int i : rm.parts[static_cast<std::size_t>(p)].nodes) {
        const Vec3 a = w.x.segment<3>(3 * i) - w.centre[static_cast<std::size_t>(p)];
        const Vec3 bi = b.segment<3>(3 * i);
        g_.segment<3>(6 * p) += bi;
        g_.segment<3>(6 * p + 3) += a.cross(bi);
      }
  };
  if (newton_) {
    // Newton: A_f's Schur complement (prepare_newton) on the caller's factorization of A_f.
    SOFTDIFF_DEMAND(newton_solver_ != nullptr && newton_serial_ >= 0,
                    "rigidified parts' Newton derivative: prepare_newton() did not run for this step");
    if (!newton_solver_->solve(b_soft_, y_)) return false;
    g_.noalias() = -C_.transpose() * y_;
    add_part_loads();
    if (with_extra) g_ += g_extra_;
    u_ = S_factor_.solve(g_);
    v = y_;
    v.noalias() -= Y_ * u_;
  } else if (w.reduced_pcg) {
    // Factor reuse: the step kept a factor, and C, Y, S are the factorization's (the
    // preconditioner): PCG on the step's P^T A P from zero, to the step's PCG tolerance.
    // Not converged: the derivative fails (false), as a failed solve does.
    const Eigen::Index n = b.size(), m6 = 6 * rm.size();
    for (VecX& z : pcg_f_) z.resize(n);
    for (VecX& z : pcg_u_) z.resize(m6);
    pcg_y_.resize(n);
    g_.setZero(m6);
    add_part_loads();
    if (with_extra) g_ += g_extra_;
    if (reduced_pcg(model, data, b_soft_, g_, y_, u_, false,
                    {pcg_f_[0], pcg_f_[1], pcg_f_[2], pcg_f_[3], pcg_u_[0], pcg_u_[1], pcg_u_[2], pcg_u_[3], pcg_y_}) < 0)
      return false;
    v = y_;
  } else {
    if (!data.solver->solve(b_soft_, y_)) return false;
    g_.noalias() = -w.C.transpose() * y_;
    add_part_loads();
    if (with_extra) g_ += g_extra_;
    u_ = w.S_factor.solve(g_);
    v = y_;
    v.noalias() -= w.Y * u_;
  }
  for (int p = 0; p < rm.size(); ++p) {
    const Vec6 up = u_.segment<6>(6 * p);
    for (int i : rm.parts[static_cast<std::size_t>(p)].nodes) {
      const Vec3 a = w.x.segment<3>(3 * i) - w.centre[static_cast<std::size_t>(p)];
      v.segment<3>(3 * i) = up.head<3>() + up.tail<3>().cross(a);
    }
  }
  return v.allFinite();
}

void RigidifiedStepDerivative::add_dPz(VecX& dv) const {
  dv += dpz_;  // zero off the parts' rows
}

void RigidifiedStepDerivative::place_jvp(const Model& model, const VecX& dx, VecX& dx_out, VecX& dv_out) {
  const RigidifyModel& rm = model.rigidify;
  const double h = h_;
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    const Part& q = parts_[static_cast<std::size_t>(p)];
    const Vec3 vp = q.u_f.head<3>(), omega = q.u_f.tail<3>();
    Vec3 dc = Vec3::Zero();
    for (int i : part.nodes) dc += model.fem.mass_diagonal[3 * i] * dx.segment<3>(3 * i);
    dc /= q.m;
    // The fit's tangent: du = N^{-1} sum m [dT^T (v~ - T u) + T^T (dv~ - dT u)].
    Vec6 rhs = Vec6::Zero();
    Mat3 dI = Mat3::Zero();
    for (int i : part.nodes) {
      const double mi = model.fem.mass_diagonal[3 * i];
      const Vec3 a = x_.segment<3>(3 * i) - q.c, da = dx.segment<3>(3 * i) - dc;
      const Vec3 rho = solve_.v.segment<3>(3 * i) - vp - omega.cross(a);
      const Vec3 wv = dv_out.segment<3>(3 * i) - omega.cross(da);
      rhs.head<3>() += mi * wv;
      rhs.tail<3>() += mi * (a.cross(wv) + da.cross(rho));
      dI += mi * (2 * a.dot(da) * Mat3::Identity() - da * a.transpose() - a * da.transpose());
    }
    const Vec6 du = q.N_factor.solve(rhs);
    const Vec3 dvp = du.head<3>(), domega = du.tail<3>();
    const Vec3 theta = h * (q.Jr * domega);  // dR = R [theta]x
    const Vec3 dL = dI * omega + q.I * domega;
    const Vec3 ds = q.I_factor.solve(Vec3(-theta.cross(Vec3(q.R.transpose() * q.L)) + q.R.transpose() * dL - dI * q.s));
    const Vec3 domega_next = q.R * (theta.cross(q.s) + ds);
    for (int i : part.nodes) {
      const Vec3 a = x_.segment<3>(3 * i) - q.c, da = dx.segment<3>(3 * i) - dc;
      const Vec3 r = q.R * a, dr = q.R * (theta.cross(a) + da);
      dx_out.segment<3>(3 * i) = dc + h * dvp + dr;
      dv_out.segment<3>(3 * i) = dvp + domega_next.cross(r) + q.omega_next.cross(dr);
    }
  }
}

void RigidifiedStepDerivative::place_vjp(const Model& model, const VecX& bar_x_out, const VecX& bar_v_out,
                                         VecX& bar_v_tilde, VecX& bar_x) {
  const RigidifyModel& rm = model.rigidify;
  const double h = h_;
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    const Part& q = parts_[static_cast<std::size_t>(p)];
    const Vec3 vp = q.u_f.head<3>(), omega = q.u_f.tail<3>();
    Vec3 bar_vp = Vec3::Zero(), bar_c = Vec3::Zero(), bar_omega_next = Vec3::Zero(), bar_theta = Vec3::Zero();
    for (int i : part.nodes) {
      const Vec3 a = x_.segment<3>(3 * i) - q.c, r = q.R * a;
      const Vec3 bx = bar_x_out.segment<3>(3 * i), bv = bar_v_out.segment<3>(3 * i);
      bar_vp += bv + h * bx;
      bar_c += bx;
      bar_omega_next += r.cross(bv);
      const Vec3 e = q.R.transpose() * (bx + bv.cross(q.omega_next));  // the cotangent of R^{-1} dr
      bar_theta += a.cross(e);
      bar_a_.segment<3>(3 * i) = e;
    }
    const Vec3 beta = q.R.transpose() * bar_omega_next;
    bar_theta += q.s.cross(beta);
    const Vec3 gamma = q.I_factor.solve(beta);
    bar_theta += gamma.cross(Vec3(q.R.transpose() * q.L));
    const Vec3 bar_L = q.R * gamma;
    Vec6 bar_u;
    bar_u.head<3>() = bar_vp;
    bar_u.tail<3>() = q.I * bar_L + h * (q.Jr.transpose() * bar_theta);
    const Vec6 kappa = q.N_factor.solve(bar_u);
    const Vec3 kv = kappa.head<3>(), kw = kappa.tail<3>();
    for (int i : part.nodes) {
      const double mi = model.fem.mass_diagonal[3 * i];
      const Vec3 a = x_.segment<3>(3 * i) - q.c;
      // dI's cotangent: bar_L^T dI omega - gamma^T dI s, with
      // p^T dI q = sum m da . (2 (p.q) a - (a.q) p - (a.p) q).
      Vec3 ba = mi * (2 * bar_L.dot(omega) * a - a.dot(omega) * bar_L - a.dot(bar_L) * omega);
      ba -= mi * (2 * gamma.dot(q.s) * a - a.dot(q.s) * gamma - a.dot(gamma) * q.s);
      // The fit's: T^T dv~ . kappa, dT^T rho . kappa, -T^T dT u . kappa.
      const Vec3 tk = kv + kw.cross(a);
      const Vec3 rho = solve_.v.segment<3>(3 * i) - vp - omega.cross(a);
      bar_v_tilde.segment<3>(3 * i) = mi * tk;
      ba += mi * (rho.cross(kw) - tk.cross(omega));
      bar_a_.segment<3>(3 * i) += ba;
      bar_x.segment<3>(3 * i).setZero();
    }
    arms_to_positions(model, p, bar_a_, bar_c, bar_x);
  }
}

void RigidifiedStepDerivative::add_solve_vjp(const Model& model, const Data& data, const VecX& t, const VecX& y,
                                             VecX& bar_x) {
  const RigidifyModel& rm = model.rigidify;
  system_product(model, data, y, Aw_);
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    const Vec3 omega_z = parts_[static_cast<std::size_t>(p)].u_z.tail<3>();
    const Vec3 omega_q = fit(model, p, y).tail<3>();  // y = T u_q on the part: N^{-1} P^T t's
    for (int i : part.nodes) {
      const Vec3 ti = t.segment<3>(3 * i), ai = Aw_.segment<3>(3 * i), ri = r_res_.segment<3>(3 * i);
      // <t, dP z> - <A y, dP z> + <u_q, dP^T r_res>, each as da_i . (...)
      bar_a_.segment<3>(3 * i) = (ti - ai).cross(omega_z) + ri.cross(omega_q);
    }
    arms_to_positions(model, p, bar_a_, Vec3::Zero(), bar_x);
  }
}

}  // namespace softdiff::integrator
