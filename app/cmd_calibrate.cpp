// softdiff calibrate SCENE.yaml: identify material parameters from an observed motion
// (docs/cli.md; the method: optim/calibration.hpp, docs/method.md "Calibration"). The
// options' checks, the scene, the parameters and the target are the library's
// (optim/calibrate_run.hpp, shared with the Python module); here: the progress, the
// iteration lines, the output file and --json.
#include "commands.hpp"
#include "common.hpp"
#include "units.hpp"

#include <softdiff/core/timer.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/input_error.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/calibrate_run.hpp>
#include <softdiff/optim/calibration.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>

#include <softdiff/core/threads.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>

namespace softdiff::app {

void add_calibrate(CLI::App& app, CalibrateOptions& o) {
  app.add_option("scene", o.scene, "Scene file (YAML, docs/scene.md)")->required()->check(CLI::ExistingFile);
  app.add_option("--param", o.param,
                 "Parameters to identify (comma-separated: young, poisson, density, rayleigh_mass, rayleigh_stiffness, "
                 "friction; rigid bodies: mass, inertia, inertia.xx|yy|zz; BODY.NAME for one body)")
      ->required();
  auto* target = app.add_option("--target", o.target, "Target trajectory (a softdiff HDF5 file, docs/output.md)");
  auto* markers = app.add_option("--markers", o.markers, "Target markers: a CSV of time,marker,x,y,z observations");
  target->excludes(markers);
  app.add_option("--frames", o.frames, "Frames of --target to match: last, all, or a list of frame indices")
      ->capture_default_str();
  app.add_option("--init", o.init, "Initial values, one per parameter (default: the scene's)");
  app.add_option("--max-iterations", o.max_iterations, "Levenberg-Marquardt iterations at most")
      ->capture_default_str()
      ->check(positive_integer());
  app.add_option("--tolerance", o.tolerance,
                 "Stop when the relative cost reduction (ftol) or the relative step (xtol) falls below this")
      ->capture_default_str()
      ->check(positive_number());
  add_run_options(app, o.output,
                  "Output HDF5 file: the scene simulated with the identified parameters, plus /calibration "
                  "(default: <scene stem>_calibrated.h5)",
                  o.force, o.set, o.threads, o.strict, o.quiet, "No progress bar, no per-iteration lines", o.json);
}

int run_calibrate(const CalibrateOptions& o, const std::string& command_line) {
  set_threads(o.threads);  // the thread plan, core/threads.hpp
  const auto t_setup = Clock::now();
  // The checks, the scene, --param, --init and the target (optim/calibrate_run.hpp, shared
  // with the Python module's softdiff.calibrate()).
  optim::CalibrateRunOptions ro;
  ro.scene = o.scene;
  ro.set = o.set;
  ro.param = o.param;
  ro.target = o.target;
  ro.markers = o.markers;
  ro.frames = o.frames;
  ro.init = o.init;
  ro.max_iterations = o.max_iterations;
  ro.tolerance = o.tolerance;
  ro.strict = o.strict;
  const optim::CalibrationProblem problem =
      optim::prepare_calibration(ro, [](const std::string& m) { warn(m); }, [](const std::string& m) { note(m); });
  const io::SceneDesc& scene = problem.scene;
  const Model& model = problem.model;
  const optim::CalibrationTarget& target = problem.target;

  // -o: its default, the refusal of an existing file without --force and of an input
  // (optim/calibrate_run.hpp, shared with softdiff.calibrate(output=...)).
  const std::filesystem::path out_path = optim::calibration_output_path(ro, o.output, o.force, scene);

  optim::CalibrationOptions co = optim::calibration_options(ro);
  // On a terminal: a progress bar over each run's steps ("run 7 [====  ] 40/100 steps"),
  // erased before each iteration's line.
  Progress progress(0, !o.quiet);
  co.on_step = [&](int run, long step, long steps) {
    if (step == 0)
      progress.start(steps, "run " + std::to_string(run));
    else
      progress.update(step);
  };
  const auto print = [&](const optim::CalibrationIteration& it) {
    if (o.quiet) return;
    std::ostringstream s;
    s.precision(8);
    s << "iteration " << it.iteration << ":";
    for (std::size_t j = 0; j < it.values.size(); ++j) s << " " << problem.names[j] << " = " << it.values[j];
    s.precision(4);
    s << ", cost " << it.cost << ", |gradient| " << it.gradient_norm << ", damping " << it.damping << " ("
      << it.evaluations << " runs, " << it.seconds << " s)";
    if (it.iteration > 0) s << ", " << it.rejected << " trial steps rejected (" << it.failed << " failed to run)";
    note(progress, s.str());
    if (it.failed > 0) note(progress, "  last failed trial: " + it.last_failure);
  };
  const auto t_run = Clock::now();
  const optim::CalibrationResult result = optim::calibrate(model, problem.ids, problem.rigid_ids, problem.init, target, co, print);
  progress.finish();
  const double run_seconds = seconds_since(t_run);
  if (!o.quiet)
    note(std::string(result.converged ? "converged" : "did not converge") + " after " + std::to_string(result.iterations) +
         " iterations (" + result.stop_reason + ")");

  // The scene with the identified parameters, written as simulate writes it, plus
  // /calibration (docs/output.md).
  const Model final_model = optim::calibrated_model(problem, result.values);
  SimulateOptions so;
  so.scene = o.scene;
  so.output = out_path.string();
  so.force = o.force;
  so.strict = o.strict;
  so.quiet = o.quiet;  // its progress bar
  so.summary = false;
  so.progress_label = "final run";
  RunHooks hooks;
  hooks.finish = [&](io::Hdf5Writer& w) { optim::write_calibration(w, problem, result); };
  const int code = simulate_model(so, scene, final_model, t_setup, command_line, hooks);
  if (code != kExitOk) return code;

  if (o.json) {
    Json j;
    j.begin_object();
    j.value("command", "calibrate").value("scene", o.scene).value("output", out_path.string());
    j.value("converged", result.converged).value("stop_reason", result.stop_reason);
    j.value("iterations", static_cast<long>(result.iterations)).value("evaluations", static_cast<long>(result.evaluations));
    j.value("rejected", static_cast<long>(result.rejected)).value("failed", static_cast<long>(result.failed));
    j.value("final_cost", result.cost).value("wall_seconds", run_seconds);
    j.value("residuals", static_cast<long>(target.residual_size())).value("target_steps", target.steps());
    j.value("rigid_matched", io::join(problem.rigid_matched));  // the rigid bodies whose pose is matched (issue 21)
    j.begin_object("parameters");
    for (std::size_t k = 0; k < problem.names.size(); ++k) j.value(problem.names[k], result.values[k]);
    j.end_object();
    j.begin_array("history");
    for (const auto& h : result.history) {
      j.begin_object()
          .value("iteration", static_cast<long>(h.iteration))
          .value("values", h.values)
          .value("cost", h.cost)
          .value("gradient_norm", h.gradient_norm)
          .value("damping", h.damping)
          .value("seconds", h.seconds)
          .value("evaluations", static_cast<long>(h.evaluations))
          .value("rejected", static_cast<long>(h.rejected))
          .value("failed", static_cast<long>(h.failed))
          .end_object();
    }
    j.end_array();
    j.end_object();
    std::printf("%s\n", j.str().c_str());
  }
  return result.converged ? kExitOk : kExitFailed;
}

}  // namespace softdiff::app
