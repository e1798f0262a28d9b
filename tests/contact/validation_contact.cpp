// Frictional contact against analytic answers (docs/method.md "Contact"):
//  - a cube on an incline (mu = 0.5): stuck at 25 degrees, sliding at 27 and 30 with
//    the acceleration g (sin a - mu cos a); mu = 0 and mu = 10;
//  - a beam resting on two supports: total normal force = weight, no penetration;
//  - a frictionless sphere dropped on a plane: no bounce, no sinking;
//  - a bar falling flat: energy never increases;
//  - self-contact: a U-shaped body whose upper arm sags onto the lower one;
//  - 0 contacts and ~2000 contacts.
// At every step of every test the contact solution is checked independently
// (support/contact.hpp) and, on sampled steps, ADMM and PGS agree on the same problem.
#include <softdiff/data.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/gmsh_msh.hpp>
#include <softdiff/io/scene.hpp>
#include <support/contact.hpp>
#include <support/contact_checks.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>
#include <support/ncp_table.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <numbers>

using namespace softdiff;

namespace {

constexpr double kG = 9.81;
constexpr double kDeg = std::numbers::pi / 180;

// Runs `steps` steps; after each: status ok, contact solution valid to `tol`, and the
// callback. Returns the final state.
// With require_converged false, a solve that stops at max_iterations is accepted
// (the residual check at `tol` still applies).
template <class F>
State run(const Model& model, Data& data, State s, long steps, double tol, F&& after_step,
          bool require_converged = true) {
  State next = s;
  for (long k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::implicit_euler_step(model, data, s, next, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    if (!st.ok()) break;
    if (require_converged) {
      EXPECT_TRUE(data.contact.result.converged) << "step " << k;
    }
    test::expect_valid_contact_solution(data, tol, "step " + std::to_string(k));
    std::swap(s, next);
    after_step(k, s);
  }
  return s;
}

// ADMM and PGS on the same problem (the last step's G, g, mu) give the same contact
// velocities and forces. The problems here have full-rank G (one node per contact),
// so the solution is unique; 1e-6 relative is what tolerance 1e-10 on the scaled
// residuals guarantees with G's condition number here (< 1e4).
void expect_admm_pgs_agree(const Data& data) {
  const auto& cd = data.contact;
  if (cd.contacts.empty()) return;
  VecX lam[2], sig[2];
  std::vector<contact::Mode> modes;
  for (int s = 0; s < 2; ++s) {
    contact::NcpOptions o;
    o.solver = s == 0 ? contact::NcpSolverKind::admm : contact::NcpSolverKind::pgs;
    o.tolerance = 1e-10;
    o.max_iterations = 20000;
    contact::NcpSolver solver;
    lam[s] = VecX::Zero(cd.g.size());
    const auto r = solver.solve(cd.G, cd.g, cd.mu, o, lam[s], sig[s], modes);
    EXPECT_TRUE(r.converged) << (s == 0 ? "admm" : "pgs") << " residual " << r.residuals.max();
  }
  EXPECT_LE((lam[0] - lam[1]).norm(), 1e-6 * lam[0].norm());
  EXPECT_LE((sig[0] - sig[1]).norm(), 1e-6 * std::max(sig[0].norm(), cd.g.norm()));
}


// ---------------------------------------------------------------------------
// The incline: a 0.1 m cube (3x3x3 cells) on the plane z = 0 with gravity tilted by
// the angle a (equivalent to a tilted plane: sliding is along +x). Gravity is on at
// t = 0; Rayleigh stiffness damping (beta = 1e-3, zero on rigid motion, so it does not
// slow the sliding) kills the elastic transient (lowest mode ~1e3 rad/s: decay rate
// beta w^2 / 2 ~ 500 /s) well before 0.1 s.
struct InclineResult {
  // max |x displacement| over 0.1-0.5 s of the bottom nodes in contact (not breaking)
  // at that step. Nodes that lift off are left out: at 30 degrees the eccentricity of
  // the weight (h/2 tan a = 0.029 m) exceeds the kern of the base (b/6 = 0.017 m), so
  // the uphill row of a stuck cube lifts (4 of its 16 contacts break) and moves with
  // the body's elastic rocking (~1e-7 m) without sliding on the plane.
  double slip = 0;
  double acceleration = 0;    // mean x acceleration of the nodes' mean over 0.1-0.5 s
};

InclineResult incline(double angle_deg, double mu, contact::NcpSolverKind solver = contact::NcpSolverKind::admm) {
  test::BodySpec spec;
  spec.young = 1e6;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_stiffness = 1e-3;
  const double a = angle_deg * kDeg;
  const Vec3 g(kG * std::sin(a), 0, -kG * std::cos(a));
  const double dt = 2e-3;
  Model model = test::make_model(test::box_mesh(3, 3, 3, 0.1, 0.1, 0.1), spec, g, dt, 250);
  test::ContactSpec cs;
  cs.mu = mu;
  cs.ncp.solver = solver;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  Data data(model);
  State s = model.initial;
  std::vector<int> bottom;
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (model.fem.X(2, i) < 1e-12) bottom.push_back(i);
  InclineResult r;
  State at_start;
  const long k0 = std::lround(0.1 / dt), k1 = std::lround(0.5 / dt);
  double v0 = 0;
  auto mean_vx = [&](const State& st) {
    double m = 0;
    for (int i = 0; i < model.fem.num_nodes; ++i) m += st.v[3 * i];
    return m / model.fem.num_nodes;
  };
  run(model, data, s, k1, 1e-9, [&](long k, const State& st) {
    EXPECT_EQ(data.contact.contacts.size(), static_cast<int>(bottom.size())) << "step " << k;
    if (k == k0) {
      at_start = st;
      v0 = mean_vx(st);
    }
    if (k > k0) {
      const auto& cd = data.contact;
      for (int c = 0; c < cd.contacts.size(); ++c) {
        if (cd.modes[c] == contact::Mode::breaking) continue;
        const int i = cd.contacts.contacts[c].nodes[0];
        r.slip = std::max(r.slip, std::abs(st.x[3 * i] - at_start.x[3 * i]));
      }
    }
    if (k == k1) r.acceleration = (mean_vx(st) - v0) / (0.4);
    if (k == k1 - 1) expect_admm_pgs_agree(data);
  });
  return r;
}

TEST(ContactValidation, InclineSticksAt25Degrees) {
  const InclineResult r = incline(25, 0.5);  // tan 25 = 0.466 < 0.5
  EXPECT_LT(r.slip, 1e-7);
}

TEST(ContactValidation, InclineSlidesAt27And30Degrees) {
  for (double angle : {27.0, 30.0}) {
    const double a = angle * kDeg;
    const double expected = kG * (std::sin(a) - 0.5 * std::cos(a));
    const InclineResult r = incline(angle, 0.5);
    EXPECT_NEAR(r.acceleration, expected, 0.01 * expected) << angle << " degrees";
  }
}

TEST(ContactValidation, InclineFrictionlessAndLargeMu) {
  const double a = 30 * kDeg;
  const InclineResult frictionless = incline(30, 0.0);
  EXPECT_NEAR(frictionless.acceleration, kG * std::sin(a), 0.01 * kG * std::sin(a));
  const InclineResult sticky = incline(30, 10.0);
  EXPECT_LT(sticky.slip, 1e-7);
}

TEST(ContactValidation, InclineWithPgs) {
  const double a = 30 * kDeg;
  const double expected = kG * (std::sin(a) - 0.5 * std::cos(a));
  EXPECT_NEAR(incline(30, 0.5, contact::NcpSolverKind::pgs).acceleration, expected, 0.01 * expected);
  EXPECT_LT(incline(25, 0.5, contact::NcpSolverKind::pgs).slip, 1e-7);
}

// ---------------------------------------------------------------------------
// A beam (0.5 x 0.05 x 0.05 m) resting on two box supports near its ends, damped to
// rest: the normal forces carry the weight exactly (a rest state of the step:
// h (P + f_int) + h H^T lambda = 0, and sum f_int = 0), and nothing penetrates.
TEST(ContactValidation, BeamOnTwoSupportsCarriesItsWeight) {
  test::BodySpec spec;
  spec.young = 5e5;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 20;  // settles within ~1 s
  const double dt = 0.01;
  Model model = test::make_model(test::box_mesh(20, 2, 2, 0.5, 0.05, 0.05), spec, Vec3(0, 0, -kG), dt, 300);
  test::ContactSpec cs;
  cs.mu = 0.3;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model,
                       {test::box(Vec3(0.03, 0.025, -0.05), Vec3(0.02, 0.05, 0.05), "left"),
                        test::box(Vec3(0.47, 0.025, -0.05), Vec3(0.02, 0.05, 0.05), "right")},
                       cs);
  Data data(model);
  double min_gap = 0;
  const State end = run(model, data, model.initial, 300, 1e-9, [&](long, const State&) {
    for (const auto& c : data.contact.contacts.contacts) min_gap = std::min(min_gap, c.gap);
  });
  double weight = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) weight -= model.fem.gravity_force[3 * i + 2];
  // Total force on the beam along z: sum_i lambda_i in world coordinates.
  double fz = 0;
  const auto& cd = data.contact;
  for (int i = 0; i < cd.contacts.size(); ++i) fz += (cd.contacts.contacts[i].frame * cd.lambda.segment<3>(3 * i))[2];
  EXPECT_GT(cd.contacts.size(), 0);
  EXPECT_NEAR(fz, weight, 1e-6 * weight);
  EXPECT_LT(end.v.cwiseAbs().maxCoeff(), 1e-6);
  // Gaps are measured at x_i; the step drives the normal velocity to -phi/h, so the
  // penetration left is of the order of the solver tolerance times h |g|.
  EXPECT_GT(min_gap, -1e-9);
}

