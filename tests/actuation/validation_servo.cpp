// Validation of the torque (rotation) servo (issue "Actuators"): the nodal forces it
// applies have exactly the prescribed moment about its axis, and the step applies them.
//
// Rotation servo, unit axis a through c, torque lambda, nodes i with moment arms
// r_i = (I - a a^T)(x_i - c) and S = sum_j |r_j|^2: f_i = lambda (a x r_i) / S. Since
// a . ((x_i - c) x (a x r_i)) = a . (r_i x (a x r_i)) = |r_i|^2 (the axial part of
// x_i - c is parallel to a and drops out of the triple product), the moment about the
// axis is a . sum_i (x_i - c) x f_i = lambda sum_i |r_i|^2 / S = lambda exactly, in
// any configuration x. In floating point every term is non-negative and of size
// lambda |r_i|^2 / S, so the sum carries a relative rounding error of a few 1e-16 per
// node: 1e-12 relative leaves three orders of margin.
//
// 1. TorqueServoMomentIsExact: servos built from a scene (world coordinates, the
//    shipped beam mesh): one on the tip face (`group: tip`, a planar patch), one on a
//    box of nodes through the volume (non-planar), each about an oblique axis through
//    an off-centre point, so that neither the resultant force nor the off-axis moment
//    vanishes (nothing symmetric helps). H_a(x)^T lambda has moment lambda about the axis
//    at rest and in a deformed configuration.
// 2. StepAppliesTorque: one implicit Euler step from rest of the free beam (no fixed
//    node, gravity off) with the tip servo's torque given by a schedule. The step uses
//    lambda at t_i + h: the schedule [[0, 0], [1, T]] must give lambda = T h. At rest
//    f_int = 0 and P = 0, so the right-hand side is h H_a(X)^T lambda: its moment about
//    the axis is h lambda (1e-12). The solution of A dv = b must then carry the angular
//    impulse: a . sum_i (X_i - c) x m_i dv_i = h lambda, because A = M + h^2 K and K(X)
//    annihilates the infinitesimal rotations about any axis (K is symmetric, so the
//    rotation's "moment" of K dv is (K w)^T dv = 0). That holds to the linear solve's
//    accuracy and the rounding of K w (~1e-16 ||K|| |X| |dv|, against m |X| |dv|):
//    checked to 1e-9 relative, which a missing or misplaced factor h fails by orders
//    of magnitude.
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <support/cli.hpp>

#include "helpers.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>

using namespace softdiff;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const Vec3 kAxisTip(0.3, -0.2, 1.0), kCenterTip(0.17, 0.004, 0.013);
const Vec3 kAxisBox(1.0, 0.4, -0.25), kCenterBox(0.09, 0.027, -0.006);
constexpr double kTorqueTip = 0.037, kTorqueBox = 0.0021;  // N m
constexpr double kRamp = 0.5;                              // N m per second (schedule)

std::string v3(const Vec3& p) {
  char s[128];
  std::snprintf(s, sizeof s, "[%.17g, %.17g, %.17g]", p.x(), p.y(), p.z());
  return s;
}

// The shipped beam (0.2 x 0.02 x 0.02 m), free, two torque servos.
std::string servo_scene(bool scheduled) {
  return "softdiff: 1\n"
         "simulation:\n"
         "  dt: 0.01\n"
         "  steps: 1\n"
         "  gravity: [0, 0, 0]\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " +
         (kRoot / "meshes/beam.msh").string() +
         "\n"
         "    material: {law: corotational, young: 1.0e6, poisson: 0.45, density: 1070}\n"
         "    actuators:\n"
         "      - name: twist_tip\n"
         "        type: servo\n"
         "        nodes: {group: tip}\n"
         "        axis: " +
         v3(kAxisTip) + "\n        center: " + v3(kCenterTip) + "\n" +
         (scheduled ? "        schedule: [[0, 0], [1, " + std::to_string(kRamp) + "]]\n"
                    : "        force: " + std::to_string(kTorqueTip) + "\n") +
         (scheduled ? std::string()
                    : "      - name: twist_box\n"
                      "        type: servo\n"
                      "        nodes: {box: [0.06, -1, -1, 0.11, 1, 1]}\n"
                      "        axis: " +
                          v3(kAxisBox) + "\n        center: " + v3(kCenterBox) +
                          "\n"
                          "        force: " +
                          std::to_string(kTorqueBox) + "\n");
}

Model load(const std::string& name, const std::string& text) {
  const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / ("validation_servo_" + std::to_string(::getpid())) / name;
  fs::remove_all(dir);
  test::write_text(dir / "scene.yaml", text);
  Model model = io::build_model(io::load_scene(dir / "scene.yaml"));
  fs::remove_all(dir);
  return model;
}

