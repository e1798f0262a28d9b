// Per-step evaluations of the actuators allocate nothing. The test binary interposes
// malloc (forwarding to glibc's __libc_malloc) and counts calls while a scope is
// active: this catches std containers (operator new calls malloc) and Eigen's dynamic
// temporaries (Eigen's aligned_malloc calls malloc) alike. Calls made from inside the
// BLAS library (its shared object's name contains "blas" or "lapack", found by dladdr on
// the caller's address) are counted apart and printed, not asserted: Debian's OpenBLAS
// 0.3.21 mallocs a buffer in its SkylakeX small-matrix GEMM kernel
// (dgemm_small_kernel_nn_SKYLAKEX, called by CHOLMOD's supernodal solve with several
// right-hand sides) on AVX-512 CPUs, 10 calls in the rigidified step below (found with
// gdb, 2026-12-04, on an Intel Xeon; 0 with OPENBLAS_CORETYPE=Haswell). That is the
// library's, not softdiff's code.
#include <softdiff/actuation/actuation_model.hpp>
#include <softdiff/actuation/cable.hpp>
#include <softdiff/actuation/effector.hpp>
#include <softdiff/actuation/pressure.hpp>
#include <softdiff/actuation/servo.hpp>

#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/rigidify.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <support/cli.hpp>

#include "helpers.hpp"

#include <cstdlib>
#include <cstring>
#include <dlfcn.h>
#include <filesystem>
#include <gtest/gtest.h>
#include <iostream>

extern "C" void* __libc_malloc(std::size_t size);

namespace {
bool counting = false;
long allocations = 0;
long blas_allocations = 0;  // made inside the BLAS library (see the top)

bool called_from_blas(void* caller) {
  Dl_info info;
  if (dladdr(caller, &info) == 0 || info.dli_fname == nullptr) return false;
  return std::strstr(info.dli_fname, "blas") != nullptr || std::strstr(info.dli_fname, "lapack") != nullptr;
}
}  // namespace

extern "C" void* malloc(std::size_t size) noexcept {
  if (counting) {
    counting = false;  // dladdr must not count itself
    ++(called_from_blas(__builtin_return_address(0)) ? blas_allocations : allocations);
    counting = true;
  }
  return __libc_malloc(size);
}

using namespace softdiff;
using namespace softdiff::actuation;

namespace {

struct Count {
  Count() {
    allocations = 0;
    blas_allocations = 0;
    counting = true;
  }
  ~Count() { counting = false; }
  long stop() {
    counting = false;
    if (blas_allocations > 0)
      std::cout << "[allocation] " << blas_allocations << " allocations inside the BLAS library (not softdiff's)\n";
    return allocations;
  }
};

// The mesh's FEM model with a pattern that holds the cable's stiffness cliques.
fem::FemModel cable_fem_model(const mesh::TetMesh& m, const ActuationModel& act) {
  fem::FemModel fem_model;
  fem::BodyModel b;
  b.mesh = m;
  b.young = 1e5;
  b.poisson = 0.3;
  b.density = 1000;
  fem::build_fem_model({b}, std::vector<unsigned char>(3 * m.num_nodes(), 0), Vec3::Zero(), fem_model,
                       act.stiffness_cliques());
  return fem_model;
}

}  // namespace

TEST(Allocation, CounterSeesAllocations) {
  Count count;
  std::vector<int> v(10);
  VecX w = VecX::Zero(100);
  const long n = count.stop();
  EXPECT_GE(n, 2) << "the malloc interposition does not work";
  EXPECT_EQ(v.size() + w.size(), 110u);
}

