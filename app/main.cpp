// softdiff: command-line entry point (spec: docs/cli.md).
#include "commands.hpp"
#include "common.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/io/hdf5_writer.hpp>

#include <unistd.h>

#include <cstdio>
#include <exception>
#include <new>

int main(int argc, char** argv) {
  using namespace softdiff::app;
  CLI::App app{"softdiff: differentiable soft-robot simulation (FEM, frictional contact, gradients)", "softdiff"};
  app.set_version_flag("--version", version_text());
  app.require_subcommand(1);
  app.fallthrough(false);

  SimulateOptions simulate;
  auto* sim_cmd = app.add_subcommand("simulate", "Simulate a scene and write its trajectory (HDF5 + XDMF)");
  add_simulate(*sim_cmd, simulate);
  InfoOptions info;
  auto* info_cmd = app.add_subcommand("info", "Describe a mesh (.msh) or validate and describe a scene (.yaml)");
  add_info(*info_cmd, info);
  CalibrateOptions calibrate;
  auto* calibrate_cmd = app.add_subcommand("calibrate", "Identify material parameters from an observed motion (Levenberg-Marquardt)");
  add_calibrate(*calibrate_cmd, calibrate);
  ControlOptions control;
  auto* control_cmd = app.add_subcommand("control", "Drive an effector to a goal by inverse dynamics (a QP per step)");
  add_control(*control_cmd, control);
  CheckGradOptions check_grad;
  auto* check_cmd = app.add_subcommand("check-grad", "Check the analytic derivatives against central finite differences");
  add_check_grad(*check_cmd, check_grad);

  SweepOptions sweep;
  auto* sweep_cmd = app.add_subcommand("sweep", "Run a parameter sweep: GNU parallel locally, or a Slurm job array (--slurm)");
  add_sweep(*sweep_cmd, sweep);
  CollectOptions collect;
  auto* collect_cmd = app.add_subcommand("collect", "Tabulate a sweep's results (CSV and HDF5) and plot one over two axes (PNG)");
  add_collect(*collect_cmd, collect);

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    error(std::string(e.what()) + " (see softdiff --help)");
    return kExitBadInput;
  }

  const int code = [&] {
    try {
      if (sim_cmd->parsed()) return run_simulate(simulate, join_argv(argc, argv));
      if (info_cmd->parsed()) return run_info(info);
      if (calibrate_cmd->parsed()) return run_calibrate(calibrate, join_argv(argc, argv));
      if (control_cmd->parsed()) return run_control(control, join_argv(argc, argv));
      if (check_cmd->parsed()) return run_check_grad(check_grad);
      if (sweep_cmd->parsed()) return run_sweep(sweep);
      if (collect_cmd->parsed()) return run_collect(collect);
    } catch (const softdiff::InputError& e) {
      error(e.what());
      return kExitBadInput;
    } catch (const softdiff::ComputationError& e) {
      error(e.what());
      return kExitFailed;
    } catch (const std::bad_alloc&) {
      error("out of memory (an allocation failed)");
      return kExitFailed;
    } catch (const std::exception& e) {
      error(std::string("internal error: ") + e.what());
      return kExitFailed;
    }
    return kExitBadInput;
  }();
  // An output file HDF5 could not close (full disk): its exit handler would crash on
  // it (hdf5_writer.hpp), so leave without running it.
  if (softdiff::io::hdf5_close_failed()) {
    std::fflush(nullptr);
    ::_exit(code);
  }
  return code;
}
