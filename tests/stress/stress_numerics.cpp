// The numerical stress suite (label `stress`, docs/method.md "Stress suite"): the
// scenes where soft-robot simulations push the solver. Each case ends either with a
// bounded, physically sensible result (no NaN, total energy not growing without
// input, no penetration beyond the contact tolerance) or with a clear, early error
// naming the cause (the step, and the element or node). Every case prints one line
//     STRESS | <case> | <outcome>
// which is the table of the README's "Accuracy and performance" section.
//
// Energy: E = 1/2 v^T M v + E_el(x) - P.x (lumped M, gravity P). Implicit Euler is
// dissipative for a convex potential; the linearized step (newton_iterations = 1) is
// not exactly, so the bound is E_k <= E_0 + 1e-6 |E_ref|, E_ref = m g L (the energy
// that a sag of the body's size would release), checked at every step.
#include <softdiff/data.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/mesh/tet_mesh.hpp>
#include <support/cli.hpp>
#include <support/contact.hpp>
#include <support/contact_checks.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>
#include <support/ncp_table.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <iostream>
#include <limits>
#include <numbers>
#include <string>

using namespace softdiff;
namespace fs = std::filesystem;

namespace {

constexpr double kG = 9.81;
const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "stress";

void report(const std::string& name, const std::string& outcome) {
  std::cout << "STRESS | " << name << " | " << outcome << "\n";
}

std::string num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.4g", v);
  return b;
}

// Total energy 1/2 v^T M v + E_el(x) - P.x; NaN if an element is inverted.
double total_energy(const Model& model, const State& s, fem::FemData& fd) {
  fem::EvalRequest rq;
  rq.energy = true;
  rq.forces = false;
  rq.stiffness = false;
  if (!fem::evaluate(model.fem, s.x, rq, fd)) return std::numeric_limits<double>::quiet_NaN();
  const double kinetic = 0.5 * s.v.dot(model.fem.mass_diagonal.cwiseProduct(s.v));
  return kinetic + fd.energy - model.fem.gravity_force.dot(s.x);
}

struct Outcome {
  StepStatus status;              // the first failure, or ok
  std::string message;            // describe(status)
  long steps = 0;                 // steps completed
  bool finite = true;             // every accepted state finite
  double energy_rise = 0;         // max over steps of (E_k - E_0) / E_ref
  double energy_final = 0;        // (E_last - E_0) / E_ref
  bool contact_converged = true;  // every NCP solve converged
  State last;                     // the last accepted state
  bool ok() const { return status.ok(); }
};

// Runs model.step.steps steps from model.initial; after each accepted step `check`
// (may be empty). Stops at the first failure.
Outcome simulate(const Model& model, const std::function<void(long, const Data&, const State&)>& check = {}) {
  Data data(model);
  fem::FemData fd;
  fd.resize(model.fem);
  Outcome o;
  State s = model.initial, next = s;
  const double e0 = total_energy(model, s, fd);
  const double e_ref = model.fem.total_mass * kG * model.fem.bodies[0].bbox_diagonal;
  for (long k = 1; k <= model.step.steps; ++k) {
    o.status = integrator::implicit_euler_step(model, data, s, next, k);
    if (!o.status.ok()) {
      o.message = describe(model, o.status);
      break;
    }
    o.finite = o.finite && next.x.allFinite() && next.v.allFinite();
    if (model.contact.enabled) o.contact_converged = o.contact_converged && data.contact.result.converged;
    o.energy_final = (total_energy(model, next, fd) - e0) / e_ref;
    o.energy_rise = std::max(o.energy_rise, o.energy_final);
    std::swap(s, next);
    o.steps = k;
    if (check) check(k, data, s);
  }
  o.last = s;
  return o;
}

std::string describe_outcome(const Outcome& o) {
  if (!o.ok()) return "error: " + o.message;
  return "ok, " + std::to_string(o.steps) + " steps, energy rise " + num(o.energy_rise) + " E_ref";
}

