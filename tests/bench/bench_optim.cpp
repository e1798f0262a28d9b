// Cost of a calibration iteration and of a control step relative to the forward step
// of the same scene, measured in the same run (issue "calibrate and control").
//
// Calibration: cantilever beam (10 n x n x n cells, 6 tets each), corotational,
// damped, 30 steps, young identified from 0.5x the truth on every frame.
//   BM_CalibrationIteration/<n>: per benchmark iteration, one plain 30-step run
//   (forward_ms: the floor, per step) and one calibration to convergence. Counters:
//   step_ms (forward step), iteration_ms (wall time per Levenberg-Marquardt iteration),
//   ratio_per_step = iteration_ms / step_ms, ratio_per_run = iteration_ms / (30 step_ms),
//   cpu_ratio_per_run (the same by the process's CPU time),
//   runs_per_iteration (simulations per iteration, the initial guess's included),
//   rejected (trial steps rejected per calibration), sim_per_run (one simulation of the
//   calibration, with its sensitivities, per plain run), iterations.
//   BM_CalibrationRun/<n>: one simulation by part (see there).
//
// Control: the shipped Trunk (configs/trunk.yaml, 3.7k tets, 8 cables).
//   BM_ControlStep: per iteration one forward step (step_ms, the floor) and one step of
//   `softdiff control` from the same state (control_ms: the computation, compute_ms: the
//   prediction step with its assembly and factorization, the 8 actuation JVPs in one
//   solve, the QP; then the committed step, commit_ms, on the prediction's factor);
//   ratio = control_ms / step_ms (cpu_ratio: by the process's CPU time), i.e. control
//   step / forward step; factorizations_per_control_step (1). The state advances along
//   the controlled trajectory every iteration.
#include <softdiff/data.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/control.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/optim/calibration.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include "beam.hpp"

#include <benchmark/benchmark.h>

#include <chrono>
#include <ctime>

using namespace softdiff;

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
// The process's CPU time (s): the ratios by CPU time hold on a loaded machine, where the
// wall times of two parts of one iteration see different loads.
double cpu_now() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

constexpr long kSteps = 30;


// A plain kSteps-step run of the model on a fresh Data (the floor of a run); fills the
// every-frame target.
optim::CalibrationTarget forward_run(benchmark::State& st, const Model& model) {
  optim::CalibrationTarget target;
  Data data(model);
  State s = model.initial, next;
  for (long k = 1; k <= kSteps; ++k) {
    if (!integrator::implicit_euler_step(model, data, s, next, k).ok()) st.SkipWithError("step failed");
    std::swap(s, next);
    target.frames.push_back(k);
    target.states.push_back(s.x);
  }
  return target;
}

void BM_CalibrationIteration(benchmark::State& st) {
  const Model model = bench::cantilever_beam(static_cast<int>(st.range(0)), material::Law::corotational, kSteps);
  double forward = 0, calibration = 0, forward_cpu = 0, calibration_cpu = 0;
  long iterations = 0, runs = 0, rejected = 0, count = 0;
  for (auto _ : st) {
    auto t0 = Clock::now();
    double c0 = cpu_now();
    const optim::CalibrationTarget target = forward_run(st, model);
    forward += since(t0);
    forward_cpu += cpu_now() - c0;
    t0 = Clock::now();
    c0 = cpu_now();
    const optim::CalibrationResult r =
        optim::calibrate(model, {{Parameter::young, 0}}, {0.5e6}, target, optim::CalibrationOptions{});
    calibration += since(t0);
    calibration_cpu += cpu_now() - c0;
    if (!r.converged) st.SkipWithError("calibration did not converge");
    iterations += r.iterations;
    runs += r.evaluations;
    rejected += r.rejected;
    ++count;
  }
  const double step_ms = 1e3 * forward / static_cast<double>(count * kSteps);
  const double iteration_ms = 1e3 * calibration / static_cast<double>(std::max<long>(iterations, 1));
  const double run_ms = 1e3 * calibration / static_cast<double>(std::max<long>(runs, 1));
  st.counters["step_ms"] = step_ms;
  st.counters["iteration_ms"] = iteration_ms;
  st.counters["ratio_per_step"] = iteration_ms / step_ms;
  st.counters["ratio_per_run"] = iteration_ms / (kSteps * step_ms);
  st.counters["cpu_ratio_per_run"] =
      calibration_cpu / static_cast<double>(std::max<long>(iterations, 1)) / (forward_cpu / static_cast<double>(count));
  st.counters["runs_per_iteration"] = static_cast<double>(runs) / static_cast<double>(std::max<long>(iterations, 1));
  st.counters["rejected"] = static_cast<double>(rejected) / static_cast<double>(count);
  // One simulation of the calibration (with its sensitivities) per forward run.
  st.counters["sim_per_run"] = run_ms / (kSteps * step_ms);
  st.counters["iterations"] = static_cast<double>(iterations) / static_cast<double>(count);
  st.counters["tets"] = model.fem.num_tets;
}

