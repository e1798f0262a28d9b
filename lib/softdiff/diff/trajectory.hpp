#pragma once
// Derivatives over a trajectory (method.md "Derivatives", paper section 3): the step's
// JVP and VJP (integrator/implicit_euler_derivatives.hpp) chained over T steps.
//
// theta, the inputs a trajectory is differentiated with respect to, in column order:
//   1. parameters, in the order given (ParameterId: kind and body);
//   2. if `actuation`: one column per actuator, a constant offset added to its value
//      at every step (d/d lambda_a of a constant actuation);
//   3. if `x0`: the initial positions (3n), 4. if `v0`: the initial velocities (3n);
//      with rigid bodies (issue 21) each also has 6 columns per rigid body after them:
//      x0 its position and the rotation vector (world axes) of an orientation change,
//      v0 its velocity and angular velocity;
//   5. rigid parameters (rigid_parameters: mass, inertia components of a rigid body).
// With rigid bodies, the sensitivities' rows are 3n soft coordinates, then 6 per rigid
// body (dx: position, rotation vector; dv: velocity, angular velocity): output.md's
// /jacobians rows. Without contact the rigid rows are propagated by each body's 12 x 12
// step Jacobian (rigid/rigid_derivatives.hpp), decoupled from the soft bodies; the
// adjoint maps their cotangents back by the transposes. With rigid bodies in contact
// (model.contact.with_rigid()) every column goes through the step's JVP with its rigid
// rows (StepTangent::rigid, rigid_p; contact/rigid_contact_derivatives.hpp), and the
// adjoint's VJP returns their cotangents. The rigid parameters' cotangents are summed
// per body over the steps and scattered to theta's columns at the end.
// Per-step actuation values (the whole sequence lambda_a(t_1..t_T)) are inputs of the
// reverse mode (adjoint()), which returns their gradient step by step.
//
// Forward sensitivities: S_x = d x_t / d theta and S_v = d v_t / d theta (3n x k) carried
// step to step: k JVPs per step, each one solve with the step's own factorization.
// Cost: k solves plus k stiffness products from the step's record per step (one sparse
// product with K and, for a dK term, an element pass without SVD:
// fem::add_stiffness_product); memory 2 (3n x k).
//
// Adjoint: a forward pass records the states on a Tape (x and v of every frame, and
// the actuation values of every step: 48 n + 8 n_a bytes per step, n the number of
// nodes, and with contact the NCP's warm start: 56 bytes per contact); the reverse sweep recomputes each step from its recorded input state
// (assembly and factorization, bitwise the same step: element colors fix the
// summation order) and applies its VJP. Cost: about one forward step plus one VJP
// (one solve, one element pass) per step, for any number of inputs.
#include <softdiff/core/parameters.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <softdiff/model.hpp>
#include <softdiff/rigid/rigid_bdf2_derivatives.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>

#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace softdiff::diff {

struct ThetaLayout {
  std::vector<ParameterId> parameters;
  bool actuation = false;
  bool x0 = false, v0 = false;
  // Directions for x0 / v0 (3n x K): empty for all 3n coordinates (the identity),
  // else only these K directions are columns (e.g. random directions for a check).
  MatX x0_basis, v0_basis;
  // Rigid body parameters (their columns come last; issue 21).
  std::vector<rigid::RigidParameterId> rigid_parameters;

  Eigen::Index size(const Model& model) const;
  // Column offsets of each group (parameters first, at 0).
  Eigen::Index actuation_offset() const { return static_cast<Eigen::Index>(parameters.size()); }
  Eigen::Index x0_offset(const Model& model) const;
  Eigen::Index v0_offset(const Model& model) const;
  Eigen::Index rigid_parameter_offset(const Model& model) const;
  // "young[beam]", "actuation[cable1]", "x0", ... one name per group, for reports;
  // then one per rigid parameter: "mass[key]", "inertia[key].xy".
  std::vector<std::string> column_names(const Model& model) const;
};

// Forward sensitivities step by step, for a caller that runs the steps itself (the
// CLI's simulate loop): construct at the initial state, then call advance() after
// every successful implicit_euler_step(model, data, in, out).
class ForwardSensitivity {
 public:
  ForwardSensitivity(const Model& model, ThetaLayout theta);
  // Propagates the columns through the step in -> out (data: that step's record).
  // Returns false if a derivative solve failed.
  bool advance(const Model& model, const Data& data, const State& in, const State& out);
  const ThetaLayout& theta() const { return theta_; }
  const MatX& dx_dtheta() const { return dx_; }  // (3n + 6 n_rigid x k) at the last state
  const MatX& dv_dtheta() const { return dv_; }
  // The step derivative of the last advance() (its contact figures: rank deficiency of
  // the NCP derivative, non-differentiable contacts).
  const integrator::StepDerivatives& step() const { return *step_; }

