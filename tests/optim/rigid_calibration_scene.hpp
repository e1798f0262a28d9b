#pragma once
// The scene of the rigid-body calibration tests (issue 21; optim/calibration.hpp): a
// rigid cube (0.02 m, 500 kg/m^3, 4 g) landing on a soft slab (4 x 4 x 1 boxes of 6
// tets, 0.06 x 0.06 x 0.01 m, bottom fixed, young 5e4 Pa, Rayleigh 20 1/s and 0.01 s:
// overdamped, so the cube sinks in and stays, no bounce that would open and close the
// contacts) as in tests/rigid/test_contact_derivatives.cpp (placed so that no
// vertex-face pair switches features: it lands 0.3 mm above the slab at 0.3 m/s, turned
// 0.1 rad about z, without horizontal velocity: the contacts stick with near-zero
// tangential forces, inside their mode), and a free box spinning about an axis off its
// principal axes far from the slab (in no contact pair): its orientation depends on its
// inertia (torque-free precession). 10 steps of 2 ms.
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>  // time_step: the rigid bodies' stage with the soft one
#include <softdiff/optim/calibration.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>

#include <gtest/gtest.h>

#include <utility>

namespace softdiff::test::rigid_calibration {

constexpr long kCubeSteps = 10;

inline Model cube_on_slab(double young = 5e4, double cube_density = 500) {
  BodySpec spec;
  spec.young = young;
  spec.poisson = 0.4;
  spec.density = 1000;
  spec.rayleigh_mass = 20;
  spec.rayleigh_stiffness = 0.01;
  spec.fixed = [](const Vec3& p) { return p.z() < 1e-9; };
  Model model = make_model(box_mesh(4, 4, 1, 0.06, 0.06, 0.01), spec, Vec3(0, 0, -9.81), 2e-3, kCubeSteps);
  rigid::RigidState s;
  s.position = Vec3(0.0375, 0.0375, 0.01 + 0.01 + 3e-4);
  s.velocity = Vec3(0, 0, -0.3);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Vec3::UnitZ()));
  add_rigid_body(model, "cube", box_shape(Vec3(0.01, 0.01, 0.01)), cube_density, s);
  rigid::RigidState spin;
  spin.position = Vec3(0.5, 0.5, 0.5);
  spin.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Vec3(1, 0, 0)));
  spin.angular_velocity = Vec3(1, 2, 8);
  add_rigid_body(model, "spinner", box_shape(Vec3(0.02, 0.01, 0.005)), 1000, spin);
  contact::NcpOptions ncp;  // tight: each run's contact solve to round-off
  ncp.tolerance = 1e-12;
  ncp.max_iterations = 5000;
  enable_rigid_contact(model, {}, {{"body", "cube", 0.5}}, 1e-3, ncp);
  model.contact.ncp.backend = contact::NcpBackend::dense;
  return model;
}

// Every frame 1..kCubeSteps of a run of `model`: the soft positions if `nodes`, and the poses
// of the rigid bodies listed (orientation rows scaled by the scene's L), each target
// orientation turned by `offset` (a rotation vector, world axes) so that the orientation
// error is not small.
inline optim::CalibrationTarget poses_target(const Model& model, bool nodes, const std::vector<int>& bodies,
                                             const Vec3& offset = Vec3::Zero()) {
  optim::CalibrationTarget t;
  for (const int b : bodies) {
    optim::CalibrationTarget::RigidPoses p;
    p.body = b;
    p.length = optim::rigid_orientation_length(model.rigid[static_cast<std::size_t>(b)]);
    t.rigid.push_back(p);
  }
  Data data(model);
  State s = model.initial, next = model.initial;
  const Eigen::Quaterniond turn(Eigen::AngleAxisd(offset.norm(), offset.norm() > 0 ? Vec3(offset.normalized()) : Vec3::UnitX()));
  for (long k = 1; k <= kCubeSteps; ++k) {
    const StepStatus st = integrator::time_step(model, data, s, nullptr, next, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    std::swap(s, next);
    t.frames.push_back(k);
    if (nodes) t.states.push_back(s.x);
    for (auto& p : t.rigid) {
      const auto& r = s.rigid[static_cast<std::size_t>(p.body)];
      p.position.push_back(r.position);
      p.orientation.push_back(turn * r.orientation);
    }
  }
  return t;
}

}  // namespace softdiff::test::rigid_calibration
