#pragma once
// Rigidified parts of soft bodies (issue 21 item 2, scene.md `rigidify`, docs/method.md
// "Rigidified parts"): the selected nodes of a soft body move as one rigid body, by a
// reduced mapping, not by stiff elements.
//
// Reduced velocities: the dofs of the soft (neither fixed nor rigidified) nodes, then 6
// per part, u_p = (v_p, omega_p), world axes. Node i of part p moves with
//     v_i = v_p + omega_p x (x_i - c_p) = T_i u_p,   T_i = [I, -[x_i - c_p]x]  (3 x 6),
// c_p the part's lumped-mass centroid at x_i (the step's start). With P the map from
// reduced to full velocities, the step solves (P^T A P) u = P^T b, v = P u.
//
// The factorized matrix is the soft system's A with the rigidified dofs given identity
// rows (the pattern's fixed_* lists include them: one pattern, one symbolic analysis,
// the step's one factorization, A_ff below). The 6 m part dofs are eliminated by the
// Schur complement
//     C = A_fr T (3n x 6m, rows of the soft dofs next to a part),  Y = A_ff^{-1} C (one
//     solve with 6m right-hand sides on the step's factor),
//     S = T^T A_rr T - C^T Y   (6m x 6m, dense, Cholesky),
// the coupling values A_fr, A_rr computed from M and K at precomputed value indices
// (the assembled A has them zeroed). Every solve is then one solve with the factor:
//     y = A_ff^{-1} b_f,  u = S^{-1} (T^T b_r - C^T y),  v_f = y - Y u,  v_r = T u,
// i.e. v = P (P^T A P)^{-1} P^T b exactly, in full coordinates.
//
// Positions are placed exactly (place_rigidified): with u = (v_p, omega) the part's
// velocity at the end of the step,
//     x_i' = c_p + h v_p + R (x_i - c_p),  R = exp(h [omega]x),
//     v_i' = v_p + omega' x (x_i' - c_p'),  omega' = I'^{-1} I omega,  I' = R I R^T,
// c_p' = c_p + h v_p, I the part's lumped inertia about c_p at x_i, instead of x_i + h v_i:
// distances inside the part are kept to round-off whatever the rotation, and the
// angular momentum of the solve is kept at the new pose.
//
// Contact: G and the correction through the same reduced solve (rigidified_congruence,
// solve_rigidified; contact/contact_step.cpp); on the sparse backend G's operator is the
// step factor's on the soft rows plus the rank-6m part as rigid rows (rigidified_rows).
//
// attach: fixed parts are fixed dofs (io::build_model); free and servo-attached parts
// are RigidifiedPart. Newton (newton_iterations > 1): the Galerkin-projected nonlinear
// equations P^T R(P u) = 0 with T at x_i (the iterates x_i + h P u; the end pose is
// placed exactly as above). BDF2: the stage from the extrapolated state with the
// parts' extrapolated state made rigid (rigidify_extrapolated_state). Static: the
// reduced static Newton (static_solver.cpp). Factor reuse: the reduced PCG
// (rigidify_pcg.hpp). Derivatives: rigidify_derivatives.hpp (implicit Euler and BDF2,
// rigidify_bdf2_derivatives.hpp; Newton too; either contact backend, rigid bodies in
// contact included) and static_solver_derivatives.cpp (static: beside rigid bodies,
// with a cable on a part and on a body held by contact alone too since rstp). Refused
// with parts (issue 21, app/theta.cpp): a limited joint in contact on the sparse backend
// or under Newton.
#include <softdiff/core/types.hpp>
#include <softdiff/fem/fem_model.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/Cholesky>
#include <string>
#include <vector>

namespace softdiff {
struct Model;
struct Data;
struct State;
struct StepStatus;
}  // namespace softdiff

