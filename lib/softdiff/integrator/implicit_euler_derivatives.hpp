#pragma once
// Derivatives of the implicit Euler step (method.md "Derivatives"; sibling of
// implicit_euler.hpp): forward (JVP) and reverse (VJP) products of
//     (x_f, v_f) = Phi(x_i, v_i, lambda_a, p)
// for the linearized step (newton_iterations = 1) without contact.
//
// With Delta = v_f - v_i, w = v_f, per body b (alpha, beta its Rayleigh factors),
// differentiating A Delta = b:
//   A dDelta = Pi r,
//   r = -h K dx_i + h d(H_a^T lambda_a)/dx dx_i + h H_a^T dlambda_a
//       - h alpha M dv_i - (h beta + h^2) K~ dv_i - (h beta + h^2) dK~[dx_i] w
//       + sum_j dp_j q_j,
//   dv_f = Pi (dv_i + dDelta),  dx_f = dx_i + h dv_f,
// K = -df_int/dx the true Hessian, K~ the stiffness the step uses (K, or its per-element
// PSD projection), and the parameter columns q_j (body b):
//   young               (h f_int - (h beta + h^2) K~ w) / E   (f_int, K~ are proportional to E)
//   poisson             h df_int/dnu - (h beta + h^2) (dK~/dnu) w
//   density             h P_b / rho - M_b (h alpha w + Delta) / rho   (M, P = M g scale with rho)
//   rayleigh_mass       -h M_b w
//   rayleigh_stiffness  -h K~_b w
// The reverse mode transposes this: with v~ = Pi (bar_v_f + h bar_x_f) and one solve
// y = A^{-1} v~ (A symmetric),
//   bar_x_i = bar_x_f - h K y + h (d(H_a^T lambda_a)/dx)^T y - (h beta + h^2) grad_x(y^T K~ w)
//   bar_v_i = v~ - h alpha M y - (h beta + h^2) K~ y
//   bar_lambda_a = h H_a y,   bar_p_j = y . q_j.
// Every solve uses the step's factorization (data.solver): k JVP columns cost k
// solves, a VJP one. The linearized step's K dx_i and dK~[dx_i] w (and their
// transposes) come from the step's record data.fem (fem::add_stiffness_product: the
// assembled K, the kept polar decompositions), not from an element pass with SVD. Fixed dofs: Pi as in the step (their dx_i still moves the
// elastic forces; their velocity stays 0).
//
// newton_iterations > 1: the implicit function theorem on the converged residual
//     R(v) = M (v - v_i) - h (P + f_int(x_i + h v) + H_a(x_i)^T lambda_a) + h D(x_i) v = 0,
// D = alpha M + beta K~(x_i): with A_f = dR/dv = (1 + h alpha) M + h beta K~(x_i) + h^2 K(x_f)
// (assembled and factorized once per step here: Newton's own last factorization is one
// iterate earlier),
//   A_f dv_f = Pi r',  r' = -h K(x_f) dx_i + h d(H_a^T lambda_a)/dx dx_i + h H_a^T dlambda_a
//                           + M dv_i - h beta dK~(x_i)[dx_i] w + sum_j dp_j q'_j,
// with q' as q but f_int at x_f and h beta in place of h beta + h^2 (young, poisson); the
// reverse mode transposes it (bar_v_i = M y). Exact for the converged solution (to
// newton_tolerance).
//
// Contact (docs/method.md "Derivatives", "Through contact"):
// with the contact record of the step (data.contact), r gains h sum_i dH_i[dx_i]^T
// lambda_i (collision/contact_derivatives.hpp); dv0, the step's derivative at fixed
// lambda, moves sigma by b = dH v_f + H_c dv0 + (0, 0, dphi / h); the NCP derivative
// (contact/ncp_derivatives.hpp, modes fixed) gives dlambda; dv_f = dv0 + Pi h A^{-1}
// H_c^T dlambda. The reverse mode transposes this with one more solve. Both are
// prepared once per step (geometry derivatives and the NCP's factorization).
// With Newton the same at the converged state (R(v_f) - h H_c^T lambda = 0, the NCP on
// sigma = H_c v_f + phi / h; H_c and phi at x_i): A_f in place of A, and the mode-fixed
// system on G_f = h H_c A_f^{-1} H_c^T (docs/method.md "Newton iterations with contact").
//
// Rigid bodies in contact (model.contact.with_rigid(); docs/method.md "Through contact
// with rigid bodies"): the tangents carry each rigid body's input state and parameters
// (StepTangent::rigid, rigid_p) and the output's rigid states (StateTangent::rigid); the
// geometry terms run on the extended positions (soft nodes, then the rigid pseudo-nodes),
// the NCP derivative on the record's G with the rigid blocks, and the rigid bodies' own
// maps are contact/rigid_contact_derivatives.hpp's. Implicit Euler with one Newton
// iteration only (the step supports nothing else with rigid contact).
//
// Rigidified parts (model.rigidify; rigidify_derivatives.hpp, docs/method.md "Rigidified
// parts"): the solves are the reduced ones on the step's factor, the terms above are
// evaluated at the solve's velocity v~ (before the placement), the arms' dependence on
// x_i adds the dP terms, and the placement's derivative maps (x_i, v~) to the output.
// One Newton iteration, implicit Euler or BDF2's stage (the parts' rigid extrapolation:
// rigidify_bdf2_derivatives.hpp, chained by bdf2_derivatives.hpp), with or without
// contact (the record's G), rigid bodies in contact included (their pseudo-node terms
// beside the reduced solves); actuation_jvps() with parts: per column the reduced
// solve on the step's factor and the placement's tangent (no contact in the record).
//
// Not covered yet (SOFTDIFF_DEMAND with a message): the static integrator (see
// static_solver_derivatives.hpp), newton_iterations > 1 with psd_projection, friction
// as a parameter.
#include <softdiff/collision/contact_derivatives.hpp>
#include <softdiff/contact/contact_step_derivatives.hpp>
#include <softdiff/contact/ncp_derivatives.hpp>
#include <softdiff/contact/rigid_contact_derivatives.hpp>
#include <softdiff/core/parameters.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/rigidify_derivatives.hpp>
#include <softdiff/model.hpp>

