#include <softdiff/core/avx512_gcc12.hpp>  // first: see there
#include <softdiff/contact/mode_system.hpp>
#include <softdiff/contact/ncp.hpp>
#include <softdiff/contact/sparse_delassus.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/timer.hpp>

#include <algorithm>
#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/QR>
#include <cmath>
#include <limits>
#include <optional>
#include <string>

// The frictional contact NCP (ncp.hpp, method.md "Contact").
//
// Cones. K = {||l_T|| <= mu l_N} and its dual K* = {mu ||v_T|| <= v_N}. For
// v = sigma + Gamma(sigma) = (sigma_T, sigma_N + mu ||sigma_T||), v ∈ K* reads sigma_N >= 0.
// Residual distances, per contact:
//   dist(lambda, K)  = ||lambda - P_K(lambda)||,
//   dist(v, K*)      = ||P_K(-v)||: Moreau's decomposition v = P_K*(v) + P_{(K*)°}(v) with
//                      the polar (K*)° = -K, so v - P_K*(v) = P_{-K}(v) = -P_K(-v). This needs
//                      only the projection on K, which is well defined for mu = 0 (the ray
//                      l_T = 0, l_N >= 0; K* is then the half space v_N >= 0 and the
//                      distance is max(-v_N, 0)), where P_K* would have an infinite aperture.
// P_K(x), with t = ||x_T||: x if t <= mu x_N; 0 if mu t <= -x_N; else the point of the
// boundary p_N = (x_N + mu t) / (1 + mu^2), p_T = mu p_N x_T / t.
// Scales: lscale = max(|lambda|_inf, tiny), vscale = max(|g|_inf, tiny), tiny = 1e-300
// (only guards a zero scale: lambda = 0 or g = 0 give zero residuals, not 0/0).
//
// Modes, from the natural map of the NCP: with z_i = lambda_i - rho_i (sigma_i + Gamma_i),
// rho_i = 1 / G_NN,i (a compliance, so z is a force), a solution satisfies
// lambda_i = P_K(z_i) for every rho_i > 0, and the mode is the face of K that P_K(z_i)
// lands on:
//   breaking  mu ||z_T|| <= -z_N (z in the polar cone, P_K(z) = 0);
//   sticking  mu > 0 and ||z_T|| <= mu z_N (z inside K, so sigma = 0);
//   sliding   otherwise (P_K(z) on the boundary: lambda_T = -mu lambda_N t). A
//             frictionless contact (mu_i = 0) that is not breaking is always "sliding":
//             its equations sigma_N = 0, lambda_T = 0 hold whatever sigma_T is, while
//             "sticking" (sigma_i = 0, 3 equations) would over-determine it.
// Near a solution this compares lambda with sigma in the same units, so it needs no
// threshold: an iterate at residual 1e-4 mostly has the right modes, and the polish
// rounds correct the others (polish_rounds()).
//
// Non-finite input (G, g or mu not finite, or mu < 0): lambda = 0, sigma = 0 (G 0 + g is
// not finite), all modes breaking, residuals +inf, converged = false, no iteration.
// A non-finite warm start is replaced by zeros. If an iterate becomes non-finite (this
// does not happen with finite input; it is a guard), the solver stops with the last
// finite iterate and converged = false.
//
// Allocation: every buffer of ADMM and PGS lives in the Workspace and is sized when
// the problem size changes (Eigen resizes are no-ops at equal size); the iterations
// allocate nothing. The polish and the semismooth Newton stage size their dense
// systems by the number of active contacts, so they may allocate when that number
// changes (per solve or Newton step, never per contact); the proximal point stage grows
// its matrix G + eps D to the largest n seen (once per solve at most); so may the working set when it grows (its reduced G_W, once per round),
// and the operator path's stall fallback (its dense G_CC, once per round).

namespace softdiff::contact {

namespace {

constexpr double tiny = 1e-300;
constexpr double infinity = std::numeric_limits<double>::infinity();
// ADMM over-relaxation factor (1: none). Measured on the 415-contact self-contact
// dump: 1.6 cuts the iterations 1.6x at a fixed rho but not with the adaptive rho and
// the PGS fallback, so it is off.
constexpr double admm_relaxation = 1.0;
// ADMM stall test window (iterations), see admm().
constexpr int admm_stall_window = 100;

// P_K(x) for the cone ||x_T|| <= mu x_N (mu >= 0).
Vec3 project_cone(const Vec3& x, double mu) {
  const double t = x.head<2>().norm();
  // x[2] >= 0: with mu = 0 and x_T = 0 the test t <= mu x_N reads 0 <= -0 for a negative
  // x_N, which is outside the cone (a frictionless row with no tangential part: a joint
  // limit's row, rigid_contact.hpp).
  if (t <= mu * x[2] && x[2] >= 0) return x;
  if (mu * t <= -x[2]) return Vec3::Zero();
  // t > 0 here: t = 0 satisfies one of the two tests above.
  const double pN = (x[2] + mu * t) / (1 + mu * mu);
  Vec3 p;
  p.head<2>() = (mu * pN / t) * x.head<2>();
  p[2] = pN;
  return p;
}

// sigma + Gamma(sigma) of one contact.
Vec3 de_saxce(const Vec3& s, double mu) { return {s[0], s[1], s[2] + mu * s.head<2>().norm()}; }

// The residuals of (lambda, sigma) with the scales of the header.
using VecCRef = Eigen::Ref<const VecX>;

NcpResiduals residuals_of(const VecCRef& lambda, const VecCRef& sigma, const VecCRef& mu, double vscale) {
  const int nc = static_cast<int>(mu.size());
  const double lscale = std::max(lambda.size() ? lambda.cwiseAbs().maxCoeff() : 0.0, tiny);
  double primal = 0, dual = 0, comp = 0;
  for (int i = 0; i < nc; ++i) {
    const Vec3 l = lambda.segment<3>(3 * i);
    const Vec3 v = de_saxce(sigma.segment<3>(3 * i), mu[i]);
    primal = std::max(primal, (l - project_cone(l, mu[i])).norm());
    dual = std::max(dual, project_cone(-v, mu[i]).norm());
    comp = std::max(comp, std::abs(l.dot(v)));
  }
  NcpResiduals r;
  r.primal = primal / lscale;
  r.dual = dual / vscale;
  r.complementarity = comp / (lscale * vscale);
  // NaN compares false everywhere: make it visible as "not converged".
  if (!std::isfinite(r.primal)) r.primal = infinity;
  if (!std::isfinite(r.dual)) r.dual = infinity;
  if (!std::isfinite(r.complementarity)) r.complementarity = infinity;
  return r;
}

double g_scale(const VecX& g) { return std::max(g.size() ? g.cwiseAbs().maxCoeff() : 0.0, tiny); }

// The 2x2 disk-constrained quadratic (a trust-region subproblem, convex since A is PSD):
//     min 1/2 l^T A l + c^T l   s.t. ||l|| <= r.
// KKT: (A + nu I) l = -c, nu >= 0, nu (||l|| - r) = 0. If the unconstrained minimizer is
// inside the disk it is the answer (nu = 0); otherwise nu > 0 solves the secular
// equation ||(A + nu I)^{-1} c|| = r, found by Newton on psi(nu) = 1/||l(nu)|| - 1/r
// (concave and increasing: Newton from a point left of the root increases monotonically
// to it, More & Sorensen 1983), safeguarded by the bracket
// ||c|| / (a_max + nu) <= ||l(nu)|| <= ||c|| / (a_min + nu).
Eigen::Vector2d disk_quadratic(const Eigen::Matrix2d& A, const Eigen::Vector2d& c, double r) {
  if (!(r > 0)) return Eigen::Vector2d::Zero();
  const double cn = c.norm();
  if (cn == 0) return Eigen::Vector2d::Zero();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig;
  eig.computeDirect(A);
  const Eigen::Vector2d a = eig.eigenvalues().cwiseMax(0.0);  // ascending
  const Eigen::Vector2d q = eig.eigenvectors().transpose() * c;
  // Directions with a (numerically) zero curvature.
  const double a_floor = 1e-14 * std::max(a[1], tiny);
  // nu = 0 is admissible if the minimizer exists (q has no component along zero
  // curvature) and lies inside the disk; the minimum-norm minimizer is taken.
  bool inside = true;
  Eigen::Vector2d w;
  for (int k = 0; k < 2; ++k) {
    if (a[k] > a_floor)
      w[k] = -q[k] / a[k];
    else if (std::abs(q[k]) <= 1e-14 * cn)
      w[k] = 0;
    else
      inside = false;
  }
  if (inside && w.norm() <= r) return eig.eigenvectors() * w;
  double lo = std::max(0.0, cn / r - a[1]), hi = std::max(lo, cn / r - a[0]);
  double nu = lo;
  for (int it = 0; it < 60; ++it) {
    const Eigen::Vector2d d = (a.array() + nu).max(tiny).matrix();
    const Eigen::Vector2d wk = -q.cwiseQuotient(d);
    const double n = wk.norm();
    const double psi = 1 / n - 1 / r;
    if (psi < 0)
      lo = std::max(lo, nu);
    else
      hi = std::min(hi, nu);
    // psi'(nu) = (sum q_k^2 / d_k^3) / n^3.
    const double dpsi = (q.array().square() / d.array().cube()).sum() / (n * n * n);
    double next = nu - psi / dpsi;
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (std::abs(next - nu) <= 1e-15 * std::max(nu, a[1]) || hi - lo <= 1e-15 * std::max(hi, a[1])) {
      nu = next;
      break;
    }
    nu = next;
  }
  Eigen::Vector2d l = eig.eigenvectors() * (-q.cwiseQuotient((a.array() + nu).max(tiny).matrix()));
  // Land exactly in the disk (the secular equation holds to rounding).
  const double ln = l.norm();
  if (ln > r) l *= r / ln;
  return l;
}

}  // namespace

NcpResiduals ncp_residuals(const MatX& G, const VecX& g, const VecX& mu, const VecX& lambda) {
  SOFTDIFF_DEMAND(g.size() == 3 * mu.size() && G.rows() == g.size() && G.cols() == g.size() &&
                      lambda.size() == g.size(),
                  "sizes: expected G (3nc x 3nc), g and lambda (3nc), mu (nc); got G " + std::to_string(G.rows()) +
                      "x" + std::to_string(G.cols()) + ", g " + std::to_string(g.size()) + ", lambda " +
                      std::to_string(lambda.size()) + ", mu " + std::to_string(mu.size()));
  const VecX sigma = G * lambda + g;
  return residuals_of(lambda, sigma, mu, g_scale(g));
}

NcpResiduals ncp_residuals_at(const VecX& sigma, const VecX& g, const VecX& mu, const VecX& lambda) {
  SOFTDIFF_DEMAND(g.size() == 3 * mu.size() && sigma.size() == g.size() && lambda.size() == g.size(),
                  "sizes: expected sigma, g and lambda (3nc), mu (nc); got sigma " + std::to_string(sigma.size()) +
                      ", g " + std::to_string(g.size()) + ", lambda " + std::to_string(lambda.size()) + ", mu " +
                      std::to_string(mu.size()));
  return residuals_of(lambda, sigma, mu, g_scale(g));
}

namespace {

template <typename V>
bool all_finite(const V& v) {
  return v.allFinite();
}

// The best iterate of a loop by the largest NCP residual: the Newton stage's, the
// proximal point stage's and the operator path's (each its own, in the workspace; they
// nest). The caller passes the residuals it has computed (none are evaluated here); an
// iterate is taken only if its largest residual is strictly lower and it is finite.
// Storage sized by Buffers::resize (n); start() and offer() copy n values, no allocation.
struct BestIterate {
  VecX l, s;             // (n) storage; the iterate is its head(size)
  Eigen::Index size = 0;
  NcpResiduals r;        // its residuals
  void resize(Eigen::Index n) {
    l.resize(n);
    s.resize(n);
  }
  template <typename L, typename S>
  void start(const L& lam, const S& sig, const NcpResiduals& res) {
    size = lam.size();
    l.head(size) = lam;
    s.head(size) = sig;
    r = res;
  }
  template <typename L, typename S>
  bool offer(const L& lam, const S& sig, const NcpResiduals& res) {
    if (!(res.max() < r.max()) || !all_finite(lam) || !all_finite(sig)) return false;
    l.head(size) = lam;
    s.head(size) = sig;
    r = res;
    return true;
  }
  double max() const { return r.max(); }
  // Copies the best iterate and its residuals out.
  template <typename L, typename S>
  void restore(L&& lam, S&& sig, NcpResiduals& res) const {
    lam = l.head(size);
    sig = s.head(size);
    res = r;
  }
};

// Every buffer of a solve; shapes in terms of n = 3 nc. (NcpSolver::Workspace is this;
// the solvers below take the base, which needs no access to NcpSolver's private part.)
struct Buffers {
  // ADMM (written by admm())
  VecX A;                        // (n n) storage of G + (rho + eta) I, then its Cholesky factor (in place);
                                 // grown by admm() only (PGS and a small working set need none of it)
  VecX x, y, z, s, rhs;          // (n) ADMM iterates: x linear, y in K, z in K*, s = Gamma(z)
  VecX x_prev, y_prev;           // (n) the previous x, y (dual residual)
  VecX power;                    // (n) power iteration vector (largest eigenvalue of G)
  VecX d, d3, d3_sqrt_inv;       // (nc) ADMM's per-contact scale d_i; (n) d_i per row, 1/sqrt(d_i) per row
  // PGS and shared
  VecX lambda_best;              // (n) last finite iterate (guard)
  // polish (written by polish())
  std::vector<int> active;       // active contact ids (not breaking)
  MatX J;                        // (3 na x 3 na) Newton matrix of the mode equations
  VecX F, du, lambda_p, sigma_p; // (3 na), (3 na), (n), (n)
  VecX lambda_kept, sigma_kept;                       // (n) polish rounds
  std::vector<Mode> modes_try, modes_next, modes_kept;  // (nc) polish rounds
  int newton_budget = 0;                              // Newton steps left to the polish rounds
  int polish_factorizations = 0;                      // of the current solve (NcpResult)
  int polish_lu = 0;                                  // LU factorizations among them, kept or not (NcpResult)
  bool polish_singular = false;                       // a Newton matrix of this solve needed the COD (polish())
  // working set (working_set_solve()): the reduced problem, (3 nw x 3 nw) and (3 nw)
  std::vector<int> set;          // the working set's contact ids, ascending
  std::vector<char> in_set;      // (nc) membership
  std::vector<Mode> modes_set;   // (nw) modes of the reduced problem
  VecX Gw;                       // storage of G_W (column-major, 9 nw^2; grown when a set needs it)
  VecX gw, muw, lw, sw;          // (n), (nc), (n), (n)
  Eigen::CompleteOrthogonalDecomposition<MatX> cod;
  Eigen::PartialPivLU<MatX> lu;  // the polish's Newton step where J is well conditioned
  // sparse operator (NcpSolver::solve(SparseDelassus&, ...))
  MatX Gs;                       // a dense G_W or G_AA of a small set
  VecX ga, la, sa, mua;          // the active set's problem, (3 na), (na)
  std::vector<int> set_a;        // positions in the working set of the active contacts of a sparse round
  std::vector<int> ids_a;        // their contact ids
  VecX lambda_alt, sigma_alt;    // (n) the polished candidate of a sparse round
  BestIterate best_op;           // (n) the operator path's best iterate of the solve (lowest max residual)
  std::vector<Mode> modes_a;
  std::vector<double> gnn;       // (nc) G_NN,i where known (dense G_W), else the power-iteration scale
  std::vector<int> ids_c;        // the candidate set of the operator's stall fallback, ascending
  std::vector<char> in_c;        // (nc) its membership
  // semismooth Newton (newton_alart_curnier())
  VecX ac_l, ac_s, ac_F, ac_d, ac_Gd, ac_lt, ac_st, ac_Ft;  // (n)
  BestIterate ac_best;           // (n) the stage's best iterate
  VecX ac_rho;                   // (nc) rho_i = 1 / G_NN,i
  std::vector<Mode> ac_modes;    // (nc) the modes of the current iterate (breaking: y_N <= 0)
  std::vector<int> ac_active;    // its non-breaking contacts
  std::vector<Eigen::Matrix<double, 3, 3>> ac_E, ac_R;  // (nc) rows of J: E on the own contact, R on sigma's rows
  MatX ac_J;                     // (3 na x 3 na)
  VecX ac_rhs, ac_du;            // (3 na)
  VecX ac_in_l, ac_in_s;         // (n) the stage's input, restored unless it converges
  // proximal point (proximal_point_stage())
  VecX pp_G;                     // storage of G + eps D (n n; grown to the largest n seen)
  VecX pp_D, pp_g, pp_l, pp_s, pp_ls, pp_ss, pp_cl, pp_cs;  // (n)
  BestIterate pp_best;           // (n) the stage's best iterate
  // restart of a stalled solve (NcpSolver::solve_restarted)
  BestIterate restart_first;     // (n) the first result while the restart runs

