// softdiff control SCENE.yaml: inverse dynamics, driving an effector to a goal by
// the per-step QP on the actuation change (docs/cli.md; optim/control.hpp). The options'
// checks, the goals and the per-step controller are the library's (optim/control_run.hpp,
// shared with the Python module); here: the output file's series, the summary line and --json.
#include "commands.hpp"
#include "common.hpp"
#include "units.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/core/timer.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/input_error.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/control.hpp>
#include <softdiff/optim/control_run.hpp>

#include <softdiff/core/threads.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace softdiff::app {

void add_control(CLI::App& app, ControlOptions& o) {
  app.add_option("scene", o.scene, "Scene file (YAML, docs/scene.md)")->required()->check(CLI::ExistingFile);
  app.add_option("--target", o.target, "Goal: X,Y,Z (metres) or a CSV file of timed goals (time,x,y,z)")->required();
  app.add_option("--effector", o.effector, "The controlled effector (default: the scene's first)");
  app.add_option("--steps", o.steps, "Number of steps (default: the scene's)")->check(positive_integer());
  app.add_option("--weights", o.weights,
                 "alpha,beta: weights of the goal term alpha |X_e - X_goal|^2 and of the contact-force term "
                 "beta |lambda_c,nodes|^2 (paper eq. 13)")
      ->capture_default_str();
  app.add_option("--axes", o.axes, "Controlled directions of the goal (a subset of xyz)")->capture_default_str();
  app.add_option("--regularization", o.regularization,
                 "Weight of |d lambda|^2, relative to the mean squared column of the objective's Jacobian")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--filter", o.filter, "Low-pass factor on the actuation change, in (0, 1] (1: none)")->capture_default_str();
  app.add_flag("--shared-actuation", o.shared,
               "One change for all actuators (a symmetric robot controlled for one side, as the paper's gripper)");
  app.add_flag("--max-actuation", o.max_actuation,
               "No QP: every actuator at its upper limit at every step (the paper's gripper heuristic, for comparison; "
               "the /control datasets are written the same way)");
  add_run_options(app, o.output, "Output HDF5 file (default: <scene stem>_control.h5)", o.force, o.set, o.threads,
                  o.strict, o.quiet, "No progress bar, no summary", o.json);
}

int run_control(const ControlOptions& o, const std::string& command_line) {
  set_threads(o.threads);  // the thread plan, core/threads.hpp
  const auto t_setup = Clock::now();
  // The checks, the scene, the effector, the weights and the goals (optim/control_run.hpp,
  // shared with the Python module's softdiff.control()).
  optim::ControlRunOptions ro;
  ro.scene = o.scene;
  ro.set = o.set;
  ro.target = o.target;
  ro.effector = o.effector;
  ro.steps = o.steps;
  ro.weights = o.weights;
  ro.axes = o.axes;
  ro.regularization = o.regularization;
  ro.filter = o.filter;
  ro.shared = o.shared;
  ro.max_actuation = o.max_actuation;
  ro.strict = o.strict;
  const optim::ControlProblem problem = optim::prepare_control(ro, [](const std::string& m) { warn(m); });
  const io::SceneDesc& scene = problem.scene;
  const Model& model = problem.model;

  // -o: its default and the refusal of an input (optim/control_run.hpp, shared with
  // softdiff.control(output=...)).
  const std::filesystem::path out_path = optim::control_output_path(ro, o.output, scene);

  // The controller, the previous actuation, BDF2's history and the frames' records
  // (optim::ControlRun: --max-actuation without limits is refused here, exit 2).
  optim::ControlRun run(problem, o.max_actuation);
  // The run's hooks: the controller's actuation and record, the /control series.
  const RunHooks hooks = optim::control_output_hooks(problem, run);
  SimulateOptions so;
  so.scene = o.scene;
  so.output = out_path.string();
  so.force = o.force;
  so.strict = o.strict;
  so.quiet = o.quiet;   // the progress bar over the steps
  so.summary = false;   // control's own summary below
  const auto t_run = Clock::now();
  const int code = simulate_model(so, scene, model, t_setup, command_line, hooks);
  const double run_seconds = seconds_since(t_run);
  if (code != kExitOk) return code;
  const optim::ControlSummary sum = run.summary();
  const long n = std::max<long>(1, sum.steps);
  if (!o.quiet) {
    std::ostringstream s;
    s.precision(4);
    s << sum.steps << " control steps in " << run_seconds << " s (" << 1e3 * sum.control_seconds / n
      << " ms/step in the controller, " << 1e3 * (run_seconds - sum.control_seconds) / n << " ms/step in the rest); "
      << "final distance to the goal " << 1e3 * sum.final_distance << " mm (closest " << 1e3 * sum.min_distance
      << " mm), largest QP KKT residual " << sum.kkt_max << " -> " << out_path.string();
    note(s.str());
  }
  if (sum.qp_not_converged_steps > 0)
    warn(std::to_string(sum.qp_not_converged_steps) + " steps' QP did not converge (see /control/kkt_residual)");
  if (o.json) {
    Json j;
    j.begin_object();
    j.value("command", "control").value("scene", o.scene).value("output", out_path.string());
    j.value("steps", sum.steps).value("effector", sum.effector);
    j.value("final_distance", sum.final_distance).value("min_distance", sum.min_distance);
    j.value("kkt_max", sum.kkt_max).value("qp_not_converged_steps", sum.qp_not_converged_steps).value("within_limits", sum.within_limits);
    j.value("actuation_final", sum.actuation_final);
    j.value("wall_seconds", run_seconds);
    j.value("control_ms_per_step", 1e3 * sum.control_seconds / n);
    j.value("other_ms_per_step", 1e3 * (run_seconds - sum.control_seconds) / n);
    j.end_object();
    std::printf("%s\n", j.str().c_str());
  }
  return kExitOk;
}

}  // namespace softdiff::app
