// Time of one implicit Euler step on cantilever beams of ~1.6k, 13k and 104k tets for
// each law (and 43.7k, n = 9, corotational only), split into assembly / factorization / solve, and its ratio to a floor
// measured in the same run: a bare CHOLMOD numeric factorization + solve of the same
// matrix A (symbolic analysis excluded from both, as in a run). Counters: see
// step_timing.hpp (step_ms, assembly_ms, factorize_ms, solve_ms, floor_ms, ratio, ...).
// BM_Step10/<n>/<law>: the same beams with 10-node tets (the same tets with mid-edge
// nodes: n = 3, 6 give 1.6k and 13k elements, 5.4k and 61k dofs), the same floor.
#include "step_timing.hpp"

#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include "beam.hpp"

#include <benchmark/benchmark.h>

using namespace softdiff;

namespace {

void BM_Step(benchmark::State& st) {
  const int n = static_cast<int>(st.range(0));
  const auto law = static_cast<material::Law>(st.range(1));
  bench::time_steps(st, bench::cantilever_beam(n, law));
  st.SetLabel(std::string(material::law_name(law)));
}

void step_args(benchmark::internal::Benchmark* b) {
  for (int n : {3, 6, 12})
    for (int law : {0, 1, 2}) b->Args({n, law});
  b->Args({9, 0});  // 43.7k tets, corotational: issue 20's "50k" row (scripts/bench figures)
}

BENCHMARK(BM_Step)->Apply(step_args)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);

void BM_Step10(benchmark::State& st) {
  const int n = static_cast<int>(st.range(0));
  const auto law = static_cast<material::Law>(st.range(1));
  bench::time_steps(st, bench::cantilever_beam(n, law, 1, true));
  st.SetLabel(std::string(material::law_name(law)) + " tet10");
}

void step10_args(benchmark::internal::Benchmark* b) {
  for (int n : {3, 6})
    for (int law : {0, 1, 2}) b->Args({n, law});
}

BENCHMARK(BM_Step10)->Apply(step10_args)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);

}  // namespace

