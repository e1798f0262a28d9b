#pragma once
// `softdiff calibrate` as a library call (docs/cli.md "calibrate"; moved here from
// app/cmd_calibrate.cpp on 2026-12-04, branch pycal, so that the CLI and the Python
// module's softdiff.calibrate() share one option parser, one target loader and one
// set of messages): the options with the CLI's names and defaults, their checks (every
// bad input an InputError with the CLI's message, exit 2), the target (--target
// trajectory or --markers CSV) loaded into a CalibrationTarget, and the model with the
// identified values. The identification itself is optim::calibrate (calibration.hpp);
// the output file is the final run written as `simulate` writes it (io/run_output.hpp,
// since 2026-12-04, branch pyout) plus /calibration (write_calibration below), by the CLI
// and by softdiff.calibrate(output=...).
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/calibration.hpp>

#include <functional>
#include <string>
#include <vector>

namespace softdiff::io {
class Hdf5Writer;
}

namespace softdiff::optim {

// The options of `softdiff calibrate` that the problem depends on (the CLI's names,
// dashes as underscores, and defaults; -o, --force, --threads, --quiet, --json are the
// caller's).
struct CalibrateRunOptions {
  std::string scene;             // the scene file
  std::vector<std::string> set;  // --set KEY=VALUE, in order
  std::string param;             // --param (comma-separated)
  std::string target, markers;   // --target FILE.h5 | --markers FILE.csv
  std::string frames = "all";    // --frames last | all | K,K,...
  std::string init;              // --init V,V,... (empty: the scene's values)
  int max_iterations = 50;       // --max-iterations
  double tolerance = 1e-10;      // --tolerance (MINPACK's ftol and xtol)
  bool strict = false;           // --strict
};

// A message to the user (the CLI: "softdiff: warning: ..." or "softdiff: ..." on stderr;
// Python: a warning, or the result's notes).
using MessageSink = std::function<void(const std::string&)>;

// A calibration, checked and loaded: what optim::calibrate runs.
struct CalibrationProblem {
  io::SceneDesc scene;
  Model model;
  std::vector<ParameterId> ids;
  std::vector<rigid::RigidParameterId> rigid_ids;  // after ids in the values (issue 21)
  // Output names: "young", or "beam.young" when several bodies have it; then the rigid
  // ones: "cube.mass", "cube.inertia.xx".
  std::vector<std::string> names;
  std::vector<double> init;  // one per name
  CalibrationTarget target;
  std::vector<std::string> rigid_matched;  // the rigid bodies whose pose is matched
};

// The CLI's checks in its order: --target or --markers, --frames with --markers, the
// scene (io::load_scene with `set`, io::build_model: its warnings to `warn`), --param,
// --init, the target file (notes on matched rigid bodies to `note`), and the warning of
// a single target frame. Throws InputError (the CLI's message) for bad input.
CalibrationProblem prepare_calibration(const CalibrateRunOptions& o, const MessageSink& warn, const MessageSink& note);

// max_iterations, ftol = xtol = tolerance, strict (no progress callback).
CalibrationOptions calibration_options(const CalibrateRunOptions& o);

// The problem's model with the result's values (the final run's).
Model calibrated_model(const CalibrationProblem& problem, const std::vector<double>& values);

// -o: the file to write (output, or <scene stem>_calibrated.h5), refused (InputError,
// the CLI's messages) when it exists without `force` or is one of the inputs (the
// scene's files, the target) - checked before the identification runs.
std::string calibration_output_path(const CalibrateRunOptions& o, const std::string& output, bool force,
                                    const io::SceneDesc& scene);

// /calibration of the output (docs/output.md): the iterations table with its units and
// the result's attributes (io::RunHooks::finish of the final run).
void write_calibration(io::Hdf5Writer& w, const CalibrationProblem& problem, const CalibrationResult& result);

}  // namespace softdiff::optim
