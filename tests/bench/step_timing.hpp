#pragma once
// The implicit Euler step timed with a floor from the same run (BM_Step, BM_Trunk):
// after 3 warm-up steps (state away from rest, symbolic analysis done), each benchmark
// iteration is one step; then a bare CHOLMOD numeric factorization + solve of the last
// step's matrix A (symbolic analysis excluded from both, as in a run) is timed as the
// floor. Every iteration repeats the same step (from the state after the warm-up). Counters:
//   step_ms, assembly_ms, factorize_ms, solve_ms, other_ms (the step's own split),
//   floor_ms, ratio = step_ms / floor_ms, L_nnz (factor non-zeros), floor_GFlops;
//   step_cpu_ms, floor_cpu_ms, ratio_cpu: the same in process CPU time (all threads),
//   the stable figure on a shared, oversubscribed machine when run with one thread
//   (OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1: CPU time is then the work done).
// The step's assembly includes the actuation forces (H_a(x_i)^T lambda_a).
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/linear_solver.hpp>

#include <benchmark/benchmark.h>
#include <algorithm>
#include <chrono>
#include <ctime>

namespace softdiff::bench {

// Wall time and process CPU time (all threads) accumulated over timed calls:
// `auto r = watch.time([&] { return work(); });`.
struct Stopwatch {
  double wall = 0, cpu = 0;
  static double cpu_now() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }
  template <class F>
  decltype(auto) time(F&& f) {
    struct Stop {  // adds the elapsed times when f has returned (void or not)
      Stopwatch& w;
      std::chrono::steady_clock::time_point t0 = std::chrono::steady_clock::now();
      double c0 = cpu_now();
      ~Stop() {
        w.cpu += cpu_now() - c0;
        w.wall += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      }
    } stop{*this};
    return f();
  }
};

inline void time_steps(benchmark::State& st, const Model& model) {
  Data data(model);
  State s = model.initial, next;
  for (int k = 1; k <= 3; ++k) {
    const auto status = integrator::implicit_euler_step(model, data, s, next, k);
    if (!status.ok()) {
      st.SkipWithError(describe(model, status).c_str());
      return;
    }
    std::swap(s, next);
  }
  StepTimings total;
  long steps = 0;
  Stopwatch run, floor_watch;
  for (auto _ : st) {
    const auto status = run.time([&] { return integrator::implicit_euler_step(model, data, s, next, 4 + steps); });
    if (!status.ok()) st.SkipWithError(describe(model, status).c_str());
    benchmark::DoNotOptimize(next.x.data());
    total += data.timings;
    ++steps;
  }
  // Floor: bare CHOLMOD factorize + solve of the last step's matrix, same run.
  auto floor_solver = integrator::make_linear_solver({integrator::SolverKind::cholmod});
  floor_solver->analyze(data.A);
  VecX x;
  const int reps = static_cast<int>(std::max<long>(3, std::min<long>(steps, 20)));
  for (int r = 0; r < reps; ++r) {
    floor_watch.time([&] {
      floor_solver->factorize(data.A);
      floor_solver->solve(data.rhs, x);
    });
    benchmark::DoNotOptimize(x.data());
  }
  const double wall = run.wall, cpu = run.cpu, floor = floor_watch.wall / reps, floor_cpu = floor_watch.cpu / reps;
  const double per = 1e3 / static_cast<double>(steps);
  st.counters["tets"] = model.fem.num_tets;
  st.counters["dofs"] = 3.0 * model.fem.num_nodes;
  st.counters["step_ms"] = wall * per;
  st.counters["assembly_ms"] = total.assembly * per;
  st.counters["factorize_ms"] = total.factorization * per;
  st.counters["solve_ms"] = total.solve * per;
  st.counters["other_ms"] = total.other * per;
  st.counters["floor_ms"] = 1e3 * floor;
  st.counters["ratio"] = wall / steps / floor;
  st.counters["step_cpu_ms"] = cpu * per;
  st.counters["floor_cpu_ms"] = 1e3 * floor_cpu;
  st.counters["ratio_cpu"] = cpu / steps / floor_cpu;
  st.counters["L_nnz"] = floor_solver->factor_nonzeros();
  st.counters["floor_GFlops"] = floor_solver->factor_flops() / floor * 1e-9;
}

}  // namespace softdiff::bench