// The cantilever of configs/beam_cantilever.yaml (0.2 x 0.02 x 0.02 m, clamped at
// x = 0), 10 x 2 x 2 cells (240 tetrahedra), undamped.
test::BodySpec beam_spec() {
  test::BodySpec spec;
  spec.young = 1e6;
  spec.poisson = 0.45;
  spec.density = 1070;
  spec.fixed = [](const Vec3& p) { return p[0] < 1e-9; };
  return spec;
}
mesh::TetMesh beam_mesh() { return test::box_mesh(10, 2, 2, 0.2, 0.02, 0.02); }

// Tip: the node at (L, 0, 0).
double tip_z(const Model& model, const State& s) {
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (std::abs(model.fem.X(0, i) - 0.2) < 1e-9 && std::abs(model.fem.X(1, i)) < 1e-9 &&
        std::abs(model.fem.X(2, i)) < 1e-9)
      return s.x[3 * i + 2];
  ADD_FAILURE() << "no tip node";
  return 0;
}

// Bounded and physical: ok, finite, energy within the bound.
void expect_bounded(const Outcome& o, const std::string& name) {
  EXPECT_TRUE(o.ok()) << name << ": " << o.message;
  EXPECT_TRUE(o.finite) << name;
  EXPECT_LE(o.energy_rise, 1e-6) << name;
  EXPECT_TRUE(o.contact_converged) << name;
}

// Either bounded (expect_bounded, with the energy bound when `energy` is true) or a
// clear error: one of the step's failure codes, in the first `early` steps, with a
// message naming the element or node (or Newton's residual), and a finite last state.
void expect_bounded_or_clear_error(const Outcome& o, const std::string& name, bool energy, long early) {
  EXPECT_TRUE(o.last.x.allFinite() && o.last.v.allFinite()) << name;
  if (o.ok()) {
    EXPECT_TRUE(o.finite) << name;
    if (energy) {
      EXPECT_LE(o.energy_rise, 1e-6) << name;
    }
    return;
  }
  using C = StepStatus::Code;
  const C c = o.status.code;
  EXPECT_TRUE(c == C::inverted_element || c == C::not_positive_definite || c == C::not_converged) << name << ": "
                                                                                                   << o.message;
  EXPECT_LE(o.status.step, early) << name << ": " << o.message;
  const bool located = o.message.find("tetrahedron ") != std::string::npos ||
                       o.message.find("node ") != std::string::npos ||
                       o.message.find("relative residual ") != std::string::npos;
  EXPECT_TRUE(located) << name << ": " << o.message;
  EXPECT_EQ(o.message.find("nan"), std::string::npos) << o.message;
}

// ---------------------------------------------------------------------------
// Time steps from 1e-5 to 0.1 s (the beam's first bending period is 0.38 s, its
// highest elastic mode ~1e-5 s): 20 steps each, linearized and Newton, undamped.
// Newton's solution is dissipative at every h. The linearized step (the paper's) is
// not exactly: at h = 0.1 s it gains 1.5% of E_ref while the beam first falls, then
// loses it; the test checks that the maximum is reached early (the same over 400
// steps as over 20: no growth), stays below 5% of E_ref, and that the energy ends
// below its start.
TEST(Stress, TimeStepsFrom1e5To0p1) {
  for (const double dt : {1e-5, 1e-4, 1e-3, 1e-2, 1e-1})
    for (const int newton : {1, 10}) {
      Model model = test::make_model(beam_mesh(), beam_spec(), Vec3(0, 0, -kG), dt, 20);
      model.step.newton_iterations = newton;
      const Outcome o = simulate(model);
      const std::string name = "dt " + num(dt) + " s, newton_iterations " + std::to_string(newton);
      EXPECT_TRUE(o.ok()) << name << ": " << o.message;
      EXPECT_TRUE(o.finite) << name;
      if (dt < 0.1 || newton > 1) {
        EXPECT_LE(o.energy_rise, 1e-6) << name;
      } else {
        model.step.steps = 400;
        const Outcome longer = simulate(model);
        EXPECT_TRUE(longer.ok()) << longer.message;
        EXPECT_EQ(longer.energy_rise, o.energy_rise) << "the energy must not grow later";
        EXPECT_LE(o.energy_rise, 0.05);
        EXPECT_LT(longer.energy_final, 0);
      }
      // The tip never goes above its rest height nor below twice the static sag
      // (~7.6 cm at this resolution; the dynamic overshoot of an undamped start is 2x).
      if (o.ok()) {
        EXPECT_LE(tip_z(model, o.last), 1e-9) << name;
        EXPECT_GE(tip_z(model, o.last), -0.16) << name;
      }
      report("time step " + name, describe_outcome(o) + ", tip z " + num(tip_z(model, o.last)) + " m");
    }
}

