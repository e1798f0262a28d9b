// The cost of a BDF2 step against an implicit Euler step (docs/performance.md, "BDF2"),
// interleaved in one run so that the machine's load affects both alike: every
// iteration takes one implicit Euler step and one BDF2 step from the same state (the
// BDF2 step with the state one step earlier as its history), each timed alone.
// Counters: euler_ms, bdf2_ms (wall per step), ratio = bdf2_ms / euler_ms, and the
// factorizations per step of each (1 and 1: the same count).
#include "beam.hpp"

#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>

#include <benchmark/benchmark.h>
#include <chrono>

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
  double euler = 0, bdf2 = 0;
  long steps = 0;
  const long fe0 = de.factorizations, fb0 = db.factorizations;
  for (auto _ : st) {
    auto t0 = Clock::now();
    const auto a = integrator::implicit_euler_step(model, de, s, next, 5 + steps);
    euler += std::chrono::duration<double>(Clock::now() - t0).count();
    benchmark::DoNotOptimize(next.x.data());
    t0 = Clock::now();
    const auto b = integrator::bdf2_step(model, db, s, &previous, next, 5 + steps);
    bdf2 += std::chrono::duration<double>(Clock::now() - t0).count();
    benchmark::DoNotOptimize(next.x.data());
    if (!a.ok() || !b.ok()) st.SkipWithError("a step failed");
    ++steps;
  }
  st.counters["dofs"] = 3.0 * model.fem.num_nodes;
  st.counters["euler_ms"] = 1e3 * euler / static_cast<double>(steps);
  st.counters["bdf2_ms"] = 1e3 * bdf2 / static_cast<double>(steps);
  st.counters["ratio"] = bdf2 / euler;
  st.counters["euler_factorizations"] = static_cast<double>(de.factorizations - fe0) / static_cast<double>(steps);
  st.counters["bdf2_factorizations"] = static_cast<double>(db.factorizations - fb0) / static_cast<double>(steps);
}

BENCHMARK(BM_Bdf2VsEuler)->Arg(3)->Arg(6)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

}  // namespace