// ---------------------------------------------------------------------------
// A frictionless soft sphere (r = 5 cm, gmsh) dropped from 1 cm above a plane.
mesh::TetMesh sphere_mesh() {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / "contact";
  fs::create_directories(dir);
  const fs::path geo = dir / "sphere.geo", msh = dir / "sphere.msh";
  if (!fs::exists(msh)) {
    std::ofstream(geo) << "SetFactory(\"OpenCASCADE\");\nSphere(1) = {0, 0, 0, 0.05};\n"
                          "Mesh.CharacteristicLengthMax = 0.02;\nPhysical Volume(\"ball\") = {1};\n";
    const std::string tmp = msh.string() + ".tmp";
    const std::string cmd = std::string("\"") + GMSH_EXECUTABLE + "\" -3 -format msh22 \"" + geo.string() + "\" -o \"" +
                            tmp + "\" >/dev/null 2>&1";
    EXPECT_EQ(std::system(cmd.c_str()), 0);
    fs::rename(tmp, msh);
  }
  return io::read_gmsh(msh);
}

// A body dropped on the plane z = 0 (margin 2 mm, tolerance 1e-10), and its energies.
Model on_floor(const mesh::TetMesh& m, const test::BodySpec& spec, double dt, long steps, double mu) {
  Model model = test::make_model(m, spec, Vec3(0, 0, -kG), dt, steps);
  test::ContactSpec cs;
  cs.mu = mu;
  cs.margin = 2e-3;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  return model;
}

