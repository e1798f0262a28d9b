#pragma once
// Material identification (`softdiff calibrate`, docs/method.md "Calibration"): the
// parameters p of a scene that make its simulated motion match observations, by
// Levenberg-Marquardt on the residual r(p) with the exact Jacobian dr/dp from forward
// sensitivities (diff/trajectory.hpp).
//
// Observations (a CalibrationTarget):
//   - states: the positions of every node at chosen frames (a softdiff trajectory);
//     r = x_k(p) - x_k* stacked over the frames;
//   - markers: positions of embedded points (in one tet each, as a
//     motion-capture marker glued to the body) at chosen frames; r = W x_k(p) - y*;
//     or points fixed on a rigid body (issue 21): r = p_k + R(q_k) b - y*.
//   - rigid bodies' poses (issue 21), with states or alone: per matched rigid body and
//     frame, r = (p_k - p*, L log(q_k q*^-1)): the centre of mass's offset (m) and the
//     rotation vector (world axes) of the orientation error times a length L (m),
//     rigid_orientation_length: the body's RMS distance of its mass from its centre.
// Static scenes have one frame, the equilibrium (frame = the last load step).
//
// Unknowns are reparametrized so that every iterate is valid: log for young, density,
// the Rayleigh factors and friction (> 0), and poisson = 0.5 / (1 + exp(-z)) in (0, 0.5);
// log for a rigid body's mass and diagonal inertia components (issue 21; they come after
// the soft parameters in the values).
// The Levenberg-Marquardt is Eigen's (unsupported/Eigen/LevenbergMarquardt, the MINPACK
// lmder port: Moré's trust-region damping with column scaling), stopped on the relative
// cost reduction (ftol), the relative step (xtol) or the gradient (gtol, the cosine
// between r and the columns of J), whichever comes first; a trial step already below
// xtol (|D dz| <= xtol |D z|) is not run: the calibration stops at the current point
// (docs/method.md "Calibration", the step test); every function evaluation is
// one simulation with its sensitivities (the Jacobian of an accepted point is the one
// computed with its residual). A trial step whose run fails (parameters the simulation
// cannot run, e.g. an element inverts) is rejected like a step that raises the cost:
// the damping grows and the iteration goes on (counted in CalibrationIteration::failed).
#include <softdiff/core/parameters.hpp>
#include <softdiff/core/types.hpp>
#include <softdiff/actuation/embedding.hpp>
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>

#include <array>
#include <functional>
#include <string>
#include <vector>