  void resize(Eigen::Index n) {
    if (x.size() == n) return;
    muw.resize(n / 3);
    d.resize(n / 3);
    in_set.resize(static_cast<std::size_t>(n / 3));
    in_c.resize(static_cast<std::size_t>(n / 3));
    for (VecX* v : {&x, &y, &z, &s, &rhs, &x_prev, &y_prev, &power, &d3, &d3_sqrt_inv, &lambda_best, &lambda_p, &sigma_p, &lambda_kept,
                     &sigma_kept, &gw, &lw, &sw, &lambda_alt, &sigma_alt, &ac_l, &ac_s, &ac_F, &ac_d, &ac_Gd, &ac_lt, &ac_st,
                     &ac_Ft, &ac_in_l, &ac_in_s, &pp_D, &pp_g, &pp_l, &pp_s, &pp_ls, &pp_ss, &pp_cl, &pp_cs})
      v->resize(n);
    for (BestIterate* b : {&best_op, &ac_best, &pp_best, &restart_first}) b->resize(n);
    ac_rho.resize(n / 3);
    ac_modes.resize(static_cast<std::size_t>(n / 3));
    ac_active.reserve(static_cast<std::size_t>(n / 3));
    ac_E.resize(static_cast<std::size_t>(n / 3));
    ac_R.resize(static_cast<std::size_t>(n / 3));
  }
};

// One solver run's shared inputs.
struct Problem {
  Eigen::Ref<const MatX> G;      // bound without copy to a MatX or to a contiguous Map
  Eigen::Ref<const VecX> g;
  Eigen::Ref<const VecX> mu;
  int nc;
  double vscale;
  double tolerance;
  int max_iterations;
};

using VecRef = Eigen::Ref<VecX>;

// ADMM with the De Saxce correction (Carpentier, Le Lidec, Montaut 2024, Alg. 1; as in
// Pinocchio's ADMMContactSolverTpl). Variables: x (the linear-step force), y = P_K(.)
// (the force in the cone, returned), z (the multiplier: z -> sigma + Gamma(sigma) in
// K*). With penalty rho and proximal weight eta (so that the x-step is well posed and
// the iteration converges for a singular G):
//   s = Gamma(z)                                   (De Saxce shift, frozen for the step)
//   x = (G + (rho + eta) I)^{-1} (rho y + eta x + z - g - s)
//   y = P_K(x - z / rho)
//   z = z - rho (x - y)                            (= rho (y - w), w = x - z/rho: in K*
//                                                    and orthogonal to y, by Moreau)
// A fixed point has x = y, z = G y + g + Gamma(z) with z_T = sigma_T, so z = sigma +
// Gamma(sigma), and y = P_K(y - z / rho): K ∋ y ⊥ z ∈ K*, the NCP.
// Parameters as Pinocchio's defaults, made relative to L = lambda_max(G) so that the
// iteration is invariant to the units of G: eta = 1e-6 L, rho_0 = sqrt(L m) (L/m)^0.2
// with m = eta ("spectral" rule), and residual balancing: if the scaled primal residual
// ||x - y|| / lscale exceeds 10 times the scaled dual one ||rho dy + eta dx|| / vscale,
// rho *= (L/m)^0.05 (~2), and the converse; each change refactors A (rho_updates).
// Stall fallback (options.admm_fallback): on a strongly rank-deficient G (self-contact,
// most contacts breaking) ADMM converges slowly (the small non-zero eigenvalues of G);
// if the NCP residual drops by less than 10x over a window of admm_stall_window
// iterations, ADMM stops and PGS continues from its iterate with the remaining budget
// (counted in iterations and in fallback_iterations). 415-contact self-contact dump,
// tolerance 1e-8: ADMM alone 3248 iterations / 3.5 s, hybrid 100 + 1882 / 0.26 s.
// With the dense G, the NCP residuals of y are checked every iteration (one product
// G y, cheaper than the two triangular solves of the x-step).
// Per-contact penalty (options.admm_scaling; Simple's and ProxSuite's diagonal
// scaling): ADMM on the scaled problem G~ = D^-1/2 G D^-1/2, g~ = D^-1/2 g,
// lambda~ = D^1/2 lambda, D = diag(d_i I_3), is the same NCP (K_mu and K_mu* are cones,
// invariant under a positive scalar per contact) and, written in the unscaled
// variables, the iteration above with rho_i = rho d_i and eta_i = eta d_i per contact:
//   x = (G + (rho + eta) D)^{-1} (D (rho y + eta x) + z - g - s),
//   y = P_K(x - z / (rho d_i)),   z = z - rho D (x - y),
// L = lambda_max(G~), and ADMM's dual residual ||D (rho dy + eta dx)||. The NCP
// residuals, the stopping rule and the returned lambda are the unscaled ones. d_i:
// tr(G_ii) / 3 (dense), the lumped-mass estimate of sparse_delassus.hpp (operator),
// normalized to max_i d_i = 1 and floored at 1e-12 (Cholesky's backward error is
// invariant to a diagonal scaling, so a small d_i costs no accuracy).
// The Delassus operator as ADMM sees it: the dense G with a dense Cholesky factor of
// G + c I kept in the workspace (DenseOperator), or the sparse operator of
// sparse_delassus.hpp (SparseOperator). cheap_apply: a product G y costs less than the
// x-step, so the NCP residuals are checked every iteration; otherwise (a product is a
// sparse solve) every sparse_check_every iterations and whenever ADMM's own primal and
// dual residuals are within the tolerance.
struct DenseOperator {
  static constexpr bool cheap_apply = true;
  static constexpr bool times_its_factorizations = false;  // admm() times factorize()
  Buffers& w;
  const Eigen::Ref<const MatX>& G;
  Eigen::Index n;
  std::optional<Eigen::LLT<Eigen::Ref<MatX>>> llt{};
  // The per-contact scale d_i (admm()): the mean of the contact's 3x3 diagonal block of G.
  void contact_scale(VecRef d) {
    for (Eigen::Index i = 0; i < n / 3; ++i) d[i] = G.block<3, 3>(3 * i, 3 * i).trace() / 3;
  }
  void set_scale(const VecCRef&) {}  // factorize() and largest_eigenvalue() read w.d3, w.d3_sqrt_inv
  // Largest eigenvalue of D^-1/2 G D^-1/2.
  double largest_eigenvalue() {
    auto v = w.power.head(n), u = w.rhs.head(n);
    const auto s = w.d3_sqrt_inv.head(n);
    for (Eigen::Index k = 0; k < n; ++k) v[k] = 1.0 + 0.01 * static_cast<double>(k % 7);  // not orthogonal to much
    v /= v.norm();
    double L = 0;
    for (int it = 0; it < 20; ++it) {
      u = s.cwiseProduct(v);
      v.noalias() = G * u;
      v.array() *= s.array();
      const double nv = v.norm();
      if (!(nv > 0)) break;
      L = nv;
      v /= nv;
    }
    return L;
  }
  double initial_rho(double rho) const { return rho; }
  void final_rho(double) {}
  void apply(const VecCRef& y, VecRef out) { out.noalias() = G * y; }
  // G + c D, factorized in place in w.A's storage (grown once to the largest n seen).
  bool factorize(double c) {
    if (w.A.size() < n * n) w.A.resize(n * n);
    Eigen::Map<MatX> A(w.A.data(), n, n);
    A = G;
    A.diagonal() += c * w.d3.head(n);
    llt.emplace(A);
    return llt->info() == Eigen::Success;
  }
  void solve(VecRef r) { llt->solveInPlace(r); }
};

struct SparseOperator {
  static constexpr bool cheap_apply = false;
  // SparseDelassus times B's factorizations itself (without the assembly of B's
  // pattern, which factorize_shifted may do first); solve() adds them to the result.
  static constexpr bool times_its_factorizations = true;
  SparseDelassus& d;  // records a missed iterative-solver tolerance itself (failed())
  // The per-contact scale d_i (admm()): the operator's estimate of G_ii (sparse_delassus.hpp).
  void contact_scale(VecRef out) { d.contact_compliance(out); }
  void set_scale(const VecCRef& scale) { d.set_scale(scale); }
  // Power iterations (on D^-1/2 G D^-1/2): L only sets rho's scale; warm-started across steps.
  double largest_eigenvalue() { return d.largest_eigenvalue(8); }
  // rho from the previous solve on this operator (the previous step's), if any: the
  // balanced value changes little from step to step, and each change costs a
  // factorization of B.
  double initial_rho(double rho) const { return d.last_rho() > 0 ? d.last_rho() : rho; }
  void final_rho(double rho) { d.set_last_rho(rho); }
  void apply(const VecCRef& y, VecRef out) { d.apply(y, out); }
  bool factorize(double c) { return d.factorize_shifted(c); }  // G + c D
  void solve(VecRef r) { d.solve_shifted(r); }
};
constexpr int sparse_check_every = 10;
// The operator's rho schedule: a change of rho refactorizes B (as costly as the step's
// own factorization), so residual balancing acts only every sparse_rho_interval
// iterations (with the dense G, every iteration).
constexpr int sparse_rho_interval = 25;

template <typename Operator>
NcpResult admm(Buffers& w, Operator& op, const Problem& p, VecRef lambda, VecRef sigma, int stall_window, bool scaled) {
  NcpResult result;
  const Eigen::Index n = 3 * static_cast<Eigen::Index>(p.nc);
  // Views on the leading parts of the workspace (its buffers only grow).
  auto x = w.x.head(n), y = w.y.head(n), z = w.z.head(n), s = w.s.head(n), rhs = w.rhs.head(n);
  auto x_prev = w.x_prev.head(n), y_prev = w.y_prev.head(n), xr = w.power.head(n);
  // The per-contact scale: D = diag(d_i I_3), d_i ~ G_ii (1 without scaling), normalized
  // to max_i d_i = 1; floored at 1e-12 (a contact whose row of G is ~0).
  auto d = w.d.head(p.nc);
  auto d3 = w.d3.head(n), d3_sqrt_inv = w.d3_sqrt_inv.head(n);
  // Unscaled (d_i = 1), every product with d3 is exact: the same arithmetic as one rho.
  d.setOnes();
  if (scaled) {
    op.contact_scale(d);
    const double dmax = p.nc > 0 ? d.maxCoeff() : 0.0;
    if (dmax > 0 && std::isfinite(dmax))
      d = (d / dmax).cwiseMax(1e-12);
    else
      d.setOnes();
  }
  for (int i = 0; i < p.nc; ++i) {
    d3.segment<3>(3 * i).setConstant(d[i]);
    d3_sqrt_inv.segment<3>(3 * i).setConstant(1 / std::sqrt(d[i]));
  }
  if (scaled) op.set_scale(d);  // (the sparse operator keeps its unscaled B otherwise)
  double L = op.largest_eigenvalue();
  if (!(L > 0) || !std::isfinite(L)) L = 1;  // G = 0: any scale (sigma = g does not depend on lambda)
  const double eta = 1e-6 * L;
  const double cond = L / eta;
  const double rho_increment = std::pow(cond, 0.05);
  const double rho_min = 1e-8 * L, rho_max = 1e8 * L;
  double rho = std::clamp(op.initial_rho(std::sqrt(L * eta) * std::pow(cond, 0.2)), rho_min, rho_max);
  auto factorize = [&]() {
    ++result.rho_updates;
    if constexpr (Operator::times_its_factorizations) return op.factorize(rho + eta);
    const auto t0 = Clock::now();
    const bool ok = op.factorize(rho + eta);
    result.factorization_seconds += seconds_since(t0);
    return ok;
  };

  // Warm start: y = P_K(lambda), z = P_K*(sigma + Gamma(sigma)) at y.
  x = lambda;
  for (int i = 0; i < p.nc; ++i) y.segment<3>(3 * i) = project_cone(x.segment<3>(3 * i), p.mu[i]);
  op.apply(y, sigma);
  sigma += p.g;
  for (int i = 0; i < p.nc; ++i) {
    const Vec3 v = de_saxce(sigma.segment<3>(3 * i), p.mu[i]);
    z.segment<3>(3 * i) = v + project_cone(-v, p.mu[i]);  // P_K*(v) = v + P_K(-v) (Moreau)
  }
  x = y;
  lambda = y;
  result.residuals = residuals_of(lambda, sigma, p.mu, p.vscale);
  if (result.residuals.max() <= p.tolerance) return result;
  if (!factorize()) return result;
  double window_start = result.residuals.max();
  bool sigma_current = true;  // sigma = G lambda + g

  for (int it = 1; it <= p.max_iterations; ++it) {
    x_prev = x;
    y_prev = y;
    for (int i = 0; i < p.nc; ++i) {
      s.segment<3>(3 * i).setZero();
      s[3 * i + 2] = p.mu[i] * z.segment<2>(3 * i).norm();
    }
    rhs = d3.cwiseProduct(rho * y + eta * x) + z - p.g - s;
    op.solve(rhs);
    x = rhs;
    // Over-relaxation (Boyd et al. 2011, sec. 3.4.3): the y- and z-steps see
    // alpha x + (1 - alpha) y_prev instead of x.
    xr = admm_relaxation * x + (1 - admm_relaxation) * y_prev;
    rhs = xr - z.cwiseQuotient(rho * d3);
    for (int i = 0; i < p.nc; ++i) y.segment<3>(3 * i) = project_cone(rhs.segment<3>(3 * i), p.mu[i]);
    z -= rho * d3.cwiseProduct(xr - y);
    result.iterations = it;

    // ADMM's own residuals (scaled, for the balancing below). Reuses rhs as scratch.
    const double lscale = std::max(y.cwiseAbs().maxCoeff(), tiny);
    const double primal = (x - y).cwiseAbs().maxCoeff() / lscale;
    rhs = d3.cwiseProduct(rho * (y - y_prev) + eta * (x - x_prev));
    const double dual = rhs.cwiseAbs().maxCoeff() / p.vscale;

    if (Operator::cheap_apply || it % sparse_check_every == 0 || std::max(primal, dual) <= p.tolerance ||
        it == p.max_iterations) {
      op.apply(y, sigma);
      sigma += p.g;
      if (!all_finite(y) || !all_finite(sigma)) {  // guard; lambda keeps the last finite iterate
        sigma_current = false;
        break;
      }
      lambda = y;
      sigma_current = true;
      result.residuals = residuals_of(lambda, sigma, p.mu, p.vscale);
      if (result.residuals.max() <= p.tolerance) break;
      // Stall: less than a factor 10 of progress over the last stall_window iterations.
      if (stall_window > 0 && it % stall_window == 0) {
        const double now = result.residuals.max();
        if (now > 0.1 * window_start) {
          result.fallback_iterations = -1;  // tells the caller (set to the PGS count there)
          break;
        }
        window_start = now;
      }
    } else if (!all_finite(y)) {
      break;
    }

    // Residual balancing: if the scaled primal residual ||x - y|| / lscale exceeds 10
    // times the scaled dual one, rho *= (L/m)^0.05, and the converse.
    double rho_new = rho;
    const bool balance = Operator::cheap_apply || it % sparse_rho_interval == 0;
    if (balance && primal > 10 * dual)
      rho_new = std::min(rho * rho_increment, rho_max);
    else if (balance && dual > 10 * primal)
      rho_new = std::max(rho / rho_increment, rho_min);
    if (rho_new != rho) {
      rho = rho_new;
      if (!factorize()) break;
    }
  }
  op.final_rho(rho);
  // sigma of the returned lambda (it is already, unless the guard stopped the loop).
  if (!sigma_current || Operator::cheap_apply) {
    op.apply(lambda, sigma);
    sigma += p.g;
  }
  return result;
}

NcpResult admm(Buffers& w, const Problem& p, VecRef lambda, VecRef sigma, int stall_window, bool scaled) {
  DenseOperator op{w, p.G, 3 * static_cast<Eigen::Index>(p.nc)};
  return admm(w, op, p, lambda, sigma, stall_window, scaled);
}

// Projected Gauss-Seidel on the contacts, each contact's block split into its normal
// and its tangential part, each solved exactly with the rest fixed (the "blocked"
// nonsmooth Gauss-Seidel of Jean & Moreau; Pinocchio's PGSContactSolverTpl uses the
// same split with a diagonal tangential step; cf. Acary et al. 2018, "Solving the
// frictional contact problem: a comparison", for NSGS variants):
//   lambda_N <- max(0, lambda_N - sigma_N / G_NN)                 (exact 1-D LCP)
//   lambda_T <- argmin_{||l|| <= mu lambda_N} 1/2 l^T G_TT l + (sigma_T - G_TT lambda_T)^T l
//                                                                   (exact 2-D disk QP)
// A fixed point satisfies 0 <= lambda_N ⊥ sigma_N >= 0 and the maximal dissipation law
// lambda_T ∈ argmin_{||l|| <= mu lambda_N} l . sigma_T (sticking with sigma_T = 0
// inside the disk, or lambda_T = -mu lambda_N sigma_T / ||sigma_T||): Coulomb's law,
// whose solutions are exactly those of the De Saxce NCP, so the De Saxce shift
// Gamma(sigma) is not needed inside the split (the normal step sees sigma_N, not
// sigma_N + mu ||sigma_T||, which is what makes it exact rather than a cone projection
// with a step size). sigma is updated incrementally by the changed columns of G (one
// sweep costs O(nnz(G))), and recomputed exactly every 50 sweeps and before accepting
// convergence, so rounding does not accumulate into the residuals.
NcpResult pgs(Buffers& w, const Problem& p, VecRef lambda, VecRef sigma) {
  auto lambda_best = w.lambda_best.head(lambda.size());
  NcpResult result;
  // Project the warm start into the cone (the sweeps keep it there).
  for (int i = 0; i < p.nc; ++i) lambda.segment<3>(3 * i) = project_cone(lambda.segment<3>(3 * i), p.mu[i]);
  sigma.noalias() = p.G * lambda;
  sigma += p.g;
  result.residuals = residuals_of(lambda, sigma, p.mu, p.vscale);
  if (result.residuals.max() <= p.tolerance) return result;
  const double Gmax = std::max(p.G.diagonal().cwiseAbs().maxCoeff(), tiny);
  lambda_best = lambda;
  for (int it = 1; it <= p.max_iterations; ++it) {
    for (int i = 0; i < p.nc; ++i) {
      const int k = 3 * i;
      // Normal.
      const double GNN = p.G(k + 2, k + 2);
      const double lN = lambda[k + 2];
      double lN_new = lN;
      if (GNN > 1e-14 * Gmax)
        lN_new = std::max(0.0, lN - sigma[k + 2] / GNN);
      else if (sigma[k + 2] >= 0)
        lN_new = 0;  // G_NN ~ 0: the row of G is ~0 (PSD), lambda_N cannot change sigma_N
      if (lN_new != lN) {
        sigma.noalias() += (lN_new - lN) * p.G.col(k + 2);
        lambda[k + 2] = lN_new;
      }
      // Tangent.
      const Eigen::Matrix2d GTT = p.G.block<2, 2>(k, k);
      const Eigen::Vector2d lT = lambda.segment<2>(k);
      const Eigen::Vector2d c = sigma.segment<2>(k) - GTT * lT;
      const Eigen::Vector2d lT_new = disk_quadratic(GTT, c, p.mu[i] * lN_new);
      const Eigen::Vector2d d = lT_new - lT;
      if (d[0] != 0 || d[1] != 0) {
        sigma.noalias() += p.G.middleCols<2>(k) * d;
        lambda.segment<2>(k) = lT_new;
      }
    }
    result.iterations = it;
    if (!all_finite(lambda)) {  // guard
      lambda = lambda_best;
      break;
    }
    lambda_best = lambda;
    if (it % 50 == 0) {
      sigma.noalias() = p.G * lambda;
      sigma += p.g;
    }
    result.residuals = residuals_of(lambda, sigma, p.mu, p.vscale);
    if (result.residuals.max() <= p.tolerance) {
      sigma.noalias() = p.G * lambda;  // confirm on the exact sigma
      sigma += p.g;
      result.residuals = residuals_of(lambda, sigma, p.mu, p.vscale);
      if (result.residuals.max() <= p.tolerance) break;
    }
  }
  sigma.noalias() = p.G * lambda;
  sigma += p.g;
  return result;
}

// The modes of (lambda, sigma), with rho_i = 1 / G_NN,i from gnn(i) (Gmax: the largest,
// for the floor 1e-12 Gmax).
template <typename Diagonal>
void classify_by(int nc, const VecCRef& mu, const VecCRef& lambda, const VecCRef& sigma, const Diagonal& gnn,
                 double Gmax, std::vector<Mode>& modes) {
  modes.resize(static_cast<std::size_t>(nc));
  for (int i = 0; i < nc; ++i) {
    const double rho = 1 / std::max(gnn(i), 1e-12 * Gmax);
    const Vec3 z = lambda.segment<3>(3 * i) - rho * de_saxce(sigma.segment<3>(3 * i), mu[i]);
    const double t = z.head<2>().norm();
    if (mu[i] * t <= -z[2])
      modes[i] = Mode::breaking;  // z in the polar cone of K, P_K(z) = 0 (mu = 0: z_N <= 0)
    else if (mu[i] > 0 && t <= mu[i] * z[2])
      modes[i] = Mode::sticking;  // z inside K
    else
      modes[i] = Mode::sliding;   // P_K(z) on the boundary (mu = 0: the ray)
  }
}

void classify(const Problem& p, const VecCRef& lambda, const VecCRef& sigma, std::vector<Mode>& modes) {
  const double Gmax = std::max(p.G.diagonal().maxCoeff(), tiny);
  classify_by(p.nc, p.mu, lambda, sigma, [&](int i) { return p.G(3 * i + 2, 3 * i + 2); }, Gmax, modes);
}

// The polish's Newton step (polish()): LU where J is well conditioned, see there.
constexpr double polish_lu_rcond = 1e-10;
// The chord steps of the polish (polish()): reuse J's factorization after a step that
// cut max |F| by at least this factor; a chord step that fails below polish_chord_floor
// (relative to the equations' scale) ends the iteration at the rounding floor.
constexpr double polish_chord_reduction = 100;
constexpr double polish_chord_floor = 1e-12;

// Polish: Newton on the mode equations F(u) = 0 over the forces u of the active
// (non-breaking) contacts, breaking forces fixed at 0:
//   sticking  sigma_i = 0                                              (3 rows of G)
//   sliding   sigma_N,i = 0,  L (lambda_T,i + mu_i lambda_N,i t_i) = 0, t_i = sigma_T,i/||sigma_T,i||
// with dF_T/du = L (I_T + mu t e_N^T + mu lambda_N (I - t t^T) / ||sigma_T|| G_T,:); the
// force rows are scaled by L = max diag G so that all rows are velocities (the rank
// decision of the QR is relative). The system is square but may be singular (G
// rank-deficient: more sticking rows than dofs); the complete orthogonal decomposition
// gives the least-squares step of minimum norm, i.e. the smallest change of the
// solver's forces; where J is well conditioned (LU's condition estimate) the step is
// unique and LU computes it at a fraction of the cost. Sticking and breaking equations
// are linear: one step is exact; sliding ones converge quadratically from the solver's
// solution (a few steps; near it, chord steps reuse the factorization).
// The result goes to w.lambda_p / w.sigma_p; returns false if it is not usable.
bool polish(Buffers& w, const Problem& p, const VecCRef& lambda, const std::vector<Mode>& modes) {
  w.active.clear();
  for (int i = 0; i < p.nc; ++i)
    if (modes[i] != Mode::breaking) w.active.push_back(i);
  const int na = static_cast<int>(w.active.size());
  const int m = 3 * na;
  w.lambda_p = lambda;
  for (int i = 0; i < p.nc; ++i)
    if (modes[i] == Mode::breaking) w.lambda_p.segment<3>(3 * i).setZero();
  if (na == 0) {
    w.sigma_p = p.g;
    return true;
  }
  const double L = std::max(p.G.diagonal().maxCoeff(), tiny);
  w.J.resize(m, m);
  w.F.resize(m);
  w.cod.setThreshold(1e-13);
  // F (and J if asked) of the mode equations at w.lambda_p; returns max |F|.
  auto evaluate = [&](bool jacobian) {
    w.sigma_p.noalias() = p.G * w.lambda_p;
    w.sigma_p += p.g;
    for (int a = 0; a < na; ++a) {
      const int i = w.active[a];
      if (jacobian)
        for (int r = 0; r < 3; ++r)
          for (int b = 0; b < na; ++b) w.J.block<1, 3>(3 * a + r, 3 * b) = p.G.block<1, 3>(3 * i + r, 3 * w.active[b]);
      if (modes[i] == Mode::sticking) {
        w.F.segment<3>(3 * a) = w.sigma_p.segment<3>(3 * i);
        continue;
      }
      // Sliding: the normal row stays the G row; the tangential rows are replaced.
      w.F[3 * a + 2] = w.sigma_p[3 * i + 2];
      const double mu = p.mu[i];
      const double lN = w.lambda_p[3 * i + 2];
      const Eigen::Vector2d sT = w.sigma_p.segment<2>(3 * i);
      const double sn = sT.norm();
      const bool has_direction = mu > 0 && sn > 0;
      const Eigen::Vector2d t = has_direction ? Eigen::Vector2d(sT / sn) : Eigen::Vector2d::Zero();
      w.F.segment<2>(3 * a) = L * (w.lambda_p.segment<2>(3 * i) + mu * lN * t);
      if (!jacobian) continue;
      if (has_direction) {
        const Eigen::Matrix2d P = (mu * lN / sn) * (Eigen::Matrix2d::Identity() - t * t.transpose());
        for (int b = 0; b < na; ++b)
          w.J.block<2, 3>(3 * a, 3 * b) = L * P * p.G.block<2, 3>(3 * i, 3 * w.active[b]);
      } else {
        w.J.middleRows<2>(3 * a).setZero();
      }
      w.J.block<2, 2>(3 * a, 3 * a) += L * Eigen::Matrix2d::Identity();
      w.J.block<2, 1>(3 * a, 3 * a + 2) += L * mu * t;
    }
    return w.F.cwiseAbs().maxCoeff();
  };
  double norm = evaluate(true);
  // The factorization of J held by w.lu or w.cod (at an earlier iterate), and the factor
  // by which the last step cut max |F|.
  bool factored = false, factored_lu = false;
  double reduction = 0;
  for (int newton = 0; newton < 8; ++newton) {
    if (!std::isfinite(norm)) return false;
    // Converged to rounding: the equations' own size is ~eps L |lambda|.
    const double rounding = std::max(p.vscale, L * w.lambda_p.cwiseAbs().maxCoeff());
    if (norm <= 1e-15 * rounding) break;
    // Near the solution (the last step cut max |F| by polish_chord_reduction or more) J
    // changes little between steps: the step reuses the last factorization (a chord
    // step, O(m^2) instead of O(m^3); it converges at the rate |J^-1 (J_old - J)|, ~the
    // last step's size, which is what the Newton step gains there too).
    const bool chord = factored && reduction >= polish_chord_reduction;
    if (!chord) {
      if (w.newton_budget <= 0) break;
      --w.newton_budget;
      // The step: by LU with partial pivoting where J is well conditioned (the solution
      // is then unique, i.e. the minimum-norm step, at a fraction of the cost: ~2/3 m^3
      // flops, blocked, against the column-pivoting QR's Householder passes), else by
      // the complete orthogonal decomposition (the minimum-norm least-squares step).
      // polish_lu_rcond (1e-10, LU's reciprocal condition estimate) is above the COD's
      // rank threshold (1e-13): where LU is used the COD would see full rank as well.
      // Once a Newton matrix of this solve needed the COD (redundant contacts: rows of
      // G_AA that depend on each other keep J singular, mostly, across iterates and mode
      // rounds), the later ones go to the COD directly: the LU and its condition
      // estimate (a third of the COD's time at m = 300 to 400) would mostly be thrown
      // away (measured on the self-contact scene: docs/performance.md). Where a later J
      // would have passed LU's test, the COD gives the same step up to J's conditioning.
      factored_lu = false;
      if (!w.polish_singular) {
        w.lu.compute(w.J);
        ++w.polish_lu;
        factored_lu = w.lu.rcond() > polish_lu_rcond;
      }
      if (!factored_lu) {
        w.cod.compute(w.J);
        w.polish_singular = true;
      }
      factored = true;
      ++w.polish_factorizations;
    }
    if (factored_lu)
      w.du = w.lu.solve(-w.F);
    else
      w.du = w.cod.solve(-w.F);
    if (!w.du.allFinite()) return false;
    // Backtracking on max |F| (the sliding equations are nonlinear; their Jacobian
    // grows like 1 / ||sigma_T|| at a slowly sliding contact): halve the step until
    // |F| decreases, at most 10 times. No decrease means that the mode equations have
    // no solution near here (wrong modes: the least-squares step of a singular,
    // inconsistent system): the full step is taken and the iteration ends, so that the
    // modes of the resulting state can correct the guess (polish_rounds()).
    double step = 1, next = infinity;
    for (int half = 0; half <= 10; ++half, step *= 0.5) {
      for (int a = 0; a < na; ++a) w.lambda_p.segment<3>(3 * w.active[a]) += step * w.du.segment<3>(3 * a);
      next = evaluate(false);
      if (next < norm) break;
      for (int a = 0; a < na; ++a) w.lambda_p.segment<3>(3 * w.active[a]) -= step * w.du.segment<3>(3 * a);
    }
    if (!(next < norm)) {
      // A chord step that does not decrease |F|: at the rounding floor (within
      // polish_chord_floor of the equations' scale) the iterate is kept and the
      // iteration ends; above it, J is factorized at the current iterate and the step
      // retried (reduction 0 forces the factorization).
      if (chord) {
        if (norm <= polish_chord_floor * rounding) break;
        reduction = 0;
        continue;
      }
      for (int a = 0; a < na; ++a) w.lambda_p.segment<3>(3 * w.active[a]) += w.du.segment<3>(3 * a);
      break;
    }
    const double previous = norm;
    norm = evaluate(true);
    reduction = norm > 0 ? previous / norm : infinity;
  }
  w.sigma_p.noalias() = p.G * w.lambda_p;
  w.sigma_p += p.g;
  return w.lambda_p.allFinite() && w.sigma_p.allFinite();
}

// The polish with mode corrections: polish with the solver's modes; while the result
// is not within tolerance and the modes of the polished state (classify()) differ
// from those used, polish again with them from the solver's lambda (at most
// polish_max_rounds polishes and polish_max_newton Newton steps in all). The best polished solution is kept if its residuals
// are below the solver's (`residuals`, updated); lambda, sigma, modes are then
// replaced. Returns whether a polished solution was kept. A wrong mode guess costs
// only time: acceptance is on the NCP residuals, which do not depend on the modes.
constexpr int polish_max_rounds = 6;
// Newton steps (factorizations of the 3 na x 3 na system) over all rounds of one call:
// bounds the polish's cost at twice that of the one-shot polish (8 steps).
constexpr int polish_max_newton = 16;
bool polish_rounds(Buffers& w, const Problem& p, VecRef lambda, VecRef sigma, std::vector<Mode>& modes,
                   NcpResiduals& residuals) {
  w.modes_try = modes;
  w.newton_budget = polish_max_newton;
  bool kept = false;
  for (int round = 0; round < polish_max_rounds; ++round) {
    if (!polish(w, p, lambda, w.modes_try)) break;
    const NcpResiduals r = residuals_of(w.lambda_p, w.sigma_p, p.mu, p.vscale);
    if (r.max() < residuals.max() || (!kept && r.max() <= residuals.max())) {
      w.lambda_kept = w.lambda_p;
      w.sigma_kept = w.sigma_p;
      w.modes_kept = w.modes_try;
      residuals = r;
      kept = true;
    }
    if (r.max() <= p.tolerance) break;
    // The modes of the polished state (an active-set step: a contact whose polished
    // state contradicts its mode, e.g. a breaking one with sigma_N < 0 or an active
    // one with lambda_N < 0, gets the mode the state indicates).
    classify(p, w.lambda_p, w.sigma_p, w.modes_next);
    if (w.modes_next == w.modes_try) break;
    std::swap(w.modes_next, w.modes_try);
  }
  if (kept) {
    lambda = w.lambda_kept;
    sigma = w.sigma_kept;
    modes = w.modes_kept;
  }
  return kept;
}

// Classify (lambda, sigma), then polish with mode corrections if the polish is on and
// the active contacts are at most polish_max_active; result.residuals and .polished
// are updated when a polished solution is kept.
void polish_if_small(Buffers& w, const Problem& p, const NcpOptions& options, VecRef lambda, VecRef sigma,
                     std::vector<Mode>& modes, NcpResult& result) {
  classify(p, lambda, sigma, modes);
  const int active = p.nc - static_cast<int>(std::count(modes.begin(), modes.end(), Mode::breaking));
  if (options.polish && p.nc > 0 && active <= options.polish_max_active &&
      polish_rounds(w, p, lambda, sigma, modes, result.residuals))
    result.polished = true;
}

// Semismooth Newton on the Alart-Curnier function (Alart & Curnier 1991; the
// generalized Newton method of Christensen, Klarbring, Pang & Stroemberg 1998; one of
// the solvers compared in Acary, Bremond & Huber 2018, "On solving contact problems
// with Coulomb friction: formulations and numerical comparisons"). Per contact, with
// sigma = G lambda + g, rho_i = 1 / G_NN,i (a compliance: y is a force),
//   y_N = lambda_N - rho sigma_N,   y_T = lambda_T - rho sigma_T,   r = mu max(0, y_N),
//   F_N = lambda_N - max(0, y_N),   F_T = lambda_T - P_{disk r}(y_T).
// F(lambda) = 0 is Coulomb's law with the Signorini condition (the fixed points of
// PGS, the solutions of the De Saxce NCP), so the stopping rule and the residuals are
// the NCP's (residuals_of), unchanged. F is piecewise smooth (strongly semismooth); on
// each piece, with the contact's "mode" read from y (not from thresholds on lambda or
// sigma):
//   breaking  y_N <= 0:        F_i = lambda_i                      (dF = e_i)
//   sticking  ||y_T|| <= r:    F_i = rho sigma_i                   (dF = rho G_i,:)
//   sliding   ||y_T|| > r:     F_N = rho sigma_N,  F_T = lambda_T - r t, t = y_T / ||y_T||,
//      dF_T = [(I - P), -mu t] e_i + rho [P, mu t] G_i,:,  P = (r / ||y_T||)(I - t t^T).
// The sliding rows' curvature is r / ||y_T|| = mu y_N / (mu y_N + rho ||sigma_T||) <= 1:
// bounded where the polish's mode equations grow like mu lambda_N / ||sigma_T|| (a slowly
// sliding contact), and continuous across the stick/slip boundary ||y_T|| = r, where the
// polish must guess a mode; a contact whose state the iterate gets slightly wrong is in
// the neighbouring piece of the same function, not a wrong equation. Each row of J is
// E_i (on the own contact) + R_i G_i,: (3 x 3 blocks E_i, R_i). The breaking contacts'
// step is d_i = -lambda_i exactly; the others' solves the (3 na) system
//   (E_A + R_A G_AA) d_A = -F_A - R_A G_A,B d_B
// by LU where well conditioned, else by the complete orthogonal decomposition (the
// minimum-norm least-squares step: two near-coincident contacts make J singular), as in
// polish(). Globalized by a backtracking line search on the merit 1/2 ||F||^2 (Armijo,
// halving). Runs from the best iterate so far (after the solver and the polish); the
// best iterate by the NCP residuals is kept, in place of lambda/sigma, if it is below
// `residuals` (updated). Returns the Newton steps taken.
constexpr int newton_ac_max_steps = 30;
constexpr int newton_ac_max_halvings = 30;
constexpr double newton_ac_armijo = 1e-4;
// The stage ends when the best NCP residual has not decreased for this many steps (a
// stall at a stationary point of the merit that is not a solution; measured on the
// grip and pads_lift: such runs never recovered later, docs/method.md).
constexpr int newton_ac_stall_steps = 8;
constexpr double newton_ac_exact = 1e-6;  // the stage iterates to this fraction of the tolerance (round-off)
int newton_alart_curnier(Buffers& w, const Problem& p, VecRef lambda, VecRef sigma, NcpResiduals& residuals,
                         double target = -1) {
  if (target < 0) target = newton_ac_exact * p.tolerance;
  const int nc = p.nc;
  const Eigen::Index n = 3 * static_cast<Eigen::Index>(nc);
  if (nc == 0) return 0;
  auto l = w.ac_l.head(n), s = w.ac_s.head(n), F = w.ac_F.head(n), d = w.ac_d.head(n), Gd = w.ac_Gd.head(n);
  auto lt = w.ac_lt.head(n), st = w.ac_st.head(n), Ft = w.ac_Ft.head(n);
  BestIterate& best = w.ac_best;
  auto rho = w.ac_rho.head(nc);
  const double Gmax = std::max(p.G.diagonal().maxCoeff(), tiny);
  for (int i = 0; i < nc; ++i) rho[i] = 1 / std::max(p.G(3 * i + 2, 3 * i + 2), 1e-12 * Gmax);
  // F at (lambda, sigma); with modes: the modes and J's blocks E_i, R_i too.
  auto evaluate = [&](const auto& lam, const auto& sig, auto&& out, bool modes) {
    double merit = 0;
    for (int i = 0; i < nc; ++i) {
      const int k = 3 * i;
      const double mu = p.mu[i], r_i = rho[i];
      const double yN = lam[k + 2] - r_i * sig[k + 2];
      Vec3 f;
      Mode mode;
      Eigen::Matrix3d E = Eigen::Matrix3d::Zero(), R = Eigen::Matrix3d::Zero();
      if (yN <= 0) {
        mode = Mode::breaking;
        f = lam.template segment<3>(k);
      } else {
        f[2] = r_i * sig[k + 2];
        R(2, 2) = r_i;
        const Eigen::Vector2d yT = lam.template segment<2>(k) - r_i * sig.template segment<2>(k);
        const double radius = mu * yN, ny = yT.norm();
        if (ny <= radius && mu > 0) {
          mode = Mode::sticking;
          f.head<2>() = r_i * sig.template segment<2>(k);
          R(0, 0) = R(1, 1) = r_i;
        } else {
          mode = Mode::sliding;
          const Eigen::Vector2d t = ny > 0 ? Eigen::Vector2d(yT / ny) : Eigen::Vector2d::Zero();
          f.head<2>() = lam.template segment<2>(k) - radius * t;
          if (modes) {
            const Eigen::Matrix2d P =
                ny > 0 ? Eigen::Matrix2d((radius / ny) * (Eigen::Matrix2d::Identity() - t * t.transpose()))
                       : Eigen::Matrix2d::Zero();
            E.topLeftCorner<2, 2>() = Eigen::Matrix2d::Identity() - P;
            E.block<2, 1>(0, 2) = -mu * t;
            R.topLeftCorner<2, 2>() = r_i * P;
            R.block<2, 1>(0, 2) = r_i * mu * t;
          }
        }
      }
      out.template segment<3>(k) = f;
      merit += f.squaredNorm();
      if (modes) {
        w.ac_modes[i] = mode;
        w.ac_E[i] = mode == Mode::breaking ? Eigen::Matrix3d::Identity() : E;
        w.ac_R[i] = R;
      }
    }
    return 0.5 * merit;
  };
  l = lambda;
  s = sigma;
  best.start(l, s, residuals_of(l, s, p.mu, p.vscale));
  const NcpResiduals start = best.r;
  double merit = evaluate(l, s, F, true);
  int steps = 0, since_best = 0;
  // Past the tolerance to round-off (Newton converges quadratically there: one or two more
  // steps): a solution only at the tolerance would carry 1e-8-level noise into the
  // finite differences of a derivative check (the polish's solutions are exact).
  for (; steps < newton_ac_max_steps && best.max() > target; ++steps) {
    if (!std::isfinite(merit) || merit == 0) break;
    // The step: d_B = -lambda_B on the breaking contacts, then the active system.
    w.ac_active.clear();
    d.setZero();
    Gd.setZero();
    for (int i = 0; i < nc; ++i) {
      if (w.ac_modes[i] != Mode::breaking) {
        w.ac_active.push_back(i);
        continue;
      }
      d.segment<3>(3 * i) = -l.segment<3>(3 * i);
      if (d.segment<3>(3 * i).squaredNorm() > 0) Gd.noalias() += p.G.middleCols<3>(3 * i) * d.segment<3>(3 * i);
    }
    const int na = static_cast<int>(w.ac_active.size());
    const Eigen::Index m = 3 * static_cast<Eigen::Index>(na);
    if (na > 0) {
      w.ac_J.resize(m, m);
      w.ac_rhs.resize(m);
      for (int a = 0; a < na; ++a) {
        const int i = w.ac_active[a];
        const Eigen::Matrix3d& R = w.ac_R[i];
        for (int b = 0; b < na; ++b)
          w.ac_J.block<3, 3>(3 * a, 3 * b).noalias() = R * p.G.block<3, 3>(3 * i, 3 * w.ac_active[b]);
        w.ac_J.block<3, 3>(3 * a, 3 * a) += w.ac_E[i];
        w.ac_rhs.segment<3>(3 * a) = -F.segment<3>(3 * i) - R * Gd.segment<3>(3 * i);
      }
      bool lu_ok = false;
      if (!w.polish_singular) {
        w.lu.compute(w.ac_J);
        ++w.polish_lu;
        lu_ok = w.lu.rcond() > polish_lu_rcond;
      }
      if (lu_ok) {
        w.ac_du = w.lu.solve(w.ac_rhs);
      } else {
        w.cod.setThreshold(1e-13);
        w.cod.compute(w.ac_J);
        w.polish_singular = true;
        w.ac_du = w.cod.solve(w.ac_rhs);
      }
      ++w.polish_factorizations;
      if (!w.ac_du.allFinite()) break;
      for (int a = 0; a < na; ++a) {
        const int i = w.ac_active[a];
        d.segment<3>(3 * i) = w.ac_du.segment<3>(3 * a);
        Gd.noalias() += p.G.middleCols<3>(3 * i) * w.ac_du.segment<3>(3 * a);
      }
    }
    // The merit's directional derivative F . J d (J d = E d + R G d per contact): -2 merit
    // for an exact Newton step, -|F projected on J's range|^2 for the least-squares one.
    double slope = 0;
    for (int i = 0; i < nc; ++i)
      slope += F.segment<3>(3 * i).dot(w.ac_E[i] * d.segment<3>(3 * i) + w.ac_R[i] * Gd.segment<3>(3 * i));
    // Backtracking on the merit (sigma is affine in lambda: sigma + alpha G d).
    double alpha = 1, trial = infinity;
    bool accepted = false;
    if (slope < 0)
      for (int half = 0; half <= newton_ac_max_halvings; ++half, alpha *= 0.5) {
        lt = l + alpha * d;
        st = s + alpha * Gd;
        trial = evaluate(lt, st, Ft, false);
        if (trial <= merit + newton_ac_armijo * alpha * slope) {
          accepted = true;
          break;
        }
      }
    // No descent along the Newton direction (a kink of F, or a stationary point of the
    // merit that is not a solution): the stage ends with the best iterate so far.
    if (!accepted) break;
    l = lt;
    s.noalias() = p.G * l;  // exact sigma (no drift from the affine updates)
    s += p.g;
    merit = evaluate(l, s, F, true);
    if (best.offer(l, s, residuals_of(l, s, p.mu, p.vscale))) {
      since_best = 0;
    } else if (++since_best >= newton_ac_stall_steps) {
      ++steps;
      break;
    }
  }
  if (best.max() < start.max() && best.max() < residuals.max()) best.restore(lambda, sigma, residuals);
  return steps;
}

// Proximal point outer loop (Rockafellar 1976; on the NCP: docs/method.md "The NCP on
// redundant contacts: a proximal point stage"). Where the solver, the polish and the
// Newton stage missed the tolerance, G is singular or nearly so (redundant contacts:
// null(G) = null(H^T)) and the forces are not unique; the stall is lambda wandering in
// null(G) while weakly active contacts flip modes. Each outer iteration solves
//   NCP(G + eps D, g - eps D lambda^k) -> lambda^{k+1},   D = blockdiag(G_NN,i I_3),
// whose matrix is positive definite (eps > 0): the Alart-Curnier Newton
// (newton_alart_curnier()) then takes LU steps, and PGS (the inner fallback where
// Newton stalls) converges linearly. sigma^k = G lambda^k + g is the subproblem's
// sigma at its start (the eps terms cancel), and a fixed point lambda^{k+1} =
// lambda^k is a solution of the original NCP; null-space components stay at the
// centre (no drift). The stop test is the original NCP's residual (residuals_of on
// G lambda + g), iterated to newton_ac_exact of the tolerance (round-off, as the
// Newton stage: a solution only at the tolerance carries 1e-8 noise into finite
// differences).
// eps adapts: with a fixed eps the iterates of the grip's stalled problems move along
// one direction by a constant step ~ residual / eps per outer iteration (measured on
// the grip's dumped fallback problems of steps 79 and 81: |lambda^{k+1} - lambda^k| =
// 2e-6 at eps = 1e-2, 2e-5 at 1e-3, the residual flat at 2e-7 over 400 iterations): the
// solution is far along a flat direction. So eps shrinks 10x after a subproblem solved
// to the target in at most prox_quick_newton Newton steps (its solution becomes the
// centre), and grows 10x, from the last centre, after one that is not solved. The
// loop ends at the target, after prox_max_outer iterations, or after prox_stall_outer
// without a lower original residual (most accepted results on pads_lift end there,
// between 1e-10 and 6e-9).
// The best iterate by the original residual is returned in lambda, sigma, residuals if
// it is below `residuals`; the caller keeps it only if it is within the tolerance.
// Measured (docs/method.md): configs/pads_lift.yaml's dense solves above 1e-8 from 24 to
// 10 of 50; on the grip's dumped fallback problems (tests/contact/data) it stalls: with a
// fixed eps the residual stays at 2e-7 over 400 outer iterations, with the adaptive eps
// Newton fails on the subproblems below eps ~ 1e-5 and the best is 3e-8 (step 81).
// Scratch in the Buffers (pp_*; the n x n matrix grown once to the largest n seen),
// nothing per contact. Returns the outer iterations.
constexpr double prox_eps = 1e-2;            // the first eps, relative to each contact's G_NN,i
constexpr double prox_eps_min = 1e-12, prox_eps_max = 1;
constexpr double prox_eps_factor = 10;
constexpr int prox_quick_newton = 8;         // a subproblem solved in at most this many Newton steps: eps shrinks
constexpr int prox_max_outer = 50;
constexpr int prox_stall_outer = 8;          // outer iterations without a lower residual: stop
constexpr int prox_pgs_sweeps = 200;         // inner PGS budget per outer iteration (where Newton stalls)
int proximal_point_stage(Buffers& w, const Problem& p, VecRef lambda, VecRef sigma, NcpResiduals& residuals,
                         int* inner_newton = nullptr, int* inner_pgs = nullptr) {
  const int nc = p.nc;
  const Eigen::Index n = 3 * static_cast<Eigen::Index>(nc);
  if (nc == 0) return 0;
  if (w.pp_G.size() < n * n) w.pp_G.resize(n * n);
  Eigen::Map<MatX> Gp(w.pp_G.data(), n, n);
  auto D = w.pp_D.head(n), gk = w.pp_g.head(n), l = w.pp_l.head(n), s = w.pp_s.head(n);
  auto ls = w.pp_ls.head(n), ss = w.pp_ss.head(n);
  BestIterate& best = w.pp_best;
  const double Gmax = std::max(p.G.diagonal().maxCoeff(), tiny);
  double eps = prox_eps;
  for (int i = 0; i < nc; ++i) D.segment<3>(3 * i).setConstant(std::max(p.G(3 * i + 2, 3 * i + 2), 1e-12 * Gmax));
  const double target = newton_ac_exact * p.tolerance;
  l = lambda;
  s = sigma;
  auto cl = w.pp_cl.head(n), cs = w.pp_cs.head(n);  // the centre: the last subproblem's solution
  cl = l;
  cs = s;
  best.start(l, s, residuals_of(l, s, p.mu, p.vscale));
  const NcpResiduals start = best.r;
  const bool singular_before = w.polish_singular;
  int outer = 0, since_best = 0;
  for (; outer < prox_max_outer && best.max() > target; ++outer) {
    Gp = p.G;
    Gp.diagonal() += eps * D;
    gk = p.g - eps * D.cwiseProduct(l);  // the subproblem's sigma at l is s (G l + g)
    const Problem q{Gp, gk, p.mu, nc, p.vscale, p.tolerance, prox_pgs_sweeps};
    NcpResiduals rq = residuals_of(l, s, p.mu, p.vscale);
    w.polish_singular = false;  // G + eps D: LU is expected to pass
    const int steps = newton_alart_curnier(w, q, l, s, rq, target);
    if (inner_newton) *inner_newton += steps;
    if (rq.max() > target) {
      // Newton stalled on the subproblem: PGS on it (linear on an SPD matrix), kept if better.
      ls = l;
      ss = s;
      const Problem qp{Gp, gk, p.mu, nc, p.vscale, target, prox_pgs_sweeps};
      const NcpResult r = pgs(w, qp, ls, ss);
      if (inner_pgs) *inner_pgs += r.iterations;
      if (r.residuals.max() < rq.max()) {
        l = ls;
        rq = r.residuals;
      }
    }
    const bool solved = rq.max() <= target;
    s.noalias() = p.G * l;  // the original sigma
    s += p.g;
    if (!all_finite(l) || !all_finite(s)) break;
    if (best.offer(l, s, residuals_of(l, s, p.mu, p.vscale))) {
      since_best = 0;
    } else if (++since_best >= prox_stall_outer) {
      ++outer;
      break;
    }
    if (solved) {
      // The new centre (even where the original residual rose: the outer map is not
      // monotone in it); a quick Newton solve: a smaller eps next.
      cl = l;
      cs = s;
      if (steps <= prox_quick_newton) eps = std::max(eps / prox_eps_factor, prox_eps_min);
    } else {
      eps = std::min(eps * prox_eps_factor, prox_eps_max);
      l = cl;
      s = cs;
    }
  }
  w.polish_singular = singular_before || w.polish_singular;
  if (best.max() < start.max() && best.max() < residuals.max()) best.restore(lambda, sigma, residuals);
  return outer;
}

// ADMM (when it stalls: the polish, then PGS from there) or PGS on p, then the polish.
NcpResult solve_core(Buffers& w, const Problem& p, const NcpOptions& options, VecRef lambda, VecRef sigma,
                     std::vector<Mode>& modes, bool newton_stage = true, bool proximal_stage = false) {
  NcpResult result = options.solver == NcpSolverKind::admm
                         ? admm(w, p, lambda, sigma, options.admm_fallback ? admm_stall_window : 0, options.admm_scaling)
                         : pgs(w, p, lambda, sigma);
  bool polish_done = false;
  if (result.fallback_iterations < 0) {
    // ADMM stalled. Its iterate usually has the right modes already: polish it first;
    // if that does not reach the tolerance, PGS continues from ADMM's iterate with
    // the remaining budget (and is polished in turn below).
    result.fallback_iterations = 0;
    polish_if_small(w, p, options, lambda, sigma, modes, result);
    polish_done = result.residuals.max() <= p.tolerance;
    if (!polish_done) {
      result.polished = false;  // PGS starts from the better of ADMM's and the polished iterate
      const Problem rest{p.G, p.g, p.mu, p.nc, p.vscale, p.tolerance, p.max_iterations - result.iterations};
      const NcpResult q = pgs(w, rest, lambda, sigma);
      result.fallback_iterations = q.iterations;
      result.iterations += q.iterations;
      result.residuals = q.residuals;
    }
  }
  if (!polish_done) polish_if_small(w, p, options, lambda, sigma, modes, result);
  // The semismooth Newton stage where the solver and the polish missed the tolerance
  // (newton_alart_curnier(); the same size limit as the polish: its system is dense).
  const int active = p.nc - static_cast<int>(std::count(modes.begin(), modes.end(), Mode::breaking));
  // A stage's result is taken only where it reaches the tolerance: a lower residual still
  // above it keeps the solver's iterate, modes and residuals (the callers' fallbacks, e.g.
  // the operator's candidate rounds, decide from that iterate and its modes; a partial
  // improvement there changed which contacts they add and made CubeRestsOnASoftSlab/
  // operator miss, 2026-12-03).
  const auto try_stage = [&](auto&& stage) {
    const Eigen::Index n = 3 * static_cast<Eigen::Index>(p.nc);
    w.ac_in_l.head(n) = lambda;
    w.ac_in_s.head(n) = sigma;
    const NcpResiduals kept = result.residuals;
    stage();
    if (result.residuals.max() <= p.tolerance) {
      result.polished = true;
      classify(p, lambda, sigma, modes);
    } else {
      lambda = w.ac_in_l.head(n);
      sigma = w.ac_in_s.head(n);
      result.residuals = kept;
    }
  };
  if (newton_stage && options.polish && result.residuals.max() > p.tolerance && active <= options.polish_max_active)
    try_stage([&] { newton_alart_curnier(w, p, lambda, sigma, result.residuals); });
  // The proximal point stage where the above still misses the tolerance (redundant
  // contacts; proximal_point_stage()): the same rule, its result only where it reaches
  // the tolerance, else the solver's iterate and modes stay. Only where the caller asks
  // (proximal_stage): the dense path's whole problem (NcpSolver::solve(const MatX&),
  // after the working set failed or without one), i.e. only where the solve would
  // otherwise return unconverged, so every solve that converges today is unchanged;
  // not in the working set's rounds, nor on the operator path (its dense rounds and its
  // stall fallback on G_CC). There it took configs/gripper_free.yaml from 15 to 0 solves
  // above the tolerance but the shipped configs/gripper_lift.yaml diverged at step 142
  // (implicit Euler) and inverted an element at step 128 (BDF2) on the changed
  // trajectory; in the stall fallback alone (no working-set round) gripper_lift passed
  // under implicit Euler (46 -> 13 solves above the tolerance, the cylinder within
  // 0.05 mm) but inverted an element at step 123 under BDF2 (docs/method.md "The NCP on
  // redundant contacts: a proximal point stage"). Both were the operator path returning a
  // worse iterate than it had seen (fixed there: it returns the best of its solve); with
  // that fix the cylinder still ends 4.2 mm low with (a), and with (b) under BDF2 a stage
  // result with 6x its input's forces (a null direction of G_CC) at step 132 starts a
  // divergence; with a guard on that (at most twice the input's largest force) the BDF2
  // run ends with the cylinder tilting out of the grip (5 deg at step 150). Not kept
  // (docs/method.md "The proximal stage on the operator path, again", 2026-12-04 opgrip).
  if (proximal_stage && options.polish && result.residuals.max() > p.tolerance && active <= options.polish_max_active)
    try_stage([&] { proximal_point_stage(w, p, lambda, sigma, result.residuals); });

  return result;
}

// The working set (exact constraint screening). A contact outside the set W has
// lambda_i = 0; the NCP restricted to W (G_WW, g_W, the full problem's scales) is
// solved by solve_core, and then the whole sigma = G_{:,W} lambda_W + g is checked:
// the contacts outside W are complementary (lambda_i = 0) and in K (0 is), so the
// full residuals are those of the reduced problem and the dual violations outside W.
// If some contact outside W violates (dist(sigma_i + Gamma_i, K*) > tolerance vscale),
// they all join W and the reduced problem is solved again, warm-started from the
// current lambda. W only grows. W starts as the contacts with a non-zero warm start
// or with a violation at the warm start. The rounds share max_iterations. Returns
// with converged = false if a reduced solve does not reach the tolerance (the caller
// then solves the full problem). lambda: in, the warm start, projected; sigma: in,
// G lambda + g; both out.
NcpResult working_set_solve(Buffers& w, const Problem& p, const NcpOptions& options, VecX& lambda, VecX& sigma) {
  NcpResult result;
  auto violates = [&](int i) {
    return project_cone(-de_saxce(sigma.segment<3>(3 * i), p.mu[i]), p.mu[i]).norm() > p.tolerance * p.vscale;
  };
  std::fill(w.in_set.begin(), w.in_set.end(), 0);
  for (int i = 0; i < p.nc; ++i)
    if (lambda.segment<3>(3 * i).squaredNorm() > 0 || violates(i)) w.in_set[i] = 1;
  for (;;) {
    w.set.clear();
    for (int i = 0; i < p.nc; ++i)
      if (w.in_set[i]) w.set.push_back(i);
    const int nw = static_cast<int>(w.set.size());
    const Eigen::Index m = 3 * static_cast<Eigen::Index>(nw);
    ++result.working_set_rounds;
    result.working_set_size = nw;
    if (w.Gw.size() < m * m) w.Gw.resize(m * m);  // grows with the largest set seen
    Eigen::Map<MatX> Gw(w.Gw.data(), m, m);
    for (int b = 0; b < nw; ++b) {
      for (int a = 0; a < nw; ++a) Gw.block<3, 3>(3 * a, 3 * b) = p.G.block<3, 3>(3 * w.set[a], 3 * w.set[b]);
      w.gw.segment<3>(3 * b) = p.g.segment<3>(3 * w.set[b]);
      w.lw.segment<3>(3 * b) = lambda.segment<3>(3 * w.set[b]);
      w.muw[b] = p.mu[w.set[b]];
    }
    const Problem r{Gw, w.gw.head(m), w.muw.head(nw), nw, p.vscale, p.tolerance, p.max_iterations - result.iterations};
    // An empty set (nothing pushes in at the warm start) is solved by lambda = 0.
    const NcpResult sub = nw > 0 ? solve_core(w, r, options, w.lw.head(m), w.sw.head(m), w.modes_set) : NcpResult{};
    result.iterations += sub.iterations;
    result.rho_updates += sub.rho_updates;
    result.factorization_seconds += sub.factorization_seconds;
    result.fallback_iterations += sub.fallback_iterations;
    result.polished = sub.polished;
    // Scatter (lambda is 0 outside W) and the full sigma, O(n m).
    sigma = p.g;
    for (int b = 0; b < nw; ++b) {
      lambda.segment<3>(3 * w.set[b]) = w.lw.segment<3>(3 * b);
      sigma.noalias() += p.G.middleCols<3>(3 * w.set[b]) * w.lw.segment<3>(3 * b);
    }
    result.residuals = residuals_of(lambda, sigma, p.mu, p.vscale);
    result.converged = result.residuals.max() <= p.tolerance;
    if (result.converged || sub.residuals.max() > p.tolerance || result.iterations >= p.max_iterations ||
        !all_finite(lambda))
      break;  // solved, or the reduced solve failed / ran out of iterations
    bool grown = false;
    for (int i = 0; i < p.nc; ++i)
      if (!w.in_set[i] && violates(i)) w.in_set[i] = grown = true;
    if (!grown) break;  // (not reached: the full residual exceeds the tolerance only through a violator)
  }
  return result;
}

// Finite g and mu >= 0 (G is checked by the dense solve; the operator's A is the step's).
bool input_valid(const VecX& g, const VecX& mu) {
  return g.allFinite() && mu.allFinite() && (mu.size() == 0 || mu.minCoeff() >= 0);
}

// The answer to non-finite input (ncp.cpp's header): lambda = 0, sigma = 0, all
// breaking, infinite residuals, not converged.
NcpResult invalid_input(VecX& lambda, VecX& sigma, std::vector<Mode>& modes, NcpResult& result) {
  const int nc = static_cast<int>(lambda.size() / 3);
  lambda.setZero();
  sigma.setZero();
  modes.assign(static_cast<std::size_t>(nc), Mode::breaking);
  result.residuals = {infinity, infinity, infinity};
  result.breaking = nc;
  return result;
}

void count_modes(const std::vector<Mode>& modes, NcpResult& result) {
  for (const Mode mode : modes) {
    if (mode == Mode::sticking) ++result.sticking;
    if (mode == Mode::sliding) ++result.sliding;
    if (mode == Mode::breaking) ++result.breaking;
  }
}

}  // namespace

struct NcpSolver::Workspace : Buffers {
  std::vector<Mode> restart_modes;  // (nc) the first result's modes while a restart runs
};

// Restarting a stalled solve (NcpOptions::restarts; docs/method.md *Restarting a stalled
// solve*): from the forces an unconverged solve returned, the same solve again, which
// starts ADMM afresh (penalty, multipliers) and the working set from their support; the
// lower result is kept (BestIterate: strictly lower and finite), the iterations add up. A
// converged solve, an invalid input (a non-finite G or g: infinite residuals, as
// invalid_input() reports them) and non-finite forces are returned as they are. The first
// result is kept in the workspace (no allocation once it has grown).
template <typename Op>
NcpResult NcpSolver::solve_restarted(Op& G, const VecX& g, const VecX& mu, const NcpOptions& options, VecX& lambda,
                                     VecX& sigma, std::vector<Mode>& modes) {
  NcpResult result = solve_once(G, g, mu, options, lambda, sigma, modes);
  for (int k = 0; k < options.restarts; ++k) {
    if (result.converged || !(result.residuals.max() < infinity) || !lambda.allFinite() || !sigma.allFinite()) break;
    Workspace& w = *work_;
    w.restart_first.start(lambda, sigma, result.residuals);
    w.restart_modes = modes;
    const NcpResult first = result;
    NcpResult again = solve_once(G, g, mu, options, lambda, sigma, modes);
    again.iterations += first.iterations;
    again.rho_updates += first.rho_updates;
    again.factorization_seconds += first.factorization_seconds;
    again.restarts = first.restarts + 1;
    if (w.restart_first.offer(lambda, sigma, again.residuals)) {
      result = again;
    } else {  // the first result stands, with the restart's cost
      w.restart_first.restore(lambda, sigma, result.residuals);
      modes = w.restart_modes;
      result = first;
      result.iterations = again.iterations;
      result.rho_updates = again.rho_updates;
      result.factorization_seconds = again.factorization_seconds;
      result.restarts = again.restarts;
      break;
    }
  }
  return result;
}

NcpResult NcpSolver::solve(const MatX& G, const VecX& g, const VecX& mu, const NcpOptions& options, VecX& lambda,
                           VecX& sigma, std::vector<Mode>& modes) {
  return solve_restarted<const MatX>(G, g, mu, options, lambda, sigma, modes);
}

NcpResult NcpSolver::solve(SparseDelassus& G, const VecX& g, const VecX& mu, const NcpOptions& options, VecX& lambda,
                           VecX& sigma, std::vector<Mode>& modes) {
  return solve_restarted<SparseDelassus>(G, g, mu, options, lambda, sigma, modes);
}

NcpResult NcpSolver::solve_once(const MatX& G, const VecX& g, const VecX& mu, const NcpOptions& options,
                                VecX& lambda, VecX& sigma, std::vector<Mode>& modes) {
  const Eigen::Index n = g.size();
  SOFTDIFF_DEMAND(n == 3 * mu.size() && G.rows() == n && G.cols() == n,
                  "sizes: expected G (3nc x 3nc), g (3nc), mu (nc); got G " + std::to_string(G.rows()) + "x" +
                      std::to_string(G.cols()) + ", g " + std::to_string(n) + ", mu " + std::to_string(mu.size()) +
                      " (hint: one (t1, t2, n) block per contact)");
  if (!work_) work_ = std::make_shared<Workspace>();
  Workspace& w = *work_;
  w.resize(n);
  w.polish_factorizations = 0;
  w.polish_lu = 0;
  w.polish_singular = false;
  const int nc = static_cast<int>(mu.size());
  if (lambda.size() != n || !lambda.allFinite()) lambda.setZero(n);
  sigma.resize(n);

  NcpResult result;
  if (!G.allFinite() || !input_valid(g, mu)) return invalid_input(lambda, sigma, modes, result);
  const Problem p{G, g, mu, nc, g_scale(g), options.tolerance, options.max_iterations};
  bool done = false;
  if (options.working_set) {
    for (int i = 0; i < nc; ++i) lambda.segment<3>(3 * i) = project_cone(lambda.segment<3>(3 * i), mu[i]);
    sigma.noalias() = G * lambda;
    sigma += g;
    result = working_set_solve(w, p, options, lambda, sigma);
    done = result.converged;
    if (done) classify(p, lambda, sigma, modes);  // all contacts (breaking outside the set)
  }
  if (!done) {
    // The full problem (directly, or after a failed working set: from its lambda, with
    // a budget of its own; the iterations add up).
    const NcpResult ws = result;
    result = solve_core(w, p, options, lambda, sigma, modes, true, true);
    result.iterations += ws.iterations;
    result.rho_updates += ws.rho_updates;
    result.factorization_seconds += ws.factorization_seconds;
    result.working_set_rounds = ws.working_set_rounds;
    result.working_set_size = ws.working_set_size;
    result.working_set_fallback = options.working_set;
  }
  result.converged = result.residuals.max() <= options.tolerance;
  result.polish_factorizations = w.polish_factorizations;
  result.polish_lu_factorizations = w.polish_lu;
  count_modes(modes, result);
  return result;
}

}  // namespace softdiff::contact