 private:
  ThetaLayout theta_;
  std::unique_ptr<integrator::StepDerivatives> step_;
  MatX dx_, dv_;
  // (model.rigid) of the last step: implicit Euler's, or BDF2's (rigid_bdf2_derivatives.hpp:
  // the step from the extrapolated state chained with the extrapolation).
  std::vector<rigid::Bdf2StepJacobian> rigid_jacobian_;
  // BDF2 with rigid bodies: the input states of the last advance() (the next step's
  // previous states). The branch each body took is the step's record (data.rigid's bdf2).
  std::vector<rigid::RigidState> previous_rigid_;
  MatX previous_dx_, previous_dv_;  // BDF2: the sensitivities of the previous state
  State previous_state_;            // BDF2 with rigidified parts: the input state of the last advance()
  MatX next_dx_, next_dv_;          // workspace
  integrator::StepTangent t_;
  integrator::StateTangent r_, previous_;
};

// Called after each successful step k (1-based) with the state reached and the
// sensitivities of that state (forward_sensitivities), e.g. to stream them out.
using SensitivityObserver = std::function<void(long k, const State& s, const MatX& dx_dtheta, const MatX& dv_dtheta)>;

// Simulates `steps` steps from `initial` and returns d x_T / d theta and d v_T / d theta
// in dx_dtheta, dv_dtheta (3n x theta.size()). `final` receives the last state. Stops at
// the first failed step (returned) or failed derivative (status solver_failed).
StepStatus forward_sensitivities(const Model& model, Data& data, const State& initial, long steps,
                                 const ThetaLayout& theta, State& final, MatX& dx_dtheta, MatX& dv_dtheta,
                                 const SensitivityObserver& observer = {});

// The states of a trajectory: frames[0] = initial, frames[k] after step k, and the
// actuation values each step used (lambda_a[k-1] for step k).
struct Tape {
  std::vector<State> frames;
  std::vector<VecX> lambda_a;
  // Contact: the NCP warm start each step began with (the previous step's contacts and
  // forces), so that the reverse sweep recomputes every step bit for bit (56 bytes per
  // contact and step).
  struct WarmStart {
    std::vector<std::pair<collision::Contact::Key, int>> keys;
    VecX lambda;
    VecX limit_lambda;  // rigid bodies' joint limits in contact: their forces (by slot)
  };
  std::vector<WarmStart> warm_start;
  // BDF2 with rigid bodies: StepInfo::at_limit of every body after every step (steps x
  // n_rigid, step-major): the next step's restart flag (rigid_bdf2.hpp), which the reverse
  // sweep restores before recomputing a step.
  std::vector<char> rigid_at_limit;
  long steps() const { return static_cast<long>(frames.size()) - 1; }
  std::size_t bytes() const;  // memory held (states and actuation values)
};

// Called after each step that succeeded, before its frame is recorded (data holds the
// step): a status that is not ok stops the recording there, as a failed step does (the
// tape then holds the frames before that step). The Python Rollout counts or refuses
// unconverged contact solves through it.
using AfterStep = std::function<StepStatus(long step, const Data& data)>;

// Runs `steps` steps from `initial`, recording them. actuation: the values of every
// step (steps columns of n_a), or empty for the model's schedules.
StepStatus record(const Model& model, Data& data, const State& initial, long steps, Tape& tape,
                  const MatX& actuation = {}, const AfterStep& after_step = {});

// The loss's direct cotangents: for frame k (0..T, called from T down to 0) and its
// state, ADD dl/dx_k and dl/dv_k into bar_x, bar_v (3n; they hold the cotangent
// propagated back from the later frames, zero at k = T). For a loss of the final
// state only, return early for k < T.
using LossCotangent = std::function<void(long k, const State& s, VecX& bar_x, VecX& bar_v)>;
// The same for the rigid bodies' states (issue 21): ADD dl/d(rigid state of frame k) into
// bar_rigid (12 per rigid body in scene order: position, rotation vector in world axes,
// velocity, angular velocity; the tangent of rigid/rigid_derivatives.hpp).
using RigidLossCotangent = std::function<void(long k, const State& s, VecX& bar_rigid)>;

struct AdjointResult {
  VecX theta;          // dl/d theta (theta.size())
  MatX lambda_a;       // (n_a x T) dl/d lambda_a of every step
  VecX x0, v0;         // dl/dx_0, dl/dv_0 (3n), whether or not theta includes them
  VecX rigid0;         // dl/d(rigid initial states) (12 per rigid body, as RigidLossCotangent)
  // The largest |x|, |v| difference between a recomputed step and the tape's frame:
  // 0 when the sweep recomputes the recorded run bit for bit (it should).
  double recompute_mismatch = 0;
};

// The reverse sweep over a recorded trajectory. Uses data as the workspace of the
// recomputed steps.
// With rigid bodies each step's VJP also maps the rigid cotangents back by the bodies'
// step Jacobians (rigid/rigid_derivatives.hpp), adding the rigid parameters' gradients;
// rigid_loss (optional) gives the loss's rigid cotangents.
StepStatus adjoint(const Model& model, Data& data, const Tape& tape, const ThetaLayout& theta,
                   const LossCotangent& loss, AdjointResult& result, const RigidLossCotangent& rigid_loss = {});

}  // namespace softdiff::diff