// Young from 1e3 to 1e9 Pa under gravity (dt 0.01). At 1e3 Pa the beam cannot carry
// its own weight (static sag ~70 L by beam theory): it hangs from the clamp.
TEST(Stress, YoungFrom1e3To1e9) {
  for (const double young : {1e3, 1e5, 1e7, 1e9}) {
    test::BodySpec spec = beam_spec();
    spec.young = young;
    Model model = test::make_model(beam_mesh(), spec, Vec3(0, 0, -kG), 0.01, 30);
    const Outcome o = simulate(model);
    const std::string name = "young " + num(young) + " Pa";
    if (young > 1e3) {
      expect_bounded(o, name);
    } else {
      // rho g L / E = 2.1: the clamp's corner elements are crushed as the beam hangs.
      EXPECT_EQ(o.status.code, StepStatus::Code::inverted_element) << o.message;
      expect_bounded_or_clear_error(o, name, true, 30);
    }
    report(name, describe_outcome(o) + (o.ok() ? ", tip z " + num(tip_z(model, o.last)) + " m" : ""));
  }
}

// Nearly incompressible: poisson 0.49, 0.499 and 0.4999 (bulk/shear ratio up to 1.7e4).
// Linear tetrahedra lock: the sag decreases as poisson approaches 1/2.
TEST(Stress, NearlyIncompressible) {
  double previous = -1;
  for (const double nu : {0.3, 0.49, 0.499, 0.4999}) {
    test::BodySpec spec = beam_spec();
    spec.poisson = nu;
    spec.rayleigh_mass = 5;  // settle towards the static sag within the 0.5 s
    Model model = test::make_model(beam_mesh(), spec, Vec3(0, 0, -kG), 0.01, 50);
    const Outcome o = simulate(model);
    const std::string name = "poisson " + num(nu);
    expect_bounded(o, name);
    const double sag = -tip_z(model, o.last);
    EXPECT_GT(sag, 0) << name;
    if (previous > 0) {
      EXPECT_LT(sag, previous) << name << ": locking stiffens";
    }
    previous = sag;
    report(name, describe_outcome(o) + ", tip sag " + num(sag) + " m");
  }
}

// ---------------------------------------------------------------------------
// Mass ratio 1e6: two 0.05 m cubes stacked on the floor, densities 1e-2 and 1e4
// kg/m^3, soft-soft and soft-floor contact (mu 0.3, ADMM, tolerance 1e-8).
//  - light on heavy: 100 steps, energy not growing, no penetration of the floor, the
//    interface within a tenth of the contact margin; the NCP reaches 1e-8 in all but
//    a few steps (each reported: a warning in the CLI, an error with --strict); the
//    same with psd_projection.
//  - heavy on light without psd_projection: the light body's mass no longer hides
//    the indefinite part of the corotational stiffness under that load: "not
//    positive definite" at step 6, naming the node and psd_projection.
//  - heavy on light with psd_projection (the light cube carries 1e6 times its weight):
//    at the impact (step 5) the NCP ends at ~1.05e-8, the rounding floor of
//    sigma = G lambda + g with G's largest eigenvalue 3e5 (docs/method.md "Stress
//    suite"); whether the linearized step then inverts an element of the light body
//    depends on round-off: a clear error by step 20, or 100 bounded steps.
struct StackResult {
  Outcome outcome;
  double floor = 0, interface = 0;  // worst penetrations (m, >= 0)
  int unconverged = 0, first_unconverged = -1;
};

