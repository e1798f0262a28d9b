// A program of your own linking the installed softdiff (docs/install.md): it loads a
// scene, runs a few steps and differentiates them in both modes.
//
//   softdiff_external_example [SCENE.yaml] [STEPS]
//
// SCENE.yaml defaults to the shipped Finger (<prefix>/share/softdiff/configs/finger.yaml,
// SOFTDIFF_DEFAULT_SCENE below); STEPS to 6. The scene needs an effector and actuators.
// Printed: the first effector's position p after STEPS steps of the scene's actuation,
// dp/dlambda_a (lambda_a: a constant offset added to actuator a at every step) by
// forward sensitivities (one JVP per actuator and step), and the gradient of
// l = 1/2 |p|^2 by the adjoint (one VJP per step). The two modes differentiate the same
// discrete trajectory, so dl/dlambda_a = p . dp/dlambda_a up to round-off: the program
// exits 1 when they differ by more than 1e-9 |p| |dp/dlambda_a| (the bound softdiff's
// own test of forward against adjoint uses, tests/diff/validation_trajectory_bdf2.cpp),
// 2 on bad input, 0 otherwise.
#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/version.hpp>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#ifndef SOFTDIFF_DEFAULT_SCENE
#define SOFTDIFF_DEFAULT_SCENE "configs/finger.yaml"
#endif

using namespace softdiff;

int main(int argc, char** argv) {
  const std::string scene = argc > 1 ? argv[1] : SOFTDIFF_DEFAULT_SCENE;
  const long steps = argc > 2 ? std::atol(argv[2]) : 6;
  if (steps < 1) {
    std::fprintf(stderr, "error: STEPS must be a positive integer\n");
    return 2;
  }
  try {
    const Model model = io::build_model(io::load_scene(scene));
    if (model.actuation.effectors.empty() || model.actuation.empty()) {
      std::fprintf(stderr, "error: %s: the scene needs an effector and actuators\n", scene.c_str());
      return 2;
    }
    const auto& effector = model.actuation.effectors[0].effector;
    std::printf("softdiff %s: %ld steps of '%s'\n", SOFTDIFF_VERSION, steps, model.actuation.effectors[0].name.c_str());

    // Forward mode: d x_T / d lambda (3n x n_a), then dp/dlambda = J dx/dlambda.
    diff::ThetaLayout theta;
    theta.actuation = true;
    Data data(model);
    State final_state;
    MatX dx, dv;
    StepStatus status = diff::forward_sensitivities(model, data, model.initial, steps, theta, final_state, dx, dv);
    if (!status.ok()) {
      std::fprintf(stderr, "error: %s\n", describe(model, status).c_str());
      return 1;
    }
    const Vec3 p = effector.position(final_state.x);
    std::printf("p = %.17g %.17g %.17g\n", p.x(), p.y(), p.z());

    // Reverse mode: l = 1/2 |p(x_T)|^2, dl/dx_T = J^T p, carried back by the adjoint.
    diff::Tape tape;
    status = diff::record(model, data, model.initial, steps, tape);
    if (!status.ok()) {
      std::fprintf(stderr, "error: %s\n", describe(model, status).c_str());
      return 1;
    }
    const Vec3 p_tape = effector.position(tape.frames.back().x);
    diff::AdjointResult g;
    const auto cotangent = [&](long k, const State&, VecX& bar_x, VecX&) {
      if (k == steps) effector.add_jacobian_transpose(p_tape, 1.0, bar_x);
    };
    status = diff::adjoint(model, data, tape, theta, cotangent, g);
    if (!status.ok()) {
      std::fprintf(stderr, "error: %s\n", describe(model, status).c_str());
      return 1;
    }

    bool agree = true;
    for (Eigen::Index a = 0; a < dx.cols(); ++a) {
      const Vec3 dp = effector.jacobian_times(dx.col(a));
      const double forward = p.dot(dp);
      const double reverse = g.theta[theta.actuation_offset() + a];
      const bool ok = std::abs(forward - reverse) <= 1e-9 * p.norm() * dp.norm();
      agree = agree && ok;
      std::printf("actuator %s: dp/dlambda = %.17g %.17g %.17g; dl/dlambda forward %.17g, adjoint %.17g%s\n",
                  model.actuation.actuators[static_cast<std::size_t>(a)].name.c_str(), dp.x(), dp.y(), dp.z(), forward,
                  reverse, ok ? "" : "  <- differ");
    }
    return agree ? 0 : 1;
  } catch (const InputError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