struct Energies {
  const Model& model;
  fem::FemData scratch;
  explicit Energies(const Model& m) : model(m) { scratch.resize(m.fem); }
  double kinetic(const State& s) const {
    VecX Mv;
    fem::symmetric_multiply(model.fem, model.fem.mass_values, s.v, Mv);
    return 0.5 * s.v.dot(Mv);
  }
  // kinetic + elastic + gravitational
  double total(const State& s) {
    fem::evaluate(model.fem, s.x, {true, false, false}, scratch);
    return kinetic(s) + scratch.energy - model.fem.gravity_force.dot(s.x);
  }
};

// The sphere's own damping decides how fast its elastic rebound dies out, not the
// contact: the contact mode of a soft sphere on a plane is slow (the impact lasts
// ~50 ms, omega ~ 60 rad/s), so Rayleigh stiffness damping barely touches it (with
// beta = 2e-3 the sphere really bounces, as an elastic ball does). beta = 0.02 damps
// that mode at ~0.6 of critical; alpha = 10 /s damps the slow rocking of this faceted
// sphere, which settles from a vertex onto a facet (a real equilibrium change: the
// energy keeps decreasing while it does). The criteria:
//   - no bounce: once the normal forces carry it, it never leaves the plane (the total
//     normal force stays > 0 at every later step);
//   - no sinking: no node goes below the plane beyond 1e-9 m (gaps are driven to 0 to
//     solver precision);
//   - it comes to rest: the energy never increases after the impact, and the kinetic
//     energy at 0.8 s is below 1e-3 of the kinetic energy at impact.
TEST(ContactValidation, FrictionlessSphereComesToRestWithoutBounceOrSinking) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_stiffness = 0.02;
  spec.rayleigh_mass = 10;
  mesh::TetMesh m = sphere_mesh();
  m.X.row(2).array() += 0.06;  // bottom at z = 0.01
  const Model model = on_floor(m, spec, 2e-3, 400, 0.0);
  Data data(model);
  Energies en(model);
  auto kinetic = [&](const State& s) { return en.kinetic(s); };
  auto energy = [&](const State& s) { return en.total(s); };
  auto min_z = [&](const State& s) {
    double z = 1e9;
    for (int i = 0; i < model.fem.num_nodes; ++i) z = std::min(z, s.x[3 * i + 2]);
    return z;
  };
  bool carried = false;
  long airborne_after = 0;
  double impact_kinetic = 0, previous = 0;
  const State end = run(model, data, model.initial, 400, 1e-9, [&](long k, const State& s) {
    const auto& cd = data.contact;
    double fn = 0;
    for (int c = 0; c < cd.contacts.size(); ++c) fn += cd.lambda[3 * c + 2];
    const double e = energy(s);
    if (!carried && fn > 0) {
      carried = true;
      impact_kinetic = kinetic(s);
    } else if (carried) {
      airborne_after += !(fn > 0);
      EXPECT_LE(e, previous + 1e-12 * std::abs(previous)) << "step " << k;
    }
    previous = e;
    EXPECT_GT(min_z(s), -1e-9) << "step " << k;  // no sinking through the plane
  });
  ASSERT_TRUE(carried);
  EXPECT_EQ(airborne_after, 0);  // no bounce
  EXPECT_LT(kinetic(end), 1e-3 * impact_kinetic);
}