TEST(Allocation, ActuatorEvaluationsAreAllocationFree) {
  std::mt19937 rng(40);
  const test::ActuatorSet set(rng);
  ASSERT_TRUE(set.ok);
  const mesh::TetMesh& m = set.mesh;
  const PointLocator locator(m.X, m.tets);
  const std::vector<EmbeddedPoint>& points = set.points;
  const Cable& cable = set.cable;
  const Cavity& cavity = set.cavity;
  const VecX& x_rest = set.x_rest;
  const Servo& translation = set.translation;
  Servo rotation;
  ASSERT_TRUE(Servo::rotation({0, 1, 2, 5, 7}, Vec3::UnitZ(), Vec3(0.01, 0.01, 0), x_rest, rotation).ok());
  const Effector effector(points[1]);

  const VecX x = test::deform(x_rest, 1e-3, rng), dx = VecX::Random(x.size());
  VecX f = VecX::Zero(x.size()), H(x.size()), out = VecX::Zero(x.size());
  Mat3X v_cable(3, cable.nodes().size()), v_cavity(3, cavity.nodes().size());
  Mat3X v_translation(3, translation.nodes().size()), v_rotation(3, rotation.nodes().size());
  double sink = 0;
  LocateResult r;
  // The cable's stiffness in a pattern built with its cliques (static tangent).
  ActuationModel act;
  act.actuators.emplace_back();
  act.actuators.back().kind = cable;
  const fem::FemModel fem_model = cable_fem_model(m, act);
  VecX values = VecX::Zero(fem_model.pattern.nnz());
  const VecX lambda = VecX::Constant(1, 2.0);

  Count count;
  cable.for_each_stiffness_block(x, 2.0, [&](int, int, int, int, int, const Mat3& block) { sink += block(0, 0); });
  act.add_stiffness(x, lambda, fem_model.pattern, values.data());
  sink += cable.length(x);
  cable.add_force(x, 1.0, 0.01, f);
  cable.gradient(x, H);
  cable.gradient_sparse(x, v_cable);
  cable.add_force_derivative(x, 1.0, dx, out);
  sink += cavity.volume(x);
  cavity.add_force(x, 1.0, 0.01, f);
  cavity.gradient(x, H);
  cavity.gradient_sparse(x, v_cavity);
  cavity.add_force_derivative(x, 1.0, dx, out);
  translation.add_force(x, 1.0, 0.01, f);
  translation.gradient(x, H);
  translation.gradient_sparse(x, v_translation);
  translation.add_force_derivative(x, 1.0, dx, out);
  rotation.add_force(x, 1.0, 0.01, f);
  rotation.gradient(x, H);
  rotation.gradient_sparse(x, v_rotation);
  rotation.add_force_derivative(x, 1.0, dx, out);
  sink += effector.position(x).sum() + effector.jacobian_times(dx).sum();
  effector.add_jacobian_transpose(Vec3(1, 2, 3), 1.0, out);
  r = locator.locate(Vec3(0.011, 0.004, 0.013));
  r = locator.locate(Vec3(0.031, 0.004, 0.013));
  const long n = count.stop();
  EXPECT_EQ(n, 0);
  EXPECT_TRUE(std::isfinite(sink + f.sum() + H.sum() + out.sum()));
  EXPECT_GT(values.norm(), 0);
  EXPECT_NE(r.status, LocateStatus::no_tets);
}

