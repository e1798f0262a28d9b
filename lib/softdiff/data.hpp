#pragma once
// Data: the preallocated workspace of a step and the record its derivative needs.
// Sized once by Data::Data(model); no allocation per step afterwards.
#include <softdiff/collision/contact_set.hpp>
#include <softdiff/collision/detection.hpp>
#include <softdiff/contact/ncp.hpp>
#include <softdiff/contact/sparse_delassus.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/model.hpp>

#include <cstdint>
#include <memory>
#include <string>
#include <utility>

namespace softdiff {

// Outcome of a step or a static solve. Never thrown from the inner loop: the
// caller turns it into a message and an exit code.
struct StepStatus {
  enum class Code { ok, inverted_element, not_positive_definite, non_finite, diverged, not_converged, solver_failed,
                    contact_not_converged };
  Code code = Code::ok;
  long step = -1;        // 1-based step (static: load step) where it happened
  int element = -1;      // global element index, if one is concerned
  int dof = -1;          // global dof, if one is concerned
  double value = 0;      // det F, residual, displacement, ...
  int iterations = 0;    // Newton iterations used
  double residual = 0;   // final relative residual (Newton / static)
  std::string detail;
  bool ok() const { return code == Code::ok; }
};

// Wall time of the last step, by stage (seconds). Contact: detection, Delassus
// (H_c, G, g), NCP solve (with polish), correction (one more solve).
struct StepTimings {
  double assembly = 0, factorization = 0, solve = 0, other = 0;
  double detection = 0, delassus = 0, ncp = 0, correction = 0;
  double contact() const { return detection + delassus + ncp + correction; }
  double total() const { return assembly + factorization + solve + other + contact(); }
  StepTimings& operator+=(const StepTimings& o) {
    assembly += o.assembly; factorization += o.factorization; solve += o.solve; other += o.other;
    detection += o.detection; delassus += o.delassus; ncp += o.ncp; correction += o.correction;
    return *this;
  }
};

// The contact stage's record of the last step (docs/method.md "Contact"). nc is
// the number of contacts of that step; every field is written by
// contact::resolve_contacts().
struct ContactData {
  std::unique_ptr<collision::CollisionDetector> detector;  // built once (model.contact.enabled)
  collision::ContactSet contacts;   // (nc) detected at x_i, with frames, gaps, features
  collision::DetectionStats stats;
  double margin = 0;                // detection margin of the step: the largest of surface_margin
  std::vector<double> surface_margin;  // per detection surface: max(margin, 2 h max|v| over its vertices)
  SparseMatrix Ht;                  // (3n, 3nc) H_c^T, projected (no fixed dof)
  MatX G;                           // (3nc, 3nc) Delassus h H_c A^{-1} H_c^T (dense backend; empty on the sparse one)
  contact::SparseDelassus sparse;   // the same as an operator (sparse backend, NcpResult::sparse)
  VecX g;                           // (3nc) H_c v_free + (0, 0, phi_i / h) (+ slip_offset)
  // static.friction: load_step (integrator/static_solver.cpp): per contact the tangential
  // slip of its points since the load step's start, (t1, t2, 0) . sum_k w_k (X_k - X_k^start),
  // added to g by solve_contact_problem when sized 3nc (set after detection, per iteration).
  VecX slip_offset;
  VecX mu;                          // (nc)
  VecX lambda;                      // (3nc) contact forces (N) in each frame (t1, t2, n)
  VecX sigma;                       // (3nc) G lambda + g: contact velocities
  std::vector<contact::Mode> modes; // (nc)
  contact::NcpResult result;        // iterations, residuals, converged, polished
  contact::NcpSolver solver;        // workspace (grows only)
  VecX v_free;                      // (3n) v_i + A^{-1}(b + h H_a^T lambda_a)
  VecX correction;                  // (3n) h A^{-1} H_c^T lambda_c
  VecX rhs;                         // (3n) scratch
  // Warm start: the previous step's contacts (by key) and forces.
  std::vector<std::pair<collision::Contact::Key, int>> previous_keys;  // sorted (key, index into previous_lambda)
  VecX previous_lambda;
  // The record's serial number: a new one, unique in the process (contact::
  // next_record_serial), each time the contact stage writes the record (detection, the
  // NCP solve, the rigid bodies' correction; a Tape replay recomputes the step through
  // them): a derivative that prepared its maps for one record knows in O(1) whether
  // the record changed since (integrator::StepDerivatives::prepare_rigid).
  std::uint64_t serial = 0;
  // Rigid bodies in the contact stage (contact/rigid_contact.hpp; model.contact.with_rigid()).
  struct Rigid {
    VecX x, v_previous, v_free;            // (3 (n + pseudo-nodes)) extended positions/velocities for detection
    std::vector<rigid::RigidState> in;     // (R) poses and velocities at the start of the step
    std::vector<rigid::RigidState> free;   // (R) the free step's end states (their derivative: rigid_contact_derivatives.hpp)
    VecX u_free, u;                        // (6R) (v, omega) per body, world: after the free step; corrected
    std::vector<rigid::Mat6> W;            // (R) T (T^T A_r T)^{-1} T^T: velocity change per impulse (0: fixed)
    MatX Ht;                               // (6R, 3nc) the rigid bodies' rows of H_c^T
    std::vector<rigid::Mat6> L;            // (R) W = L L^T; its first rank columns (6 free, 1 joint, 0 fixed)
    std::vector<int> rank;                 // (R) L's nonzero columns
    MatX Kt;                               // (k, 3nc) L^T H_r^T of the bodies in contact (sparse backend)
    std::vector<int> dofs;                 // scratch: the contact rows of one body (add_rigid_delassus)
    MatX Kc, Gc;                           // scratch: L^T H_r^T on those rows, its h K^T K
    // The manifold reduction (rigid_contact.hpp reduce_rigid_manifolds): scratch (grows
    // only) and the contacts it dropped in the last detection.
    std::vector<int> manifold, hull;       // candidate contacts of a group; their convex hull
    std::vector<double> plane;             // (2 per candidate) coordinates in the tangent plane
    std::vector<char> drop;                // (contacts) dropped by the reduction
    int manifold_dropped = 0;
    // Joint limits as rows of the NCP (rigid_contact.hpp "limit rows"): 2 slots per body on
    // a limited hinge or slider (lower, upper, in body order); the L selected ones are
    // frictionless contacts of 3 rows appended after the nc contacts while the NCP is solved.
    struct LimitRow {
      int body = 0, side = 0, slot = 0;    // side 0: lower, 1: upper
    };
    std::vector<LimitRow> limit_rows;      // (L) this solve's rows
    VecX mu_ext;                           // (nc + L) the contacts' mu, then 0 per limit row
    VecX limit_lambda;                     // (slots) each limit's reaction of the last solve (N m or N; 0 unselected)
  } rigid;
};

struct Data {
  explicit Data(const Model& model);

