#pragma once
// Subcommands: one cmd_<name>.cpp each. add_* registers the options on CLI11's app
// (so that `--help` lists them with defaults), run_* executes and returns the exit code.
#include <CLI/CLI.hpp>

#include <softdiff/data.hpp>
#include <softdiff/io/run_output.hpp>
#include <softdiff/model.hpp>

#include <chrono>
#include <functional>
#include <optional>
#include <string>
#include <vector>


namespace softdiff::app {

struct SimulateOptions {
  std::string scene;
  std::string output;
  bool force = false;
  std::optional<long> steps;
  std::optional<double> duration;
  std::optional<double> dt;
  std::vector<std::string> set;
  std::string jacobian;
  int threads = 0;
  bool strict = false, quiet = false, json = false;
  // simulate_model only: the closing summary line (calibrate and control print their
  // own; their --quiet also silences the progress bar).
  bool summary = true;
  std::string progress_label;  // before the progress bar (e.g. "final run")
};
void add_simulate(CLI::App& app, SimulateOptions& o);
int run_simulate(const SimulateOptions& o, const std::string& command_line);
// What a caller of simulate_model adds to the run: the library's (io/run_output.hpp).
using RunHooks = io::RunHooks;

// simulate's run of a model already built from `scene` (calibrate and control write
// their runs this way): frames, series, contact, --jacobian, the summary and --json.
// t_setup: when the setup began (for setup_seconds).
int simulate_model(const SimulateOptions& o, const io::SceneDesc& scene, const Model& model,
                   std::chrono::steady_clock::time_point t_setup, const std::string& command_line,
                   const RunHooks& hooks = {});

struct InfoOptions {
  std::string file;
  std::vector<std::string> set;
  bool json = false;
  bool strict = false;  // an implausible body size or mass is bad input (exit 2)
};
void add_info(CLI::App& app, InfoOptions& o);
int run_info(const InfoOptions& o);

struct CheckGradOptions {
  std::string scene;
  std::string wrt;
  long steps = 1;
  double eps = 1e-4;
  double tolerance = 1e-5;
  int directions = 4;
  std::vector<std::string> set;
  int threads = 0;
  bool json = false, quiet = false;
};
void add_check_grad(CLI::App& app, CheckGradOptions& o);
int run_check_grad(const CheckGradOptions& o);

// The options calibrate and control share: -o, --force, --set, --threads, --strict,
// --quiet (its help says what it silences), --json.
void add_run_options(CLI::App& app, std::string& output, const std::string& output_help, bool& force,
                     std::vector<std::string>& set, int& threads, bool& strict, bool& quiet,
                     const std::string& quiet_help, bool& json);

struct CalibrateOptions {
  std::string scene;
  std::string param;
  std::string target, markers;
  std::string frames = "all";
  std::string init;
  int max_iterations = 50;
  double tolerance = 1e-10;
  std::string output;
  bool force = false;
  std::vector<std::string> set;
  int threads = 0;
  bool strict = false, quiet = false, json = false;
};
void add_calibrate(CLI::App& app, CalibrateOptions& o);
int run_calibrate(const CalibrateOptions& o, const std::string& command_line);

struct ControlOptions {
  std::string scene;
  std::string target;
  std::string effector;
  std::optional<long> steps;
  std::string weights = "1,0";
  std::string axes = "xyz";
  double regularization = 1e-6;
  double filter = 1;
  bool shared = false;
  bool max_actuation = false;
  std::string output;
  bool force = false;
  std::vector<std::string> set;
  int threads = 0;
  bool strict = false, quiet = false, json = false;
};
void add_control(CLI::App& app, ControlOptions& o);
int run_control(const ControlOptions& o, const std::string& command_line);

// softdiff sweep / collect (docs/cli.md "sweep and collect"; sweep.hpp: the file format).
struct SweepOptions {
  std::string file;
  std::string dir;
  std::optional<long> jobs;
  bool resume = false, dry_run = false, slurm = false, quiet = false;
  std::vector<std::string> slurm_opts;
};
void add_sweep(CLI::App& app, SweepOptions& o);
int run_sweep(const SweepOptions& o);

struct CollectOptions {
  std::string dir;
  std::string table;  // default DIR/results.csv
  bool quiet = false;
};
void add_collect(CLI::App& app, CollectOptions& o);
int run_collect(const CollectOptions& o);

std::string version_text();

// CLI11 checks whose messages a person reads ("--dt: must be > 0 s, got 0"), for
// options that must be positive: a number (with its unit, if any) or an integer.
CLI::Validator positive_number(const std::string& unit = "");
CLI::Validator positive_integer();

// Files the run reads, and the refusal of an output that is an input (exit 2): the
// library's (io/run_output.hpp).
using io::check_output_is_not_input;
using io::scene_input_files;

}  // namespace softdiff::app