// Quadratic bodies: a cable embedded in curved 10-node tets (20-node segment stencils,
// its stiffness through the pattern's cliques), a closed cavity of 6-node triangles,
// an effector, and the locator's Newton on curved tets.
TEST(Allocation, QuadraticActuatorEvaluationsAreAllocationFree) {
  std::mt19937 rng(41);
  const mesh::TetMesh m = test::curved_box(3, 2, 2, 0.03, 0.02, 0.02, 0.08, rng);
  const PointLocator locator(m.X, m.tets, m.tets10);
  std::vector<EmbeddedPoint> points;
  for (const Vec3& p : {Vec3(0.001, 0.01, 0.01), Vec3(0.015, 0.017, 0.006), Vec3(0.029, 0.003, 0.009)})
    points.push_back(embedded_point(locator.locate(p).embedding, locator, 0));
  const Cable cable(points, Vec3(-0.01, 0.01, 0.01));
  const Triangles tris = mesh::boundary_triangles(m.tets);
  const mesh::Triangles6 tris6 = mesh::quadratic_triangles(m, tris);
  Cavity cavity;
  ASSERT_TRUE(Cavity::create(m.X, m.tets, tris, 0, cavity, &tris6).ok());
  const Effector effector(points[1]);
  const VecX x = test::deform(test::flatten(m.X), 1e-4, rng), dx = VecX::Random(x.size());
  VecX f = VecX::Zero(x.size()), H(x.size()), out = VecX::Zero(x.size());
  Mat3X v_cable(3, cable.nodes().size()), v_cavity(3, cavity.nodes().size());
  ActuationModel act;
  act.actuators.emplace_back();
  act.actuators.back().kind = cable;
  const fem::FemModel fem_model = cable_fem_model(m, act);
  VecX values = VecX::Zero(fem_model.pattern.nnz());
  const VecX lambda = VecX::Constant(1, 2.0);
  double sink = 0;
  LocateResult r;

  Count count;
  act.add_stiffness(x, lambda, fem_model.pattern, values.data());
  sink += cable.length(x);
  cable.add_force(x, 1.0, 0.01, f);
  cable.gradient_sparse(x, v_cable);
  cable.add_force_derivative(x, 1.0, dx, out);
  sink += cavity.volume(x);
  cavity.add_force(x, 1.0, 0.01, f);
  cavity.gradient(x, H);
  cavity.gradient_sparse(x, v_cavity);
  cavity.add_force_derivative(x, 1.0, dx, out);
  cavity.add_force_derivative_transpose(x, 1.0, dx, out);
  sink += effector.position(x).sum() + effector.jacobian_times(dx).sum();
  effector.add_jacobian_transpose(Vec3(1, 2, 3), 1.0, out);
  r = locator.locate(Vec3(0.011, 0.004, 0.013));
  const long n = count.stop();
  EXPECT_EQ(n, 0);
  EXPECT_TRUE(std::isfinite(sink + f.sum() + H.sum() + out.sum()));
  EXPECT_GT(values.norm(), 0);
  EXPECT_EQ(r.status, LocateStatus::inside);
}

// Rigidified parts (integrator/rigidify.hpp): after the first step has sized the
// workspace, the Schur complement (prepare), the reduced solve and the exact placement
// allocate nothing. The clamped beam with its tip region rigidified and attached to a
// torque servo.
TEST(Allocation, RigidifiedPartsStepIsAllocationFree) {
  const std::filesystem::path dir = std::filesystem::path(SOFTDIFF_TEST_DATA_DIR) / "allocation_rigidify";
  test::write_text(dir / "scene.yaml",
                   "softdiff: 1\nsimulation: {dt: 0.01, steps: 3}\nbodies:\n  - name: beam\n    mesh: " +
                       (std::filesystem::path(SOFTDIFF_SOURCE_DIR) / "meshes/beam.msh").string() +
                       "\n    material: {young: 1.0e6, poisson: 0.45, density: 1070}\n    fixed: [{group: clamp}]\n"
                       "    rigidify: [{box: [0.15, -1, -1, 1, 1, 1], attach: turn}]\n    actuators:\n"
                       "      - {name: turn, type: servo, nodes: {group: tip}, axis: [1, 0, 0], center: [0.2, 0.01, "
                       "0.01], force: 0.001}\n");
  const Model model = io::build_model(io::load_scene(dir / "scene.yaml"));
  ASSERT_EQ(model.rigidify.size(), 1);
  Data data(model);
  State a = model.initial, b = model.initial;
  ASSERT_TRUE(integrator::implicit_euler_step(model, data, a, b, 1).ok());  // sizes the workspace
  std::swap(a, b);
  ASSERT_TRUE(integrator::implicit_euler_step(model, data, a, b, 2).ok());  // the factor and rhs of step 2
  const double h = model.step.dt;
  VecX v = VecX::Zero(a.v.size());
  Count count;
  const StepStatus s = integrator::prepare_rigidified(model, data, a.x, h, 2);
  const bool solved = integrator::solve_rigidified(model, data, data.rhs, v);
  b.v = a.v + v;
  integrator::place_rigidified(model, data, a, b, h);
  const long n = count.stop();
  EXPECT_EQ(n, 0);
  EXPECT_TRUE(s.ok());
  EXPECT_TRUE(solved);
  EXPECT_TRUE(b.x.allFinite());
  std::filesystem::remove_all(dir);
}