// What one simulation of a calibration costs, by part, against a plain run in the same
// benchmark iteration:
//   fresh_ratio: optim::residual() (a copy of the model, a new Data with its symbolic
//     analysis, the run with its sensitivities) / the plain run;
//   setup_ratio: the copy, the Data and the symbolic analysis alone / the plain run;
//   workspace_ratio: the same run on a CalibrationWorkspace (after its first run) / the
//     plain run: what calibrate() pays per simulation (workspace_cpu_ratio: by CPU time).
void BM_CalibrationRun(benchmark::State& st) {
  const Model model = bench::cantilever_beam(static_cast<int>(st.range(0)), material::Law::corotational, kSteps);
  const std::vector<ParameterId> young = {{Parameter::young, 0}};
  optim::CalibrationWorkspace workspace(model, young);
  double forward = 0, fresh = 0, setup = 0, reused = 0, forward_cpu = 0, reused_cpu = 0;
  long count = 0;
  VecX r;
  MatX J;
  for (auto _ : st) {
    auto t0 = Clock::now();
    double c0 = cpu_now();
    const optim::CalibrationTarget target = forward_run(st, model);
    forward += since(t0);
    forward_cpu += cpu_now() - c0;
    t0 = Clock::now();
    optim::residual(model, young, {0.8e6}, target, false, r, J);
    fresh += since(t0);
    workspace.residual({0.9e6}, target, false, r, J);  // not timed: the workspace's first run
    t0 = Clock::now();
    c0 = cpu_now();
    workspace.residual({0.8e6}, target, false, r, J);
    reused += since(t0);
    reused_cpu += cpu_now() - c0;
    t0 = Clock::now();
    {
      Model m = model;
      Data data(m);
      data.solver->analyze(data.A);
      benchmark::DoNotOptimize(data.A.valuePtr());
    }
    setup += since(t0);
    ++count;
  }
  st.counters["run_ms"] = 1e3 * forward / static_cast<double>(count);
  st.counters["fresh_ratio"] = fresh / forward;
  st.counters["setup_ratio"] = setup / forward;
  st.counters["workspace_ratio"] = reused / forward;
  st.counters["workspace_cpu_ratio"] = reused_cpu / forward_cpu;
  st.counters["tets"] = model.fem.num_tets;
}

void BM_ControlStep(benchmark::State& st) {
  const Model model = io::build_model(io::load_scene(std::string(SOFTDIFF_SOURCE_DIR) + "/configs/trunk.yaml"));
  optim::InverseDynamics controller(model, optim::ControlOptions{});
  Data data(model);
  State s = model.initial, next;
  VecX lambda = VecX::Constant(static_cast<Eigen::Index>(model.actuation.actuators.size()), 0.05), out;
  long k = 1;
  for (; k <= 5; ++k) {  // moving, bent a little
    if (!integrator::implicit_euler_step(model, data, s, next, k, &lambda).ok()) st.SkipWithError("step failed");
    std::swap(s, next);
  }
  const Vec3 goal(0.02, -0.05, 0.17);
  double step = 0, compute = 0, commit = 0, step_cpu = 0, control_cpu = 0;
  long count = 0;
  const long factorizations_before = controller.data().factorizations;
  // Every iteration is a step of `softdiff control` from a new state (the trajectory
  // advances): the controller's prediction assembles and factorizes at that state, the
  // committed step reuses its factor (optim/control.hpp). From the same state every
  // iteration, the prediction would keep the last iteration's linearization and skip
  // the assembly and the factorization (data.hpp, keep_linearization): not a control step.
  for (auto _ : st) {
    // The floor: a forward step from s on its own record.
    auto t0 = Clock::now();
    double c0 = cpu_now();
    if (!integrator::implicit_euler_step(model, data, s, next, k, &lambda).ok()) st.SkipWithError("step failed");
    step += since(t0);
    step_cpu += cpu_now() - c0;
    // The control step from the same s: the computation, then the committed step.
    t0 = Clock::now();
    c0 = cpu_now();
    optim::ControlStep info;
    if (!controller.compute(model, s, k, goal, lambda, out, info).ok()) st.SkipWithError("control failed");
    const double t_compute = since(t0);
    if (!integrator::implicit_euler_step(model, controller.data(), s, next, k, &out).ok())
      st.SkipWithError("committed step failed");
    control_cpu += cpu_now() - c0;
    commit += since(t0) - t_compute;
    compute += t_compute;
    std::swap(s, next);
    lambda = out;
    ++k;
    ++count;
  }
  const double n = static_cast<double>(count);
  st.counters["step_ms"] = 1e3 * step / n;
  st.counters["control_ms"] = 1e3 * (compute + commit) / n;
  st.counters["compute_ms"] = 1e3 * compute / n;
  st.counters["commit_ms"] = 1e3 * commit / n;
  st.counters["ratio"] = (compute + commit) / step;
  st.counters["cpu_ratio"] = control_cpu / step_cpu;
  st.counters["factorizations_per_control_step"] =
      static_cast<double>(controller.data().factorizations - factorizations_before) / n;
  st.counters["actuators"] = static_cast<double>(lambda.size());
  st.counters["tets"] = model.fem.num_tets;
}

BENCHMARK(BM_ControlStep)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);
BENCHMARK(BM_CalibrationIteration)->Arg(3)->Arg(6)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);
BENCHMARK(BM_CalibrationRun)->Arg(3)->Arg(6)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

}  // namespace
