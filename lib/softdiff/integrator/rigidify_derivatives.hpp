#pragma once
// Derivatives of the implicit Euler step with rigidified parts (issue 21 item 4 for
// item 2; docs/method.md "Rigidified parts", "Derivatives"). Used by StepDerivatives
// (implicit_euler_derivatives.hpp) when model.rigidify is not empty: implicit Euler (or
// BDF2's stage, from the record's hat state) with one Newton iteration, with or without
// contact (dense backend: the record's G, formed by rigidified_congruence, is the
// mode-fixed system's; sparse backend: the operator's rows H_f^T and K_p), rigid bodies in
// contact included (their rows L_r^T H_r^T beside the parts', on both backends); with
// Newton (below) with or without contact, rigid bodies in contact included (rpsn), with a
// limited joint in contact too (rplim: the joint limits' extended system on the parts'
// rows, implicit_euler_derivatives.cpp prepare_contact and prepare_rigid).
//
// The step with parts (rigidify.hpp): P^T A P z = P^T (b + h H^T lambda), Delta = P z,
// v~ = v_i + Delta (the solve's velocity), then the exact placement of every part from
// v~ (the lumped-mass fit u_f = (v_p, omega) of v~ at x_i about c, x_i' = c + h v_p +
// R a_i, R = exp(h [omega]), v_i' = v_p + omega' x R a_i, omega' = R I^{-1} R^T I omega).
// P depends on x_i through the arms a_i = x_i - c (c the part's lumped-mass centroid):
// dP z has rows omega_z x da_i on the part's nodes (da_i = dx_i - dc), dP^T s has the
// part's rows (0, sum_i da_i x s_i). Differentiating the reduced system,
//     d Delta = A_red^{-1} (rho) + P N^{-1} dP^T r_res + dP z,
//     rho = (the step's right-hand side derivative without parts, at v~) - A dP z,
// A_red^{-1} = P N^{-1} P^T (N = P^T A P; rigidify.hpp's Schur complement on the step's
// factor: every solve is one solve with the factor), r_res = b + h H^T lambda - A Delta
// the step's residual (zero resultant and moment on each part: its internal forces).
// The placement's derivative: the fit's (du = N_p^{-1} sum_i m_i [dT_i^T (v~_i - T_i u)
// + T_i^T (dv~_i - dT_i u)]), R's through SO(3)'s right Jacobian (dR = R [J_r(h omega) h
// domega]x), the inertia's dI = sum m_i (2 a_i.da_i I - da_i a_i^T - a_i da_i^T). The
// reverse mode transposes each piece.
//
// v~ and u_f are not stored by the step: they are recovered from the step's output
// (the part's rigid field at the placed pose gives v_p and omega', and I' omega' = I
// omega = L), and u_z = u_f - fit(v_i) (v~ = v_i + T u_z on the part).
//
// Newton (newton_iterations > 1; docs/method.md "Rigidified parts", *Derivatives*,
// *Newton with parts*): the step solves F(z) = P^T R(v_i + P z) = 0 with P at x_i, R the
// nonlinear residual (the elastic force at the straight-line iterate x_i + h v~). The
// implicit function theorem at the converged z has the same terms as above with A the
// converged tangent A_f = (1 + h alpha) M + h beta K~(x_i) + h^2 K(x_i + h v~) and r_res
// = -R(v~) (h f_int(x_f), h beta K~(x_i) v~): prepare_newton() forms A_f's own Schur
// complement (C, Y, S on the caller's factorization of A_f; the record's is one iterate
// earlier), and the products, solves and r_res below are then A_f's.
#include <softdiff/core/types.hpp>
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <Eigen/Cholesky>
#include <vector>

namespace softdiff::integrator {

class LinearSolver;

// The parts' coupling of A = (1 + h alpha) M + h beta K_damping + h^2 data.fem.K_values
// (K_damping null: K_values) at the arms of data.rigidify (x, centre): C = A_fr T (3n x
// 6m), D = T^T A_rr T (6m x 6m) (rigidify.cpp's, for the Newton derivative's Schur complement).
void rigidified_coupling(const Model& model, const Data& data, double h, const VecX* K_damping, MatX& C, MatX& D);

class RigidifiedStepDerivative {
 public:
  // From the record of the step in -> out (step size h): the parts' centres, fits,
  // velocities, v~ (solve_state()) and the residual r_res on the parts' rows.
  void prepare(const Model& model, const Data& data, const State& in, const State& out, double h);
  // The step's output before the placement (v = v~; x, t, rigid those of out): the state
  // the derivative terms of the step without parts are evaluated at.
  const State& solve_state() const { return solve_; }
  // Newton (model.step.newton_iterations > 1, after prepare()): the Schur complement on
  // `solver`, a factorization of A_f (the parts' dofs identity rows, as the step's A),
  // with K~(x_i) = data.K_i_values and K(x_f) = data.fem.K_values. `serial` names that
  // factorization: the Schur complement is recomputed only when it changes (one 6m-column
  // solve per step, not per tangent). False if a solve failed or S is not positive definite.
  bool prepare_newton(const Model& model, const Data& data, LinearSolver& solver, long serial);
  // Newton with contact (after prepare_newton): the rows of the reduced Delassus matrix at
  // A_f, G_f = h (H_f A_f,ff^{-1} H_f^T + K_f^T K_f) with H_f^T = Ht without the parts'
  // rows and K_f = L_{S_f}^{-1} W_f, W_f = T^T H_r^T - Y_f^T H_f^T (rigidify.cpp's
  // rigidified_rows on A_f's Schur complement), for the mode-fixed system
  // (ContactStageDerivative::prepare's NcpSystem Ht, Kt_more). No solve.
  void newton_contact_rows(const Model& model, const Data& data, const SparseMatrix& Ht);
  const SparseMatrix& newton_Ht_soft() const { return Ht_soft_; }
  const MatX& newton_K() const { return K_; }

