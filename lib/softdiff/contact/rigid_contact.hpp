#pragma once
// Rigid bodies in the contact stage (issue 21; docs/method.md "Rigid bodies in contact").
// The rigid bodies enter the one NCP with the soft bodies:
//   - detection: each rigid body's surface vertices, posed at the start of the step, are
//     pseudo-nodes numbered after the soft nodes (Model::contact.rigid_node_begin), with a
//     collision::BodySurface over them, so the detector's vertex-obstacle, vertex-triangle
//     and edge-edge contacts give the rigid body its contact manifold unchanged;
//   - velocity unknowns u = (v_soft (3n), then (v, omega) (world) per rigid body); a
//     pseudo-node k of body r moves with v_r + omega_r x (x_k - p_r): its Jacobian block
//     is [I, -[x_k - p_r]x];
//   - Delassus: G = h H_s A_s^{-1} H_s^T + h sum_r H_r W_r H_r^T with
//     W_r = A_r^{-1}, A_r = diag(m I, I_w(q_free)) (the symmetric linearization of the
//     free step's velocity update; rigid::step_matrix's angular block at omega = 0),
//     W_r = 0 for a body on a fixed joint (joints: below);
//   - correction u_r = u_r,free + h W_r H_r^T lambda, and the pose integrated with it as
//     rigid::step does (p + h v, exp(h [omega]) q).
// Hinge and slider bodies: W_r = T a^{-1} T^T, a = T^T A_r T, T the joint's motion basis
// at the start of the step, u_free = T cdot_free; the pose moves along the joint.
// Limit rows (issue 21 item 2): a hinge or slider with limits takes its free step without
// them (cdot_free unclamped) and each limit is one frictionless unilateral row of the same
// NCP, appended after the contacts as a contact of 3 rows with mu = 0: its normal row's
// Jacobian on the body's (v, omega) is j = s T / |T|^2 (s = +1 for the lower limit, -1
// for the upper), so that j.u = s cdot on the joint's motion u = T cdot and W_r j =
// s T / a (a = T^T A_r T, the joint's inertia); its gap is the distance to the
// limit at the start of the step (c_n - lower, upper - c_n), and g = s cdot_free + gap / h.
// The coordinate after the step, c_n + h cdot, is linear in cdot, so the limit holds
// exactly (to the NCP's tolerance), with the contact forces, no penalty. The tangential
// rows have a zero Jacobian (their force is 0: mu = 0) and a unit-scaled diagonal.
// Without any contact detected the limits are the free step's clamp (rigid::step, the
// exact size-1 LCP) and no NCP runs.
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