// ---------------------------------------------------------------------------
// A bar (0.2 x 0.04 x 0.04 m) falling flat onto a plane with friction: the total
// energy (kinetic + elastic + gravitational) never increases.
TEST(ContactValidation, BarFallingOnItsSideKeepsEnergyNonIncreasing) {
  test::BodySpec spec;
  spec.young = 2e5;
  spec.poisson = 0.3;
  spec.density = 1000;
  mesh::TetMesh m = test::box_mesh(10, 2, 2, 0.2, 0.04, 0.04);
  m.X.row(2).array() += 0.005;
  const Model model = on_floor(m, spec, 2e-3, 200, 0.4);
  Data data(model);
  Energies en(model);
  auto energy = [&](const State& s) { return en.total(s); };
  double previous = energy(model.initial);
  const double scale = std::abs(model.fem.gravity_force.sum()) * 0.005;  // m g h of the drop
  long contact_steps = 0;
  run(model, data, model.initial, 200, 1e-9, [&](long k, const State& s) {
    const double e = energy(s);
    EXPECT_LE(e, previous + 1e-9 * scale) << "step " << k;
    previous = e;
    contact_steps += data.contact.contacts.size() > 0;
  });
  EXPECT_GT(contact_steps, 50);
}

// ---------------------------------------------------------------------------
// Self-contact: a U-shaped body (one mesh): the lower arm is fixed, the soft upper
// arm sags under gravity onto it. No surface vertex of the upper arm may go below
// the lower arm's top face (z = 0.01, fixed) beyond the solver's tolerance.
mesh::TetMesh u_mesh() {
  const mesh::TetMesh box = test::box_mesh(20, 2, 5, 0.2, 0.02, 0.05);
  std::vector<int> keep;
  for (int e = 0; e < box.tets.cols(); ++e) {
    Vec3 c = Vec3::Zero();
    for (int a = 0; a < 4; ++a) c += box.X.col(box.tets(a, e)) / 4;
    if (!(c.x() > 0.02 && c.z() > 0.01 && c.z() < 0.04)) keep.push_back(e);
  }
  std::vector<int> new_index(box.X.cols(), -1);
  mesh::TetMesh m;
  m.source = "u_mesh";
  int n = 0;
  for (int e : keep)
    for (int a = 0; a < 4; ++a)
      if (new_index[box.tets(a, e)] < 0) new_index[box.tets(a, e)] = n++;
  m.X.resize(3, n);
  for (int i = 0; i < box.X.cols(); ++i)
    if (new_index[i] >= 0) m.X.col(new_index[i]) = box.X.col(i);
  // The upper arm's nodes are shifted along x by up to half a cell (5 mm, ramped over
  // x in [0.02, 0.05] next to the bend), so that the arms' faces do not meet vertex on
  // vertex. Meshes that match node for node (no shift) give massively redundant,
  // degenerate problems (~190 contacts on ~60 facing vertex pairs, point-point and
  // point-edge; 408 of 558 eigenvalues of G zero) on which ADMM + PGS + polish stop at
  // 1e-5 to 3e-4 at a few impact steps out of 200 (measured: steps 36, 62, 113 before
  // the polish's mode corrections, steps 22, 25, 82 after; which steps depends on the
  // trajectory, i.e. on rounding): docs/method.md, "Limits".
  for (int i = 0; i < n; ++i)
    if (m.X(2, i) > 0.04 - 1e-9) m.X(0, i) += 0.005 * std::clamp((m.X(0, i) - 0.02) / 0.03, 0.0, 1.0);
  m.tets.resize(4, static_cast<int>(keep.size()));
  for (int k = 0; k < static_cast<int>(keep.size()); ++k)
    for (int a = 0; a < 4; ++a) m.tets(a, k) = new_index[box.tets(a, keep[k])];
  m.file_index.resize(n);
  m.file_tag.resize(n);
  for (int i = 0; i < n; ++i) m.file_index[i] = m.file_tag[i] = i;
  return m;
}

