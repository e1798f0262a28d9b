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
#include <softdiff/contact/contact_step_derivatives.hpp>
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

// The mixed derivative's crossover (NcpOptions::derivative_mixed_dense_max_active;
// docs/performance.md "The mixed derivative's crossover"): the contact derivative's
// mode-fixed system with sliding contacts on the dense G_AA (3 na congruence solves and
// an O(na^3) decomposition, then O(na^2) per right-hand side) against the operator
// (the scale's power iteration, GMRES with the reduced preconditioner: one
// factorization of B, then a few solves per right-hand side). A c x c x 1-element slab
// (1 cm cells, (c + 1)^2 bottom vertices on the plane, mu 0.3) pressed 0.1 mm into the
// plane, spreading radially (v_T = 0.02 m/s r / R): the rim slides, the middle sticks.
// Per iteration: ContactStageDerivative::prepare and 2 jvps (the slab's --jacobian
// young,friction), both paths on the same step. Reported as ratios to the floor, one
// solve with the step's factorization (3n), measured in the same run: prepare, one jvp,
// and the total (prepare + 2 jvps); the crossover is where dense_total / operator_total
// passes 1.
void BM_MixedDerivative(benchmark::State& st) {
  const int cells = static_cast<int>(st.range(0));
  const bool dense = st.range(1) == 0;
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = 5e4;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 0.5;
  spec.rayleigh_stiffness = 1e-3;
  const double side = 0.01 * cells;
  Model model = test::make_model(test::box_mesh(cells, cells, 1, side, side, 0.01), spec, Vec3(0, 0, -9.81), 2e-3, 1);
  test::ContactSpec cs;
  cs.mu = 0.3;
  cs.margin = 2e-3;
  cs.ncp.tolerance = 1e-12;
  cs.ncp.max_iterations = 20000;
  cs.ncp.backend = contact::NcpBackend::sparse;  // no dense G recorded: the derivative forms G_AA or uses the operator
  cs.ncp.dense_max_contacts = 0;
  cs.ncp.derivative_dense_max_active = dense ? 1 << 30 : 0;
  cs.ncp.derivative_mixed_dense_max_active = dense ? 1 << 30 : 0;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  State in = model.initial, out;
  const Vec3 center(side / 2, side / 2, 0);
  for (int i = 0; i < model.fem.num_nodes; ++i) {
    Vec3 p = in.x.segment<3>(3 * i);
    const Vec3 r(p.x() - center.x(), p.y() - center.y(), 0);
    p.z() -= 1e-4;
    in.x.segment<3>(3 * i) = p;
    in.v.segment<3>(3 * i) = 0.02 * r / (side / 2) + Vec3(0, 0, -0.01);
  }
  Data data(model);
  if (!integrator::implicit_euler_step(model, data, in, out, 1).ok()) {
    st.SkipWithError("step failed");
    return;
  }
  const auto& cd = data.contact;
  int active = 0, sliding = 0;
  for (const auto m : cd.modes) {
    active += m != contact::Mode::breaking;
    sliding += m == contact::Mode::sliding;
  }
  if (sliding == 0) {
    st.SkipWithError("no sliding contact: not a mixed set");
    return;
  }
  const double h = model.step.dt;
  const int nc = cd.contacts.size();
  const VecX b1 = random_vector(3 * nc, 1.0, 11), b2 = random_vector(3 * nc, 1.0, 12);
  const VecX dmu = random_vector(nc, 0.2, 13);
  // The floor: one solve with the step's factorization.
  const VecX f = random_vector(3L * model.fem.num_nodes, 1.0, 14);
  VecX fx;
  double floor_s = 0;
  long floor_n = 0;
  {
    const auto t0 = Clock::now();
    do {
      if (!data.solver->solve(f, fx)) st.SkipWithError("solve failed");
      ++floor_n;
    } while (since(t0) < 0.2);
    floor_s = since(t0) / static_cast<double>(floor_n);
  }
  contact::ContactStageDerivative stage;
  VecX d1, d2;
  double prepare_s = 0, jvp_s = 0;
  long count = 0;
  for (auto _ : st) {
    auto t0 = Clock::now();
    if (!stage.prepare(model, cd, in.x, *data.solver, h, false, nullptr, nullptr, &data.A))
      st.SkipWithError("prepare failed");
    prepare_s += since(t0);
    t0 = Clock::now();
    stage.ncp().jvp(b1, dmu, d1);
    stage.ncp().jvp(b2, VecX(), d2);
    jvp_s += since(t0);
    benchmark::DoNotOptimize(d1.data());
    benchmark::DoNotOptimize(d2.data());
    ++count;
  }
  if (stage.ncp().on_operator() == dense) st.SkipWithError("not on the requested path");
  const double k = 1.0 / static_cast<double>(std::max<long>(count, 1));
  st.counters["active"] = active;
  st.counters["sliding"] = sliding;
  st.counters["floor_ms"] = 1e3 * floor_s;
  st.counters["prepare_ms"] = 1e3 * prepare_s * k;
  st.counters["jvp_ms"] = 1e3 * jvp_s * k / 2;
  st.counters["total_ms"] = 1e3 * (prepare_s + jvp_s) * k;
  st.counters["prepare_floor"] = prepare_s * k / floor_s;
  st.counters["jvp_floor"] = jvp_s * k / 2 / floor_s;
  st.counters["total_floor"] = (prepare_s + jvp_s) * k / floor_s;
}

// Active counts about (c + 1)^2: 16, 36, 64, 121, 196, 400; second argument 0 dense, 1 operator.
BENCHMARK(BM_MixedDerivative)
    ->ArgsProduct({{3, 5, 7, 10, 13, 19}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(0.5);

}  // namespace
