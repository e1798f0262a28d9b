// Cost of the derivatives relative to the forward step, measured in the same run
// (issue "End-to-end derivatives": a JVP column at most 0.3x a forward step; a full
// reverse sweep at most 2x the forward run). Cantilever beam (10 n x n x n cells, 6
// tets each: n = 6 is 13k tets), corotational, Rayleigh damping, no contact.
//   BM_StepDerivatives/<n>/<contact>: per iteration one step, one JVP column (a full tangent:
//     dx, dv and d young, as every column is after the first step) and one VJP with
//     the step's factorization. Counters: step_ms, jvp_ms, vjp_ms, jvp_ratio =
//     jvp_ms / step_ms, vjp_ratio, contacts. contact = 1: the beam's underside pressed
//     onto a plane (sticking contacts; the derivatives' contact part: geometry
//     derivatives, the NCP derivative's factorization, one more solve).
//   BM_Adjoint/<n>/<contact>: 100 steps recorded (forward_ms, the plain run), then the
//     reverse sweep over them (adjoint_ms: each step recomputed from its recorded state
//     plus its VJP). Counters: forward_ms, adjoint_ms, ratio = adjoint_ms / forward_ms,
//     tape_MB. contact = 1: the beam pressed onto the plane as above (each step of the
//     sweep recomputes the contact solve from the taped warm start and factorizes its
//     NCP derivative).
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <support/contact.hpp>
#include <support/fd.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include "beam.hpp"

#include <benchmark/benchmark.h>

#include <chrono>
#include <random>

using namespace softdiff;

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// The cantilever's underside pressed 0.1 mm into a plane (mu = 0.5): every bottom
// vertex beyond the clamp is a vertex-plane contact.
void press_onto_plane(Model& model) {
  test::ContactSpec cs;
  cs.mu = 0.5;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 1e-4)}, cs);
}


using test::random_vector;

void BM_StepDerivatives(benchmark::State& st) {
  Model model = bench::cantilever_beam(static_cast<int>(st.range(0)), material::Law::corotational, 10);
  if (st.range(1)) press_onto_plane(model);
  Data data(model);
  State s = model.initial, next;
  for (int k = 1; k <= 3; ++k) {
    if (!integrator::implicit_euler_step(model, data, s, next, k).ok()) {
      st.SkipWithError("step failed");
      return;
    }
    std::swap(s, next);
  }
  integrator::StepDerivatives d(model, {{Parameter::young, 0}});
  const Eigen::Index n = s.x.size();
  integrator::StepTangent t;
  t.x = random_vector(n, 1e-4, 1);
  t.v = random_vector(n, 1e-2, 2);
  t.p = VecX::Ones(1);
  integrator::StateTangent w, r;
  w.x = random_vector(n, 1.0, 3);
  w.v = random_vector(n, 1.0, 4);
  integrator::StepCotangent c;
  double step = 0, jvp = 0, vjp = 0;
  long count = 0;
  for (auto _ : st) {
    auto t0 = Clock::now();
    if (!integrator::implicit_euler_step(model, data, s, next, 4 + count).ok()) st.SkipWithError("step failed");
    step += since(t0);
    t0 = Clock::now();
    if (!d.jvp(model, data, s, next, t, r)) st.SkipWithError("jvp failed");
    jvp += since(t0);
    t0 = Clock::now();
    if (!d.vjp(model, data, s, next, w, c)) st.SkipWithError("vjp failed");
    vjp += since(t0);
    benchmark::DoNotOptimize(r.x.data());
    benchmark::DoNotOptimize(c.x.data());
    ++count;
  }
  const double k = 1e3 / static_cast<double>(std::max<long>(count, 1));
  st.counters["step_ms"] = step * k;
  st.counters["jvp_ms"] = jvp * k;
  st.counters["vjp_ms"] = vjp * k;
  st.counters["jvp_ratio"] = jvp / step;
  st.counters["vjp_ratio"] = vjp / step;
  st.counters["tets"] = model.fem.num_tets;
  st.counters["contacts"] = model.contact.enabled ? data.contact.contacts.size() : 0;
}

void BM_Adjoint(benchmark::State& st) {
  constexpr long kSteps = 100;
  Model model = bench::cantilever_beam(static_cast<int>(st.range(0)), material::Law::corotational, kSteps);
  if (st.range(1)) press_onto_plane(model);
  Data data(model);
  diff::Tape tape;
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}, {Parameter::poisson, 0}, {Parameter::density, 0}};
  const VecX c = random_vector(model.initial.x.size(), 1.0, 5);
  double forward = 0, reverse = 0;
  long count = 0;
  for (auto _ : st) {
    auto t0 = Clock::now();
    if (!diff::record(model, data, model.initial, kSteps, tape).ok()) st.SkipWithError("forward run failed");
    forward += since(t0);
    diff::AdjointResult g;
    t0 = Clock::now();
    const auto loss = [&](long k, const State&, VecX& bar_x, VecX&) {
      if (k == kSteps) bar_x += c;
    };
    if (!diff::adjoint(model, data, tape, theta, loss, g).ok()) st.SkipWithError("adjoint failed");
    reverse += since(t0);
    benchmark::DoNotOptimize(g.theta.data());
    ++count;
  }
  const double k = 1e3 / static_cast<double>(std::max<long>(count, 1));
  st.counters["forward_ms"] = forward * k;
  st.counters["adjoint_ms"] = reverse * k;
  st.counters["ratio"] = reverse / forward;
  st.counters["tape_MB"] = static_cast<double>(tape.bytes()) / 1e6;
  st.counters["tets"] = model.fem.num_tets;
  st.counters["contacts"] = model.contact.enabled ? data.contact.contacts.size() : 0;
}

BENCHMARK(BM_StepDerivatives)
    ->Args({3, 0})
    ->Args({6, 0})
    ->Args({6, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(1.0);
BENCHMARK(BM_Adjoint)->Args({6, 0})->Args({3, 1})->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

}  // namespace
