// A shipped scene's whole run against the sum of its per-step floors, measured in the
// same run (issue 20 "Measure and report": "the pianist (the whole run)").
// BM_PianistRun/<steps>: configs/pianist.yaml as shipped (3 fingers, 3 keys, contact,
// 450 steps of 0.01 s); steps = 0 runs the whole run, another value its first steps.
// The symbolic analysis is done before the clock starts (as in a run). After each step,
// outside the clock, a bare CHOLMOD numeric factorization + solve of that step's matrix
// A (the floor of BM_Step) is timed; the floor of the run is their sum. Counters:
//   run_ms, floor_ms (sums over the steps), ratio = run_ms / floor_ms, step_ms (run_ms
//   per step); run_cpu_ms, floor_cpu_ms, ratio_cpu (process CPU time: with one thread
//   the work done, the figure that holds on a loaded machine); assembly_ms,
//   factorize_ms, solve_ms, contact_ms, other_ms (the steps' own split, per step);
//   contacts (per step, mean).
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>

#include "step_timing.hpp"

#include <benchmark/benchmark.h>
#include <algorithm>
#include <chrono>
#include <ctime>
#include <string>

using namespace softdiff;
using softdiff::bench::Stopwatch;

namespace {

void BM_PianistRun(benchmark::State& st) {
  const Model model = io::build_model(io::load_scene(std::string(SOFTDIFF_SOURCE_DIR) + "/configs/pianist.yaml"));
  const long steps = st.range(0) > 0 ? std::min<long>(st.range(0), model.step.steps) : model.step.steps;
  Stopwatch run, floor_watch;
  double contacts = 0;
  StepTimings total;
  long runs = 0;
  auto floor_solver = integrator::make_linear_solver({integrator::SolverKind::cholmod});
  VecX x;
  for (auto _ : st) {
    Data data(model);
    data.solver->analyze(data.A);
    data.analyzed = true;
    if (runs == 0) floor_solver->analyze(data.A);
    State s = model.initial, next, previous;
    for (long k = 1; k <= steps; ++k) {
      const auto status =
          run.time([&] { return integrator::time_step(model, data, s, k > 1 ? &previous : nullptr, next, k); });
      if (!status.ok()) {
        st.SkipWithError(describe(model, status).c_str());
        return;
      }
      total += data.timings;
      contacts += static_cast<double>(data.contact.contacts.size());
      // The floor of this step's matrix (outside the run's clock).
      floor_watch.time([&] {
        floor_solver->factorize(data.A);
        floor_solver->solve(data.rhs, x);
      });
      benchmark::DoNotOptimize(x.data());
      previous = s;
      std::swap(s, next);
    }
    benchmark::DoNotOptimize(s.x.data());
    ++runs;
  }
  if (runs == 0) return;
  const double wall = run.wall, cpu = run.cpu, floor = floor_watch.wall, floor_cpu = floor_watch.cpu;
  const double per_run = 1e3 / static_cast<double>(runs), per_step = per_run / static_cast<double>(steps);
  st.counters["tets"] = model.fem.num_tets;
  st.counters["dofs"] = 3.0 * model.fem.num_nodes;
  st.counters["steps"] = static_cast<double>(steps);
  st.counters["run_ms"] = wall * per_run;
  st.counters["floor_ms"] = floor * per_run;
  st.counters["ratio"] = wall / floor;
  st.counters["step_ms"] = wall * per_step;
  st.counters["run_cpu_ms"] = cpu * per_run;
  st.counters["floor_cpu_ms"] = floor_cpu * per_run;
  st.counters["ratio_cpu"] = cpu / floor_cpu;
  st.counters["assembly_ms"] = total.assembly * per_step;
  st.counters["factorize_ms"] = total.factorization * per_step;
  st.counters["solve_ms"] = total.solve * per_step;
  st.counters["contact_ms"] = total.contact() * per_step;
  st.counters["other_ms"] = total.other * per_step;
  st.counters["contacts"] = contacts / static_cast<double>(runs * steps);
}

BENCHMARK(BM_PianistRun)->Arg(0)->Arg(50)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

}  // namespace