namespace softdiff::contact {

namespace {

// The polish on the operator (docs/method.md "The mode-fixed system at scale"): the
// Newton steps of polish() with J = S G_BB + T applied, never formed (B: the
// non-breaking contacts of the modes tried, within the set A that G is restricted
// to), each step the minimum-norm least-squares solution of J du = -F by CGLS
// (mode_system.hpp: the complete orthogonal decomposition's answer without a rank
// decision). F, the backtracking on max |F| and the mode rounds are those of polish()
// and polish_rounds(); L (the force rows' scale) is the largest known G_NN or the power
// iteration's eigenvalue instead of max diag G (a row scale: the same Newton step for a
// consistent system). Scratch is allocated per call (once per round, not per iteration).
// Where every contact of B sticks (J = G_BB), preconditioned (mode_system.hpp) by
// M = (G_AA + c I)^{-1}, c = operator_shift_fraction L, one factorization of B per polish
// (polish_rounds_operator); when some contacts of A break under the modes tried (B a
// proper subset), by M's principal block on B (symmetric positive definite, but not a
// function of G_BB: the polish's steps are judged by the residuals, the minimum-norm
// property is not needed there). With sliding contacts, GMRES with the reduced
// preconditioner (mode_system.hpp "Mixed sets"; its factorization on A's rows with
// weight 0 on A's breaking contacts, one per Newton step since S and T change), at any
// size; where B does not factorize, unpreconditioned CGLS on sets of at most
// polish_operator_mixed_max_active active contacts (it needs about kappa(J) iterations).
// Where GMRES does not reach its tolerance the CGLS that follows is capped at
// polish_reduced_cgls_max_iterations (the step is still tried and judged by max |F|).
constexpr int polish_operator_mixed_max_active = 64;
constexpr int polish_reduced_cgls_max_iterations = 200;

struct OperatorPolish {
  std::vector<int> act;                           // positions in A of the non-breaking contacts
  VecX F, du, full, Gfull, lam, sig, lam_kept, sig_kept;
  std::vector<Mode> modes_try, modes_next, modes_kept;
  std::vector<Mat3> S, T;
  OperatorModeSystem sys;
  bool preconditioned = false;                    // B = A + (h/c) H_A^T H_A factorizes (G_AA + c I)
  bool frames_set = false;                        // G holds the reduced preconditioner's frames
  std::vector<Mat3> frames;                       // (nA) its frames on A (I on breaking contacts)
  VecX weights;                                   // (3 nA) its row weights on A (0 on breaking)
  VecX pre_full;                                  // (3 nA) scratch of the preconditioner on B
  int newton_budget = 0;
  int newton_steps = 0, cgls_iterations = 0;
};

bool polish_operator(OperatorPolish& o, SparseDelassus& G, const VecX& g, const VecX& mu, double L, double vscale,
                     const VecX& lambda, const std::vector<Mode>& modes) {
  const int nA = static_cast<int>(mu.size());
  o.act.clear();
  for (int i = 0; i < nA; ++i)
    if (modes[i] != Mode::breaking) o.act.push_back(i);
  const int na = static_cast<int>(o.act.size());
  bool all_sticking = true;
  for (int a = 0; a < na; ++a) all_sticking = all_sticking && modes[o.act[a]] == Mode::sticking;
  // Mixed: the reduced preconditioner (mode_system.hpp "Mixed sets") where B factorizes
  // (o.preconditioned); unpreconditioned only up to polish_operator_mixed_max_active.
  if (!all_sticking && na > polish_operator_mixed_max_active && !o.preconditioned) return false;
  o.lam = lambda;
  for (int i = 0; i < nA; ++i)
    if (modes[i] == Mode::breaking) o.lam.segment<3>(3 * i).setZero();
  o.sig.resize(3 * nA);
  auto sigma_of = [&](const VecX& lam) {
    const bool ok = G.apply(lam, o.sig);
    o.sig += g;
    return ok;
  };
  if (na == 0) {
    o.sig = g;
    return true;
  }
  o.F.resize(3 * na);
  o.S.resize(static_cast<std::size_t>(na));
  o.T.resize(static_cast<std::size_t>(na));
  o.full.setZero(3 * nA);
  o.Gfull.resize(3 * nA);
  // F (and S, T if asked) of the mode equations at o.lam; returns max |F| (inf if a
  // solve failed).
  auto evaluate = [&](bool jacobian) {
    if (!sigma_of(o.lam)) return infinity;
    for (int a = 0; a < na; ++a) {
      const int i = o.act[a];
      if (jacobian) {
        o.S[a].setIdentity();
        o.T[a].setZero();
      }
      if (modes[i] == Mode::sticking) {
        o.F.segment<3>(3 * a) = o.sig.segment<3>(3 * i);
        continue;
      }
      o.F[3 * a + 2] = o.sig[3 * i + 2];
      const double m = mu[i], lN = o.lam[3 * i + 2];
      const Eigen::Vector2d sT = o.sig.segment<2>(3 * i);
      const double sn = sT.norm();
      const bool has_direction = m > 0 && sn > 0;
      const Eigen::Vector2d t = has_direction ? Eigen::Vector2d(sT / sn) : Eigen::Vector2d::Zero();
      o.F.segment<2>(3 * a) = L * (o.lam.segment<2>(3 * i) + m * lN * t);
      if (!jacobian) continue;
      o.S[a].topRows<2>().setZero();
      if (has_direction)
        o.S[a].topLeftCorner<2, 2>() = (L * m * lN / sn) * (Eigen::Matrix2d::Identity() - t * t.transpose());
      o.T[a].topLeftCorner<2, 2>() = L * Eigen::Matrix2d::Identity();
      o.T[a].block<2, 1>(0, 2) = L * m * t;
    }
    return o.F.cwiseAbs().maxCoeff();
  };
  // G_BB y: y scattered on A (zero on its breaking contacts), one product, gathered.
  auto apply_active = [&](const VecX& y, VecX& out) {
    for (int a = 0; a < na; ++a) o.full.segment<3>(3 * o.act[a]) = y.segment<3>(3 * a);
    const bool ok = G.apply(o.full, o.Gfull);
    out.resize(3 * na);
    for (int a = 0; a < na; ++a) out.segment<3>(3 * a) = o.Gfull.segment<3>(3 * o.act[a]);
    return ok;
  };
  double norm = evaluate(true);
  bool reduced_factorized = false;  // the reduced preconditioner of this call (below)
  for (int newton = 0; newton < 8 && o.newton_budget > 0; ++newton) {
    if (!std::isfinite(norm)) return false;
    if (norm <= 1e-15 * std::max(vscale, L * o.lam.cwiseAbs().maxCoeff())) break;
    --o.newton_budget;
    ++o.newton_steps;
    o.sys.set(apply_active, o.S, o.T);
    if (o.preconditioned && all_sticking && o.frames_set) {
      // The reduced preconditioner replaced G's scale: back to (G_AA + c I)^{-1}.
      o.frames_set = false;
      G.set_scale(VecX::Ones(nA));
      o.preconditioned = G.factorize_shifted(operator_shift_fraction * L);
    }
    if (o.preconditioned && !all_sticking) {
      // On A's rows: frames and weights of B's, weight 0 (no column) on A's breaking
      // contacts. Factorized at the first Newton step of this call and kept for the
      // following ones (the modes, and so the local rows, are those of the call; the
      // frames and C of the later steps differ a little from the factorized ones: a
      // preconditioner still, GMRES's answer is the same).
      o.sys.set_reduced_preconditioner(
          [&](const std::vector<Mat3>& frames, const VecX& s) {
            if (reduced_factorized) return true;
            o.frames.assign(static_cast<std::size_t>(nA), Mat3::Identity());
            o.weights.setZero(3 * nA);
            for (int a = 0; a < na; ++a) {
              o.frames[static_cast<std::size_t>(o.act[a])] = frames[static_cast<std::size_t>(a)];
              o.weights.segment<3>(3 * o.act[a]) = s.segment<3>(3 * a);
            }
            o.frames_set = true;
            G.set_frames(o.frames, o.weights);
            reduced_factorized = G.factorize_shifted(1.0);
            return reduced_factorized;
          },
          [&](VecX& v) {
            o.pre_full.setZero(3 * nA);
            for (int a = 0; a < na; ++a) o.pre_full.segment<3>(3 * o.act[a]) = v.segment<3>(3 * a);
            const bool ok = G.solve_shifted(o.pre_full);
            for (int a = 0; a < na; ++a) v.segment<3>(3 * a) = o.pre_full.segment<3>(3 * o.act[a]);
            return ok;
          });
      // GMRES not converging falls back to CGLS: bounded here (the step is judged by the
      // residuals), so that a hard system costs at most this many iterations.
      o.sys.max_iterations = polish_reduced_cgls_max_iterations;
    }
    if (o.preconditioned && all_sticking)
      o.sys.set_preconditioner([&](VecX& v) {
        if (na == nA) return G.solve_shifted(v);
        o.pre_full.setZero(3 * nA);
        for (int a = 0; a < na; ++a) o.pre_full.segment<3>(3 * o.act[a]) = v.segment<3>(3 * a);
        const bool ok = G.solve_shifted(o.pre_full);
        for (int a = 0; a < na; ++a) v.segment<3>(3 * a) = o.pre_full.segment<3>(3 * o.act[a]);
        return ok;
      });
    o.F = -o.F;
    o.sys.solve(o.F, o.du);  // not converged within its budget: the step is still tried
    o.F = -o.F;
    o.cgls_iterations += o.sys.last_iterations();
    if (!o.du.allFinite()) return false;
    double step = 1, next = infinity;
    for (int half = 0; half <= 10; ++half, step *= 0.5) {
      for (int a = 0; a < na; ++a) o.lam.segment<3>(3 * o.act[a]) += step * o.du.segment<3>(3 * a);
      next = evaluate(false);
      if (next < norm) break;
      for (int a = 0; a < na; ++a) o.lam.segment<3>(3 * o.act[a]) -= step * o.du.segment<3>(3 * a);
    }
    if (!(next < norm)) {
      for (int a = 0; a < na; ++a) o.lam.segment<3>(3 * o.act[a]) += o.du.segment<3>(3 * a);
      break;
    }
    norm = evaluate(true);
  }
  if (!sigma_of(o.lam)) return false;
  return o.lam.allFinite() && o.sig.allFinite();
}

// polish_rounds() on the operator: the problem on the set A (g, mu, lambda, sigma of
// A; G restricted to A); lambda, sigma, modes and residuals replaced when a polished
// solution is kept (its residuals below the given ones).
bool polish_rounds_operator(OperatorPolish& o, SparseDelassus& G, const VecX& g, const VecX& mu, double L,
                            double vscale, double tol, VecX& lambda, VecX& sigma, std::vector<Mode>& modes,
                            NcpResiduals& residuals) {
  o.modes_try = modes;
  o.newton_budget = polish_max_newton;
  o.preconditioned = G.factorize_shifted(operator_shift_fraction * L);  // else unpreconditioned
  bool kept = false;
  const int nA = static_cast<int>(mu.size());
  for (int round = 0; round < polish_max_rounds; ++round) {
    if (!polish_operator(o, G, g, mu, L, vscale, lambda, o.modes_try)) break;
    const NcpResiduals r = residuals_of(o.lam, o.sig, mu, vscale);
    if (r.max() < residuals.max() || (!kept && r.max() <= residuals.max())) {
      o.lam_kept = o.lam;
      o.sig_kept = o.sig;
      o.modes_kept = o.modes_try;
      residuals = r;
      kept = true;
    }
    if (r.max() <= tol) break;
    classify_by(nA, mu, o.lam, o.sig, [&](int) { return L; }, L, o.modes_next);
    if (o.modes_next == o.modes_try) break;
    std::swap(o.modes_next, o.modes_try);
  }
  if (kept) {
    lambda = o.lam_kept;
    sigma = o.sig_kept;
    modes = o.modes_kept;
  }
  return kept;
}

}  // namespace

// The sparse path (ncp.hpp; docs/method.md "Contact at scale"). The working set of
// working_set_solve() with G as an operator: the full sigma = G_:W lambda_W + g is one
// solve, so screening costs no dense G. Each reduced problem: on its dense G_W (at most
// dense_max_contacts contacts: the dense path's solve_core, ADMM or PGS, then the
// polish), or by ADMM on the operator; then the polish on their dense G_AA if its
// active contacts are at most polish_max_active, else on the operator (a candidate, kept if the full
// residuals are lower). A reduced solve that fails (or exhausts its budget) before the
// set covers every contact is retried once on all of them. Modes are classified with
// rho_i = 1 / G_NN,i where a dense G_W gave it, else 1 / L (L the power iteration's
// largest eigenvalue; the modes at a solution do not depend on rho_i).
NcpResult NcpSolver::solve_once(SparseDelassus& G, const VecX& g, const VecX& mu, const NcpOptions& options,
                                VecX& lambda, VecX& sigma, std::vector<Mode>& modes) {
  const Eigen::Index n = g.size();
  SOFTDIFF_DEMAND(n == 3 * mu.size() && 3 * static_cast<Eigen::Index>(G.contacts()) == n,
                  "sizes: expected 3 nc rows of g for the operator's " + std::to_string(G.contacts()) +
                      " contacts; got g " + std::to_string(n) + ", mu " + std::to_string(mu.size()));
  if (!work_) work_ = std::make_shared<Workspace>();
  Workspace& w = *work_;
  w.resize(n);
  w.polish_factorizations = 0;
  w.polish_lu = 0;
  w.polish_singular = false;
  const int nc = static_cast<int>(mu.size());
  if (lambda.size() != n || !lambda.allFinite()) lambda.setZero(n);
  sigma.resize(n);
  NcpResult result;
  result.sparse = true;
  if (!input_valid(g, mu)) return invalid_input(lambda, sigma, modes, result);
  const double vscale = g_scale(g), tol = options.tolerance;
  w.gnn.assign(static_cast<std::size_t>(nc), 0.0);
  double Gscale = 0;  // the largest known G_NN,i or eigenvalue
  const MatX none;    // the Problem's G on the operator path (unused there)
  auto violates = [&](int i) {
    return project_cone(-de_saxce(sigma.segment<3>(3 * i), mu[i]), mu[i]).norm() > tol * vscale;
  };
  // The full sigma for lambda supported on the current restriction `set` (lw: its forces).
  auto full_sigma = [&](const std::vector<int>& set, VecX& lam, VecX& sig) {
    sig = g;
    if (set.empty()) return;
    const Eigen::Index m = 3 * static_cast<Eigen::Index>(set.size());
    for (std::size_t b = 0; b < set.size(); ++b) w.rhs.segment<3>(3 * b) = lam.segment<3>(3 * set[b]);
    G.apply_full(w.rhs.head(m), w.power.head(n));  // power: scratch here
    sig += w.power.head(n);
  };

  // Warm start (projected) and the first working set.
  for (int i = 0; i < nc; ++i) lambda.segment<3>(3 * i) = project_cone(lambda.segment<3>(3 * i), mu[i]);
  w.set.clear();
  for (int i = 0; i < nc; ++i)
    if (lambda.segment<3>(3 * i).squaredNorm() > 0) w.set.push_back(i);
  if (!w.set.empty()) G.restrict_to(w.set);
  full_sigma(w.set, lambda, sigma);
  for (int i = 0; i < nc; ++i)
    w.in_set[i] = !options.working_set || lambda.segment<3>(3 * i).squaredNorm() > 0 || violates(i);
  // The best iterate of the solve: the (projected) warm start, each round's result and
  // each of its polished candidates, by the largest full residual. An unconverged solve
  // returns it (below) instead of its last round's, with its residuals (docs/method.md
  // "The grip's operator path", 2026-12-04 opgrip): its rounds may each end further from
  // a solution than an earlier one or than the warm start (configs/gripper_lift.yaml
  // under bdf2 with the proximal stage in the stall fallback, step 123: the warm start
  // at 0.34, the working set's round at 1.0e-2, the retry on every contact at 0.75 with
  // forces up to 1.9e5 N, which were returned and inverted an element). Copies of n
  // values per round (the workspace's, no allocation).
  BestIterate& best = w.best_op;
  best.start(lambda, sigma, residuals_of(lambda, sigma, mu, vscale));
  NcpResiduals alt_r;  // the residuals of the candidate in lambda_alt / sigma_alt (where there is one)

  // The polish of a round solved on the operator (lw, sw over the set W of nw
  // contacts): on the dense G_AA of its active contacts, if they are at most
  // polish_max_active, else on the operator (polish_rounds_operator). The candidate (the polished forces on A, 0 elsewhere) goes to
  // lambda_alt, with its full sigma in sigma_alt; returns whether there is one.
  auto polish_sparse = [&](int nw, Eigen::Index m, bool needed) {
    if (!options.polish) return false;
    const auto gnn = [&](int b) { return w.gnn[w.set[b]] > 0 ? w.gnn[w.set[b]] : Gscale; };
    classify_by(nw, w.muw.head(nw), w.lw.head(m), w.sw.head(m), gnn, std::max(Gscale, tiny), w.modes_set);
    w.set_a.clear();
    w.ids_a.clear();
    for (int b = 0; b < nw; ++b)
      if (w.modes_set[b] != Mode::breaking) {
        w.set_a.push_back(b);
        w.ids_a.push_back(w.set[b]);
      }
    const int na = static_cast<int>(w.set_a.size());
    if (na == 0) return false;
    // Beyond polish_max_active, the polish on the operator runs only where ADMM did not
    // reach the tolerance by itself, unless asked for always (NcpOptions).
    if (na > options.polish_max_active && !needed && !options.polish_at_scale_always) return false;
    const Eigen::Index ma = 3 * static_cast<Eigen::Index>(na);
    G.restrict_to(w.ids_a);
    w.ga.resize(ma);
    w.la.resize(ma);
    w.sa.resize(ma);
    w.mua.resize(na);
    for (int a = 0; a < na; ++a) {
      w.ga.segment<3>(3 * a) = w.gw.segment<3>(3 * w.set_a[a]);
      w.la.segment<3>(3 * a) = w.lw.segment<3>(3 * w.set_a[a]);
      w.mua[a] = w.muw[w.set_a[a]];
    }
    bool candidate = false;
    if (na <= options.polish_max_active) {
      G.dense(w.Gs);
      w.sa.noalias() = w.Gs * w.la;
      w.sa += w.ga;
      const Problem pa{w.Gs, w.ga, w.mua, na, vscale, tol, 0};
      NcpResiduals ra = residuals_of(w.la, w.sa, w.mua, vscale);
      classify(pa, w.la, w.sa, w.modes_a);
      candidate = polish_rounds(w, pa, w.la, w.sa, w.modes_a, ra);
    } else {
      // Beyond polish_max_active: the polish on the operator (never a dense G_AA).
      ++result.operator_polishes;
      const double L = std::max(Gscale, tiny);
      G.apply(w.la, w.sa);
      w.sa += w.ga;
      NcpResiduals ra = residuals_of(w.la, w.sa, w.mua, vscale);
      classify_by(na, w.mua, w.la, w.sa, [&](int) { return L; }, L, w.modes_a);
      OperatorPolish o;
      candidate = polish_rounds_operator(o, G, w.ga, w.mua, L, vscale, tol, w.la, w.sa, w.modes_a, ra);
      result.operator_polish_newton += o.newton_steps;
      result.operator_polish_cgls += o.cgls_iterations;
    }
    if (candidate) {
      w.lambda_alt.setZero(n);
      for (int a = 0; a < na; ++a) w.lambda_alt.segment<3>(3 * w.ids_a[a]) = w.la.segment<3>(3 * a);
      full_sigma(w.ids_a, w.lambda_alt, w.sigma_alt);
    }
    G.restrict_to(w.set);
    return candidate;
  };

  int spent = 0;  // iterations before the retry on every contact (which gets a budget of its own)
  // The stall fallback of a round solved on the operator (the dense path's, on a dense
  // G_CC): when ADMM stalls and the polish does not reach the tolerance, the contacts C
  // that may carry force (not breaking at ADMM's iterate, or violating at it; at most
  // polish_max_active) are solved on their dense G_CC by the dense path's solve_core
  // (ADMM, the polish, PGS from there, the polish), lambda = 0 outside C, from the
  // best candidate so far. Contacts outside C that then violate join C and the reduced
  // problem is solved again (a working set inside W; at most fallback_max_rounds). The
  // result replaces the candidate in lambda_alt / sigma_alt if its full residuals are
  // lower. With one rho, ADMM converges on the contacts whose compliance G_ii is near
  // rho only (a 1e6 mass ratio spreads G_NN over 5e5); PGS's per-contact steps 1 / G_NN
  // and the polish are invariant to that spread (docs/method.md "Contact at scale").
  // Returns whether it ran (its iterations go to sub).
  constexpr int fallback_max_rounds = 4;
  auto dense_fallback = [&](int nw, Eigen::Index m, bool candidate, NcpResult& sub) {
    const int budget_left = options.max_iterations - (result.iterations - spent) - sub.iterations;
    if (budget_left <= 0) return false;
    std::fill(w.in_c.begin(), w.in_c.end(), 0);
    // C from the round's state (lw, sw: sw = G_WW lw + g_W, the full sigma on W).
    const auto gnn = [&](int b) { return w.gnn[w.set[b]] > 0 ? w.gnn[w.set[b]] : Gscale; };
    classify_by(nw, w.muw.head(nw), w.lw.head(m), w.sw.head(m), gnn, std::max(Gscale, tiny), w.modes_set);
    int size = 0;
    for (int b = 0; b < nw; ++b) {
      const int i = w.set[b];
      const bool violating =
          project_cone(-de_saxce(w.sw.segment<3>(3 * b), w.muw[b]), w.muw[b]).norm() > tol * vscale;
      if (w.modes_set[b] != Mode::breaking || violating || (candidate && w.lambda_alt.segment<3>(3 * i).squaredNorm() > 0)) {
        w.in_c[i] = 1;
        ++size;
      }
    }
    if (size == 0 || size > options.polish_max_active) return false;
    // The start: the candidate if there is one (its residuals are the lower), else the
    // round's iterate; lambda_p holds it (n).
    if (candidate) {
      w.lambda_p = w.lambda_alt;
    } else {
      w.lambda_p.setZero(n);
      for (int b = 0; b < nw; ++b) w.lambda_p.segment<3>(3 * w.set[b]) = w.lw.segment<3>(3 * b);
    }
    double best_fallback = candidate ? alt_r.max() : infinity;
    NcpOptions inner = options;
    inner.working_set = false;
    for (int round = 0; round < fallback_max_rounds; ++round) {
      w.ids_c.clear();
      for (int i = 0; i < nc; ++i)
        if (w.in_c[i]) w.ids_c.push_back(i);
      const int nc_c = static_cast<int>(w.ids_c.size());
      if (nc_c > options.polish_max_active) break;
      const Eigen::Index mc = 3 * static_cast<Eigen::Index>(nc_c);
      G.restrict_to(w.ids_c);
      G.dense(w.Gs);
      w.ga.resize(mc);
      w.la.resize(mc);
      w.sa.resize(mc);
      w.mua.resize(nc_c);
      for (int a = 0; a < nc_c; ++a) {
        const int i = w.ids_c[a];
        w.ga.segment<3>(3 * a) = g.segment<3>(3 * i);
        w.la.segment<3>(3 * a) = project_cone(w.lambda_p.segment<3>(3 * i), mu[i]);
        w.mua[a] = mu[i];
        w.gnn[i] = w.Gs(3 * a + 2, 3 * a + 2);
        Gscale = std::max(Gscale, w.gnn[i]);
      }
      const int left = options.max_iterations - (result.iterations - spent) - sub.iterations;
      if (left <= 0) break;
      const Problem pc{w.Gs, w.ga, w.mua, nc_c, vscale, tol, left};
      const NcpResult q = solve_core(w, pc, inner, w.la, w.sa, w.modes_a, false);
      sub.iterations += q.iterations;
      sub.rho_updates += q.rho_updates;
      sub.factorization_seconds += q.factorization_seconds;
      sub.fallback_iterations += q.fallback_iterations;
      // The full candidate (0 outside C) and its full sigma (sigma_p: scratch, n).
      w.lambda_p.setZero(n);
      for (int a = 0; a < nc_c; ++a) w.lambda_p.segment<3>(3 * w.ids_c[a]) = w.la.segment<3>(3 * a);
      full_sigma(w.ids_c, w.lambda_p, w.sigma_p);
      const NcpResiduals rr = residuals_of(w.lambda_p, w.sigma_p, mu, vscale);
      const double r = rr.max();
      if (r < best_fallback) {
        best_fallback = r;
        w.lambda_alt = w.lambda_p;
        w.sigma_alt = w.sigma_p;
        alt_r = rr;
      }
      if (r <= tol || q.residuals.max() > tol) break;  // solved, or the reduced solve failed
      bool grown = false;
      for (int i = 0; i < nc; ++i)
        if (!w.in_c[i] && project_cone(-de_saxce(w.sigma_p.segment<3>(3 * i), mu[i]), mu[i]).norm() > tol * vscale)
          w.in_c[i] = grown = true;
      if (!grown) break;
    }
    G.restrict_to(w.set);
    return std::isfinite(best_fallback);
  };

  for (;;) {
    w.set.clear();
    for (int i = 0; i < nc; ++i)
      if (w.in_set[i]) w.set.push_back(i);
    const int nw = static_cast<int>(w.set.size());
    const Eigen::Index m = 3 * static_cast<Eigen::Index>(nw);
    ++result.working_set_rounds;
    result.working_set_size = nw;
    if (nw == 0) {  // nothing pushes: lambda = 0 is the solution
      lambda.setZero();
      sigma = g;
      result.residuals = residuals_of(lambda, sigma, mu, vscale);
      break;
    }
    G.restrict_to(w.set);
    for (int b = 0; b < nw; ++b) {
      w.gw.segment<3>(3 * b) = g.segment<3>(3 * w.set[b]);
      w.lw.segment<3>(3 * b) = lambda.segment<3>(3 * w.set[b]);
      w.muw[b] = mu[w.set[b]];
    }
    const int budget = options.max_iterations - (result.iterations - spent);
    NcpResult sub;
    bool polish_candidate = false;
    if (nw <= options.dense_max_contacts) {
      G.dense(w.Gs);
      for (int b = 0; b < nw; ++b) {
        w.gnn[w.set[b]] = w.Gs(3 * b + 2, 3 * b + 2);
        Gscale = std::max(Gscale, w.gnn[w.set[b]]);
      }
      const Problem r{w.Gs, w.gw.head(m), w.muw.head(nw), nw, vscale, tol, budget};
      sub = solve_core(w, r, options, w.lw.head(m), w.sw.head(m), w.modes_set);
    } else {
      ++result.sparse_rounds;
      // ADMM on the operator. When it stalls (as on the dense path: less than 10x in
      // admm_stall_window iterations), the polish is tried on its iterate; if that does
      // not reach the tolerance, ADMM restarts from there once and runs to the tolerance
      // or the budget (PGS would need G's columns; restarting at every stall would
      // reset rho and the multiplier each time), then the polish again.
      for (int attempt = 0;; ++attempt) {
        const Problem r{none, w.gw.head(m), w.muw.head(nw), nw, vscale, tol,
                        budget - sub.iterations};
        SparseOperator op{G};
        const int window = options.admm_fallback && attempt == 0 ? admm_stall_window : 0;
        const NcpResult part = admm(w, op, r, w.lw.head(m), w.sw.head(m), window, options.admm_scaling);
        sub.iterations += part.iterations;
        sub.rho_updates += part.rho_updates;
        sub.factorization_seconds += part.factorization_seconds;
        sub.residuals = part.residuals;
        Gscale = std::max(Gscale, G.last_eigenvalue());
        const bool stalled = part.fallback_iterations < 0;
        polish_candidate = polish_sparse(nw, m, stalled || part.residuals.max() > tol);
        if (polish_candidate) {  // (a second attempt overwrites it)
          alt_r = residuals_of(w.lambda_alt, w.sigma_alt, mu, vscale);
          best.offer(w.lambda_alt, w.sigma_alt, alt_r);
        }
        if (!stalled || sub.iterations >= budget || part.iterations == 0) break;
        if (polish_candidate && alt_r.max() <= tol) break;
        if (options.admm_fallback && attempt == 0 && dense_fallback(nw, m, polish_candidate, sub)) {
          polish_candidate = true;
          break;
        }
      }
    }
    result.iterations += sub.iterations;
    result.rho_updates += sub.rho_updates;
    result.factorization_seconds += sub.factorization_seconds;
    result.fallback_iterations += sub.fallback_iterations;
    result.polished = sub.polished;
    // Scatter (lambda is 0 outside W) and the full sigma.
    for (int b = 0; b < nw; ++b) lambda.segment<3>(3 * w.set[b]) = w.lw.segment<3>(3 * b);
    full_sigma(w.set, lambda, sigma);
    result.residuals = residuals_of(lambda, sigma, mu, vscale);
    if (polish_candidate) {
      const NcpResiduals rp = alt_r;
      if (rp.max() < result.residuals.max()) {
        lambda = w.lambda_alt;
        sigma = w.sigma_alt;
        result.residuals = rp;
        result.polished = true;
        sub.residuals = rp;  // the round's outcome (an upper bound of its reduced residuals)
      }
    }
    best.offer(lambda, sigma, result.residuals);
    result.converged = result.residuals.max() <= tol;
    if (result.converged || !all_finite(lambda) || G.failed()) break;
    const bool sub_failed = sub.residuals.max() > tol || result.iterations - spent >= options.max_iterations;
    if (sub_failed) {
      if (nw == nc || result.working_set_fallback) break;
      // Retry once on every contact, from here, with a budget of its own.
      result.working_set_fallback = true;
      spent = result.iterations;
      std::fill(w.in_set.begin(), w.in_set.end(), 1);
      continue;
    }
    bool grown = false;
    for (int i = 0; i < nc; ++i)
      if (!w.in_set[i] && violates(i)) w.in_set[i] = grown = true;
    if (!grown) break;
  }
  // Unconverged (or not finite): the best iterate seen, if it is lower. A converged
  // result stays as it is (every solve that converges is unchanged by this rule).
  if (!(result.residuals.max() <= tol) && (best.max() < result.residuals.max() || !all_finite(lambda)))
    best.restore(lambda, sigma, result.residuals);
  const auto gnn = [&](int i) { return w.gnn[i] > 0 ? w.gnn[i] : Gscale; };
  classify_by(nc, mu, lambda, sigma, gnn, std::max(Gscale, tiny), modes);
  result.converged = result.residuals.max() <= tol && !G.failed();
  result.polish_factorizations = w.polish_factorizations;
  result.factorization_seconds += G.factorization_seconds();
  result.polish_lu_factorizations = w.polish_lu;
  count_modes(modes, result);
  return result;
}

}  // namespace softdiff::contact
