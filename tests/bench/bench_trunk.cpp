// The implicit Euler step on the shipped Trunk scene (configs/trunk.yaml: 1158 nodes,
// 3653 tets, 8 embedded cables of 21 / 11 points), every cable at a tension of 0.01 N,
// gravity as shipped. Counters as BM_Step (step_timing.hpp), plus cables_us: one
// evaluation of the 8 cable forces H_a(x)^T lambda_a (part of assembly_ms).
#include "step_timing.hpp"

#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>

#include <benchmark/benchmark.h>
#include <chrono>
#include <string>
#include <vector>

using namespace softdiff;

namespace {

void BM_Trunk(benchmark::State& st) {
  std::vector<std::string> overrides;
  for (const char* cable : {"cableL0", "cableL1", "cableL2", "cableL3", "cableS0", "cableS1", "cableS2", "cableS3"})
    overrides.push_back(std::string("bodies.trunk.actuators.") + cable + ".force=0.01");  // replaces cableL0's schedule
  const Model model =
      io::build_model(io::load_scene(std::string(SOFTDIFF_SOURCE_DIR) + "/configs/trunk.yaml", overrides));
  bench::time_steps(st, model);

  VecX lambda, f = VecX::Zero(model.initial.x.size());
  model.actuation.values(0.0, lambda);
  const int reps = 1000;
  const auto t0 = std::chrono::steady_clock::now();
  for (int r = 0; r < reps; ++r) {
    model.actuation.add_forces(model.initial.x, lambda, 1.0, f);
    benchmark::DoNotOptimize(f.data());
  }
  st.counters["cables_us"] =
      1e6 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / reps;
  st.counters["cables"] = static_cast<double>(model.actuation.actuators.size());
}

BENCHMARK(BM_Trunk)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

}  // namespace
