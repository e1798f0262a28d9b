#pragma once
// Rigid bodies in the static solver (issue 21; docs/method.md "Static equilibrium with
// rigid bodies"). Each rigid body with dofs takes part in every Newton iteration of
// integrator::solve_static with the soft bodies, through the one contact solve of the
// iteration (contact/contact_step.cpp, h = 1: the unknowns are increments, not
// velocities):
//   - unknowns: the increment u_r of the body's pose, (dp, dtheta) in world axes
//     (free: 6; hinge, slider: T dc with T the joint's motion basis, dc the increment
//     of the joint coordinate; fixed: none);
//   - equations: the generalized force on the joint's dofs vanishes,
//         T^T (w_r + H_r^T lambda) = 0,    w_r = (f m g, 0)
//     (gravity at the centre of mass, ramped by the load step's factor f = s / L as on the soft bodies; H_r^T lambda the contact forces and torques on the
//     body; a limit's row of the NCP is the limit's reaction);
//   - the rigid body has no stiffness: its free increment is that of a proximal term
//     A_r = k diag(m I, I_w) (k in 1/s^2, the same for every body), u_free = A_r^{-1} w_r
//     (on a joint: T (T^T w_r) / (T^T A_r T)), W_r = A_r^{-1} (on a joint: T T^T / a),
//     and the NCP finds the contact forces that stop it: where the contact set holds the
//     body, lambda satisfies H_r^T lambda = -w_r on its dofs whatever k (the equations
//     above are linear in lambda), so the rigid equations hold at the end of the
//     iteration up to the NCP's tolerance and the lever arms' change with the increment;
//   - k = |g| / (0.01 s), s the scene's size (the soft bodies' largest bounding-box
//     diagonal): the free increment of a body is 0.01 s. The NCP's accuracy is relative
//     to |g| ~ |H u_free|, so a large free increment costs accuracy (measured: a cube on
//     a soft slab stalls at a relative residual 8e-6 with 10 s, converges to 1e-10 in 7
//     iterations with 0.01 s); a larger k slows the proximal iteration where the body's
//     support is soft (the contraction per iteration ~ k a / (k a + the support's
//     stiffness on the joint's dof: 0.53 for the hinged bar on a soft pad);
//   - a body with a load on its dofs that no contact of an iteration touches has no
//     support within contact.margin: the solver stops, not converged, naming it;
//   - after the contact solve, each pose moves by its increment exactly on its joint
//     (free: p + dp, exp(dtheta) q; hinge, slider: rigid::move_along_joint), velocities 0.
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <functional>
#include <string>
#include <vector>