// The self-contact scene (80 steps of 5 ms): ncp_edit may change the NCP options.
Model self_contact_model(const std::function<void(contact::NcpOptions&)>& ncp_edit = {}) {
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = 3e3;  // the 0.18 m upper arm would sag ~5 cm under its weight: more than the 3 cm gap
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_stiffness = 5e-3;
  spec.psd_projection = true;  // the arm's impact compresses elements into the indefinite range
  spec.fixed = [](const Vec3& p) { return p.z() < 0.01 + 1e-9; };
  const double dt = 5e-3;
  Model model = test::make_model(u_mesh(), spec, Vec3(0, 0, -kG), dt, 80);
  test::ContactSpec cs;
  cs.mu = 0.2;
  cs.margin = 2e-3;
  cs.self = true;
  cs.ncp.tolerance = 1e-8;
  cs.ncp.max_iterations = 2000;
  if (ncp_edit) ncp_edit(cs.ncp);
  test::enable_contact(model, {}, cs);
  return model;
}

TEST(ContactValidation, SelfContactFoldedBeamDoesNotPassThroughItself) {
  Model model = self_contact_model();
  Data data(model);
  std::vector<int> upper;
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (model.fem.X(2, i) > 0.04 - 1e-9 && model.fem.X(0, i) > 0.03) upper.push_back(i);
  long contact_steps = 0;
  double lowest = 1;
  // ~145 contacts (vertex-triangle and edge-edge from both sides) on ~48 free nodes,
  // rank-deficient (288 of 432 eigenvalues of G zero) and with friction: ADMM + PGS +
  // polish do not always reach 1e-8 in 2000 iterations (measured 2026-12-02 with
  // DISABLED_SelfContactResidualTable below: 33 of the 67 solves with contacts stop
  // between 1.5e-8 and 2.7e-5): docs/method.md, "Limits". Such a solve must still
  // return its best iterate with residuals that the independent check confirms: the
  // solution is checked at 1e-4 (about 4x the worst measured) and the count printed.
  long unconverged = 0;
  run(model, data, model.initial, 80, 1e-4, [&](long k, const State& s) {
    unconverged += !data.contact.result.converged;
    if (!data.contact.contacts.empty()) {
      // The converged flag (and so the warning) tells the truth about the returned forces.
      const auto& cd = data.contact;
      const double r = contact::ncp_residuals(cd.G, cd.g, cd.mu, cd.lambda).max();
      EXPECT_EQ(cd.result.converged, r <= 1e-8) << "step " << k << " residual " << r;
    }
    contact_steps += data.contact.contacts.size() > 0;
    for (int i : upper) {
      lowest = std::min(lowest, s.x[3 * i + 2]);
      // 1e-5 m (0.5% of the margin): the solves stop at residuals up to 1e-4, and a
      // vertex-triangle gap is linearized at x_i (the triangle turns within the step).
      EXPECT_GT(s.x[3 * i + 2], 0.01 - 1e-5) << "step " << k << " node " << i;
    }
  }, /*require_converged=*/false);
  std::cout << "self-contact: " << unconverged << " of 80 contact solves stopped at max_iterations\n";
  EXPECT_GT(contact_steps, 20);   // the arms did meet
  EXPECT_LT(lowest, 0.01 + 2e-3); // and the upper arm lies on the lower one
}

