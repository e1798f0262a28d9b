#pragma once
// The run that writes a softdiff output file (docs/output.md): `softdiff simulate`'s run
// of a built model (frames, series, contact, --jacobian, the run's end written in the
// file's status), with its output safety (the output is not an input, the free space,
// side files for an unfinished run: hdf5_writer.hpp). Moved here from app/cmd_simulate.cpp
// on 2026-12-04 (branch pyout) so that the CLI (simulate, calibrate's and control's final
// runs) and the Python module (softdiff.simulate, calibrate and control with output=)
// write the file with one code. What is the CLI's stays in app/: options, progress bar,
// printing (through RunCallbacks), the summary line, --json, the signal handlers (which
// call OutputRun::abandon on a second signal).
#include <softdiff/core/timer.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/model.hpp>

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace softdiff::io {

class Hdf5Writer;

// What a caller of the run adds to it (all optional):
//   setup: before frame 0 (e.g. add series to the writer);
//   actuation: the actuation values of step k (1-based) from the state it starts from,
//     instead of the scene's schedules (control); a failed status stops the run;
//   frame: after each written frame (first: frame 0), with the step's record;
//   finish: once the run is complete, before the file is finished (own groups);
//   data: the record to step with instead of the run's own (control: the controller's,
//     whose factorization of the step's matrix the committed step reuses).
struct RunHooks {
  std::function<void(Hdf5Writer&)> setup;
  std::function<StepStatus(long k, const State& s, VecX& lambda)> actuation;
  std::function<void(Hdf5Writer&, const State& s, const Data& data, bool first)> frame;
  std::function<void(Hdf5Writer&)> finish;
  Data* data = nullptr;
};

// Messages, progress and the stop request of a run (each optional). The CLI: its
// stderr lines ("softdiff: warning: ...") and progress bar, and its first signal; the
// Python module: collected messages, no progress, the interpreter's pending SIGINT.
struct RunCallbacks {
  std::function<void(const std::string&)> warn, note, error;
  std::function<void(long total, const std::string& label)> progress_start;
  std::function<void(long done)> progress_update;
  std::function<void()> progress_clear;  // before a warning line
  std::function<bool()> stop_requested;  // checked between steps
};

// The options of `softdiff simulate` the run depends on (the CLI's names).
struct RunOutputOptions {
  std::string scene;         // the scene file (the default output name: <stem>.h5)
  std::string output;        // -o (empty: the scene's output.file, else <scene stem>.h5)
  bool force = false;        // --force
  std::string jacobian;      // --jacobian (comma-separated theta; empty: none)
  bool strict = false;       // --strict
  std::string command_line;  // the file's `command` attribute
  std::string progress_label;
};

// The scene overrides of simulate's --set, --dt, --steps and --duration, in the CLI's order.
std::vector<std::string> simulate_overrides(const std::vector<std::string>& set, std::optional<long> steps,
                                            std::optional<double> duration, std::optional<double> dt);

// What `simulate --json` reports of a run (docs/cli.md), and how it ended.
struct RunOutputResult {
  // "complete", "interrupted" (a stop request), or a failure: ok is false and error
  // holds the message given to RunCallbacks::error (the file finished as
  // "diverged: ..." or "failed: ..." with its frames, unfinished: hdf5_writer.hpp).
  bool ok = false;
  std::string status;
  std::string error;
  std::string path;  // the file written (the final name; the side file of an unfinished run)
  bool is_static = false;
  long steps_done = 0, frames = 0;
  double run_seconds = 0, setup_seconds = 0, derivative_seconds = 0, output_seconds = 0;
  StepTimings timings;
  long factorizations = 0;
  integrator::SolverCounters solver;
  bool jacobian = false;
  long rank_deficient_steps = 0, rank_deficiency_max = 0, nondifferentiable_contacts = 0, smoothed_contacts = 0;
  long newton_not_converged_steps = 0, contact_not_converged_steps = 0;
  long contacts_total = 0, contacts_max = 0, contact_iterations = 0;
  State state;  // the last state
};

// One run writing one file. The constructor makes the checks (InputError, exit 2, before
// any file is created): --jacobian's theta, the output not an input, the free space (a
// warning above 10 GB). run() writes the file: once.
class OutputRun {
 public:
  OutputRun(const RunOutputOptions& o, const SceneDesc& scene, const Model& model, Clock::time_point t_setup,
            RunHooks hooks = {}, RunCallbacks callbacks = {});
  ~OutputRun();
  OutputRun(const OutputRun&) = delete;
  OutputRun& operator=(const OutputRun&) = delete;

  const std::filesystem::path& output_path() const;
  bool is_static() const;
  // The step (load step) being computed, 0 between steps: safe from another thread.
  long step_in_progress() const;
  RunOutputResult run();
  // From another thread (the CLI's second signal): unless the run is finishing by
  // itself, gives `message` to error(), finishes the file as "interrupted" with the
  // frames written so far, says where they are (note) and returns true (the caller
  // leaves the process: the step in progress cannot be cut short). Returns false when
  // the run finishes the file itself.
  bool abandon(const std::string& message);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Files the run reads: the scene, its bodies' and obstacles' meshes.
std::vector<std::string> scene_input_files(const SceneDesc& scene);
// InputError (exit 2) when the output, or a file written beside it (.partial, .xmf,
// the side files of an unfinished run), is one of `inputs` (the same file: compared
// by identity, so links and other spellings of a path are caught).
void check_output_is_not_input(const std::string& output, const std::vector<std::string>& inputs);

}  // namespace softdiff::io