namespace softdiff::optim {

// An embedded point: sum_a w[a] x_{nodes[a]} (global node indices; 4 nodes with
// barycentric weights in a linear tet, 10 with the quadratic shape functions in a
// quadratic one).
// On a rigid body (issue 21): rigid_body >= 0 (Model::rigid index) and the point in
// its body axes relative to its centre of mass, p + R(q) body_point (`point` unused).
struct Marker {
  std::string name;
  actuation::EmbeddedPoint point;
  int rigid_body = -1;
  Vec3 body_point = Vec3::Zero();
};

struct CalibrationTarget {
  // Frames (0 .. steps, increasing; for a static scene: the last load step) and, per
  // frame, what is observed there.
  std::vector<long> frames;
  // States: the whole 3n positions per frame (empty when markers are used).
  std::vector<VecX> states;
  // Markers: observations (frame index into `frames`, marker index, position).
  std::vector<Marker> markers;
  struct Observation {
    int frame = 0;
    int marker = 0;
    Vec3 position = Vec3::Zero();
  };
  std::vector<Observation> observations;
  // Rigid bodies' poses (issue 21; with states, or alone: then states is empty and only
  // these rows are matched; not with markers, which may be on rigid bodies themselves:
  // Marker::rigid_body): 6 rows per matched body and frame,
  // after the frame's 3n soft rows.
  struct RigidPoses {
    int body = 0;       // Model::rigid index
    double length = 0;  // L (m): the orientation rows are L log(q q*^-1) (rigid_orientation_length)
    std::vector<Vec3> position;                   // per frame (of `frames`)
    std::vector<Eigen::Quaterniond> orientation;  // per frame, unit
  };
  std::vector<RigidPoses> rigid;
  long steps() const { return frames.empty() ? 0 : frames.back(); }
  Eigen::Index residual_size() const;
};

// The reparametrization of a parameter kind: value = from_internal(z).
double to_internal(Parameter kind, double value);
double from_internal(Parameter kind, double z);
double dvalue_dinternal(Parameter kind, double z);

// The length of a rigid body's orientation rows: L = sqrt(tr(I) / (3 m)) of its mass m
// and inertia I (pass the scene's, not the calibrated values: L is a constant of the
// target). For the orientation error delta (rotation vector), L^2 |delta|^2 is the mean
// over directions of delta^T (I / m) delta, the body's mass-averaged squared point
// displacement: a rotation is weighted as the motion of its points (docs/method.md
// "Calibration"). A cube of side a: L = a / sqrt(6).
double rigid_orientation_length(const rigid::RigidBody& body);

struct CalibrationOptions {
  int max_iterations = 50;  // Levenberg-Marquardt iterations (Jacobian evaluations)
  double ftol = 1e-12;      // relative reduction of the cost
  double xtol = 1e-10;      // relative step in the internal coordinates
  double gtol = 0;          // cosine between r and J's columns (0: off)
  bool strict = false;      // a contact solve that misses its tolerance is an error
  // Called as every run starts (step 0) and after each of its steps (load steps of a
  // static scene), with the run's number (1-based, counting every simulation) and its
  // steps: a progress display.
  std::function<void(int run, long step, long steps)> on_step;
};

struct CalibrationIteration {
  int iteration = 0;
  std::vector<double> values;  // the parameters (physical units)
  double cost = 0;             // 1/2 |r|^2
  double gradient_norm = 0;    // |J^T r| in the physical parameters
  double damping = 0;          // the Levenberg-Marquardt parameter
  double seconds = 0;          // wall time since the start
  int evaluations = 0;         // simulations so far
  int rejected = 0;            // trial steps rejected in this iteration (the cost did not drop
                               // enough, or the trial's run failed)
  int failed = 0;              // of these, trial steps whose run failed (e.g. an inverted element)
  std::string last_failure;    // the last such failure's message (empty if none)
};

struct CalibrationResult {
  std::vector<double> values;
  bool converged = false;
  std::string stop_reason;
  int iterations = 0;
  int evaluations = 0;
  int rejected = 0;  // trial steps rejected over all iterations
  int failed = 0;    // of these, trial steps whose run failed
  double cost = 0;
  std::vector<CalibrationIteration> history;  // iteration 0 = the initial guess
};

// Residual r(p) and dr/dp (rows: the target's, columns: the parameters) of `model`
// with the parameters set to `values`. Throws ComputationError if the run fails (with
// the step and the reason) or, with strict, if a contact solve misses its tolerance.
// on_step: called with (0, steps) first, then after each step (load step) with (step, steps).
// One run on a fresh copy of the model and a fresh Data; calibrate() runs on one
// CalibrationWorkspace.
void residual(const Model& model, const std::vector<ParameterId>& parameters, const std::vector<double>& values,
              const CalibrationTarget& target, bool strict, VecX& r, MatX& J,
              const std::function<void(long step, long steps)>& on_step = {});
// With rigid bodies' parameters (issue 21): values holds the soft parameters' then the
// rigid ones' (J's columns in that order).
void residual(const Model& model, const std::vector<ParameterId>& parameters,
              const std::vector<rigid::RigidParameterId>& rigid_parameters, const std::vector<double>& values,
              const CalibrationTarget& target, bool strict, VecX& r, MatX& J,
              const std::function<void(long step, long steps)>& on_step = {});

// The runs of a calibration on one workspace: a copy of the model whose parameter
// values are changed in place before each run (diff::restore_parameter then
// diff::set_parameter: only what a parameter change invalidates - the Lame constants,
// the masses and gravity forces for density, ...), and one Data kept across the runs
// (Data::restart: its buffers and the linear solver's symbolic analysis stay; the
// pattern does not depend on the values). residual() gives the same r and J, bit for
// bit, as the free residual() below on a fresh copy of the model and a fresh Data
// (tests/optim/test_calibration_workspace.cpp). The workspace refers to `model`, which
// must outlive it.
class CalibrationWorkspace {
 public:
  CalibrationWorkspace(const Model& model, std::vector<ParameterId> parameters,
                       std::vector<rigid::RigidParameterId> rigid_parameters = {});
  // As the free residual() (the same arguments, the same exceptions).
  void residual(const std::vector<double>& values, const CalibrationTarget& target, bool strict, VecX& r, MatX& J,
                const std::function<void(long step, long steps)>& on_step = {});
  // The model with the values of the last residual().
  const Model& model() const { return model_; }
  // The runs so far.
  int runs() const { return runs_; }
  // The record of the last run (e.g. its factorizations: one per step of a linearized
  // scene, the sensitivities using the step's own).
  const Data& data() const { return data_; }

 private:
  const Model& base_;
  std::vector<ParameterId> parameters_;
  std::vector<rigid::RigidParameterId> rigid_parameters_;
  bool friction_ = false;  // a parameter is a friction coefficient (the detector is rebuilt)
  Model model_;
  Data data_;
  int runs_ = 0;
};

using IterationCallback = std::function<void(const CalibrationIteration&)>;

// Levenberg-Marquardt from `initial`. Throws ComputationError if a run fails.
CalibrationResult calibrate(const Model& model, const std::vector<ParameterId>& parameters,
                            const std::vector<double>& initial, const CalibrationTarget& target,
                            const CalibrationOptions& options, const IterationCallback& callback = {});
// With rigid bodies' parameters (issue 21): initial and the result's values hold the soft
// parameters' then the rigid ones'.
CalibrationResult calibrate(const Model& model, const std::vector<ParameterId>& parameters,
                            const std::vector<rigid::RigidParameterId>& rigid_parameters,
                            const std::vector<double>& initial, const CalibrationTarget& target,
                            const CalibrationOptions& options, const IterationCallback& callback = {});

}  // namespace softdiff::optim
