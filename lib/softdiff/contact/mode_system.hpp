#pragma once
// The mode-fixed system of the contact problem without G_AA (docs/method.md "Contact at
// scale", "The mode-fixed system at scale"). Both the polish's Newton steps and the
// implicit derivative (ncp_derivatives.hpp) solve, over the active (non-breaking)
// contacts A,
//     J x = r,   J = S G_AA + T,
// with S and T block-diagonal (one 3x3 block per active contact: sticking S = I, T = 0;
// sliding the tangential law's rows, see ncp_derivatives.hpp) and G_AA = h H_A A^{-1}
// H_A^T. The dense path forms J (3 na x 3 na) and decomposes it; this one applies it:
//     J x   = S (G_AA x) + T x,        J^T y = G_AA (S^T y) + T^T y,
// each product one solve with the step's factorization of A (G_AA is symmetric), and
// solves by CGLS (conjugate gradients on the normal equations, Hestenes-Stiefel; Bjorck
// 1996, sec. 7.4). From x_0 = 0 its iterates stay in range(J^T), so it converges to the
// minimum-norm least-squares solution J^+ r: the dense path's complete orthogonal
// decomposition's answer, also for redundant contacts (J singular) and inconsistent
// right-hand sides, with no rank decision. The transposed system (the adjoint) is the
// same iteration with J and J^T exchanged: (J^T)^+ = (J^+)^T.
// Every active contact sticking (S = I, T = 0: J = G_AA, symmetric positive
// semi-definite): conjugate gradients first (one product per iteration and about
// sqrt(kappa) iterations where CGLS needs two and about kappa), whose iterates stay in
// range(G_AA) and so converge to G_AA^+ r when the system is consistent; when it is not
// (redundant contacts and r outside the range: CG does not reach its tolerance), CGLS.
// Memory: a few vectors of 3 na and those of the solves (3n); never (3 na)^2.
//
// Preconditioned (set_preconditioner; docs/method.md "The mode-fixed system at scale"):
// M = (G_AA + c I)^{-1}, SparseDelassus's Woodbury shifted solve, one factorization of
// B = A + (h/c) H_A^T H_A per system. M is a function of G_AA (same eigenvectors,
// eigenvalues 1 / (lambda_i + c)), so it commutes with G_AA and maps range(G_AA) into
// itself:
// - all sticking: preconditioned CG. Its iterates stay in span{M r, (M G) M r, ...},
//   inside range(G_AA) for r in range(G_AA): the limit is still G_AA^+ r. The
//   eigenvalues of M G_AA are lambda_i / (lambda_i + c): kappa <= 1 + c / lambda_min.
// - otherwise: CGLS on the right-preconditioned system min ||J M z - r|| from z = 0,
//   x = M z. J invertible: x = J^{-1} r, exact. J = G_AA (or any J whose null space and
//   range M maps into themselves): x = M (J M)^+ r = J^+ r. A singular mixed J: x is a
//   least-squares solution (J x - r the same residual as J^+ r's) that may differ from
//   J^+ r by an element of null(J). Where CGLS on J M does not reach its stopping rule
//   (a singular J and r outside its range: M's 1 / c on null(G_AA) amplifies rounding
//   there, test_mode_system.cpp PreconditionedRedundantSticking), the unpreconditioned
//   CGLS from x = 0 follows: J^+ r.
// Without a preconditioner, the unpreconditioned iterations above.
//
// Mixed sets, the reduced preconditioner (set_reduced_preconditioner; docs/method.md
// "The mixed preconditioner"). Per sliding contact with a sliding direction t (T's
// column L mu t), rotate its tangent plane to (t, t_perp) and write x = (x_s, x_p, x_N):
//   row s:  L (x_s + mu x_N) = r_s                (P t = 0: no G in it; local, exact)
//   row p:  L w (G x)_p + L x_p = r_p, w = mu lambda_N / |sigma_T| (S's factor)
//           scaled by 1 / (L w): (G x)_p + (1 / w) x_p = r_p / (L w)
//   row N:  (G x)_N = r_N.
// Without a direction (mu = 0 or sigma_T = 0) both tangential rows are L x_T = r_T, and
// with w = 0 (lambda_N = 0) so is row p: local too. In these coordinates and row scales,
// J' = Dl Rot J Rot^T, and the rows that are not local (every sticking row, N and p of
// a sliding one: "reduced", R) read Q G' Q^T x_R + C x_R + (the -mu column: x_s of a
// sliding contact follows -mu x_N, which enters G' through its s column), G' = Rot G_AA
// Rot^T, C = diag(1 / w) on the p rows. The preconditioner (right, exact on the local
// rows):
//   P' v:  z_R = (Q G' Q^T + C + c I)^{-1} v_R,   local rows z_k = v_k / L,
//          and z_s -= mu z_N (the s row's own elimination),
// its first part by the Woodbury identity on B = A + h H~^T H~, H~ = (C + c I)^{-1/2} Q
// Rot H_A (SparseDelassus::set_frames; one factorization per system, on the analyzed
// pattern of A + H_A^T H_A), c = operator_shift_fraction L. What P' leaves of J' P' is
// the coupling through the -mu columns (rank: the sliding contacts). Solved by
// restarted GMRES (right-preconditioned, Saad 2003 sec. 9.3.2) on J' P' z = Dl Rot r,
// x = Rot^T P' z, to ||Dl Rot (r - J x)|| <= gmres_tolerance ||Dl Rot r||; the adjoint
// by the same on J'^T with P'^T (J^T = Rot^T J'^T Dl^{-1} Rot). J invertible: x = J^{-1} r
// to that tolerance. J singular (redundant contacts): GMRES converges to a solution of
// a consistent system, not necessarily J^+ r (it may differ by an element of null(J));
// where it does not reach its tolerance (r outside range(J)), the CGLS of the
// preconditioned path above follows (slow but J^+ r). The dense path keeps the minimum
// norm below the crossover (contact_step_derivatives.cpp, ncp.cpp).
#include <softdiff/core/types.hpp>