// ncp_edit may change the NCP options; table (a measurement harness) gets every step.
StackResult stack(bool heavy_on_top, bool psd, const std::function<void(contact::NcpOptions&)>& ncp_edit = {},
                  test::NcpTable* table = nullptr) {
  const double a = 0.05, gap = 5e-4;
  test::BodySpec bottom_spec, top_spec;
  for (test::BodySpec* s : {&bottom_spec, &top_spec}) {
    s->young = 1e6;
    s->poisson = 0.3;
    s->rayleigh_stiffness = 1e-3;
    s->psd_projection = psd;
  }
  bottom_spec.density = heavy_on_top ? 1e-2 : 1e4;
  top_spec.density = heavy_on_top ? 1e4 : 1e-2;
  mesh::TetMesh bottom = test::box_mesh(3, 3, 3, a, a, a), top = bottom;
  for (int i = 0; i < top.num_nodes(); ++i) top.X(2, i) += a + gap;
  Model model = test::make_model({{bottom, bottom_spec, heavy_on_top ? "light" : "heavy"},
                                  {top, top_spec, heavy_on_top ? "heavy" : "light"}},
                                 Vec3(0, 0, -kG), 2e-3, 100);
  test::ContactSpec cs;
  cs.mu = 0.3;
  cs.ncp.tolerance = 1e-8;
  cs.ncp.max_iterations = 2000;
  if (ncp_edit) ncp_edit(cs.ncp);
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  model.contact.detection.pairs.push_back({0, 1, 0.3});
  const int n_bottom = bottom.num_nodes();
  StackResult r;
  r.outcome = simulate(model, [&](long k, const Data& data, const State& s) {
    if (!data.contact.result.converged && r.unconverged++ == 0) r.first_unconverged = static_cast<int>(k);
    double top_of_bottom = -1e9, bottom_of_top = 1e9;
    for (int i = 0; i < model.fem.num_nodes; ++i) {
      const double z = s.x[3 * i + 2], z0 = model.fem.X(2, i);
      if (i < n_bottom) {
        r.floor = std::max(r.floor, -z);
        if (z0 > a - 1e-9) top_of_bottom = std::max(top_of_bottom, z);
      } else if (z0 < a + gap + 1e-9) {
        bottom_of_top = std::min(bottom_of_top, z);
      }
    }
    r.interface = std::max(r.interface, top_of_bottom - bottom_of_top);
    if (table) {
      table->row(k, data);
      double low = 1e9;  // the bottom cube's height now, relative to its rest height a
      for (int i = 0; i < n_bottom; ++i) low = std::min(low, s.x[3 * i + 2]);
      std::printf("NCPTABLE | %s | %s | %3ld | bottom cube height %.6f a, interface %.3g m\n", table->scene.c_str(),
                  table->backend.c_str(), k, (top_of_bottom - low) / a, top_of_bottom - bottom_of_top);
    }
  });
  return r;
}

std::string describe_stack(const StackResult& r) {
  return describe_outcome(r.outcome) + "; NCP above tolerance in " + std::to_string(r.unconverged) +
         " steps (first: " + std::to_string(r.first_unconverged) + "); worst penetration floor " + num(r.floor) +
         " m, interface " + num(r.interface) + " m";
}