namespace softdiff::integrator {

struct RigidifiedPart {
  std::string name;         // "body 'b' rigidify[k]" (messages)
  int body = 0;             // soft body index
  std::vector<int> nodes;   // global node indices, sorted, distinct
  int servo = -1;           // attach: <servo>: the actuator index in model.actuation; -1 free
};

struct RigidifyModel {
  std::vector<RigidifiedPart> parts;  // free or servo-attached; empty: nothing of this runs
  std::vector<int> dof_part;          // (3n when parts exist) part of each dof, -1 if not rigidified
  // Entries of the system pattern's upper triangle that couple a rigidified dof: `value`
  // the value index, `rigid` the rigidified dof, `other` the other dof (free for
  // rigid_free; rigidified, possibly equal to `rigid`, for rigid_rigid). Entries with a
  // fixed dof are left out (a fixed dof does not move).
  struct Entry {
    int value = 0, rigid = 0, other = 0;
  };
  std::vector<Entry> rigid_free, rigid_rigid;
  bool empty() const { return parts.empty(); }
  int size() const { return static_cast<int>(parts.size()); }
};

// The per-step workspace (sized on first use; no allocation afterwards).
struct RigidifyData {
  MatX C, Y;                    // (3n, 6m)
  MatX S;                       // (6m, 6m)
  Eigen::LLT<MatX> S_factor;
  VecX b_soft, y, g, u;         // (3n), (3n), (6m), (6m)
  std::vector<Vec3> centre;     // (m) c_p at the step's start
  VecX x;                       // (3n) the step's start x_i (T's arms)
  // Contact (rigidified_congruence): H_f^T (H_c^T without the parts' rows), W = E^T H_c^T
  // (6m x 3nc) and S^{-1} W (rigidified_rows: L_S^{-1} W).
  SparseMatrix Ht_soft;
  MatX W, SW;
  VecX f;                       // (3n) Newton: scratch of the projected internal forces
  // Factor reuse (linear_solver.factor_reuse: pcg; docs/method.md "Rigidified parts",
  // *Factor reuse*): with a kept factor, C, Y and S above stay the last factorization's
  // (the preconditioner's) and the step's own coupling is C_step = A_fr T and D_step =
  // T^T A_rr T; solve_rigidified then runs PCG on P^T A P.
  bool reduced_pcg = false;     // this step's solves are the reduced PCG
  MatX C_step, D_step;          // (3n, 6m), (6m, 6m)
  VecX r_f, z_f, p_f, q_f;      // (3n) reduced PCG: the soft rows of residual, preconditioned residual, direction, A p
  VecX r_u, z_u, p_u, q_u;      // (6m) the same, the parts' rows
  int pcg_iterations = 0;       // of the last reduced PCG solve (0: direct)
};

// Fills r.dof_part and the coupling entries from the pattern (io::build_model, after
// fem::build_fem_model was given the parts' dofs as fixed and fem.fixed was restored).
void build_rigidify(const fem::FemModel& fem, RigidifyModel& r);

// The row of T for dof c of a node at arm r from the centre: v_c = row . (v_p, omega).
inline Eigen::Matrix<double, 1, 6> rigid_row(const Vec3& r, int c) {
  Eigen::Matrix<double, 1, 6> t = Eigen::Matrix<double, 1, 6>::Zero();
  t[c] = 1;
  t.tail<3>() = -rigid::hat(r).row(c);  // omega x r = -[r]x omega
  return t;
}

// After the step's A (at x, step size h) is assembled and factorized: the centres, C,
// Y and S's Cholesky factor. S not positive definite: a not_positive_definite status.
// A = (1 + h alpha) M + h beta K_damping + h^2 K, K = data.fem.K_values, K_damping the
// same unless given (Newton: the damping's K frozen at x_i). The arms of T are x's.
StepStatus prepare_rigidified(const Model& model, Data& data, const VecX& x, double h, long step_index,
                              const VecX* K_damping = nullptr);

// Newton with parts: replaces the parts' rows of a residual (force) r by its M-weighted
// projection on the parts' rigid motions, r_p <- M_p T_p N_p^{-1} T_p^T r_p,
// N_p = T_p^T M_p T_p (the prepared T): the resultant and moment are kept (T^T r, what
// the reduced step solves for), the internal forces between the part's nodes, which do
// no work on its rigid motions, drop out, and norms of r measure what the reduced
// system leaves unbalanced, in newtons.
void project_rigidified_residual(const Model& model, Data& data, VecX& r);

// v = P (P^T A P)^{-1} P^T b with the prepared factors. b is projected (zero on the
// fixed dofs). Returns false if the linear solver failed (an iterative one).
bool solve_rigidified(const Model& model, Data& data, const VecX& b, VecX& v);

// The contact stage's Delassus matrix with parts (docs/method.md "Rigidified parts",
// "Contact"): G = H A_red^{-1} H^T (without the factor h) for H^T = Ht (3n x 3nc), with
// A_red^{-1} = P (P^T A P)^{-1} P^T = Z + E S^{-1} E^T, Z = A_ff^{-1} on the soft dofs,
// E = [-Y; T]: G = H_f Z H_f^T + W^T S^{-1} W, W = E^T H^T = T^T H_r^T - Y^T H_f^T, H_f
// the soft dofs' rows. One multi-right-hand-side congruence on the step's factor (as
// without parts) plus a rank-6m correction. Returns false if the linear solver failed.
bool rigidified_congruence(const Model& model, Data& data, const SparseMatrix& Ht, MatX& G);

// The same G as an operator (the sparse contact backend, contact/sparse_delassus.hpp):
// G = H_f Z H_f^T + K_p^T K_p with K_p = L_S^{-1} W (6m x 3nc, S = L_S L_S^T), i.e. the
// soft operator on H_f^T (data.rigidify.Ht_soft, with the step's factor and A) plus 6m
// dense rows (data.rigidify.SW), SparseDelassus::set_rigid's second block. No solve:
// W needs the prepared Y only.
void rigidified_rows(const Model& model, Data& data, const SparseMatrix& Ht);

// The exact placement: out.x, out.v of the parts' nodes from in.x and out.v (the
// rigid velocity field the solve gave), see above.
void place_rigidified(const Model& model, Data& data, const State& in, State& out, double h);

// BDF2 (integrator/bdf2.cpp): the extrapolated state x^ = 4/3 x_n - 1/3 x_{n-1},
// v^ = 4/3 v_n - 1/3 v_{n-1} of a rotating part is not a rigid pose and field (a blend
// of two rotations shrinks it by O(angle^2); the blended nodal velocities hold a
// different angular momentum at the blended pose). The parts' rows of hat are replaced
// by the rigid pose and field with the same extrapolation of the centroid, the
// rotation, the velocity and the angular momentum:
//     x^_i = c^ + exp(1/3 log R) (x_{n,i} - c_n),   c^ = 4/3 c_n - 1/3 c_{n-1},
//     v^_i = v_p^ + omega^ x (x^_i - c^),   v_p^ = 4/3 v_p,n - 1/3 v_p,n-1,
//     omega^ = I^{-1} (4/3 L_n - 1/3 L_{n-1}),
// R the part's rotation from x_{n-1} to x_n (the polar factor of the mass-weighted
// cross-covariance, exact for rigid poses), L the angular momentum about the centroid
// (world), I the inertia of the pose x^. A constant torque then gives L_n = n dt tau
// exactly, as implicit Euler does.
void rigidify_extrapolated_state(const Model& model, const State& in, const State& previous, State& hat);

// The part's (v_p, omega) from a nodal velocity field at positions x, about centre c:
// the lumped-mass least-squares fit (exact for a rigid field).
Eigen::Matrix<double, 6, 1> part_velocity(const Model& model, const RigidifiedPart& part, const VecX& x,
                                          const Vec3& c, const VecX& v);
// The part's lumped-mass centroid at x.
Vec3 part_centre(const Model& model, const RigidifiedPart& part, const VecX& x);

}  // namespace softdiff::integrator
