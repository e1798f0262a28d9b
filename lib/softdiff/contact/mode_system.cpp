// The mode-fixed system on the operator: see mode_system.hpp.
#include <softdiff/contact/mode_system.hpp>

#include <softdiff/core/assert.hpp>

#include <algorithm>
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
  }
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
      const bool ok = solve(r, x, transposed);
      last_iterations_ += it;
      M_ = std::move(M);
      return ok;
    }
  }
  return converged;
}

}  // namespace softdiff::contact
