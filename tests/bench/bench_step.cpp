// Time of one implicit Euler step on cantilever beams of ~1.6k, 13k and 104k tets for
// each law, split into assembly / factorization / solve, and its ratio to a floor
// measured in the same run: a bare CHOLMOD numeric factorization + solve of the same
// matrix A (symbolic analysis excluded from both, as in a run). Reported as counters:
//   step_ms, assembly_ms, factorize_ms, solve_ms, floor_ms, ratio = step_ms / floor_ms.
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <benchmark/benchmark.h>
#include <chrono>

using namespace softdiff;

namespace {

using Clock = std::chrono::steady_clock;

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
  const Model model = beam(n, law);
  Data data(model);
  State s = model.initial, next;
  // Warm up: move away from rest (rotations non-trivial), analyze once.
  for (int k = 1; k <= 3; ++k) {
    integrator::implicit_euler_step(model, data, s, next, k);
    std::swap(s, next);
  }
  StepTimings total;
  long steps = 0;
  double wall = 0;
  for (auto _ : st) {
    const auto t0 = Clock::now();
    const auto status = integrator::implicit_euler_step(model, data, s, next, 4 + steps);
    wall += std::chrono::duration<double>(Clock::now() - t0).count();
    if (!status.ok()) st.SkipWithError(describe(model, status).c_str());
    benchmark::DoNotOptimize(next.x.data());
    total += data.timings;
    ++steps;
  }
  // Floor: bare CHOLMOD factorize + solve of the last step's matrix, same run.
  auto floor_solver = integrator::make_linear_solver({integrator::SolverKind::cholmod});
  floor_solver->analyze(data.A);
  VecX x;
  double floor = 0;
  const int reps = std::max<long>(3, std::min<long>(steps, 20));
  for (int r = 0; r < reps; ++r) {
    const auto t0 = Clock::now();
    floor_solver->factorize(data.A);
    floor_solver->solve(data.rhs, x);
    floor += std::chrono::duration<double>(Clock::now() - t0).count();
    benchmark::DoNotOptimize(x.data());
  }
  floor /= reps;
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
  st.counters["L_nnz"] = floor_solver->factor_nonzeros();
  st.counters["floor_GFlops"] = floor_solver->factor_flops() / floor * 1e-9;
  st.SetLabel(std::string(material::law_name(law)));
}

void step_args(benchmark::internal::Benchmark* b) {
  for (int n : {3, 6, 12})
    for (int law : {0, 1, 2}) b->Args({n, law});
}

BENCHMARK(BM_Step)->Apply(step_args)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);

}  // namespace

