// Hot loops allocate nothing: after a warm-up, assembly and a whole implicit Euler
// step make no heap allocation in softdiff's code. The test executable is linked
// with -Wl,--wrap=malloc,... (tests/CMakeLists.txt), so every malloc/calloc/realloc
// call from softdiff and Eigen code (statically linked) goes through the counters
// below, and operator new is replaced; allocations inside shared libraries
// (CHOLMOD, libgomp) are not counted: they are not softdiff's loops.
#include <softdiff/data.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/fem_derivatives.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <atomic>
#include <cstdlib>
#include <gtest/gtest.h>
#include <new>

namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};
void count() {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
}
}  // namespace

extern "C" {
void* __real_malloc(size_t);
void* __real_calloc(size_t, size_t);
void* __real_realloc(void*, size_t);
void* __wrap_malloc(size_t n) {
  count();
  return __real_malloc(n);
}
void* __wrap_calloc(size_t a, size_t b) {
  count();
  return __real_calloc(a, b);
}
void* __wrap_realloc(void* p, size_t n) {
  count();
  return __real_realloc(p, n);
}
}

void* operator new(size_t n) {
  count();
  if (void* p = std::malloc(n)) return p;
  throw std::bad_alloc();
}
void* operator new[](size_t n) { return operator new(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, size_t) noexcept { std::free(p); }
void operator delete[](void* p, size_t) noexcept { std::free(p); }

using namespace softdiff;

namespace {

struct Counting {
  Counting() {
    g_allocations = 0;
    g_counting = true;
  }
  ~Counting() { g_counting = false; }
  long count() const { return g_allocations.load(); }
};

TEST(NoAllocation, CounterSeesAllocations) {  // the check can fail
  Counting c;
  VecX v(1000);
  v.setZero();
  EXPECT_GE(c.count(), 1);
}

TEST(NoAllocation, AssemblyAndStepAllocateNothing) {
  for (const bool quadratic : {false, true})
  for (auto law : {material::Law::corotational, material::Law::stvk, material::Law::neo_hookean}) {
    SCOPED_TRACE(quadratic ? "10-node tets" : "4-node tets");
    test::BodySpec spec;
    spec.law = law;
    spec.rayleigh_mass = 0.1;
    spec.rayleigh_stiffness = 0.01;
    spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
    mesh::TetMesh box = test::box_mesh(8, 3, 3, 0.1, 0.02, 0.02);
    if (quadratic) mesh::elevate_to_quadratic(box);
    spec.psd_projection = true;  // the skip, the 9x9 (4-node) and 30x30 (10-node) eigensolvers too
    const Model model = test::make_model(box, spec);
    Data data(model);
    State s = model.initial, next = model.initial;
    ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, next, 1).ok());  // warm-up (symbolic analysis)
    std::swap(s, next);
    {
      Counting c;
      ASSERT_TRUE(fem::evaluate(model.fem, s.x, {true, true, true}, data.fem));
      integrator::assemble_system_matrix(model, 0.01, data.fem.K_values, data.fem.K_values, data);
      fem::symmetric_multiply(model.fem, data.fem.K_values, s.v, data.Kv);
      EXPECT_EQ(c.count(), 0) << material::law_name(law) << ": assembly allocated";
    }
    {
      Counting c;
      ASSERT_TRUE(integrator::implicit_euler_step(model, data, s, next, 2).ok());
      EXPECT_EQ(c.count(), 0) << material::law_name(law) << ": the step allocated";
    }
  }
}

// The stiffness products of a JVP/VJP from the step's record (fem::add_stiffness_product:
// the sparse product with K, the element pass on the kept polar decompositions; with
// psd_projection the element pass with the projection's derivative) allocate nothing.
TEST(NoAllocation, StiffnessProductsFromTheRecordAllocateNothing) {
  for (const bool psd : {false, true})
  for (auto law : {material::Law::corotational, material::Law::stvk, material::Law::neo_hookean}) {
    SCOPED_TRACE(psd ? "psd_projection" : "no projection");
    test::BodySpec spec;
    spec.law = law;
    spec.psd_projection = psd;
    spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
    const Model model = test::make_model(test::box_mesh(8, 3, 3, 0.1, 0.02, 0.02), spec);
    fem::FemData record;
    record.resize(model.fem);
    const VecX x = model.initial.x + VecX::Constant(model.initial.x.size(), 1e-4).cwiseProduct(
                                         VecX::LinSpaced(model.initial.x.size(), -1.0, 1.0));
    const VecX u = VecX::LinSpaced(x.size(), 0.0, 1e-3), w = VecX::LinSpaced(x.size(), 1.0, -1.0);
    const VecX a = VecX::Constant(1, -0.01), c = VecX::Constant(1, -1e-4);
    VecX out = VecX::Zero(x.size()), work = VecX::Zero(x.size());
    ASSERT_TRUE(fem::evaluate(model.fem, x, {false, true, true}, record));
    {
      Counting counter;
      for (auto kind : {fem::StiffnessProduct::jvp, fem::StiffnessProduct::vjp})
        ASSERT_EQ(fem::add_stiffness_product(model.fem, record, x, kind, u, w, a, c, out, work), -1);
      EXPECT_EQ(counter.count(), 0) << material::law_name(law) << ": the products allocated";
    }
    EXPECT_GT(out.norm(), 0);
  }
}

// BDF2 (integrator/bdf2.hpp): after its first two steps (implicit Euler, then the first
// BDF2 step, which sizes data.hat), a BDF2 step allocates nothing either.
TEST(NoAllocation, Bdf2StepAllocatesNothing) {
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.rayleigh_mass = 0.1;
  spec.rayleigh_stiffness = 0.01;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  Model model = test::make_model(test::box_mesh(8, 3, 3, 0.1, 0.02, 0.02), spec);
  model.step.integrator = IntegratorKind::bdf2;
  Data data(model);
  State previous = model.initial, s = model.initial, next = model.initial;
  ASSERT_TRUE(integrator::bdf2_step(model, data, s, nullptr, next, 1).ok());
  std::swap(previous, s);
  std::swap(s, next);
  ASSERT_TRUE(integrator::bdf2_step(model, data, s, &previous, next, 2).ok());
  std::swap(previous, s);
  std::swap(s, next);
  Counting c;
  ASSERT_TRUE(integrator::bdf2_step(model, data, s, &previous, next, 3).ok());
  EXPECT_EQ(c.count(), 0) << "the BDF2 step allocated";
}

}  // namespace
