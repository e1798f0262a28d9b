#pragma once
// The contact stage of the step (docs/method.md "Contact", paper eq. 2), between
// the free solve and the final update:
//   1. collision detection at x_i (contacts with frames, gaps, Jacobian weights);
//   2. H_c^T (3n x 3nc, projected on the free dofs), the Delassus matrix
//      G = h H_c A^{-1} H_c^T from the step's factorization (LinearSolver::
//      inverse_congruence), g = H_c v_free + (0, 0, phi_i / h);
//   3. the NCP (ADMM or PGS, then polish), warm-started from the previous step's
//      forces of the same contacts (same kind, sides and nodes);
//   4. the correction v_f = v_free + h A^{-1} H_c^T lambda_c (one more solve).
// With no contact detected, v_f = v_free and nothing else runs.
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

namespace softdiff::contact {

// v: in, v_free; out, v_f. Returns not ok for a failed solve. A contact solve that
// misses its tolerance is not a failure here: data.contact.result.converged tells
// (the caller warns, or stops with --strict).
// h: the step's effective size (dt for implicit Euler, 2 dt / 3 for BDF2, whose
// positions are x_f = x^ + h v_f with x^ = 4/3 x_n - 1/3 x_{n-1}; `in` is then the
// state (x^, v^)): the scale of G = h H A^{-1} H^T, of the correction and of the gap
// term phi / h.
StepStatus resolve_contacts(const Model& model, Data& data, const State& in, VecX& v, long step_index, double h);

// The same stage for any linearized problem A u = b with contact forces entering as
// h H_c^T lambda_c: detection at x (margin widened to 2 h max|u| over v_previous and
// the free solution v; v_previous only when free_motion_widens is false),
// G = h H A^{-1} H^T, g = H v + (0, 0, phi_i / h), the NCP, and v <- v + h A^{-1} H^T
// lambda. The dynamic step is (x_i, v_i, dt, true); the static solver's Newton
// iteration is (x_k, the previous corrected increment, 1, false) with v the increment
// dx (docs/method.md "Static equilibrium": its free increment includes the rigid
// motion of a body held by contact alone, which must not widen the margin).
StepStatus resolve_contacts(const Model& model, Data& data, const VecX& x, const VecX& v_previous, double h, VecX& v,
                            long step_index, bool free_motion_widens);

// The two halves of the stage above (resolve_contacts is detect_contacts then
// solve_contact_problem), for a Newton loop that detects once and solves the contact
// problem of every iteration on the same contacts (docs/method.md "Newton iterations
// with contact"):
// detect_contacts: detection at x with the widened margin (as above), the contact set,
// H_c^T and mu into data.contact.
void detect_contacts(const Model& model, Data& data, const VecX& x, const VecX& v_previous, double h, const VecX& v,
                     bool free_motion_widens);
// A new contact record serial number (ContactData::serial), unique in the process
// (an atomic counter): every function above that writes data.contact takes one.
std::uint64_t next_record_serial();

// An empty contact record: no contact, a trivially converged solve, no warm start (a
// step or load step without contacts, and the start of a static solve).
void clear_contact_record(ContactData& cd);

// solve_contact_problem: on data.contact's contacts and H_c^T and the current
// factorization of data.A: G = h H A^{-1} H^T (or its operator), g = H v + (0, 0,
// phi_i / h), the NCP warm-started from the last solve's forces of the same contacts,
// and v <- v + h A^{-1} H^T lambda. v: in, the free velocity; out, corrected.
StepStatus solve_contact_problem(const Model& model, Data& data, double h, VecX& v, long step_index);

// H_c^T (3n x 3nc) of a contact set: column 3i+r is row r of H_i = C_i^T sum_k w_k E_k,
// with the fixed dofs' rows removed (H_c <- H_c Pi).
void contact_jacobian_transpose(const Model& model, const collision::ContactSet& contacts, SparseMatrix& Ht);

}  // namespace softdiff::contact
