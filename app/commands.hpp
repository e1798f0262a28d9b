#pragma once
// Subcommands: one cmd_<name>.cpp each. add_* registers the options on CLI11's app
// (so that `--help` lists them with defaults), run_* executes and returns the exit code.
#include <CLI/CLI.hpp>

#include <chrono>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace softdiff {
struct Model;
namespace io {
struct SceneDesc;
class Hdf5Writer;
}  // namespace io
}  // namespace softdiff

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
};
void add_simulate(CLI::App& app, SimulateOptions& o);
int run_simulate(const SimulateOptions& o, const std::string& command_line);
// simulate's run of a model already built from `scene` (calibrate writes its final run
// this way): frames, series, contact, --jacobian, the summary and --json. `extra`
// writes the caller's own groups into the file once the run is complete, before the
// file is finished. t_setup: when the setup began (for setup_seconds).
int simulate_model(const SimulateOptions& o, const io::SceneDesc& scene, const Model& model,
                   std::chrono::steady_clock::time_point t_setup, const std::string& command_line,
                   const std::function<void(io::Hdf5Writer&)>& extra = {});

struct InfoOptions {
  std::string file;
  std::vector<std::string> set;
  bool json = false;
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
  bool json = false;
};
void add_check_grad(CLI::App& app, CheckGradOptions& o);
int run_check_grad(const CheckGradOptions& o);

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

std::string version_text();

}  // namespace softdiff::app