TEST(Stress, MassRatio1e6) {
  for (const bool psd : {false, true}) {
    const StackResult light_on_heavy = stack(false, psd);
    const Outcome& o = light_on_heavy.outcome;
    EXPECT_TRUE(o.ok()) << o.message;
    EXPECT_TRUE(o.finite);
    EXPECT_LE(o.energy_rise, 1e-6);
    EXPECT_LE(light_on_heavy.floor, 1e-9);
    EXPECT_LE(light_on_heavy.interface, 1e-4);  // a tenth of the 1 mm margin
    EXPECT_LE(light_on_heavy.unconverged, 5);
    report(std::string("mass ratio 1e6, light cube on a heavy one") + (psd ? " (psd_projection)" : ""),
           describe_stack(light_on_heavy));
  }

  const StackResult plain = stack(true, false);
  EXPECT_EQ(plain.outcome.status.code, StepStatus::Code::not_positive_definite) << plain.outcome.message;
  EXPECT_NE(plain.outcome.message.find("psd_projection: true"), std::string::npos) << plain.outcome.message;
  EXPECT_NE(plain.outcome.message.find("of body 'light'"), std::string::npos) << plain.outcome.message;
  report("mass ratio 1e6, heavy cube on a light one", describe_stack(plain));

  // With psd_projection the run sits at the limit of what the NCP resolves (a 1e6 mass
  // ratio across the interface): whether ADMM stalls and the light cube then inverts
  // an element or is flung away, or the run completes, and at which step, depends on
  // round-off (the machine, the thread count, the build). Measured: the -march=native
  // build inverted at step 19; e06721d's portable build completed its 100 steps in CI
  // and inverted at step 54 when run alone; with the thread plan and the 9x9 PSD
  // projection it diverges at step 22 (docs/method.md "Stress", left as found). The
  // contract holds whatever the outcome: bounded, or a clear error that the step's
  // checks detected and that names the light body, with a finite last state.
  const StackResult heavy_on_light = stack(true, true);
  const Outcome& hl = heavy_on_light.outcome;
  EXPECT_TRUE(hl.last.x.allFinite() && hl.last.v.allFinite()) << hl.message;
  if (hl.ok()) {
    EXPECT_TRUE(hl.finite);
    EXPECT_LE(hl.energy_rise, 1e-6);
    EXPECT_LE(heavy_on_light.floor, 1e-9);
    EXPECT_LE(heavy_on_light.interface, 1e-4);
  } else {
    using C = StepStatus::Code;
    const C c = hl.status.code;
    EXPECT_TRUE(c == C::inverted_element || c == C::diverged || c == C::not_positive_definite) << hl.message;
    EXPECT_NE(hl.message.find("of body 'light'"), std::string::npos) << hl.message;
    EXPECT_EQ(hl.message.find("nan"), std::string::npos) << hl.message;
  }
  report("mass ratio 1e6, heavy cube on a light one (psd_projection)", describe_stack(heavy_on_light));
}

// The light-on-heavy stack on the sparse operator (contact.backend sparse,
// dense_max_contacts 0: every reduced problem by ADMM on the operator, as beyond 400
// contacts). ADMM with one rho converges only on the contacts whose compliance G_NN is
// near rho, and here G_NN spans 0.013 (floor, heavy cube) to ~6e3 (interface, light
// cube): before the operator's stall fallback (the dense path's PGS and polish on the
// dense G_CC of the contacts that may carry force, ncp.cpp) the interface solves ended
// at 1e-2 to 1.04 from step 6 and the light cube's stiffness turned indefinite at step
// 9. Asserted as for the dense G above: 100 bounded steps, no floor penetration, the
// interface within a tenth of the margin, and at most 5 reported solves above the
// tolerance (the dense path's bound: none was measured, docs/method.md "Stress suite").
TEST(Stress, MassRatio1e6OnTheSparseOperator) {
  const StackResult r = stack(false, false, [](contact::NcpOptions& o) {
    o.backend = contact::NcpBackend::sparse;
    o.dense_max_contacts = 0;
  });
  const Outcome& o = r.outcome;
  EXPECT_TRUE(o.ok()) << o.message;
  EXPECT_TRUE(o.finite);
  EXPECT_LE(o.energy_rise, 1e-6);
  EXPECT_LE(r.floor, 1e-9);
  EXPECT_LE(r.interface, 1e-4);
  EXPECT_LE(r.unconverged, 5);
  report("mass ratio 1e6, light cube on a heavy one, sparse operator", describe_stack(r));
}