  // Back to the state of a fresh Data(model) for a new run of the same scene (the same
  // mesh, pattern, solver and contact settings) whose parameter values may have
  // changed (calibration's workspace, optim/calibration.hpp): keeps the buffers, the
  // linear solver with its symbolic analysis (the pattern does not depend on the
  // values) and the contact detector; forgets what a run leaves behind (the factor,
  // which a constant system matrix would otherwise keep, the linearization record, the
  // contact records, warm start, NCP workspace and sparse Delassus pattern).
  // detection_changed: the pair rules' friction changed (the detector holds a copy of
  // the rules; it is rebuilt). keep_linearization, a setting of the owner, is kept.
  void restart(const Model& model, bool detection_changed);

  fem::FemData fem;                 // record of the FEM stage at the last evaluation: x_i for the
                                    // linearized step, the last Newton iterate otherwise
  VecX K_i_values;                  // (nnz) K(x_i), kept for damping when newton_iterations > 1
  SparseMatrix A;                   // (3n, 3n) upper: A = M + h D + h^2 K, projected; written by the step
  VecX rhs;                         // (3n) right-hand side of the last solve (projected)
  VecX dv;                          // (3n) solution of the last solve
  VecX Mv, Kv, Mvi;                 // (3n) scratch: M v, K v, M v_i
  VecX lambda_a;                    // (n_a) actuation values used by the last step (at t_i + h)
  VecX f_act;                       // (3n) H_a(x_i)^T lambda_a of the last step (unprojected, without h)
  VecX x_iter, v_iter;              // (3n) Newton iterates
  std::unique_ptr<integrator::LinearSolver> solver;
  bool analyzed = false;            // symbolic factorization done (once per scene)
  bool factor_is_current = false;   // the factor matches A (constant matrices are factorized once)
  double A_h = 0;                   // the h data.A was assembled with (assemble_system_matrix)
  // Reuse of one linearization by the next step from the same positions (control: the
  // prediction and the committed step differ only in the actuation, which enters the
  // right-hand side). When keep_linearization is set, a linearized step (one Newton
  // iteration) records the x it evaluated K, f_int and A's factor at; the next step from
  // the same x and h keeps all three.
  bool keep_linearization = false;
  VecX linearized_x;                // (3n) the x of the record, when keep_linearization
  // The step's effective input (integrator/bdf2.hpp): the last step is the implicit
  // Euler step of size h from hat = (1 + c) in - c previous, c = history_weight:
  // implicit Euler h = dt, c = 0 (hat = in); BDF2 after its first step h = 2 dt / 3,
  // c = 1/3. Written by the step, read by its derivatives.
  double h = 0;
  double history_weight = 0;
  State hat;                        // (3n) x, v; t = t_i
  int newton_iterations_used = 0;
  double newton_residual = 0;
  VecX static_load_step_start;       // (3n) solve_static: x at the start of the last load step (the
                                    // static contact derivative's slip over that load step)
  // solve_static: the extended positions at the start of the last load step (3 (n +
  // pseudo-nodes): soft x, then the rigid bodies' surface vertices posed; static.friction
  // load_step's slip of a rigid point).
  VecX static_load_step_start_extended;
  int static_shifted_iterations = 0;  // solve_static: Newton iterations of the last solve whose
                                      // tangent was shifted (A + tau I: A not positive definite)
  ContactData contact;              // contact stage (model.contact.enabled)
  std::vector<rigid::StepInfo> rigid;  // (model.rigid) the last step of each rigid body: limit, joint reaction
  integrator::RigidifyData rigidify;  // (model.rigidify) the step's reduced-mapping workspace
  StepTimings timings;              // of the last step
  long factorizations = 0;          // count over the run
};

// Human-readable one-line description of a failed status (names the model's body,
// element, node as the user sees them).
std::string describe(const Model& model, const StepStatus& status);

}  // namespace softdiff
