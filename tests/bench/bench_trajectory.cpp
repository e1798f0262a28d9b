// A 100-step trajectory against the sum of its per-step floors, with and without
// factor reuse (linear_solver.factor_reuse: pcg, docs/method.md "Reusing the factor").
// BM_Trajectory/<case>/<reuse>/<t>: pcg_tolerance 10^-t (10: the default; 6 shows
// what a looser tolerance would buy, not a supported setting's figure); case 0 the Trunk (configs/trunk.yaml, every cable at
// 0.01 N, gravity: the trunk droops from rest), case 1 the 13k-tet cantilever beam of
// BM_Step/6/0 (corotational, falling from rest under gravity). Each benchmark
// iteration runs the 100 steps from the initial state with a fresh Data whose symbolic
// analysis is done before the clock starts (as in a run); every step's matrix A and
// right-hand side are recorded (outside the clock). The floor, in the same run: a bare
// CHOLMOD numeric factorization + solve of each recorded step's A, summed over the
// 100 steps (the direct trajectory's floor; with reuse the matrices are those of the
// reuse trajectory, equal to the direct ones to the PCG tolerance). Counters:
//   trajectory_ms, floor_ms (sums over 100 steps), ratio = trajectory / floor;
//   trajectory_cpu_ms, floor_cpu_ms, ratio_cpu: the same in process CPU time (with one
//   thread the work done: the figure that holds on a loaded machine);
//   assembly_ms, factorize_ms, solve_ms (the steps' own split, summed);
//   factorizations (numeric), pcg_iterations_per_step (over the kept-factor steps),
//   iteration_ms (one PCG iteration: solve_ms / pcg_iterations on the kept steps, an
//   upper bound), factor_ms (floor per step) and their ratio iteration_per_factor.
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>

#include "beam.hpp"
#include "step_timing.hpp"

#include <benchmark/benchmark.h>
#include <chrono>
#include <cmath>
#include <ctime>
#include <string>
#include <vector>

using namespace softdiff;
using softdiff::bench::Stopwatch;

namespace {

Model trajectory_model(int which) {
  if (which == 1) return bench::cantilever_beam(6, material::Law::corotational, 100);
  std::vector<std::string> overrides;
  for (const char* cable : {"cableL0", "cableL1", "cableL2", "cableL3", "cableS0", "cableS1", "cableS2", "cableS3"})
    overrides.push_back(std::string("bodies.trunk.actuators.") + cable + ".force=0.01");
  return io::build_model(io::load_scene(std::string(SOFTDIFF_SOURCE_DIR) + "/configs/trunk.yaml", overrides));
}

void BM_Trajectory(benchmark::State& st) {
  const int which = static_cast<int>(st.range(0));
  Model model = trajectory_model(which);
  model.solver.factor_reuse = st.range(1) != 0;
  model.solver.pcg_tolerance = std::pow(10.0, -static_cast<double>(st.range(2)));
  constexpr int steps = 100;
  std::vector<VecX> A_values(steps), rhs(steps);
  Stopwatch run, floor_watch;
  StepTimings total;
  long runs = 0, numeric = 0, pcg_iterations = 0, kept = 0;
  auto floor_solver = integrator::make_linear_solver({integrator::SolverKind::cholmod});
  for (auto _ : st) {
    Data data(model);
    data.solver->analyze(data.A);
    data.analyzed = true;
    State s = model.initial, next;
    for (int k = 1; k <= steps; ++k) {
      const auto status = run.time([&] { return integrator::time_step(model, data, s, nullptr, next, k); });
      if (!status.ok()) {
        st.SkipWithError(describe(model, status).c_str());
        return;
      }
      total += data.timings;
      A_values[k - 1] = Eigen::Map<const VecX>(data.A.valuePtr(), data.A.nonZeros());
      rhs[k - 1] = data.rhs;
      std::swap(s, next);
    }
    benchmark::DoNotOptimize(s.x.data());
    const auto& c = data.solver->counters();
    numeric += c.numeric_factorizations;
    pcg_iterations += c.pcg_iterations;
    kept += c.kept_factors;
    // The floor of the same 100 matrices.
    if (runs == 0) floor_solver->analyze(data.A);
    SparseMatrix A = data.A;
    VecX x;
    for (int k = 0; k < steps; ++k) {
      Eigen::Map<VecX>(A.valuePtr(), A.nonZeros()) = A_values[k];
      floor_watch.time([&] {
        floor_solver->factorize(A);
        floor_solver->solve(rhs[k], x);
      });
      benchmark::DoNotOptimize(x.data());
    }
    ++runs;
  }
  const double per_run = 1e3 / static_cast<double>(runs);
  const double wall = run.wall, cpu = run.cpu, floor = floor_watch.wall, floor_cpu = floor_watch.cpu;
  st.counters["tets"] = model.fem.num_tets;
  st.counters["dofs"] = 3.0 * model.fem.num_nodes;
  st.counters["trajectory_ms"] = wall * per_run;
  st.counters["floor_ms"] = floor * per_run;
  st.counters["ratio"] = wall / floor;
  st.counters["trajectory_cpu_ms"] = cpu * per_run;
  st.counters["floor_cpu_ms"] = floor_cpu * per_run;
  st.counters["ratio_cpu"] = cpu / floor_cpu;
  st.counters["assembly_ms"] = total.assembly * per_run;
  st.counters["factorize_ms"] = total.factorization * per_run;
  st.counters["solve_ms"] = total.solve * per_run;
  st.counters["factorizations"] = static_cast<double>(numeric) / runs;
  st.counters["pcg_iterations_per_step"] = kept ? static_cast<double>(pcg_iterations) / kept : 0.0;
  st.counters["factor_ms"] = floor * per_run / steps;
  if (pcg_iterations > 0) {
    const double iteration_ms = total.solve * per_run * runs / pcg_iterations;
    st.counters["iteration_ms"] = iteration_ms;
    st.counters["iteration_per_factor"] = iteration_ms / (floor * per_run / steps);
  }
  st.SetLabel(std::string(which == 0 ? "trunk" : "beam 13k") +
              (model.solver.factor_reuse ? " pcg 1e-" + std::to_string(st.range(2)) : " direct"));
}

BENCHMARK(BM_Trajectory)
    ->Args({0, 0, 10})
    ->Args({0, 1, 10})
    ->Args({0, 1, 6})
    ->Args({1, 0, 10})
    ->Args({1, 1, 10})
    ->Args({1, 1, 6})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

}  // namespace