namespace softdiff::integrator {

// The proximal factor k (1/s^2) of a scene of size `size` (m) under the model's
// gravity; first: the load step's first iteration (see above).
double static_rigid_stiffness(const Model& model, double size, bool first);

// Fills data.contact.rigid for the contact solve of one Newton iteration at the poses
// `poses`: in = free = poses, W_r, L_r, rank_r, u_free = A_r^{-1} w_r (6 R), u = u_free.
// load_factor: the load step's s / L (gravity ramped as on the soft bodies).
void begin_static_rigid(const Model& model, Data& data, const std::vector<rigid::RigidState>& poses, double k,
                        double load_factor);

// After the contact solve (or without contacts): each pose moved by its increment
// data.contact.rigid.u, velocities zero. Returns the largest displacement of a body's
// surface vertex (m) and its body in *body. A non-finite pose: non_finite status.
StepStatus end_static_rigid(const Model& model, Data& data, std::vector<rigid::RigidState>& poses, long load_step,
                            double& moved, int& body);

// Joint limits (docs/method.md "Static equilibrium with joint limits"): with contacts,
// each limit near enough is a frictionless unilateral row of the iteration's NCP
// (contact_step.cpp, h = 1: select_limit_rows, gap = the distance to the limit, g =
// s dc_free + gap; the limit's force is the reaction on the joint coordinate). Without
// any contact detected no NCP runs; then this function solves each limited body's own
// size-1 LCP exactly: dc = dc_free + s lambda / a, gap_s + s dc >= 0, lambda >= 0,
// complementary (dc_free = T.u_free / |T|^2, a = T^T A_r T), writing rigid.u, the
// selected rows (rigid.limit_rows) and their reactions (rigid.limit_lambda, by slot).
// Call after resolve_contacts when data.contact.contacts is empty.
void static_limits_without_contact(const Model& model, Data& data);

// After the contact solve: the first body with dofs and a load along them that no
// contact of this solve touches (it has no support within contact.margin: no
// equilibrium), or -1. A body on a limited joint is held by a limit on either side.
int static_rigid_unsupported(const Model& model, const Data& data);

// The rigid equations' residual at `poses` with the contact forces of the last contact
// solve (data.contact: rigid.Ht, lambda; none when `with_contact` is false or no contact
// was found): max over the bodies of |T^T (w_r + H_r^T lambda)| relative to the body's
// weight (forces) and weight times reach (torques: the largest distance of a surface
// vertex from the centre of mass, or from the hinge's axis). 0 without rigid dofs.
double static_rigid_residual(const Model& model, const Data& data, const std::vector<rigid::RigidState>& poses,
                             double load_factor, bool with_contact, std::string* worst = nullptr);

// A scene of rigid bodies only (no soft node; docs/method.md "Static equilibrium of
// rigid bodies only"): solve_static's load steps and Newton iterations without the soft
// stage. Per iteration: begin_static_rigid (k from the rigid bodies' size: the largest
// diagonal of a body's surface box), the contact stage on the rigid increments alone
// (contact::resolve_contacts with h = 1 and no soft dof: the dense G = sum_r H_r W_r
// H_r^T, the limit rows as above), the poses moved (end_static_rigid). A load step has
// converged when the rigid residual (static_rigid_residual, with this load step's NCP)
// is below static.tolerance and that NCP met its own. The soft state stays empty.
// `on_load_step` as solve_static's; status.iterations the total count.
StepStatus solve_static_rigid_only(const Model& model, Data& data, const State& in, State& out,
                                   const std::function<void(long, const State&)>& on_load_step);

// static.friction: load_step (docs/method.md "Static equilibrium with contact",
// *Load-step-anchored friction*; 2026-12-04, branch sfric). record_load_step_start: at a
// load step's start, x (Data::static_load_step_start) and, under static.friction load_step
// only (empty otherwise), the extended positions there (static_load_step_start_extended: x,
// then each rigid body's surface vertices posed, as contact::extend_for_detection numbers them). static_slip_offset: after the detection of
// a Newton iteration (data.contact.contacts; with rigid bodies the extended positions of
// the current iterate in data.contact.rigid.x, otherwise x), per contact i the slip of its
// points since the load step's start through its current frame,
//     slip_offset[3i + r] = t_r . sum_k w_k (X_k - X_k^start)  (r = 0, 1; 0 on the normal row),
// which solve_contact_problem adds to g: the NCP then acts on the load step's total slip
// H_T (x_k - x_start) + H_T dx (a rigid point's share the exact displacement of its
// material point under the pose change since x_start; a contact that appeared during the
// load step measured the same way, from its points' start positions). With
// static.friction: iterate, static_slip_offset empties it (g unchanged).
void record_load_step_start(const Model& model, Data& data, const VecX& x, const std::vector<rigid::RigidState>& poses);
// The extended positions of (x, poses): x, then (with rigid bodies in contact) each rigid
// body's surface vertices posed (contact::extend_for_detection's numbering); x alone otherwise.
void extended_positions(const Model& model, const VecX& x, const std::vector<rigid::RigidState>& poses, VecX& e);
// Per contact of `contacts` the tangential slip of its points from the extended positions
// `from` to `to` through its frame: slip[3i + r] = t_r . sum_k w_k (X_k(to) - X_k(from))
// (r = 0, 1; 0 on the normal row).
void contact_slips(const collision::ContactSet& contacts, const VecX& from, const VecX& to, VecX& slip);
void static_slip_offset(const Model& model, Data& data, const VecX& x);
// Empties data.contact.slip_offset when the solve ends, whichever way (the offsets are the
// static solve's: a later contact solve on the same Data must not see them).
struct SlipOffsetGuard {
  ContactData& cd;
  ~SlipOffsetGuard() { cd.slip_offset.resize(0); }
};

// Rigidified parts in the static solver (docs/method.md "Static equilibrium with
// rigidified parts"; defined in rigidify.cpp beside the dynamic step's functions): the
// reduced Newton P^T R(P u) = 0 on the static tangent A = K (prepare_rigidified with
// h = 1 reads K alone for a static model), its increment solved by solve_rigidified.
// rigidified_static_pose: the parts' centres and T's arms at x (data.rigidify.x,
// centre), for project_rigidified_residual before the iteration's prepare.
void rigidified_static_pose(const Model& model, Data& data, const VecX& x);
// trial = x + alpha dx, with the parts' nodes placed exactly: the part's rigid increment
// (dp, dtheta), the lumped-mass fit of dx about its centre at x, scaled by alpha:
// x_i' = c + alpha dp + exp(alpha [dtheta]) (x_i - c). Needs rigidified_static_pose(x).
void place_rigidified_static(const Model& model, const Data& data, const VecX& x, const VecX& dx, double alpha,
                             VecX& trial);

}  // namespace softdiff::integrator