// Measurement harness (not run by ctest: DISABLED_; run with
// --gtest_filter='*SelfContactResidualTable' --gtest_also_run_disabled_tests): the
// per-step NCP residual, iterations and modes of the self-contact scene, on the dense
// G and on the sparse operator (every reduced problem by the operator's ADMM).
TEST(ContactValidation, DISABLED_SelfContactResidualTable) {
  for (const bool sparse : {false, true}) {
    Model model = self_contact_model([&](contact::NcpOptions& o) {
      o.backend = sparse ? contact::NcpBackend::sparse : contact::NcpBackend::dense;
      if (sparse) o.dense_max_contacts = 0;
    });
    Data data(model);
    test::NcpTable table;
    table.scene = "self";
    table.backend = sparse ? "sparse" : "dense";
    table.dump_dir = std::string(SOFTDIFF_TEST_DATA_DIR) + "/ncp_dumps";
    State s = model.initial, next = s;
    std::string end = "completed";
    const auto t0 = std::chrono::steady_clock::now();
    for (long k = 1; k <= model.step.steps; ++k) {
      const StepStatus st = integrator::implicit_euler_step(model, data, s, next, k);
      if (!st.ok()) {
        end = describe(model, st);
        break;
      }
      table.row(k, data);
      std::swap(s, next);
    }
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    table.summary(end + ", " + std::to_string(seconds) + " s");
  }
}

// ---------------------------------------------------------------------------
// No contact: a body far above the plane: zero contacts, the step equals the
// contact-free step exactly.
TEST(ContactValidation, ZeroContactsGiveTheFreeStep) {
  test::BodySpec spec;
  mesh::TetMesh m = test::box_mesh(2, 2, 2, 0.1, 0.1, 0.1);
  m.X.row(2).array() += 1.0;
  Model free = test::make_model(m, spec, Vec3(0, 0, -kG), 0.01, 5);
  Model with = free;
  test::enable_contact(with, {test::plane(Vec3(0, 0, 1), 0)}, {});
  Data df(free), dw(with);
  State a = free.initial, b = with.initial, na = a, nb = b;
  for (long k = 1; k <= 5; ++k) {
    ASSERT_TRUE(integrator::implicit_euler_step(free, df, a, na, k).ok());
    ASSERT_TRUE(integrator::implicit_euler_step(with, dw, b, nb, k).ok());
    EXPECT_EQ(dw.contact.contacts.size(), 0);
    std::swap(a, na);
    std::swap(b, nb);
    EXPECT_EQ(a.x, b.x);
    EXPECT_EQ(a.v, b.v);
  }
}

