// The mode-fixed system on the operator: see mode_system.hpp.
#include <softdiff/contact/mode_system.hpp>

#include <softdiff/core/assert.hpp>

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <string>
#include <utility>

namespace softdiff::contact {

void OperatorModeSystem::set(Apply G_AA, std::vector<Mat3> S, std::vector<Mat3> T) {
  SOFTDIFF_DEMAND(S.size() == T.size(), "OperatorModeSystem::set: S and T differ in size");
  G_ = std::move(G_AA);
  S_ = std::move(S);
  T_ = std::move(T);
  M_ = nullptr;
  reduced_factorize_ = nullptr;
  reduced_apply_ = nullptr;
  reduced_state_ = 0;
  last_reduced_ok_ = false;
}

bool OperatorModeSystem::prepare_reduced() const {
  // The rotated frames, row scales and local rows of mode_system.hpp "Mixed sets", read
  // off S and T; any block of another form (not a mode system of ncp_derivatives.hpp):
  // not applicable.
  const int na = static_cast<int>(S_.size());
  rot_.assign(static_cast<std::size_t>(na), Mat3::Identity());
  dl_.setOnes(3 * na);
  local_.setZero(3 * na);
  mu_s_.setZero(na);
  weights_.setZero(3 * na);
  double L = 0;
  for (int a = 0; a < na; ++a)
    if (!(S_[a].isIdentity(0) && T_[a].isZero(0))) L = std::max(L, T_[a](0, 0));
  if (!(L > 0) || !std::isfinite(L)) return false;
  const double c = operator_shift_fraction * L;
  VecX d = VecX::Constant(3 * na, c);  // the diagonal C + c I of the reduced rows
  for (int a = 0; a < na; ++a) {
    const Mat3& S = S_[a];
    const Mat3& T = T_[a];
    if (S.isIdentity(0) && T.isZero(0)) continue;  // sticking
    const double La = T(0, 0);
    const Eigen::Vector2d tv = T.block<2, 1>(0, 2);
    const double tn = tv.norm();
    const Eigen::Vector2d t = tn > 0 ? Eigen::Vector2d(tv / tn) : Eigen::Vector2d(1, 0);
    Mat3& R = rot_[a];
    R << t[0], t[1], 0, -t[1], t[0], 0, 0, 0, 1;
    const Mat3 Sr = R * S * R.transpose(), Tr = R * T * R.transpose();
    const double mu = tn / La, Lw = Sr(1, 1);
    Mat3 Se = Mat3::Zero(), Te = Mat3::Zero();
    Se(1, 1) = Lw;
    Se(2, 2) = 1;
    Te(0, 0) = Te(1, 1) = La;
    Te(0, 2) = La * mu;
    const double eps = 1e-12 * std::max(La, Sr.cwiseAbs().maxCoeff());
    if (!(La > 0) || !(Lw >= 0) || (Sr - Se).cwiseAbs().maxCoeff() > eps || (Tr - Te).cwiseAbs().maxCoeff() > eps)
      return false;
    local_[3 * a] = La;  // row s (or the first tangent): L (x_s + mu x_N)
    mu_s_[a] = mu;
    if (Lw > 0) {
      dl_[3 * a + 1] = 1 / Lw;  // row p / (L w): (G x)_p + (L / (L w)) x_p
      d[3 * a + 1] = c + La / Lw;
    } else {
      local_[3 * a + 1] = La;  // L x_p = r_p
    }
  }
  for (int k = 0; k < 3 * na; ++k) weights_[k] = local_[k] > 0 ? 0.0 : 1 / std::sqrt(d[k]);
  ++precond_solves_;  // (the factorization, counted with the applications)
  return reduced_factorize_(rot_, weights_);
}

bool OperatorModeSystem::apply_scaled(const VecX& v, VecX& out, bool transposed) const {
  // J' v = Dl Rot J Rot^T v;  J'^T v = Rot J^T Rot^T Dl v.
  const int na = static_cast<int>(S_.size());
  gv_.resize(3 * na);
  if (!transposed) {
    for (int a = 0; a < na; ++a) gv_.segment<3>(3 * a) = rot_[a].transpose() * v.segment<3>(3 * a);
  } else {
    for (int a = 0; a < na; ++a)
      gv_.segment<3>(3 * a) = rot_[a].transpose() * (dl_.segment<3>(3 * a).cwiseProduct(v.segment<3>(3 * a)));
  }
  if (!apply(gv_, out, transposed)) return false;
  for (int a = 0; a < na; ++a) {
    const Vec3 o = rot_[a] * out.segment<3>(3 * a);
    out.segment<3>(3 * a) = transposed ? o : Vec3(dl_.segment<3>(3 * a).cwiseProduct(o));
  }
  return true;
}

bool OperatorModeSystem::precondition_reduced(VecX& v, bool transposed) const {
  // P' = [M_R, 0; E M_R, diag(1 / L)] with E's row s = -mu e_N^T (mode_system.hpp);
  // P'^T = [M_R, M_R E^T; 0, diag(1 / L)]. gw_ keeps v's local rows.
  const int na = static_cast<int>(S_.size());
  gw_ = v;
  if (transposed)
    for (int a = 0; a < na; ++a) v[3 * a + 2] += -mu_s_[a] * v[3 * a];
  ++precond_solves_;
  if (!reduced_apply_(v)) return false;  // 0 on the local rows (weight 0)
  for (int k = 0; k < 3 * na; ++k)
    if (local_[k] > 0) v[k] = gw_[k] / local_[k];
  if (!transposed)
    for (int a = 0; a < na; ++a) v[3 * a] += -mu_s_[a] * v[3 * a + 2];
  return v.allFinite();
}

bool OperatorModeSystem::solve_gmres(const VecX& r, VecX& x, bool transposed) const {
  // Restarted GMRES on J' P' z = b' (right preconditioning; modified Gram-Schmidt,
  // Givens rotations), x' = P' z accumulated per cycle, the true residual recomputed
  // at each restart. Workspace sized here, once per size; the iteration allocates nothing.
  const int na = static_cast<int>(S_.size());
  const Eigen::Index m = 3 * na;
  const int k = std::max(1, std::min<int>(gmres_restart, static_cast<int>(m)));
  if (V_.rows() != m || V_.cols() != k + 1) V_.resize(m, k + 1);
  Hh_.setZero(k + 1, k);
  gc_.resize(k);
  gs_.resize(k);
  gg_.resize(k + 1);
  gy_.resize(k);
  gb_.resize(m);
  gx_.setZero(m);
  // b' = Dl Rot r (forward) or Rot r (transposed).
  for (int a = 0; a < na; ++a) {
    const Vec3 o = rot_[a] * r.segment<3>(3 * a);
    gb_.segment<3>(3 * a) = transposed ? o : Vec3(dl_.segment<3>(3 * a).cwiseProduct(o));
  }
  const double bnorm = gb_.norm();
  last_iterations_ = 0;
  if (!(bnorm > 0)) {
    x.setZero(m);
    return std::isfinite(bnorm);
  }
  const double target = gmres_tolerance * bnorm;
  VecX& w = t_;   // (3 na) the new basis vector
  VecX& res = s_; // (3 na) the residual b' - J' x'
  res = gb_;
  double beta = bnorm;
  bool converged = false;
  while (last_iterations_ < gmres_max_iterations) {
    V_.col(0) = res / beta;
    gg_.setZero();
    gg_[0] = beta;
    int j_used = 0;
    for (int j = 0; j < k && last_iterations_ < gmres_max_iterations; ++j) {
      mv_ = V_.col(j);
      if (!precondition_reduced(mv_, transposed)) return false;
      if (!apply_scaled(mv_, w, transposed)) return false;
      for (int i = 0; i <= j; ++i) {
        Hh_(i, j) = w.dot(V_.col(i));
        w.noalias() -= Hh_(i, j) * V_.col(i);
      }
      const double hn = w.norm();
      Hh_(j + 1, j) = hn;
      if (hn > 0) V_.col(j + 1) = w / hn;
      for (int i = 0; i < j; ++i) {  // the previous rotations on column j
        const double h0 = Hh_(i, j), h1 = Hh_(i + 1, j);
        Hh_(i, j) = gc_[i] * h0 + gs_[i] * h1;
        Hh_(i + 1, j) = -gs_[i] * h0 + gc_[i] * h1;
      }
      const double h0 = Hh_(j, j), h1 = Hh_(j + 1, j), rho = std::hypot(h0, h1);
      if (!(rho > 0) || !std::isfinite(rho)) return false;
      gc_[j] = h0 / rho;
      gs_[j] = h1 / rho;
      Hh_(j, j) = rho;
      Hh_(j + 1, j) = 0;
      gg_[j + 1] = -gs_[j] * gg_[j];
      gg_[j] = gc_[j] * gg_[j];
      ++last_iterations_;
      ++total_iterations_;
      j_used = j + 1;
      if (std::abs(gg_[j + 1]) <= target || !(hn > 0)) break;
    }
    // x' += P' V y, H y = g (upper triangular, j_used columns).
    gy_.head(j_used) = gg_.head(j_used);
    Hh_.topLeftCorner(j_used, j_used).triangularView<Eigen::Upper>().solveInPlace(gy_.head(j_used));
    mv_.noalias() = V_.leftCols(j_used) * gy_.head(j_used);
    if (!precondition_reduced(mv_, transposed)) return false;
    gx_ += mv_;
    if (!apply_scaled(gx_, w, transposed)) return false;
    res = gb_ - w;
    beta = res.norm();
    if (!std::isfinite(beta)) return false;
    if (beta <= target) {
      converged = true;
      break;
    }
    if (j_used == 0) break;
  }
  // x = Rot^T x' (forward) or Rot^T Dl y' (transposed).
  x.resize(m);
  for (int a = 0; a < na; ++a) {
    const Vec3 o = transposed ? Vec3(dl_.segment<3>(3 * a).cwiseProduct(gx_.segment<3>(3 * a)))
                              : Vec3(gx_.segment<3>(3 * a));
    x.segment<3>(3 * a) = rot_[a].transpose() * o;
  }
  return converged;
}

bool OperatorModeSystem::precondition(VecX& v) const {
  ++precond_solves_;
  return M_(v) && v.allFinite();
}

bool OperatorModeSystem::apply(const VecX& x, VecX& out, bool transposed) const {
  const int na = static_cast<int>(S_.size());
  out.resize(3 * na);
  ++solves_;
  if (!transposed) {
    // J x = S (G x) + T x.
    if (!G_(x, g_)) return false;
    for (int a = 0; a < na; ++a)
      out.segment<3>(3 * a) = S_[a] * g_.segment<3>(3 * a) + T_[a] * x.segment<3>(3 * a);
    return true;
  }
  // J^T x = G (S^T x) + T^T x.
  st_.resize(3 * na);
  for (int a = 0; a < na; ++a) st_.segment<3>(3 * a) = S_[a].transpose() * x.segment<3>(3 * a);
  if (!G_(st_, g_)) return false;
  for (int a = 0; a < na; ++a) out.segment<3>(3 * a) = g_.segment<3>(3 * a) + T_[a].transpose() * x.segment<3>(3 * a);
  return true;
}

bool OperatorModeSystem::symmetric() const {
  for (std::size_t a = 0; a < S_.size(); ++a)
    if (!S_[a].isIdentity(0) || !T_[a].isZero(0)) return false;
  return true;
}

bool OperatorModeSystem::solve_cg(const VecX& r, VecX& x) const {
  // Conjugate gradients on G_AA x = r from x = 0 (G_AA symmetric positive semi-definite),
  // preconditioned by M when one is set (M = I otherwise): the iterates lie in
  // span{M r, (M G) M r, ...}, inside range(G_AA) for r in range(G_AA) (M maps the range
  // into itself), so the limit is G_AA^+ r. Converged when ||r - G x|| <= cg_tolerance
  // ||r||; otherwise (r has a component outside the range larger than that: redundant
  // contacts) false, and x is dropped.
  const Eigen::Index m = r.size();
  s_ = r;
  z_ = r;
  if (M_ && !precondition(z_)) return false;
  p_ = z_;
  double rz = s_.dot(z_);
  const double stop = cg_tolerance * cg_tolerance * r.squaredNorm();
  const int max_it = static_cast<int>(std::min<Eigen::Index>(2 * m + 50, 2000));
  for (int it = 1; it <= max_it; ++it) {
    ++solves_;
    if (!G_(p_, t_)) return false;
    const double pt = p_.dot(t_);
    if (!(pt > 0) || !(rz > 0)) return false;  // a direction in the null space: not consistent, or rounding
    const double alpha = rz / pt;
    x += alpha * p_;
    s_ -= alpha * t_;
    const double rr_new = s_.squaredNorm();
    last_iterations_ = it;
    ++total_iterations_;
    if (!std::isfinite(rr_new)) return false;
    if (rr_new <= stop) return true;
    z_ = s_;
    if (M_ && !precondition(z_)) return false;
    const double rz_new = s_.dot(z_);
    p_ = z_ + (rz_new / rz) * p_;
    rz = rz_new;
  }
  return false;
}

bool OperatorModeSystem::solve(const VecX& r, VecX& x, bool transposed) const {
  const Eigen::Index m = size();
  SOFTDIFF_DEMAND(r.size() == m, "OperatorModeSystem::solve: expected " + std::to_string(m) + " rows");
  x.setZero(m);
  last_iterations_ = 0;
  if (m == 0) return true;
  if (symmetric()) {
    if (solve_cg(r, x)) return true;
    x.setZero(m);  // not consistent: the least-squares iteration below
  } else if (reduced_factorize_) {
    // Mixed: GMRES with the reduced preconditioner (mode_system.hpp "Mixed sets").
    if (reduced_state_ == 0) reduced_state_ = prepare_reduced() ? 1 : -1;
    last_reduced_ok_ = false;
    if (reduced_state_ == 1) {
      if (solve_gmres(r, x, transposed)) {
        last_reduced_ok_ = true;
        return true;
      }
      const int it = last_iterations_;
      x.setZero(m);
      const bool ok = solve_cgls(r, x, transposed);
      last_iterations_ += it;
      return ok;
    }
  }
  return solve_cgls(r, x, transposed);
}

bool OperatorModeSystem::solve_cgls(const VecX& r, VecX& x, bool transposed) const {
  const Eigen::Index m = size();
  // CGLS for min ||A M z - r||, A = J (or J^T), M the preconditioner (I without one),
  // from z = 0; x = M z. (A M)^T = M A^T (M symmetric).
  const bool tr = transposed;
  const bool pre = static_cast<bool>(M_);
  VecX& z = pre ? z_ : x;  // without M, z is x
  z.setZero(m);
  s_ = r;
  if (!apply(s_, q_, !tr)) return false;  // q = (A M)^T s = M A^T s
  if (pre && !precondition(q_)) return false;
  p_ = q_;
  double gamma = q_.squaredNorm();
  const double gamma0 = gamma;
  if (!(gamma > 0)) return std::isfinite(gamma);  // (A M)^T r = 0: x = 0 is the answer
  const int max_it = max_iterations > 0 ? max_iterations : static_cast<int>(std::min<Eigen::Index>(20 * m + 200, 3000));
  double norm_est = 0;
  bool converged = false;
  for (int it = 1; it <= max_it; ++it) {
    const VecX* dir = &p_;
    if (pre) {
      mv_ = p_;
      if (!precondition(mv_)) return false;
      dir = &mv_;
    }
    if (!apply(*dir, t_, tr)) return false;  // t = A M p
    const double tt = t_.squaredNorm();
    if (!(tt > 0)) break;  // p in the null space of A M: nothing left to gain
    norm_est = std::max(norm_est, std::sqrt(tt / p_.squaredNorm()));
    const double alpha = gamma / tt;
    z += alpha * p_;
    s_ -= alpha * t_;
    if (!apply(s_, q_, !tr)) return false;
    if (pre && !precondition(q_)) return false;
    const double gamma_new = q_.squaredNorm();
    last_iterations_ = it;
    ++total_iterations_;
    if (!std::isfinite(gamma_new)) return false;
    if (gamma_new <= tolerance * tolerance * gamma0 || std::sqrt(gamma_new) <= 1e-14 * norm_est * s_.norm()) {
      converged = true;
      break;
    }
    p_ = q_ + (gamma_new / gamma) * p_;
    gamma = gamma_new;
  }
  if (pre) {
    x = z_;
    if (!precondition(x)) return false;
    if (!converged) {
      // Not converged on J M (a singular J with r outside its range: M's 1 / c on the
      // null space amplifies rounding there): the unpreconditioned CGLS, J^+ r.
      Precondition M = std::move(M_);
      M_ = nullptr;
      const int it = last_iterations_;
      x.setZero(m);
      const bool ok = solve_cgls(r, x, transposed);
      last_iterations_ += it;
      M_ = std::move(M);
      return ok;
    }
  }
  return converged;
}

PowerIteration power_iteration(const OperatorModeSystem::Apply& G, VecX& y, VecX& Gy, double tolerance,
                               int max_iterations) {
  PowerIteration p;
  const double ny = y.norm();
  if (!(ny > 0) || !std::isfinite(ny)) {
    p.failed = true;
    return p;
  }
  y /= ny;
  double previous = 0;
  for (int k = 0; k < max_iterations; ++k) {
    if (!G(y, Gy)) {
      p.failed = true;
      return p;
    }
    ++p.iterations;
    const double value = y.dot(Gy), n = Gy.norm();  // |y| = 1
    if (!(n > 0) || !std::isfinite(n) || !std::isfinite(value)) {
      p.failed = true;
      return p;
    }
    y = Gy / n;
    p.value = value;
    if (k > 0) {
      p.change = std::abs(value - previous) / value;
      if (p.change <= tolerance) {
        p.converged = true;
        return p;
      }
    }
    previous = value;
  }
  return p;
}

}  // namespace softdiff::contact
