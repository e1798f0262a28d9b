// Time of one implicit Euler step on cantilever beams of ~1.6k, 13k and 104k tets for
// each law, split into assembly / factorization / solve, and its ratio to a floor
// measured in the same run: a bare CHOLMOD numeric factorization + solve of the same
// matrix A (symbolic analysis excluded from both, as in a run). Counters: see
// step_timing.hpp (step_ms, assembly_ms, factorize_ms, solve_ms, floor_ms, ratio, ...).
#include "step_timing.hpp"

#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <benchmark/benchmark.h>

using namespace softdiff;

namespace {

Model beam(int n, material::Law law) {
  test::BodySpec spec;
  spec.law = law;
  spec.young = 1e6;
  spec.poisson = 0.45;
  spec.density = 1070;
  spec.rayleigh_mass = 0.1;
  spec.rayleigh_stiffness = 0.001;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  return test::make_model(test::box_mesh(10 * n, n, n, 0.2, 0.02, 0.02), spec, Vec3(0, 0, -9.81), 0.01);
}

void BM_Step(benchmark::State& st) {
  const int n = static_cast<int>(st.range(0));
  const auto law = static_cast<material::Law>(st.range(1));
  bench::time_steps(st, beam(n, law));
  st.SetLabel(std::string(material::law_name(law)));
}

void step_args(benchmark::internal::Benchmark* b) {
  for (int n : {3, 6, 12})
    for (int law : {0, 1, 2}) b->Args({n, law});
}

BENCHMARK(BM_Step)->Apply(step_args)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);

}  // namespace

