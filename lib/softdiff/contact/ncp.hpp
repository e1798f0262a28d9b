#pragma once
// The contact problem of a step (docs/method.md, paper eq. 2): find lambda with
//     K_mu  ∋ lambda  ⊥  sigma + Gamma_mu(sigma) ∈ K_mu*,   sigma = G lambda + g,
// per contact i: K_mu = {||lambda_T|| <= mu_i lambda_N}, Gamma(sigma)_i = (0, 0, mu_i ||sigma_T,i||),
// each 3-block ordered (t1, t2, n). G is the (3 nc x 3 nc) symmetric positive
// semi-definite Delassus matrix.
//
// Solvers: ADMM (Carpentier, Le Lidec, Montaut, RSS 2024) with the De Saxce
// correction, adaptive rho and warm start; projected Gauss-Seidel on 3x3 blocks.
// Both stop when the three scaled residuals are below `tolerance`. Then the
// solution is polished: with the contact modes fixed, the mode equations are
// solved exactly (breaking: lambda_i = 0; sticking: sigma_i = 0; sliding:
// sigma_N,i = 0 and lambda_T,i = -mu_i lambda_N,i sigma_T,i / ||sigma_T,i||); when
// the polished state contradicts some modes, they are corrected and the polish is
// repeated (an active-set method, a few rounds). The best polished solution is kept
// if its residuals are below the solver's. When ADMM stalls, the polish is tried
// on its iterate before the PGS fallback.
#include <softdiff/core/types.hpp>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

