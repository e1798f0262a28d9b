#pragma once
// Subcommands: one cmd_<name>.cpp each. add_* registers the options on CLI11's app
// (so that `--help` lists them with defaults), run_* executes and returns the exit code.
#include <CLI/CLI.hpp>

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
};
void add_simulate(CLI::App& app, SimulateOptions& o);
int run_simulate(const SimulateOptions& o, const std::string& command_line);

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

std::string version_text();

}  // namespace softdiff::app
