// Newton iterations (newton_iterations > 1) with rigid bodies in contact (docs/method.md
// "Newton with rigid contact", issue 21): run build/tests/validation_rigid
// --gtest_filter='RigidNewton*' (it prints the figures the docs quote).
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <iostream>

using namespace softdiff;

namespace rigid_newton_validation {

constexpr double g0 = 9.81;

Vec3 force_on_rigid(const Data& data, int side, int* count = nullptr) {
  Vec3 f = Vec3::Zero();
  int k = 0;
  for (int i = 0; i < data.contact.contacts.size(); ++i) {
    const auto& c = data.contact.contacts.contacts[static_cast<std::size_t>(i)];
    const Vec3 w = c.frame * data.contact.lambda.segment<3>(3 * i);
    if (c.side_a == side) f += w, ++k;
    else if (c.side_b == side) f -= w, ++k;
  }
  if (count) *count = k;
  return f;
}

// The cube on a soft slab of validation_rigid_contact.cpp (CubeRestsOnASoftSlab), the
// slab Neo-Hookean: 0.12 x 0.12 x 0.01 m, E = 50 kPa, bottom fixed, damped; the 40 mm
// cube (32 g) released at zero gap.
Model cube_on_slab(double h, int newton_iterations) {
  test::BodySpec spec;
  spec.law = material::Law::neo_hookean;
  spec.young = 5e4;
  spec.poisson = 0.4;
  spec.density = 1000;
  spec.rayleigh_mass = 20;
  spec.rayleigh_stiffness = 0.01;
  spec.fixed = [](const Vec3& p) { return p.z() < 1e-9; };
  const mesh::TetMesh m = test::box_mesh(8, 8, 2, 0.12, 0.12, 0.01);
  Model model = test::make_model(m, spec, Vec3(0, 0, -g0), h);
  model.step.newton_iterations = newton_iterations;
  rigid::RigidState s;
  s.position = Vec3(0.06, 0.06, 0.01 + 0.02);
  test::add_rigid_body(model, "cube", test::box_shape(Vec3(0.02, 0.02, 0.02)), 500, s);
  test::enable_rigid_contact(model, {}, {{"body", "cube", 0.5}}, 1e-3, contact::NcpOptions{});
  return model;
}

TEST(RigidNewton, Diagnose) {
  const char* ni = std::getenv("NEWTON");
  Model model = cube_on_slab(2e-3, ni ? std::atoi(ni) : 8);
  if (const char* mi = std::getenv("MAXIT")) model.contact.ncp.max_iterations = std::atoi(mi);
  Data data(model);
  State a = model.initial, b;
  for (long n = 1; n <= 150; ++n) {
    const StepStatus st = integrator::time_step(model, data, a, nullptr, b, n);
    std::cout << "step " << n << " ok " << st.ok() << " newton " << data.newton_iterations_used << " res "
              << data.newton_residual << " ncp " << data.contact.result.residuals.max() << " it "
              << data.contact.result.iterations << " nc " << data.contact.contacts.size() << " pol "
              << data.contact.result.polished << " ws " << data.contact.result.working_set_fallback << "\n";
    a = b;
  }
}

}  // namespace rigid_newton_validation