// Measurement harness (not run by ctest: DISABLED_; run with
// --gtest_filter='*MassRatioResidualTable' --gtest_also_run_disabled_tests): the
// per-step NCP residual, iterations and modes of the mass-ratio stacks (light on
// heavy; heavy on light with and without psd_projection), on the dense G and on the
// sparse operator (every reduced problem by the operator's ADMM).
// SOFTDIFF_TABLE_ONLY=<scene>/<dense|sparse> runs one of the six cases.
TEST(Stress, DISABLED_MassRatioResidualTable) {
  struct Scene {
    const char* name;
    bool heavy_on_top, psd;
  };
  for (const Scene sc : {Scene{"light-on-heavy", false, false}, Scene{"heavy-on-light", true, false},
                         Scene{"heavy-on-light-psd", true, true}})
    for (const bool sparse : {false, true}) {
      // SOFTDIFF_TABLE_ONLY=<scene>/<backend> (e.g. heavy-on-light-psd/sparse): that case alone.
      const char* only = std::getenv("SOFTDIFF_TABLE_ONLY");
      if (only && std::string(only) != std::string(sc.name) + (sparse ? "/sparse" : "/dense")) continue;
      test::NcpTable table;
      table.scene = sc.name;
      table.backend = sparse ? "sparse" : "dense";
      table.dump_dir = std::string(SOFTDIFF_TEST_DATA_DIR) + "/ncp_dumps";
      const auto t0 = std::chrono::steady_clock::now();
      const StackResult r = stack(sc.heavy_on_top, sc.psd, [&](contact::NcpOptions& o) {
        o.backend = sparse ? contact::NcpBackend::sparse : contact::NcpBackend::dense;
        if (sparse) o.dense_max_contacts = 0;
      }, &table);
      const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      table.summary(describe_stack(r) + ", " + num(seconds) + " s");
    }
}

// ---------------------------------------------------------------------------
// Slivers: the beam with one layer of cells 1e-4 of the others' height (flat
// tetrahedra, aspect ratio ~1e4, volume ratio 1e-4 to the mean), undamped.
TEST(Stress, SliverLayer) {
  mesh::TetMesh m = test::box_mesh(10, 2, 3, 0.2, 0.02, 0.02);
  // z levels 0, 0.01, 0.01 + 1e-6 * ..., 0.02: squash the middle layer.
  for (int i = 0; i < m.num_nodes(); ++i) {
    double& z = m.X(2, i);
    const int level = static_cast<int>(std::lround(z / (0.02 / 3)));
    z = level == 0 ? 0.0 : level == 1 ? 0.01 : level == 2 ? 0.01 + 1e-6 : 0.02;
  }
  const mesh::Quality q = mesh::quality(m.X, m.tets);
  Model model = test::make_model(m, beam_spec(), Vec3(0, 0, -kG), 0.01, 30);
  const Outcome o = simulate(model);
  expect_bounded(o, "slivers");
  report("slivers (a layer 1e-4 as thick, worst aspect " + num(q.max_aspect) + ")",
         describe_outcome(o) + ", tip z " + num(tip_z(model, o.last)) + " m");
}

// ---------------------------------------------------------------------------
// An impact: the beam thrown at its clamp at 30 m/s (it would travel 1.5 times its
// length in one step), every law, with and without psd_projection, linearized and
// Newton: bounded, or a clear error in the first two steps.
TEST(Stress, ImpactAt30MetresPerSecond) {
  for (const bool psd : {false, true})
    for (const auto law : {material::Law::corotational, material::Law::stvk, material::Law::neo_hookean})
      for (const int newton : {1, 10}) {
        test::BodySpec spec = beam_spec();
        spec.law = law;
        spec.psd_projection = psd;
        Model model = test::make_model(beam_mesh(), spec, Vec3(0, 0, -kG), 0.01, 5);
        model.step.newton_iterations = newton;
        for (int i = 0; i < model.fem.num_nodes; ++i)
          if (!model.fem.fixed[3 * i]) model.initial.v[3 * i] = -30;
        const Outcome o = simulate(model);
        const std::string name = "impact at 30 m/s, " + std::string(material::law_name(law)) +
                                 (psd ? ", psd_projection" : "") + ", newton_iterations " + std::to_string(newton);
        expect_bounded_or_clear_error(o, name, true, 2);
        report(name, describe_outcome(o));
      }
}