// Many contacts: a 0.5 x 0.4 m slab (50 x 40 cells) pressed on a plane by gravity:
// 2091 vertex contacts (a 6273 x 6273 Delassus matrix), solved to tolerance by PGS
// over 3 steps and by ADMM on the first step (ADMM's dense Cholesky of G + rho I costs
// ~n^3/3 = 8e10 flops a refactorization at this size: PGS is the solver to use here;
// docs/performance.md).
TEST(ContactValidation, TwoThousandContacts) {
  for (const auto solver : {contact::NcpSolverKind::pgs, contact::NcpSolverKind::admm}) {
    test::BodySpec spec;
    spec.young = 1e5;
    spec.rayleigh_stiffness = 1e-3;
    const long steps = solver == contact::NcpSolverKind::pgs ? 3 : 1;
    Model model =
        test::make_model(test::box_mesh(50, 40, 1, 0.5, 0.4, 0.01), spec, Vec3(0, 0, -kG), 0.005, steps);
    test::ContactSpec cs;
    cs.mu = 0.3;
    cs.ncp.solver = solver;
    cs.ncp.tolerance = 1e-8;
    cs.ncp.max_iterations = 2000;
    test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
    Data data(model);
    run(model, data, model.initial, steps, 1e-8, [&](long, const State&) {
      EXPECT_EQ(data.contact.contacts.size(), 51 * 41);
    });
  }
}

// ---------------------------------------------------------------------------
// Contact at scale (docs/method.md "Contact at scale"): the shipped
// configs/slab_on_plane.yaml, a 0.3 x 0.3 x 0.01 m gmsh slab (5 mm tetrahedra) laid on a
// plane: 4337 vertex contacts each step, ADMM to 1e-6 on the sparse operator (the
// automatic backend beyond 400 contacts; its dense G would be 13011^2 doubles, 1.35 GB).
// At the last of 3 steps: the normal forces carry the weight within 5% (at rest on a
// flat plane they carry it exactly, up to the tolerance), the residuals are within the
// tolerance (recomputed independently by run()), and no node is more than 1e-6 m below
// the plane (the step drives each gap to zero within the tolerance times h |g|).
TEST(ContactValidation, SlabOnAPlaneWithFourThousandContacts) {
  const Model model = io::build_model(io::load_scene(std::string(SOFTDIFF_SOURCE_DIR) + "/configs/slab_on_plane.yaml"));
  ASSERT_EQ(model.step.steps, 3);
  Data data(model);
  const double tol = model.contact.ncp.tolerance;
  const State end = run(model, data, model.initial, model.step.steps, tol, [&](long k, const State&) {
    EXPECT_TRUE(data.contact.result.sparse) << "step " << k;
    EXPECT_EQ(data.contact.G.size(), 0) << "step " << k << ": a dense G was formed";
  });
  const auto& cd = data.contact;
  EXPECT_EQ(cd.contacts.size(), 4337);
  double weight = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) weight -= model.fem.gravity_force[3 * i + 2];
  double fz = 0;
  for (int i = 0; i < cd.contacts.size(); ++i) fz += (cd.contacts.contacts[i].frame * cd.lambda.segment<3>(3 * i))[2];
  EXPECT_NEAR(fz, weight, 0.05 * weight);
  EXPECT_LE(cd.result.residuals.max(), tol);
  double lowest = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i) lowest = std::min(lowest, end.x[3 * i + 2]);
  EXPECT_GE(lowest, -1e-6);
  std::cout << "slab on a plane: " << cd.contacts.size() << " contacts, normal force " << fz << " N for a weight of "
            << weight << " N, residual " << cd.result.residuals.max() << ", " << cd.result.iterations
            << " ADMM iterations, " << cd.result.rho_updates << " factorizations of A + (h/c) H^T H\n";
}

}  // namespace