#include <functional>
#include <vector>

namespace softdiff::contact {

// The preconditioner's shift c = operator_shift_fraction L, L = max diag G_AA (the
// derivative) or the largest known G_NN / eigenvalue (the polish): the eigenvalues of
// M G_AA are lambda_i / (lambda_i + c), so a smaller c preconditions better, down to
// where the Woodbury solve's cancellation, about 1e-16 L / c relative, spoils M
// (docs/method.md "The mode-fixed system at scale": the measurement).
inline constexpr double operator_shift_fraction = 1e-4;

class OperatorModeSystem {
 public:
  // out = G_AA y (3 na); false if the solve failed (an iterative solver's tolerance).
  using Apply = std::function<bool(const VecX& y, VecX& out)>;
  // r <- M r (3 na), M symmetric positive definite, commuting with G_AA (see above).
  using Precondition = std::function<bool(VecX& r)>;

  // The system for na = S.size() active contacts (S, T: one 3x3 block each).
  // Clears the preconditioner.
  void set(Apply G_AA, std::vector<Mat3> S, std::vector<Mat3> T);
  // M (empty: none) for the following solves.
  void set_preconditioner(Precondition M) { M_ = std::move(M); }
  // The mixed sets' preconditioner (see above): factorize(frames, s) prepares
  // v <- s (I + h H~ A^{-1} H~^T)^{-1} s v, H~ = diag(s) blockdiag(frames) H_A (the
  // na rotations and 3 na row weights, s = 0 on local rows), apply does it
  // (SparseDelassus::set_frames, factorize_shifted(1), solve_shifted). Used where some
  // active contact does not stick, before M; factorized once, at the first solve.
  using FactorizeReduced = std::function<bool(const std::vector<Mat3>& frames, const VecX& s)>;
  void set_reduced_preconditioner(FactorizeReduced factorize, Precondition apply) {
    reduced_factorize_ = std::move(factorize);
    reduced_apply_ = std::move(apply);
    reduced_state_ = 0;
  }
  // The reduced preconditioner was factorized and used (false: not set, not applicable
  // or GMRES did not converge with it in the last solve).
  bool reduced_used() const { return reduced_state_ == 1 && last_reduced_ok_; }
  bool preconditioned() const { return static_cast<bool>(M_); }
  int size() const { return 3 * static_cast<int>(S_.size()); }

  // x = J^+ r (transposed: x = (J^T)^+ r). False if a solve failed or CGLS did not
  // reach its stopping rule within max_iterations (x is then its last iterate).
  bool solve(const VecX& r, VecX& x, bool transposed = false) const;

