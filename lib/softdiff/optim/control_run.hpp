#pragma once
// `softdiff control` as a library call (docs/cli.md "control"; moved here from
// app/cmd_control.cpp on 2026-12-04, branch pycal, so that the CLI and the Python
// module's softdiff.control() share one option parser, one goal-file reader, one set of
// messages and one per-step controller): the options with the CLI's names and
// defaults, their checks (InputError with the CLI's message, exit 2), the goals
// (--target X,Y,Z or a CSV of timed goals), and ControlRun: the actuation of each step
// (the CLI's RunHooks::actuation) and what each written frame records (RunHooks::frame:
// the goal, the distance over the controlled axes, the contact force norm, the KKT
// residual), with the summary the CLI prints and writes in --json.
// run_control() steps the scene as `softdiff simulate` does (app/cmd_simulate.cpp's
// simulate_model: integrator::time_step with the previous state for BDF2, the same
// non-convergence policy, a frame every output.every steps and at the last) without
// writing a file (the Python module); the CLI runs the same hooks inside simulate_model.
#include <softdiff/io/run_output.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/control.hpp>

#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace softdiff::optim {

// The options of `softdiff control` the run depends on (the CLI's names, dashes as
// underscores, and defaults; -o, --force, --threads, --quiet, --json are the caller's).
struct ControlRunOptions {
  std::string scene;             // the scene file
  std::vector<std::string> set;  // --set KEY=VALUE, in order
  std::string target;            // --target X,Y,Z | GOALS.csv
  std::string effector;          // --effector NAME | BODY.NAME (empty: the scene's first)
  std::optional<long> steps;     // --steps (default: the scene's)
  std::string weights = "1,0";   // --weights ALPHA,BETA
  std::string axes = "xyz";      // --axes
  double regularization = 1e-6;  // --regularization
  double filter = 1;             // --filter
  bool shared = false;           // --shared-actuation
  bool max_actuation = false;    // --max-actuation
  bool strict = false;           // --strict
};

using ControlMessageSink = std::function<void(const std::string&)>;

// Goals over time: piecewise linear between the given times, constant outside.
struct Goals {
  std::vector<double> times;
  std::vector<Vec3> points;
  Vec3 at(double t) const;
};
// --target X,Y,Z or a CSV file `time,x,y,z`; InputError with the CLI's messages.
Goals parse_goals(const std::string& target);

struct ControlProblem {
  io::SceneDesc scene;
  Model model;
  ControlOptions options;
  std::vector<std::string> effector_names;  // BODY.NAME of every effector of the scene
  Goals goals;
};

// The CLI's checks in its order: the scene (--set, --steps; io::build_model's warnings to
// `warn`), its integrator, actuators, the step's derivative, effectors, --effector,
// --weights, --axes, --filter, --target. Throws InputError (the CLI's message).
ControlProblem prepare_control(const ControlRunOptions& o, const ControlMessageSink& warn);

// What `control --json` reports (docs/cli.md), but its file name and wall time.
struct ControlSummary {
  long steps = 0;
  std::string effector;
  double final_distance = 0, min_distance = 0, kkt_max = 0;
  long qp_not_converged_steps = 0;
  bool within_limits = true;
  std::vector<double> actuation_final;
  double control_seconds = 0;  // in the controller (the QP and its JVPs)
};

// The controlled run's per-step and per-frame logic on one problem (which must outlive
// it): one InverseDynamics, the previous actuation (the scene's at t = 0 within the
// limits), BDF2's history as the hook saw it.
class ControlRun {
 public:
  // Throws InputError for --max-actuation with an actuator without limits.
  ControlRun(const ControlProblem& problem, bool max_actuation);
  // The actuation of step k (1-based) from state s (RunHooks::actuation).
  StepStatus actuation(long k, const State& s, VecX& lambda);
  // A written frame (RunHooks::frame; first: frame 0): sets frame().
  struct Frame {
    Vec3 goal = Vec3::Zero();
    double distance = 0;     // over the controlled axes (m)
    double force_norm = 0;   // the effector body's nodal contact forces (N; 0 at frame 0 or without contact)
    double kkt = 0;          // the last QP's KKT residual (0 at frame 0)
  };
  void observe(const State& s, const Data& data, bool first);
  const Frame& frame() const { return frame_; }
  // The actuation last applied (n_a): /control/actuation's row.
  const VecX& applied() const { return previous_; }
  // The record to step with (RunHooks::data: the committed step reuses the prediction's
  // factorization).
  Data& data() { return controller_.data(); }
  ControlSummary summary() const;

 private:
  const ControlProblem& problem_;
  bool max_actuation_;
  InverseDynamics controller_;
  VecX previous_;
  State history_state_, history_next_;
  long history_step_ = 0;
  Frame frame_;
  double kkt_max_ = 0, control_seconds_ = 0, distance_ = 0, min_distance_ = 0, last_kkt_ = 0;
  long steps_done_ = 0, qp_failures_ = 0;
  bool limits_ok_ = true;
};

// The result of run_control: the summary, the frames' records (every output.every steps
// and the last, frame 0 first, as the CLI's /control series) and the run's end.
struct ControlRunResult {
  ControlSummary summary;
  std::vector<double> times;
  std::vector<ControlRun::Frame> frames;
  std::vector<VecX> actuation;  // per frame: the actuation applied (frame 0: the initial)
  long newton_not_converged_steps = 0, contact_not_converged_steps = 0;
  double run_seconds = 0;
};

// Steps the problem's scene under control as simulate_model does (without a file).
// warn: the first Newton and the first contact non-convergence (not strict; the CLI's
// texts). A failed step (or with strict a non-converged solve) throws ComputationError
// with describe(model, status), the CLI's message.
ControlRunResult run_control(const ControlProblem& problem, bool max_actuation, bool strict, const ControlMessageSink& warn);

// -o: the file to write (output, or <scene stem>_control.h5), refused (InputError, the
// CLI's message) when it is one of the inputs (the scene's files, a CSV of goals).
std::string control_output_path(const ControlRunOptions& o, const std::string& output, const io::SceneDesc& scene);

// The hooks of the run that writes control's file (io::OutputRun; since 2026-12-04,
// branch pyout, shared by the CLI and softdiff.control(output=...)): run's actuation at
// each step, its record (one factorization per step), and the /control series (goal,
// distance, actuation, contact_force_norm with contact, kkt_residual) at each frame.
// `problem` and `run` must outlive the hooks; on_frame (optional) is called after each frame's rows.
io::RunHooks control_output_hooks(const ControlProblem& problem, ControlRun& run,
                                  std::function<void(const State& s)> on_frame = {});

}  // namespace softdiff::optim