namespace softdiff::contact {

// Appends each rigid body's surface (pseudo-nodes after the soft nodes) to
// model.contact.detection's surfaces and names, and fills rigid_node_begin/body. Call
// after the soft bodies' surfaces and before the obstacles' names (names: soft bodies,
// rigid bodies, obstacles). Nothing without rigid bodies.
void add_rigid_surfaces(Model& model);

// The record's per-body storage (data.contact.rigid): in, free (copies), u_free (6R), W,
// L, rank (R entries, R = in.size()), resized only when R changes (no allocation after the
// first step). Their values are the caller's: begin_rigid_contact (a dynamic step) and
// integrator::begin_static_rigid (a static Newton iteration, free = in) fill them.
ContactData::Rigid& size_rigid_record(Data& data, const std::vector<rigid::RigidState>& in,
                                      const std::vector<rigid::RigidState>& free);

// Before the soft step: records the rigid bodies' start states and free velocities
// (`free`: rigid::step without contact, from `in`) and each body's W_r.
void begin_rigid_contact(const Model& model, Data& data, const std::vector<rigid::RigidState>& in,
                         const std::vector<rigid::RigidState>& free);

// Extended positions and velocities for detection: data.contact.rigid.{x, v_previous,
// v_free} = the soft x, v_previous, v_free followed by the pseudo-nodes' (posed at
// the start of the step; velocities from the start and the free step).
void extend_for_detection(const Model& model, Data& data, const VecX& x, const VecX& v_previous, const VecX& v_free);

// The manifold reduction (docs/method.md "Rigid bodies in contact", redundant manifolds):
// a rigid body resting on a planar obstacle face touches it at many surface vertices
// (a cylinder's cap: 105), a block of rank <= 6 in G on which ADMM converges slowly.
// Among a group of vertex-obstacle contacts of one rigid body's pseudo-nodes on one
// obstacle face (same plane, frame and mu), a contact whose point x_i is a convex
// combination sum_j w_j x_j of the group's extreme points (the convex hull of the
// points in the tangent plane; checked in 3D to 1e-12 of the group's size) is dropped.
// Exact: its constraint value gap_i + h n.(v + omega x (x_i - p)) and its tangential
// velocity are affine in x_i, so they are the same convex combination of the kept
// points' (sigma_N,i >= 0 follows, lambda_i = 0 is complementary), and a force at x_i
// moves to the kept points with weights w_j, with the same wrench and in the same cones.
// The reduced problem's solution, extended by zero forces, solves the full one with
// residuals no larger. Soft contacts and other kinds are untouched. Drops from `list`
// in place (order kept); returns the number dropped (also data.contact.rigid.
// manifold_dropped). No allocation once the scratch has grown.
int reduce_rigid_manifolds(const Model& model, Data& data, std::vector<collision::Contact>& list);

// The rigid rows of H_c^T (6R x 3nc) into data.contact.rigid.Ht, column 3i + c being row
// c of contact i's Jacobian on each body's (v, omega); zero rows for a fixed body.
void rigid_jacobian_transpose(const Model& model, const collision::ContactSet& contacts,
                              const std::vector<rigid::RigidState>& in, MatX& Ht);

// G += h sum_r H_r W_r H_r^T and g += H_r u_free (G: 3nc square, g: 3nc). Each body
// updates only the rows and columns of its own contacts (3 k_r square, not 3nc square).
void add_rigid_delassus(const Model& model, Data& data, double h, MatX& G, VecX& g);

// The sparse backend's rigid rows: Kt = (L_r^T H_r^T) stacked over the bodies with dofs
// and contacts (rank_r rows each: 6 free, 1 hinge/slider), so that
// h sum_r H_r W_r H_r^T = h Kt^T Kt (SparseDelassus::set_rigid), and g += H_r u_free.
// With L limit rows (append_limit_rows before, Ht and g of 3 (nc + L)): Kt has their
// columns too (a limit's normal column L_r^T j couples it with its body's contacts, as
// the dense G), and 2 more rows per limit row, each with one entry |L_r^T j| = 1/sqrt(a)
// on one tangential column: h Kt^T Kt then holds the limit rows' decoupled tangential
// diagonals h / a (finish_limit_rows' on the dense backend).
void rigid_delassus_rows(const Model& model, Data& data, MatX& Kt, VecX& g);

// The bodies' rows alone: Kt = (L_r^T H_r^T) stacked over the bodies (rank_r rows each;
// a body without dofs or contact has none), with the record's columns (rd.Ht's). What
// rigid_delassus_rows starts from; the contact derivative forms it from a dense record
// (ContactStageDerivative::rigid_rows).
void rigid_body_rows(const Model& model, const ContactData::Rigid& rd, MatX& Kt);

// u = u_free + h W H_r^T lambda (data.contact.rigid.u).
void correct_rigid_velocities(const Model& model, Data& data, double h, const VecX& lambda);

// The limit slots of the model (2 per body on a hinge or slider with limits).
int num_limit_slots(const Model& model);

// Selects the limit rows of this solve into data.contact.rigid.limit_rows: a limit whose
// gap at the start of the step is below the detection margin (in the joint coordinate:
// over the farthest surface vertex's distance from a hinge's axis) plus 2 h max(|cdot_n|,
// |cdot_free|), as the speculative margin of the contacts (contact_step.cpp), or every
// limit when `all`. A far limit stays out: its large gap / h would set the NCP's velocity
// scale. Returns L.
int select_limit_rows(const Model& model, Data& data, double h, bool all);

// Before add_rigid_delassus (dense) or rigid_delassus_rows (sparse): extends
// data.contact.rigid.Ht by the L limit rows' columns (3 each: tangential zero, normal j),
// G (3nc square; nullptr on the sparse backend, which has no dense G) and g (3nc) by zero
// rows and columns to 3 (nc + L), and fills rigid.mu_ext. Only rigid.mu_ext when L = 0.
void append_limit_rows(const Model& model, Data& data, int nc, MatX* G, VecX& g);
// After add_rigid_delassus: the limit rows' gap terms (gap / h) and, with a dense G, their
// tangential diagonals (equal to their normal diagonal h / a; decoupled, with mu = 0;
// the sparse backend's are rows of Kt, rigid_delassus_rows).
void finish_limit_rows(const Model& model, Data& data, double h, int nc, MatX* G, VecX& g);
// After correct_rigid_velocities: whether the corrected rates cross a limit that was not
// selected (the contact forces drove the joint further than the speculative margin
// allowed); the caller then solves again with every limit (select_limit_rows(all)).
bool unselected_limit_crossed(const Model& model, const Data& data, double h);
// After the correction: keeps the limits' normal forces in rigid.limit_lambda (by slot)
// and cuts lambda, sigma, modes, G (dense backend), g, rigid.Ht and, on the sparse
// backend (sparse true), rigid.Kt (the limits' columns and tangential rows) back to
// the nc contacts.
void remove_limit_rows(const Model& model, Data& data, int nc, bool sparse = false);

// After the soft step with contact: out = the start poses integrated with the corrected
// velocities (p + h v, exp(h [omega]) q) for every body with dofs when contacts were
// detected; out keeps the free step otherwise. A non-finite result is a non_finite
// status naming the body.
StepStatus end_rigid_contact(const Model& model, Data& data, std::vector<rigid::RigidState>& out, double h,
                             long step_index);

}  // namespace softdiff::contact