#include <memory>
#include <vector>

namespace softdiff::integrator {

// A direction in the step's inputs. An empty vector stands for zero.
struct StepTangent {
  VecX x, v;       // (3n)
  VecX lambda_a;   // (n_a) actuation values of the step (at t_i + h)
  VecX p;          // (parameters().size())
  // Rigid bodies in contact (model.contact.with_rigid(); empty: zero): 12 per body, the
  // tangent of its input state (rigid_derivatives.hpp: dp, dtheta, dv, domega), and 7 per
  // body, of its mass and inertia components.
  VecX rigid, rigid_p;
};

// A tangent or cotangent of a state.
struct StateTangent {
  VecX x, v;       // (3n); empty: zero
  VecX rigid;      // (12 per rigid body) with rigid bodies in contact; empty: zero
};

// Cotangents of the step's inputs (all sized by vjp()).
struct StepCotangent {
  VecX x, v, lambda_a, p;
  VecX rigid, rigid_p;  // (12, 7 per rigid body) with rigid bodies in contact
};

class StepDerivatives {
 public:
  StepDerivatives(const Model& model, std::vector<ParameterId> parameters);
  const std::vector<ParameterId>& parameters() const { return parameters_; }
  // Of the last step differentiated with contact: contacts whose geometry derivative
  // does not exist (taken as zero), contacts whose active feature pair is not unique
  // and whose geometry derivative is the randomized-smoothing estimate
  // (model.contact.smoothing), and the NCP derivative (its rank deficiency).
  int nondifferentiable_contacts() const { return contact_.nondifferentiable_contacts(); }
  int smoothed_contacts() const { return contact_.smoothed_contacts(); }
  const contact::NcpDerivative& ncp_derivative() const { return contact_.ncp(); }
  // The contact forces' tangent d lambda_c (3 nc, in the contact frames) of the last
  // jvp() of a step with contact (the control's contact-force objective).
  const VecX& contact_force_tangent() const { return dlambda_; }
  // How many times the rigid contact maps were prepared (once per step, whatever the
  // number of jvp / vjp calls: prepare_rigid's cache key).
  long rigid_prepare_count() const { return rigid_.prepare_count(); }

  // Valid when data holds the record of the step in -> out: right after
  // implicit_euler_step(model, data, in, out) returned ok. Returns false (outputs
  // unspecified) if a solve failed or an element is inverted at x_i.
  bool jvp(const Model& model, const Data& data, const State& in, const State& out, const StepTangent& d,
           StateTangent& d_out);
  bool vjp(const Model& model, const Data& data, const State& in, const State& out, const StateTangent& bar_out,
           StepCotangent& bar_in);
  // Several actuation tangents at once, without contact in the record (the control's
  // actuation Jacobian): column j of dx_out is d_out.x of jvp() with d.lambda_a =
  // dlambda.col(j) and d.x, d.v, d.p zero (the velocity's tangent is dx_out / h). The
  // right-hand sides h Pi H_a^T dlambda_j go to the step's factor in ONE solve with k
  // columns (LinearSolver::solve(MatX)), not k solves. With contacts in the record the
  // tangent goes through the NCP's modes (jvp(), one column at a time): demanded absent.
  // Returns false as jvp() does.
  bool actuation_jvps(const Model& model, const Data& data, const State& in, const State& out, const MatX& dlambda,
                      MatX& dx_out);