// A tetrahedron driven to inversion: a cable along the beam's top pulled with 2 kN
// (the beam's axial stiffness E A is 400 N: a strain of 5) folds the end elements
// over. Every law ends with a clear error at step 1 naming the tetrahedron and det F;
// the state before it is finite. Neo-Hookean is undefined at det F <= 0 (ln J):
// this error is its documented remedy, and nothing evaluates it at an inverted state
// (with Newton, the line search halves steps that would invert an element; when even
// that fails, the error is Newton's). The cable at its upper limit (20 N) is in
// CableAtItsLimit.
std::string cable_scene(const std::string& law, const std::string& force, int newton) {
  return "softdiff: 1\n"
         "simulation: {dt: 0.01, steps: 20, newton_iterations: " + std::to_string(newton) + "}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
         "    material: {law: " + law + ", young: 1.0e6, poisson: 0.45, density: 1070}\n"
         "    damping: {rayleigh_mass: 0.1, rayleigh_stiffness: 0.001}\n"
         "    fixed: [{group: clamp}]\n"
         "    actuators:\n"
         "      - {name: cable, type: cable, force: " + force +
         ", limits: [0, 20], points: [[0.2, 0.01, 0.0175], [0.1, 0.01, 0.0175], [0.005, 0.01, 0.0175]]}\n";
}

Outcome run_scene(const std::string& text, const std::string& name) {
  const fs::path dir = test::fresh_dir(kWork, name);
  test::write_text(dir / "scene.yaml", text);
  return simulate(io::build_model(io::load_scene(dir / "scene.yaml")));
}

TEST(Stress, InversionIsAClearError) {
  for (const std::string law : {"corotational", "stvk", "neo_hookean"})
    for (const int newton : {1, 10}) {
      const Outcome o = run_scene(cable_scene(law, "2000", newton), "inversion");
      const std::string name = "cable pulled with 2 kN (limits [0, 20]), " + law + ", newton_iterations " +
                               std::to_string(newton);
      expect_bounded_or_clear_error(o, name, false, 1);
      EXPECT_FALSE(o.ok()) << name;
      if (newton == 1) {
        EXPECT_EQ(o.message, "step 1: inverted element: tetrahedron 0 of body 'beam' has det F = -1.58646 <= 0");
      }
      report(name, describe_outcome(o));
    }
}

// The cable at its upper limit, 20 N, whose whole tension acts at its last point
// (docs/method.md): a point load that crushes the elements around that node for the
// hyperelastic laws. Corotational runs; the others end with a clear error.
TEST(Stress, CableAtItsLimit) {
  for (const std::string law : {"corotational", "stvk", "neo_hookean"}) {
    const Outcome o = run_scene(cable_scene(law, "20", 1), "cable_limit");
    const std::string name = "cable at its limit (20 N), " + law;
    expect_bounded_or_clear_error(o, name, false, 20);
    if (law == "corotational") {
      EXPECT_TRUE(o.ok()) << o.message;
    }
    report(name, describe_outcome(o));
  }
}

// The same through the command line: exit code 1 and the message on stderr.
TEST(Stress, InversionThroughTheCli) {
  const fs::path dir = test::fresh_dir(kWork, "inversion_cli");
  test::write_text(dir / "scene.yaml", cable_scene("neo_hookean", "2000", 1));
  const test::CliRun r = test::run_cli("simulate scene.yaml -o out.h5", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("step 1: inverted element: tetrahedron 0 of body 'beam' has det F = -1.586"), std::string::npos)
      << r.err;
  EXPECT_EQ(r.err.find("nan"), std::string::npos) << r.err;
  report("cable pulled with 2 kN through the CLI (neo_hookean)",
         "exit " + std::to_string(r.code) + ": " + r.err.substr(0, r.err.find('\n')));
}