// a . sum_i (x_i - c) x f_i over all nodes.
double axial_moment(const VecX& x, const VecX& f, const Vec3& axis, const Vec3& center) {
  const Vec3 a = axis.normalized();
  Vec3 m = Vec3::Zero();
  for (Eigen::Index i = 0; i < x.size() / 3; ++i)
    m += (Vec3(x.segment<3>(3 * i)) - center).cross(Vec3(f.segment<3>(3 * i)));
  return a.dot(m);
}

Vec3 resultant(const VecX& f) {
  Vec3 r = Vec3::Zero();
  for (Eigen::Index i = 0; i < f.size() / 3; ++i) r += f.segment<3>(3 * i);
  return r;
}

TEST(ServoValidation, TorqueServoMomentIsExact) {
  const Model model = load("exact", servo_scene(false));
  ASSERT_EQ(model.actuation.actuators.size(), 2u);
  std::mt19937 rng(7);
  const VecX deformed = test::deform(model.initial.x, 1e-4, rng);
  struct Case {
    const char* name;
    Vec3 axis, center;
    double torque;
  } cases[] = {{"twist_tip", kAxisTip, kCenterTip, kTorqueTip}, {"twist_box", kAxisBox, kCenterBox, kTorqueBox}};
  for (int k = 0; k < 2; ++k) {
    const auto& act = model.actuation.actuators[k];
    const Case& c = cases[k];
    ASSERT_EQ(act.name, c.name);
    const auto& servo = std::get<actuation::Servo>(act.kind);
    ASSERT_TRUE(servo.is_rotation());
    EXPECT_DOUBLE_EQ(act.value.at(0.3), c.torque);
    for (const VecX* x : {&model.initial.x, &deformed}) {
      VecX f = VecX::Zero(x->size());
      act.add_force(*x, c.torque, 1.0, f);
      const double moment = axial_moment(*x, f, c.axis, c.center);
      const Vec3 a = c.axis.normalized();
      Vec3 full = Vec3::Zero();  // the full moment vector about c, for the report
      for (Eigen::Index i = 0; i < x->size() / 3; ++i)
        full += (Vec3(x->segment<3>(3 * i)) - c.center).cross(Vec3(f.segment<3>(3 * i)));
      std::printf("%s (%d nodes), %s: axial moment %.17g N m (prescribed %.17g, relative error %.2e); "
                  "|resultant force| %.3e N, |off-axis moment| %.3e N m\n",
                  c.name, static_cast<int>(servo.nodes().size()), x == &deformed ? "deformed" : "rest", moment,
                  c.torque, moment / c.torque - 1, resultant(f).norm(), (full - a * a.dot(full)).norm());
      EXPECT_LT(std::abs(moment / c.torque - 1), 1e-12);
      // Nothing symmetric: the test would not pass by a vanishing sum.
      EXPECT_GT(resultant(f).norm(), 1e-3 * c.torque / 0.02);
    }
  }
}

TEST(ServoValidation, StepAppliesTorque) {
  const Model model = load("step", servo_scene(true));
  ASSERT_EQ(model.actuation.actuators.size(), 1u);
  ASSERT_EQ(model.fem.num_fixed_dofs, 0);
  const double h = model.step.dt, lambda = kRamp * h;  // schedule value at t_i + h
  Data data(model);
  State out;
  const StepStatus status = integrator::implicit_euler_step(model, data, model.initial, out, 1);
  ASSERT_TRUE(status.ok()) << describe(model, status);
  ASSERT_EQ(data.lambda_a.size(), 1);
  EXPECT_NEAR(data.lambda_a[0], lambda, 1e-15 * lambda);

  const VecX& X = model.initial.x;
  const double rhs_moment = axial_moment(X, data.rhs, kAxisTip, kCenterTip);
  VecX momentum(X.size());  // m_i dv_i (lumped mass; v_i = 0)
  for (Eigen::Index k = 0; k < X.size(); ++k) momentum[k] = model.fem.mass_diagonal[k] * (out.v[k] - model.initial.v[k]);
  const double impulse = axial_moment(X, momentum, kAxisTip, kCenterTip);
  std::printf("one step, h = %g s, lambda(t_i + h) = %.6e N m: moment of the right-hand side %.17g (h lambda %.17g, "
              "relative error %.2e); angular impulse a . sum (X - c) x m dv = %.17g (relative error %.2e)\n",
              h, data.lambda_a[0], rhs_moment, h * lambda, rhs_moment / (h * lambda) - 1, impulse,
              impulse / (h * lambda) - 1);
  EXPECT_LT(std::abs(rhs_moment / (h * lambda) - 1), 1e-12);
  EXPECT_LT(std::abs(impulse / (h * lambda) - 1), 1e-9);
}

}  // namespace
