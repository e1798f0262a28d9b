// The cost of a BDF2 step against an implicit Euler step (docs/performance.md, "BDF2"),
// interleaved in one run so that the machine's load affects both alike: every
// iteration takes one implicit Euler step and one BDF2 step from the same state (the
// BDF2 step with the state one step earlier as its history), each timed alone.
// Counters: euler_ms, bdf2_ms (wall per step), ratio = bdf2_ms / euler_ms; the same in
// process CPU time (euler_cpu_ms, bdf2_cpu_ms, cpu_ratio: with one thread, OMP_NUM_THREADS=1
// and OPENBLAS_NUM_THREADS=1, the figure that waiting for a loaded machine's cores does
// not inflate); and the factorizations per step of each (1 and 1: the same count).
#include "beam.hpp"

#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>

#include <benchmark/benchmark.h>
#include <chrono>
#include <ctime>

namespace {

using namespace softdiff;

void BM_Bdf2VsEuler(benchmark::State& st) {
  using Clock = std::chrono::steady_clock;
  const int n = static_cast<int>(st.range(0));
  Model model = bench::cantilever_beam(n, material::Law::neo_hookean);
  model.step.integrator = IntegratorKind::bdf2;
  Data de(model), db(model);
  State previous = model.initial, s = model.initial, next;
  for (int k = 1; k <= 3; ++k) {  // away from rest; symbolic analyses done
    const auto status = integrator::implicit_euler_step(model, de, s, next, k);
    if (!status.ok()) {
      st.SkipWithError(describe(model, status).c_str());
      return;
    }
    previous = s;
    std::swap(s, next);
  }
  if (!integrator::bdf2_step(model, db, s, &previous, next, 4).ok()) {
    st.SkipWithError("bdf2 step failed");
    return;
  }
  const auto cpu_now = [] {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
  };
  double euler = 0, bdf2 = 0, euler_cpu = 0, bdf2_cpu = 0;
  long steps = 0;
  const long fe0 = de.factorizations, fb0 = db.factorizations;
  for (auto _ : st) {
    auto t0 = Clock::now();
    double c0 = cpu_now();
    const auto a = integrator::implicit_euler_step(model, de, s, next, 5 + steps);
    euler_cpu += cpu_now() - c0;
    euler += std::chrono::duration<double>(Clock::now() - t0).count();
    benchmark::DoNotOptimize(next.x.data());
    t0 = Clock::now();
    c0 = cpu_now();
    const auto b = integrator::bdf2_step(model, db, s, &previous, next, 5 + steps);
    bdf2_cpu += cpu_now() - c0;
    bdf2 += std::chrono::duration<double>(Clock::now() - t0).count();
    benchmark::DoNotOptimize(next.x.data());
    if (!a.ok() || !b.ok()) st.SkipWithError("a step failed");
    ++steps;
  }
  st.counters["dofs"] = 3.0 * model.fem.num_nodes;
  st.counters["euler_ms"] = 1e3 * euler / static_cast<double>(steps);
  st.counters["bdf2_ms"] = 1e3 * bdf2 / static_cast<double>(steps);
  st.counters["ratio"] = bdf2 / euler;
  st.counters["euler_cpu_ms"] = 1e3 * euler_cpu / static_cast<double>(steps);
  st.counters["bdf2_cpu_ms"] = 1e3 * bdf2_cpu / static_cast<double>(steps);
  st.counters["cpu_ratio"] = bdf2_cpu / euler_cpu;
  st.counters["euler_factorizations"] = static_cast<double>(de.factorizations - fe0) / static_cast<double>(steps);
  st.counters["bdf2_factorizations"] = static_cast<double>(db.factorizations - fb0) / static_cast<double>(steps);
}

BENCHMARK(BM_Bdf2VsEuler)->Arg(3)->Arg(6)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(5.0);

}  // namespace
