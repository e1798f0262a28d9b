// The contact stage of the step (issues "Frictional contact", "Contact at scale"): a
// slab pressed onto a plane by gravity with 10, 100, 1000, 5000 and 20000 active vertex
// contacts, for ADMM and PGS, on the automatic backend (dense G up to 400 contacts, the
// sparse operator beyond) and, up to 1000 contacts, on the dense one.
// After 5 warm-up steps (contacts established, warm start in place), each iteration
// is one step. Counters (per step): contacts, step_ms and its split detection_ms
// (broad and narrow phase, the speculative filter), system_ms (the assembly of the
// contact system: H_c, g, and G from forward solves on the dense backend or, on the
// sparse one, B's pattern and values and the dense G_W of small working sets; the
// CLI's ms_per_step.delassus; named delassus_ms before 2026-12-02, when B's assembly
// was still booked as NCP time), ncp_ms (the solver and the polish, their
// factorizations included), ncp_factor_ms (of which the factorizations of G + rho I or
// of B), correction_ms (one more solve), fem_ms (assembly + factorization + free solve);
// iterations (ADMM/PGS); floor_ms: a bare CHOLMOD factorize + solve of the same A in
// the same run; ratio = step_ms / floor_ms; free_ms: a step of the same slab with
// contact disabled (it falls freely), same run; over_free = step_ms / free_ms;
// rho_updates: ADMM's factorizations of G + rho I (dense) or A + (h/c) H^T H (sparse);
// sparse: 1 if the step used the sparse backend; step_cpu_ms, floor_cpu_ms, free_cpu_ms,
// ratio_cpu, over_free_cpu: the same in process CPU time (with one thread the work done,
// the figure that holds on a loaded machine, as in step_timing.hpp). BM_Gripper: the same counters on the
// shipped gripper scene (soft fingers, self-contact, a fixed object).
// BM_ContactMemory/<contacts>/<contact>: the peak resident memory (getrusage's
// ru_maxrss, the whole process) of the slab after 6 steps with contact (1) or with
// contact disabled (0). It is only meaningful when it is the process's one benchmark:
// `scripts/bench contact-memory` runs each case in its own process and prints the ratio.
#include <softdiff/collision/obstacle.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <support/contact.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <benchmark/benchmark.h>
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <vector>
#include <string>

using namespace softdiff;