  // Forward: with the position tangent dx (empty: zero), r -= A dP z (rho above) and
  // the reduced right-hand side's dP^T r_res is kept for solve(..., true, ...).
  void add_rhs_jvp(const Model& model, const Data& data, const VecX& dx, VecX& r);
  // v = A_red^{-1} b (b projected), plus P N^{-1} dP^T r_res of the last add_rhs_jvp when
  // with_extra. One solve with the step's factor. False if the linear solver failed.
  bool solve(const Model& model, const Data& data, const VecX& b, bool with_extra, VecX& v);
  // dv += dP z (on the parts' rows) for the dx of the last add_rhs_jvp.
  void add_dPz(VecX& dv) const;
  // The placement's tangent: the parts' rows of dx_out, dv_out from dx and dv~ (= dv_out
  // on entry; the other rows are the caller's: dx + h dv~, dv~).
  void place_jvp(const Model& model, const VecX& dx, VecX& dx_out, VecX& dv_out);

  // Reverse: the placement's transpose. bar_v_tilde, bar_x are the cotangents of v~ and
  // x_i through the placement (the rows of the other nodes: bar_v + h bar_x and bar_x,
  // set by the caller); the parts' rows are set here from bar_x_out, bar_v_out.
  void place_vjp(const Model& model, const VecX& bar_x_out, const VecX& bar_v_out, VecX& bar_v_tilde, VecX& bar_x);
  // The dP terms' transpose: t the cotangent of Delta (projected), y = A_red^{-1} t; adds
  // to bar_x (the parts' nodes).
  void add_solve_vjp(const Model& model, const Data& data, const VecX& t, const VecX& y, VecX& bar_x);

 private:
  struct Part {
    Vec3 c = Vec3::Zero();
    double m = 0;
    Eigen::Matrix<double, 6, 6> N;              // the fit's matrix at x_i about c
    Eigen::LDLT<Eigen::Matrix<double, 6, 6>> N_factor;
    Eigen::Matrix<double, 6, 1> u_f, u_z;       // the fit of v~, the reduced Delta
    Mat3 R, Jr, I;                              // exp(h omega), J_r(h omega), inertia about c at x_i
    Eigen::LDLT<Mat3> I_factor;
    Vec3 L, s, omega_next;                      // I omega, I^{-1} R^T L, R s
  };
  // (A w) on the parts' rows: A = (1 + h alpha) M + (h beta + h^2) K~ of the part's body.
  void system_product(const Model& model, const Data& data, const VecX& w, VecX& out);
  // u = N_p^{-1} sum_i m_i T_i^T w_i (the fit of w's part rows).
  Eigen::Matrix<double, 6, 1> fit(const Model& model, int p, const VecX& w) const;
  // bar_x += bar_a - m_i / m sum bar_a (+ m_i / m bar_c) on part p's rows: the arms'
  // cotangent through a_i = x_i - c.
  void arms_to_positions(const Model& model, int p, const VecX& bar_a, const Vec3& bar_c, VecX& bar_x) const;

  double h_ = 0;
  bool newton_ = false;              // the step is Newton's (A is A_f: prepare_newton)
  LinearSolver* newton_solver_ = nullptr;
  long newton_serial_ = -1;          // the factorization C_, Y_, S_ belong to
  MatX C_, Y_, S_;                   // Newton: A_f's C (3n x 6m), Y = A_f,ff^{-1} C, S (6m x 6m)
  Eigen::LLT<MatX> S_factor_;
  SparseMatrix Ht_soft_;             // Newton with contact: H_f^T (3n x 3nc)
  MatX K_;                           // and K_f = L_{S_f}^{-1} W_f (6m x 3nc)
  VecX Kiw_;                         // (3n) Newton: K~(x_i) w
  std::vector<Part> parts_;
  State solve_;
  VecX x_;                 // (3n) the step's x_i
  VecX r_res_;             // (3n) the step's residual on the parts' rows (zero elsewhere)
  VecX da_, dpz_, w_, Mw_, Kw_, Aw_, bar_a_;  // (3n) workspace
  Eigen::Matrix<double, Eigen::Dynamic, 1> g_extra_, g_, u_;  // (6m)
  VecX b_soft_, y_;        // (3n) the reduced solve's
  // Factor reuse (the step's record kept a factor: data.rigidify.reduced_pcg): the reduced
  // solves are PCG on the step's own P^T A P (rigidify_pcg.hpp), as the soft derivative's
  // solves are PCG on its A; their vectors (3n, then 6m).
  VecX pcg_f_[4], pcg_u_[4], pcg_y_;
};

}  // namespace softdiff::integrator
