// softdiff simulate SCENE.yaml: run a scene, stream frames to HDF5 (+ XDMF). The run and
// its file are the library's (io/run_output.hpp); here: options, progress, signals, --json.
#include "commands.hpp"
#include "common.hpp"
#include "theta.hpp"
#include "units.hpp"

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/contact_status.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/integrator/static_solver_derivatives.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/run_output.hpp>
#include <softdiff/io/scene.hpp>

#include <softdiff/core/threads.hpp>

#include <softdiff/core/timer.hpp>

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <mutex>
#include <new>
#include <optional>
#include <sstream>

namespace softdiff::app {
namespace {

std::string fmt_ms(double seconds, long steps) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", steps > 0 ? 1e3 * seconds / steps : 0.0);
  return buf;
}

}  // namespace

void add_simulate(CLI::App& app, SimulateOptions& o) {
  app.add_option("scene", o.scene, "Scene file (YAML, docs/scene.md)")->required()->check(CLI::ExistingFile);
  app.add_option("-o,--output", o.output,
                 "Output HDF5 file (default: the scene's output.file, else <scene name>.h5 in the current folder)");
  app.add_flag("--force", o.force, "Overwrite an existing output file");
  auto* steps = app.add_option("--steps", o.steps, "Number of steps (overrides simulation.steps/duration)")
                    ->check(positive_integer());
  auto* duration = app.add_option("--duration", o.duration, "Simulated time in seconds (overrides the scene)")
                       ->check(positive_number("s"));
  steps->excludes(duration);
  app.add_option("--dt", o.dt, "Time step in seconds (overrides simulation.dt)")->check(positive_number("s"));
  app.add_option("--set", o.set, "Override a scene value: KEY=VALUE, e.g. bodies.beam.material.young=2e5 (repeatable)");
  app.add_option("--jacobian", o.jacobian,
                 "Write d x_T / d theta to /jacobians/<theta> for these theta (comma-separated: young, poisson, density, "
                 "rayleigh_mass, rayleigh_stiffness, actuation, x0, v0; rigid bodies: mass, inertia), by forward sensitivities");
  app.add_option("--threads", o.threads, "OpenMP threads (default: all cores)")->check(CLI::NonNegativeNumber);
  app.add_flag("--strict", o.strict, "Treat a solver that does not reach its tolerance as an error (exit 1), and a body of implausible size or mass as bad input (exit 2)");
  app.add_flag("--quiet", o.quiet, "No progress bar, no summary");
  app.add_flag("--json", o.json, "Print a JSON summary of the run on stdout");
}

int run_simulate(const SimulateOptions& o, const std::string& command_line) {
  set_threads(o.threads);  // the thread plan, core/threads.hpp

  // 1. Scene and model: every input error is raised here, before any file is created.
  const std::vector<std::string> overrides = io::simulate_overrides(o.set, o.steps, o.duration, o.dt);
  auto t_setup = Clock::now();
  const io::SceneDesc scene = io::load_scene(o.scene, overrides);
  io::BuildReport report;
  report.strict = o.strict;
  const Model model = io::build_model(scene, &report);
  for (const auto& w : report.warnings) warn(w);
  return simulate_model(o, scene, model, t_setup, command_line);
}

