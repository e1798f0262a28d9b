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
// at the start of the step, u_free = T cdot_free; the pose moves along the joint. A joint
// with limits is refused with contact (issue 21).
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

namespace softdiff::contact {

// Appends each rigid body's surface (pseudo-nodes after the soft nodes) to
// model.contact.detection's surfaces and names, and fills rigid_node_begin/body. Call
// after the soft bodies' surfaces and before the obstacles' names (names: soft bodies,
// rigid bodies, obstacles). Nothing without rigid bodies.
void add_rigid_surfaces(Model& model);

// Before the soft step: records the rigid bodies' start states and free velocities
// (`free`: rigid::step without contact, from `in`) and each body's W_r.
void begin_rigid_contact(const Model& model, Data& data, const std::vector<rigid::RigidState>& in,
                         const std::vector<rigid::RigidState>& free);

// Extended positions and velocities for detection: data.contact.rigid.{x, v_previous,
// v_free} = the soft x, v_previous, v_free followed by the pseudo-nodes' (posed at
// the start of the step; velocities from the start and the free step).
void extend_for_detection(const Model& model, Data& data, const VecX& x, const VecX& v_previous, const VecX& v_free);

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
void rigid_delassus_rows(const Model& model, Data& data, MatX& Kt, VecX& g);

// u = u_free + h W H_r^T lambda (data.contact.rigid.u).
void correct_rigid_velocities(const Model& model, Data& data, double h, const VecX& lambda);

// After the soft step with contact: out = the start poses integrated with the corrected
// velocities (p + h v, exp(h [omega]) q) for every body with dofs when contacts were
// detected; out keeps the free step otherwise. A non-finite result is a non_finite
// status naming the body.
StepStatus end_rigid_contact(const Model& model, Data& data, std::vector<rigid::RigidState>& out, double h,
                             long step_index);

}  // namespace softdiff::contact