 private:
  // q = the column of parameter j (see above) at the step's record.
  bool parameter_column(const Model& model, const Data& data, const State& in, const State& out, int j, VecX& q);
  // out = scale_b * (S w) per body, S the symmetric pattern matrix `values` (M or K~).
  void body_scaled_product(const Model& model, const VecX& values, const VecX& w, const VecX& scale, VecX& out);

  // The factorized system of the step's derivative: the step's own (linearized), or
  // dR/dv at the converged Newton iterate (assembled and factorized here, once per step).
  LinearSolver* system(const Model& model, const Data& data, const State& out);

  // The coefficients below for the record's step size h (data.h: dt, or 2 dt / 3 for BDF2).
  void set_step_size(const Model& model, double h);

  std::vector<ParameterId> parameters_;
  double coef_h_ = -1;               // the h of the coefficients
  VecX h_alpha_, k_coef_;            // (bodies) h alpha_b, h beta_b + h^2
  VecX minus_h_, minus_k_coef_;      // (bodies) -h, -(coefficient of K~(x_i) w): -(h beta_b + h^2), Newton -h beta_b
  VecX zero_bodies_;                 // (bodies) zeros
  VecX r_, y_, q_, w_, delta_, tmp_, tmp2_, zero_, q_extra_, work_;  // (3n) workspace
  // Contact (the linearized step with contact): the geometry derivative of every
  // contact and the NCP derivative at the step's solution, computed once per step
  // (cached by v_f). Counts the contacts whose geometry is not differentiable (their
  // geometry derivative is taken as zero). solver: the step derivative's system
  // (system(): A, or A_f with Newton), whose G the mode-fixed NCP derivative takes.
  // Returns false if a solve failed (jvp and vjp then return false).
  bool prepare_contact(const Model& model, const Data& data, const State& in, const State& out, LinearSolver& solver);
  // Rigid bodies in contact: checks the rigid tangent's sizes and prepares rigid_ from the
  // step's record; false (nothing to do) without them.
  bool prepare_rigid(const Model& model, const Data& data, const State& out, double h, const VecX& rigid,
                     const VecX& rigid_p);
  // r += h sum_i dH_i[dx]^T lambda_i
  void add_contact_force_jvp(const Model& model, const Data& data, const VecX& dx, VecX& r) const;
  // b = dH[dx] v_f + H dv0 + (0, 0, dgap / h): the change of sigma at fixed lambda.
  void contact_sigma_jvp(const Model& model, const Data& data, const State& out, const VecX& dx, const VecX& dv0,
                         VecX& b) const;
  // bar_x += the transposes of both, for the cotangents y (of r) and bar_b (of b).
  void add_contact_geometry_vjp(const Model& model, const Data& data, const State& out, const VecX& y,
                                const VecX& bar_b, VecX& bar_x) const;

  contact::ContactStageDerivative contact_;  // geometry and NCP derivatives (contact/contact_step_derivatives.hpp)
  // Rigid bodies in contact (model.contact.with_rigid()): their maps, and the extended
  // (soft then pseudo-node) vectors of the geometry terms.
  contact::RigidContactDerivative rigid_;
  VecX ext_dx_, ext_r_, ext_u_, ext_y_, ext_bar_x_, du0_, bar_du0_;
  VecX contact_v_;                   // the v_f (and rigid u) the contact derivatives were prepared for
  std::uint64_t rigid_serial_ = 0;   // the record rigid_ was prepared for (ContactData::serial; 0: none)
  VecX b_, dlambda_, bar_lambda_, bar_b_, bar_mu_, y2_;
  SparseMatrix newton_A_;            // Newton: dR/dv at x_f (the pattern's structure)
  std::unique_ptr<LinearSolver> newton_solver_;
  MatX newton_G_;                    // Newton with joint limits in contact: the contacts' G with A_f
  VecX newton_v_;                    // the v_f newton_A_ was factorized for
  double newton_h_ = 0;              // and its step size
  long newton_serial_ = 0;           // counts newton_solver_'s factorizations (parts_.prepare_newton's cache key)
  VecX newton_work_;                 // (3n) Newton with parts: (A_f - M) w's scratch
  // Rigidified parts (model.rigidify; rigidify_derivatives.hpp): the reduced solve's and
  // the placement's derivative terms, prepared per jvp / vjp from the step's record.
  RigidifiedStepDerivative parts_;
  VecX lambda_column_;               // (n_a) actuation_jvps(): one column of dlambda
  MatX rhs_columns_, y_columns_;     // (3n x k) actuation_jvps(): right-hand sides, solutions
};

}  // namespace softdiff::integrator