namespace {

constexpr long kGripperWarmup = 100;  // steps until the fingers hold the object (configs/gripper.yaml)

// The process's CPU time (s), all threads.
double cpu_now() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

struct Seconds {
  double wall = 0, cpu = 0;
};

Model slab(int contacts, contact::NcpSolverKind solver, contact::NcpBackend backend) {
  int nx = 4, ny = 1;  // (nx + 1)(ny + 1) bottom vertices
  if (contacts == 100) nx = ny = 9;
  if (contacts == 200) { nx = 14; ny = 13; }  // 210
  if (contacts == 400) nx = ny = 19;         // 400
  if (contacts == 1000) { nx = 39; ny = 24; }
  if (contacts == 5000) nx = ny = 70;    // 5041
  if (contacts == 20000) nx = ny = 141;  // 20164
  test::BodySpec spec;
  spec.young = 1e5;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_stiffness = 1e-3;
  const double cell = 0.01;
  Model model = test::make_model(test::box_mesh(nx, ny, 2, nx * cell, ny * cell, 2 * cell), spec, Vec3(0, 0, -9.81), 0.005);
  test::ContactSpec cs;
  cs.mu = 0.5;
  cs.ncp.solver = solver;
  cs.ncp.tolerance = 1e-8;
  cs.ncp.max_iterations = 5000;
  cs.ncp.backend = backend;
  if (backend == contact::NcpBackend::sparse) cs.ncp.dense_max_contacts = 0;  // ADMM on the operator throughout
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  return model;
}

// Seconds of one step of `model` without contact (the same state), wall and CPU, each
// the median of 3.
Seconds free_step_seconds(Model model, const State& s, long k) {
  model.contact.enabled = false;
  Data data(model);
  State next;
  std::vector<double> t, c;
  for (int r = 0; r < 3; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = cpu_now();
    (void)integrator::implicit_euler_step(model, data, s, next, k);
    c.push_back(cpu_now() - c0);
    t.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(t.begin(), t.end());
  std::sort(c.begin(), c.end());
  return {t[1], c[1]};
}

// Runs `warmup` steps, then one step per benchmark iteration (the state advances),
// and sets the counters of the header.
void time_contact_steps(benchmark::State& st, const Model& model, long warmup) {
  using Clock = std::chrono::steady_clock;
  Data data(model);
  State s = model.initial, next;
  long k = 0;
  for (; k < warmup; ++k) {
    const auto status = integrator::implicit_euler_step(model, data, s, next, k + 1);
    if (!status.ok()) {
      st.SkipWithError(describe(model, status).c_str());
      return;
    }
    std::swap(s, next);
  }
  StepTimings total;
  double wall = 0, cpu = 0, iterations = 0, contacts = 0, rho_updates = 0, sparse = 0, ncp_factor = 0;
  long steps = 0;
  for (auto _ : st) {
    const auto t0 = Clock::now();
    const double c0 = cpu_now();
    const auto status = integrator::implicit_euler_step(model, data, s, next, ++k);
    cpu += cpu_now() - c0;
    wall += std::chrono::duration<double>(Clock::now() - t0).count();
    if (!status.ok()) {
      st.SkipWithError(describe(model, status).c_str());
      break;
    }
    std::swap(s, next);
    total += data.timings;
    iterations += data.contact.result.iterations;
    rho_updates += data.contact.result.rho_updates;
    ncp_factor += data.contact.result.factorization_seconds;
    sparse += data.contact.result.sparse;
    contacts += data.contact.contacts.size();
    ++steps;
  }
  if (steps == 0) return;
  auto floor_solver = integrator::make_linear_solver({integrator::SolverKind::cholmod});
  floor_solver->analyze(data.A);
  VecX x;
  double floor = 0, floor_cpu = 0;
  for (int r = 0; r < 5; ++r) {
    const auto t0 = Clock::now();
    const double c0 = cpu_now();
    floor_solver->factorize(data.A);
    floor_solver->solve(data.rhs, x);
    floor_cpu += (cpu_now() - c0) / 5;
    floor += std::chrono::duration<double>(Clock::now() - t0).count() / 5;
  }
  const double per = 1e3 / static_cast<double>(steps);
  st.counters["contacts"] = contacts / steps;
  st.counters["dofs"] = 3.0 * model.fem.num_nodes;
  st.counters["step_ms"] = wall * per;
  st.counters["fem_ms"] = (total.assembly + total.factorization + total.solve + total.other) * per;
  st.counters["detection_ms"] = total.detection * per;
  st.counters["system_ms"] = total.delassus * per;
  st.counters["ncp_ms"] = total.ncp * per;
  st.counters["ncp_factor_ms"] = ncp_factor * per;
  st.counters["correction_ms"] = total.correction * per;
  st.counters["iterations"] = iterations / steps;
  st.counters["floor_ms"] = 1e3 * floor;
  st.counters["ratio"] = wall / steps / floor;
  const Seconds free = free_step_seconds(model, s, k + 1);
  st.counters["free_ms"] = 1e3 * free.wall;
  st.counters["over_free"] = wall / steps / free.wall;
  st.counters["step_cpu_ms"] = cpu * per;
  st.counters["floor_cpu_ms"] = 1e3 * floor_cpu;
  st.counters["free_cpu_ms"] = 1e3 * free.cpu;
  st.counters["ratio_cpu"] = cpu / steps / floor_cpu;
  st.counters["over_free_cpu"] = cpu / steps / free.cpu;
  st.counters["rho_updates"] = rho_updates / steps;
  st.counters["sparse"] = sparse / steps;
  const auto backend = model.contact.ncp.backend;
  st.SetLabel(std::string(model.contact.ncp.solver == contact::NcpSolverKind::admm ? "admm" : "pgs") +
              (backend == contact::NcpBackend::dense    ? " dense"
               : backend == contact::NcpBackend::sparse ? " sparse"
                                                        : " auto"));
}

// range(0): contacts; range(1): 0 admm, 1 pgs; range(2): 0 automatic, 1 dense backend,
// 2 sparse with no dense G_W at all (dense_max_contacts 0): the crossover's two sides.
void BM_Contact(benchmark::State& st) {
  const auto solver = st.range(1) == 0 ? contact::NcpSolverKind::admm : contact::NcpSolverKind::pgs;
  const auto backend = st.range(2) == 0   ? contact::NcpBackend::automatic
                       : st.range(2) == 1 ? contact::NcpBackend::dense
                                          : contact::NcpBackend::sparse;
  time_contact_steps(st, slab(static_cast<int>(st.range(0)), solver, backend), 5);
}

BENCHMARK(BM_Contact)
    ->ArgsProduct({{10, 100, 1000, 5000, 20000}, {0, 1}, {0}})
    ->ArgsProduct({{100, 1000}, {0, 1}, {1}})
    ->ArgsProduct({{100, 200, 400, 1000}, {0}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(0.5);

// The shipped gripper (configs/gripper.yaml) once its fingers hold the object:
// GRIPPER_WARMUP steps first (the time the servos need to close them), then as above.
void BM_Gripper(benchmark::State& st) {
  const auto solver = st.range(0) == 0 ? "admm" : "pgs";
  const Model model = io::build_model(io::load_scene(std::string(SOFTDIFF_SOURCE_DIR) + "/configs/gripper.yaml",
                                                     {std::string("contact.solver=") + solver}));
  time_contact_steps(st, model, kGripperWarmup);
}

BENCHMARK(BM_Gripper)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);

void BM_ContactMemory(benchmark::State& st) {
  Model model = slab(static_cast<int>(st.range(0)), contact::NcpSolverKind::admm, contact::NcpBackend::automatic);
  model.contact.enabled = st.range(1) != 0;
  for (auto _ : st) {
    Data data(model);
    State s = model.initial, next;
    for (long k = 1; k <= 6; ++k) {
      const auto status = integrator::implicit_euler_step(model, data, s, next, k);
      if (!status.ok()) {
        st.SkipWithError(describe(model, status).c_str());
        return;
      }
      std::swap(s, next);
    }
    st.counters["contacts"] = data.contact.contacts.size();
  }
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  st.counters["peak_rss_mb"] = static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

BENCHMARK(BM_ContactMemory)
    ->ArgsProduct({{10, 100, 1000, 5000, 20000}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1);

}  // namespace
