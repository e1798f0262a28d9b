#pragma once
// Inverse dynamics (`softdiff control`, paper section IV-D, docs/method.md "Control"):
// at every step, the actuation change d that brings an effector to its goal, from the
// step's derivative with respect to the actuation (through contact where present).
//
// At step k from state s with the previous actuation lambda:
//   1. the step with lambda gives the free prediction x_f, and the effector's X_f;
//   2. the JVPs of the actuators (the step's factorization; without contact all in one
//      solve with n_a right-hand sides) give J_a = W dx_f/dlambda (W the
//      effector's barycentric rows, S the selected axes) and, with contact, the nodal
//      contact forces' Jacobian J_c = P_body H_c^T dlambda_c/dlambda (P_body: the rows of
//      the effector's body) with F the body's nodal contact forces, over the contacts
//      with other sides (obstacles, other bodies, rigid bodies; not the body's
//      self-contacts, whose forces are internal);
//   3. the QP (optim/box_qp.hpp)
//        min_d  alpha/2 |S (X_f + J_a d - X_goal)|^2 + beta/2 |F + J_c d|^2 + rho/2 |d|^2
//        s.t.   lo - lambda <= d <= hi - lambda   (the actuators' limits)
//      rho = regularization * (alpha |S J_a|_F^2 + beta |J_c|_F^2) / n_a (relative, so it
//      needs no units; it also makes an over-actuated robot's QP strictly convex);
//   4. lambda' = lambda + filter d (a first-order low-pass on the change, 0 < filter <= 1;
//      lambda' stays within the limits: a convex combination of feasible points).
// The caller then takes the step with lambda'.
// Rigid bodies (issue 21; docs/method.md "Control", "Through contact with rigid bodies"):
// their state is an input of the step, not controlled: the JVPs carry a zero rigid
// tangent in and go through the one NCP with the rigid blocks, so J_a and J_c see the
// rigid bodies' response (an object pushed or held by the effector's body). The caller
// refuses what the step's derivative does not cover (app/theta.cpp: BDF2 with rigid
// bodies, a limited joint in contact, rigidified parts beyond implicit Euler with one
// Newton iteration on the dense backend). Rigidified parts: J_a by one jvp() per
// actuation column (the reduced step's tangent with the parts' placement).
#include <softdiff/core/types.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <softdiff/model.hpp>

#include <array>
#include <memory>

namespace softdiff::optim {

struct ControlOptions {
  int effector = 0;                  // index into model.actuation.effectors
  std::array<bool, 3> axes{true, true, true};  // controlled directions of the goal
  double alpha = 1;                  // weight of the goal term
  double beta = 0;                   // weight of the contact-force term
  double regularization = 1e-6;      // relative weight of |d|^2
  double filter = 1;                 // low-pass factor on the change
  // One change for every actuator (d = s 1, s scalar): a symmetric robot controlled for
  // one side, as the paper's gripper ("we can write this problem for one finger and
  // apply the result to both"); one JVP per step instead of n_a.
  bool shared = false;
};

struct ControlStep {
  Vec3 predicted = Vec3::Zero();     // X_f: the effector after the step with the previous actuation
  VecX delta;                        // the QP's solution d
  double contact_force_norm = 0;     // |F| of the prediction (N)
  double kkt = 0;                    // the QP's KKT residual
  int qp_iterations = 0;
  bool qp_converged = false;
  // The QP's data (kept for the finite-difference tests; sized per step, not per
  // contact): J_a (3 x nd, before the axis selection), and with contact and beta > 0
  // the body's nodal contact forces F (3 n_body) and their Jacobian J_c (3 n_body x nd).
  Eigen::Matrix<double, 3, Eigen::Dynamic> Ja;
  VecX F;
  MatX Jc;
};

class InverseDynamics {
 public:
  InverseDynamics(const Model& model, const ControlOptions& options);
  // The actuation of step k (1-based) from state s, given the previous actuation
  // (n_a). Returns the prediction step's status (not ok: lambda_out unset).
  // history: the state before s (BDF2, k > 1; ignored by implicit Euler).
  StepStatus compute(const Model& model, const State& s, long k, const Vec3& goal, const VecX& previous, VecX& lambda_out,
                     ControlStep& info, const State* history = nullptr);
  // The nodal contact force norm of the effector's body for a step's record (N).
  double contact_force_norm(const Model& model, const Data& data) const;
  // The record the prediction steps with. Committing the step through it (time_step
  // with lambda_out from the same state) reuses the prediction's linearization and
  // factorization: one factorization per control step (linearized steps; Newton
  // iterates refactorize).
  Data& data() { return data_; }
  // P_body H_c^T lambda over the contacts with other sides (obstacles, other bodies,
  // rigid bodies: a rigid body is another side, e.g. the object a gripper holds): a
  // body's self-contact forces are internal (action and reaction on its own nodes) and
  // act on nothing it holds. H_c^T's soft rows only (a rigid body's pseudo-nodes are not
  // in it): the forces on the effector's body's nodes (3 n_body).
  VecX nodal_contact_forces(const Data& data, const VecX& lambda) const;

 private:
  ControlOptions options_;
  Data data_;
  std::unique_ptr<integrator::StepDerivatives> derivatives_;
  State prediction_;
  MatX directions_, dx_columns_;  // (n_a x nd) the actuation tangents, (3n x nd) their dx_f
  VecX column_;                   // (3n) one column of dx_columns_
  VecX lo_, hi_;
  int body_begin_ = 0, body_nodes_ = 0;
};

}  // namespace softdiff::optim