  // Stopping rule: ||J^T s|| <= tolerance ||J^T r|| (s = r - J x, the normal equations'
  // relative residual), or <= 1e-14 ||J||_est ||s|| (the rounding floor of an
  // inconsistent system, ||J||_est the largest ||J p|| / ||p|| seen).
  double tolerance = 1e-13;
  int max_iterations = 0;  // 0: 20 (3 na) + 200
  // The symmetric case's CG: ||r - G_AA x|| <= cg_tolerance ||r|| (so ||x - x*|| <=
  // cg_tolerance kappa ||x*||); at most min(2 (3 na) + 50, 2000) iterations.
  double cg_tolerance = 1e-12;

  // The mixed path's GMRES: relative residual of the scaled system (above), restart
  // length, and at most gmres_max_iterations iterations (then the CGLS path).
  double gmres_tolerance = 1e-12;
  int gmres_restart = 100;
  int gmres_max_iterations = 1000;

  int last_iterations() const { return last_iterations_; }
  int total_iterations() const { return total_iterations_; }
  int solves() const { return solves_; }  // products with G_AA (solves with A's factor)
  int preconditioner_solves() const { return precond_solves_; }  // applications of M

 private:
  bool apply(const VecX& x, VecX& out, bool transposed) const;  // J x or J^T x
  bool symmetric() const;                                       // S = I, T = 0: J = G_AA
  bool solve_cg(const VecX& r, VecX& x) const;
  bool solve_cgls(const VecX& r, VecX& x, bool transposed) const;  // from x = 0 (CGLS on J M or J)
  bool precondition(VecX& v) const;  // v <- M v (counted)
  bool prepare_reduced() const;      // rot_, dl_, local_, mu_s_, weights_; factorize
  bool apply_scaled(const VecX& v, VecX& out, bool transposed) const;  // J' v or J'^T v
  bool precondition_reduced(VecX& v, bool transposed) const;         // P' v or P'^T v
  bool solve_gmres(const VecX& r, VecX& x, bool transposed) const;

  Apply G_;
  mutable Precondition M_;  // (solve() sets it aside for its unpreconditioned fallback)
  std::vector<Mat3> S_, T_;
  mutable VecX g_, st_;  // (3 na) scratch of apply
  mutable VecX s_, p_, q_, t_;  // (3 na) CGLS
  mutable VecX z_, mv_;         // (3 na) preconditioned: CG's M s; CGLS's z and M p
  FactorizeReduced reduced_factorize_;
  Precondition reduced_apply_;
  mutable int reduced_state_ = 0;  // 0: not prepared, 1: factorized, -1: not applicable / failed
  mutable bool last_reduced_ok_ = false;
  mutable std::vector<Mat3> rot_;  // (na) the rotated frames Rot_a (rows s, p, N; I for sticking)
  mutable VecX dl_;                // (3 na) row scales Dl
  mutable VecX local_;             // (3 na) L on the local rows, 0 on the reduced ones
  mutable VecX mu_s_;              // (na) mu of the s row's -mu x_N (0: none)
  mutable VecX weights_;           // (3 na) s = (C + c I)^{-1/2} on reduced rows, 0 on local
  mutable MatX V_, Hh_;            // GMRES: (3 na x (m + 1)) basis, ((m + 1) x m) Hessenberg
  mutable VecX gc_, gs_, gg_, gy_, gb_, gw_, gx_, gv_;  // Givens cos / sin, rhs, y; (3 na) vectors
  mutable int last_iterations_ = 0, total_iterations_ = 0, solves_ = 0, precond_solves_ = 0;
};

// The largest eigenvalue of a symmetric positive semi-definite operator G (3 na) by
// power iteration (docs/method.md "The derivative's scale"): from y (in: the start,
// nonzero; out: the last iterate, normalized), estimates lambda_k = y_k^T G y_k /
// y_k^T y_k with y_{k+1} = G y_k / |G y_k|, one product each. For a positive
// semi-definite G the estimates increase monotonically to lambda_max (the ratios of the
// moments y_0^T G^j y_0 are non-decreasing), each a lower bound. Stops when two
// successive estimates differ by at most `tolerance` relative (converged), or after
// max_iterations products, or when a product fails or is zero or non-finite.
// Allocation-free after the first call at a size (Gy: scratch of 3 na).
struct PowerIteration {
  double value = 0;     // the last estimate (a lower bound of lambda_max)
  double change = 0;    // its relative change over the previous one
  int iterations = 0;   // products with G
  bool converged = false;
  bool failed = false;  // a product failed (solve), or G y was zero or non-finite
};
PowerIteration power_iteration(const OperatorModeSystem::Apply& G, VecX& y, VecX& Gy, double tolerance,
                               int max_iterations);

}  // namespace softdiff::contact