// ---------------------------------------------------------------------------
// 5000 contacts: a 0.7 x 0.7 x 0.01 m slab (70 x 70 cells) on a plane, 5041 vertex
// contacts, one step with `solver: pgs` to 1e-6. Beyond the crossover (400 contacts)
// the automatic backend never forms the 15123 x 15123 Delassus matrix (1.8 GB; with it
// the step took a 38-40 s Delassus assembly and 23-31 s of PGS): PGS needs G's columns,
// so the sparse operator's ADMM solves the problem (docs/method.md "Contact at
// scale"). The line reports both times and the iterations.
TEST(Stress, FiveThousandContacts) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.rayleigh_stiffness = 1e-3;
  Model model = test::make_model(test::box_mesh(70, 70, 1, 0.7, 0.7, 0.01), spec, Vec3(0, 0, -kG), 0.005, 1);
  test::ContactSpec cs;
  cs.mu = 0.3;
  cs.ncp.solver = contact::NcpSolverKind::pgs;
  cs.ncp.tolerance = 1e-6;
  cs.ncp.max_iterations = 2000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  int contacts = 0, sweeps = 0;
  double lowest = 0, delassus_s = 0, ncp_s = 0;
  const Outcome o = simulate(model, [&](long, const Data& data, const State& s) {
    contacts = data.contact.contacts.size();
    sweeps = data.contact.result.iterations;
    delassus_s = data.timings.delassus;
    ncp_s = data.timings.ncp;
    test::expect_valid_contact_solution(data, 1e-6, "5000 contacts");
    for (int i = 0; i < model.fem.num_nodes; ++i) lowest = std::min(lowest, s.x[3 * i + 2]);
  });
  expect_bounded(o, "5000 contacts");
  EXPECT_EQ(contacts, 71 * 71);
  EXPECT_GE(lowest, -1e-9);
  report("5041 contacts (slab on a plane, solver pgs: the sparse backend's ADMM)",
         describe_outcome(o) + ", " + std::to_string(contacts) + " contacts, lowest z " + num(lowest) + " m; Delassus " +
             num(delassus_s) + " s, NCP " + num(ncp_s) + " s (" + std::to_string(sweeps) + " ADMM iterations)");
}

// ---------------------------------------------------------------------------
// Friction from 0 to 10: a 0.1 x 0.1 x 0.01 m slab on a plane (flat enough not to
// tip over at 80 degrees: h/2 tan 80 = 0.028 < b/2), gravity tilted by 10 degrees
// (frictionless: slides with g sin a) and by 80 degrees (mu = 10 > tan 80 = 5.67:
// sticks; mu = 5: slides with g (sin a - mu cos a)).
TEST(Stress, FrictionFrom0To10) {
  struct Case {
    double angle, mu;
    bool slides;
  };
  for (const Case c : {Case{10, 0, true}, Case{80, 10, false}, Case{80, 5, true}}) {
    test::BodySpec spec;
    spec.young = 1e6;
    spec.poisson = 0.3;
    spec.rayleigh_stiffness = 1e-3;
    const double a = c.angle * std::numbers::pi / 180;
    Model model = test::make_model(test::box_mesh(5, 5, 1, 0.1, 0.1, 0.01), spec,
                                   Vec3(kG * std::sin(a), 0, -kG * std::cos(a)), 2e-3, 100);
    test::ContactSpec cs;
    cs.mu = c.mu;
    cs.ncp.tolerance = 1e-10;
    cs.ncp.max_iterations = 5000;
    test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
    double lowest = 0;
    const Outcome o = simulate(model, [&](long k, const Data& data, const State& s) {
      test::expect_valid_contact_solution(data, 1e-9, "step " + std::to_string(k));
      for (int i = 0; i < model.fem.num_nodes; ++i) lowest = std::min(lowest, s.x[3 * i + 2]);
    });
    const std::string name = "friction " + num(c.mu) + ", incline " + num(c.angle) + " deg";
    EXPECT_TRUE(o.ok()) << name << ": " << o.message;
    EXPECT_TRUE(o.contact_converged) << name;
    EXPECT_GE(lowest, -1e-6) << name;
    // Mean x velocity after 0.2 s: g (sin a - mu cos a) t when sliding.
    double vx = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i) vx += o.last.v[3 * i];
    vx /= model.fem.num_nodes;
    const double expected = c.slides ? kG * (std::sin(a) - c.mu * std::cos(a)) * 0.2 : 0.0;
    EXPECT_NEAR(vx, expected, 0.02 * kG * 0.2) << name;
    report(name, describe_outcome(o) + ", mean vx " + num(vx) + " m/s (analytic " + num(expected) + ")");
  }
}

}  // namespace