namespace softdiff::contact {

enum class NcpSolverKind { admm, pgs };
// Where the Delassus matrix lives (docs/method.md "Contact at scale"): dense, formed
// as G = h H A^{-1} H^T (cost and memory (3 nc)^2), or sparse, as an operator on the
// step's factorization (sparse_delassus.hpp). automatic: dense up to
// dense_max_contacts contacts, sparse beyond.
enum class NcpBackend { automatic, dense, sparse };
enum class Mode : std::int8_t { breaking = 0, sticking = 1, sliding = 2 };

struct NcpOptions {
  NcpSolverKind solver = NcpSolverKind::admm;
  double tolerance = 1e-8;      // bounds the three scaled residuals
  int max_iterations = 1000;
  bool polish = true;
  // Solve on a working set of contacts first (exact screening, see ncp.cpp): the
  // contacts with a warm-start force or a violation at the warm start, grown by the
  // contacts that the reduced solution violates; the full problem only if that fails.
  bool working_set = true;
  bool admm_fallback = true;    // ADMM: finish with PGS from ADMM's iterate when ADMM stalls (see ncp.cpp)
  // ADMM with a penalty per contact, rho_i = rho d_i, d_i the contact's compliance
  // (ADMM on the diagonal-scaled problem D^-1/2 G D^-1/2, see ncp.cpp's admm()). Off
  // by default: measured on the self-contact and 1e6 mass-ratio scenes it did not
  // lower the residuals (docs/method.md "Contact", robustness); on, the dense path
  // takes d_i = tr(G_ii) / 3 and the sparse operator the lumped-mass estimate of
  // sparse_delassus.hpp.
  bool admm_scaling = false;
  // The polish factorizes a dense (3 na x 3 na) system over the na non-breaking
  // contacts (a few times). Beyond this many: on the dense path it is skipped (O(na^3)
  // would exceed the rest of the step) and the solver's tolerance stands; on the sparse
  // operator it runs on the operator (mode_system.hpp, never a dense G_AA) where every
  // such contact sticks (preconditioned CG), and on sets with sliding contacts only up
  // to 64 of them (ncp.cpp; docs/method.md "The mode-fixed system at scale").
  int polish_max_active = 400;
  // The polish on the operator (beyond polish_max_active active contacts, sparse path):
  // by default only where ADMM stalled (its iterate did not reach the tolerance
  // without help); where ADMM converged, its solution within `tolerance` stands, as
  // without a polish. true: after every solve on the operator (scene key
  // contact.polish_at_scale: always). Measured on configs/slab_on_plane.yaml: the
  // polish after a converged ADMM costs 3.6x the whole run's CPU (docs/performance.md
  // "Contact at scale").
  bool polish_at_scale_always = false;
  // The implicit derivative's mode-fixed system (ncp_derivatives.hpp) where no dense G
  // exists: on the dense G_AA of the active contacts up to this many of them, on the
  // operator beyond (mode_system.hpp; docs/method.md "The mode-fixed system at scale"),
  // where every active contact sticks (PCG).
  int derivative_dense_max_active = 400;
  // The same crossover for sets with sliding contacts (GMRES with the reduced
  // preconditioner on the operator; contact_step_derivatives.cpp): measured by
  // tests/bench BM_MixedDerivative, the dense G_AA faster at 36 active contacts, the
  // operator at 64 (docs/performance.md "The mixed derivative's crossover").
  int derivative_mixed_dense_max_active = 40;
  // The scale L of the operator path's preconditioner shift where every active contact
  // sticks: the largest eigenvalue of G_AA by power iteration (mode_system.hpp
  // power_iteration), stopped when two successive estimates differ by at most
  // derivative_scale_tolerance relative; not within derivative_scale_max_iterations
  // products: ComputationError. (Mixed sets: the sampled largest diagonal entry of G_AA,
  // contact_step_derivatives.cpp.)
  double derivative_scale_tolerance = 1e-3;
  int derivative_scale_max_iterations = 50;
  NcpBackend backend = NcpBackend::automatic;
  // The crossover (measured, docs/method.md "Contact at scale"): the dense G for up to
  // this many contacts (automatic backend); on the sparse path, a working set of at
  // most this many contacts is solved on its dense G_W (the same solver as the dense
  // path), a larger one by ADMM on the sparse operator.
  int dense_max_contacts = 400;
  // A solve that ends above the tolerance (finite, valid input) is solved again from the
  // forces it returned, up to this many times; the lower of the two results is kept
  // (docs/method.md *Restarting a stalled solve*). ADMM then starts afresh (its penalty
  // from the spectral estimate, its multipliers from those forces) and the working set
  // from their support: measured on the 1e6 mass-ratio stacks, the heavy cube on the
  // light one stalled at 1.2e-6 on step 19 and its restart reaches 3.9e-12. A converged
  // solve is unchanged; 0: off.
  int restarts = 1;
};

// Scaled residuals (method.md): primal = max_i dist(lambda_i, K_mu) / max(|lambda|_inf, tiny);
// dual = max_i dist(sigma_i + Gamma_i, K_mu*) / max(|g|_inf, tiny);
// complementarity = max_i |lambda_i . (sigma_i + Gamma_i)| / (max(|lambda|_inf, tiny) max(|g|_inf, tiny)).
struct NcpResiduals {
  double primal = 0, dual = 0, complementarity = 0;
  double max() const { return std::max(primal, std::max(dual, complementarity)); }
};

struct NcpResult {
  int iterations = 0;           // of ADMM or PGS
  NcpResiduals residuals;       // of the returned lambda
  bool converged = false;       // residuals.max() <= tolerance
  bool polished = false;        // the polished solution was kept
  int rho_updates = 0;          // ADMM: refactorizations of G + rho I
  // Wall seconds (reports only) of the NCP's factorizations of its shifted systems: ADMM's
  // dense G + rho D, and on the operator B = A + (h/c) H^T D^-1 H (ADMM's and the
  // polish preconditioner's; SparseDelassus::factorization_seconds). Part of the NCP's time.
  double factorization_seconds = 0;
  int sticking = 0, sliding = 0, breaking = 0;
  int working_set_rounds = 0;   // reduced solves (0: the full problem was solved directly)
  int working_set_size = 0;     // contacts in the last working set
  bool working_set_fallback = false;  // the working set failed; the full problem was solved
  int fallback_iterations = 0;  // ADMM: PGS sweeps after ADMM stalled (included in iterations)
  bool sparse = false;          // solved on the sparse operator (NcpSolver::solve(SparseDelassus&, ...))
  int sparse_rounds = 0;        // sparse: reduced problems solved by ADMM on the operator (the others on a dense G_W)
  int polish_factorizations = 0;  // O(na^3) factorizations of the polish's Newton matrix (LU or COD)
  // LU factorizations tried among them (kept where the Newton matrix is well conditioned;
  // after the first that is not, the solve's later Newton steps use the COD directly)
  int polish_lu_factorizations = 0;
  // sparse: polishes on the operator (more than polish_max_active active contacts), their
  // Newton steps and CGLS iterations (two solves with the step's factorization each)
  int operator_polishes = 0, operator_polish_newton = 0, operator_polish_cgls = 0;
  int restarts = 0;             // restarts run (NcpOptions::restarts; their iterations are included)
};

NcpResiduals ncp_residuals(const MatX& G, const VecX& g, const VecX& mu, const VecX& lambda);
// The same from sigma = G lambda + g computed by the caller (the sparse backend has no G).
NcpResiduals ncp_residuals_at(const VecX& sigma, const VecX& g, const VecX& mu, const VecX& lambda);

// Solver with a reusable workspace (sized on first use, grows only).
class SparseDelassus;

class NcpSolver {
 public:
  // lambda: in, the warm start (size 3 nc; zeros for none); out, the solution.
  // sigma: out, G lambda + g. modes: out, one per contact.
  NcpResult solve(const MatX& G, const VecX& g, const VecX& mu, const NcpOptions& options, VecX& lambda,
                  VecX& sigma, std::vector<Mode>& modes);
  // The same problem with G as a sparse operator (never formed for all contacts): the
  // working set as above, each reduced problem on its dense G_W when it has at most
  // options.dense_max_contacts contacts, else ADMM on the operator (PGS needs G's
  // columns: solver pgs runs ADMM there), polished on the dense G_AA of its active
  // contacts when they are at most polish_max_active; when that ADMM stalls and the
  // polish misses the tolerance, the dense path's solve (PGS included) on the dense
  // G_CC of the contacts that may carry force, if at most polish_max_active (ncp.cpp).
  // G is left restricted to some subset (callers restrict it again).
  NcpResult solve(SparseDelassus& G, const VecX& g, const VecX& mu, const NcpOptions& options, VecX& lambda,
                  VecX& sigma, std::vector<Mode>& modes);

 private:
  struct Workspace;
  std::shared_ptr<Workspace> work_;
  // One solve, without restarts (the public solve() restarts it).
  NcpResult solve_once(const MatX& G, const VecX& g, const VecX& mu, const NcpOptions& options, VecX& lambda,
                       VecX& sigma, std::vector<Mode>& modes);
  NcpResult solve_once(SparseDelassus& G, const VecX& g, const VecX& mu, const NcpOptions& options, VecX& lambda,
                       VecX& sigma, std::vector<Mode>& modes);
  template <typename Op>
  NcpResult solve_restarted(Op& G, const VecX& g, const VecX& mu, const NcpOptions& options, VecX& lambda,
                            VecX& sigma, std::vector<Mode>& modes);
};

}  // namespace softdiff::contact