int simulate_model(const SimulateOptions& o, const io::SceneDesc& scene, const Model& model,
                   std::chrono::steady_clock::time_point t_setup, const std::string& command_line,
                   const RunHooks& hooks) {
  // The run and its file are the library's (io/run_output.hpp, shared with the Python
  // module); here: the progress bar, the messages on stderr, the signals, the summary
  // line and --json.
  io::RunOutputOptions ro;
  ro.scene = o.scene;
  ro.output = o.output;
  ro.force = o.force;
  ro.jacobian = o.jacobian;
  ro.strict = o.strict;
  ro.command_line = command_line;
  ro.progress_label = o.progress_label;
  Progress progress(0, !o.quiet);
  io::RunCallbacks cb;
  cb.warn = [](const std::string& m) { warn(m); };
  cb.error = [](const std::string& m) { error(m); };
  cb.note = [](const std::string& m) { note(m); };
  cb.progress_start = [&](long total, const std::string& label) { progress.start(total, label); };
  cb.progress_update = [&](long done) { progress.update(done); };
  cb.progress_clear = [&] { progress.clear(); };
  cb.stop_requested = [] { return SignalWatch::stop_requested(); };
  io::OutputRun run(ro, scene, model, t_setup, hooks, cb);  // the checks: exit 2 before any file exists
  const bool is_static = run.is_static();

  // Signals (docs/cli.md "Signals"): the first stops the run after the step in
  // progress; a second one stops it at once. The step cannot be cut short (a CHOLMOD
  // factorization has no stop test), so the watcher thread finishes the file itself
  // (status interrupted, the frames written so far: OutputRun::abandon) and leaves with
  // _exit(1) while the step is still computing.
  const char* step_word = is_static ? "load step " : "step ";
  SignalWatch signals([&](int count, const char* name) {
    const long k = run.step_in_progress();
    if (count == 1) {
      note(std::string(name) + ": stopping " +
           (k > 0 ? "after " + std::string(step_word) + std::to_string(k) + " (in progress)" : "before the next step") +
           "; send it again to stop at once");
      return;
    }
    if (!run.abandon(std::string(name) + " again: stopped" +
                     (k > 0 ? " during " + std::string(step_word) + std::to_string(k) + " (abandoned)" : std::string())))
      return;  // the run is finishing by itself
    std::fflush(nullptr);
    ::_exit(kExitFailed);
  });

  const io::RunOutputResult result = run.run();
  if (!result.ok) return kExitFailed;
  const long steps_done = result.steps_done;
  const StepTimings& timings = result.timings;
  const double run_seconds = result.run_seconds, setup_seconds = result.setup_seconds;
  const double derivative_seconds = result.derivative_seconds, output_seconds = result.output_seconds;
  const long warnings_newton = result.newton_not_converged_steps, warnings_contact = result.contact_not_converged_steps;
  const State& state = result.state;

  const long n = std::max<long>(1, steps_done);
  if (!o.quiet && o.summary) {
    std::ostringstream s;
    s.precision(3);
    s << steps_done << (is_static ? " load steps" : " steps") << " in " << run_seconds << " s (setup "
      << setup_seconds << " s); ms/step: assembly " << fmt_ms(timings.assembly, n) << ", factorization "
      << fmt_ms(timings.factorization, n) << ", solve " << fmt_ms(timings.solve, n) << ", contact "
      << fmt_ms(timings.contact(), n) << ", derivatives " << fmt_ms(derivative_seconds, n) << ", output "
      << fmt_ms(output_seconds, n) << " -> " << result.path;
    note(s.str());
  }
  if (warnings_newton > 1) warn(std::to_string(warnings_newton) + " steps did not reach newton_tolerance");
  if (warnings_contact > 1) warn(std::to_string(warnings_contact) + " contact solves did not reach the contact tolerance");

  if (o.json) {
    Json j;
    j.begin_object();
    j.value("command", "simulate").value("scene", o.scene).value("output", result.path);
    j.value("status", result.status).value("steps", steps_done).value("frames", result.frames);
    j.value("time", state.t).value("wall_seconds", run_seconds).value("setup_seconds", setup_seconds);
    j.begin_object("ms_per_step")
        .value("assembly", 1e3 * timings.assembly / n)
        .value("factorization", 1e3 * timings.factorization / n)
        .value("solve", 1e3 * timings.solve / n)
        .value("other", 1e3 * timings.other / n)
        .value("contact", 1e3 * timings.contact() / n)
        .value("detection", 1e3 * timings.detection / n)
        .value("delassus", 1e3 * timings.delassus / n)
        .value("ncp", 1e3 * timings.ncp / n)
        .value("correction", 1e3 * timings.correction / n)
        .value("derivatives", 1e3 * derivative_seconds / n)
        .value("output", 1e3 * output_seconds / n)
        .end_object();
    j.value("factorizations", result.factorizations);
    {
      // The step's solver (docs/cli.md): with linear_solver.factor_reuse: pcg, the
      // factorizations above are the matrices formed, these the work done on them.
      const auto& c = result.solver;
      j.begin_object("linear_solver")
          .value("numeric_factorizations", c.numeric_factorizations)
          .value("kept_factors", c.kept_factors)
          .value("pcg_solves", c.pcg_solves)
          .value("pcg_iterations", c.pcg_iterations)
          .value("pcg_fallbacks", c.pcg_fallbacks)
          .end_object();
    }
    if (result.jacobian) {
      j.begin_object("derivatives")
          .value("ncp_rank_deficient_steps", result.rank_deficient_steps)
          .value("ncp_rank_deficiency_max", result.rank_deficiency_max)
          .value("nondifferentiable_contacts", result.nondifferentiable_contacts)
          .value("smoothed_contacts", result.smoothed_contacts)
          .end_object();
    }
    j.value("newton_not_converged_steps", warnings_newton);
    if (model.contact.enabled) {
      j.begin_object("contact")
          .value("contacts_mean", static_cast<double>(result.contacts_total) / n)
          .value("contacts_max", result.contacts_max)
          .value("iterations_mean", static_cast<double>(result.contact_iterations) / n)
          .value("not_converged_steps", warnings_contact)
          .end_object();
    }
    j.begin_object("bodies");
    for (const auto& b : model.fem.bodies) {
      double max_disp = 0;
      Vec3 centroid = Vec3::Zero();
      for (int i = b.node_begin; i < b.node_begin + b.num_nodes; ++i) {
        max_disp = std::max(max_disp, (state.x.segment<3>(3 * i) - model.fem.X.col(i)).norm());
        centroid += state.x.segment<3>(3 * i);
      }
      centroid /= b.num_nodes;
      j.begin_object(b.name)
          .value("nodes", b.num_nodes)
          .value("tets", b.num_tets)
          .value("max_displacement", max_disp)
          .value("centroid", std::vector<double>{centroid.x(), centroid.y(), centroid.z()})
          .end_object();
    }
    for (std::size_t r = 0; r < model.rigid.size(); ++r) {
      const auto& rs = state.rigid[r];
      j.begin_object(model.rigid[r].name)
          .value("position", std::vector<double>{rs.position.x(), rs.position.y(), rs.position.z()})
          .value("orientation",
                 std::vector<double>{rs.orientation.w(), rs.orientation.x(), rs.orientation.y(), rs.orientation.z()});
      if (model.rigid[r].joint.kind == rigid::Joint::Kind::hinge || model.rigid[r].joint.kind == rigid::Joint::Kind::slider)
        j.value("joint_coordinate", rigid::joint_coordinate(model.rigid[r], rs));
      j.end_object();
    }
    j.end_object();
    j.end_object();
    std::printf("%s\n", j.str().c_str());
  }
  return kExitOk;
}

}  // namespace softdiff::app
