// Example of the library API (issue "End-to-end derivatives"): the gradient of a loss
// over an effector's position with respect to the whole per-step actuation sequence,
// by the adjoint, and a few steps of projected gradient descent with it.
//
//   softdiff_example_effector_gradient SCENE.yaml [STEPS] [ITERATIONS]
//
// Loss: l(lambda_1..T) = 1/2 |p(x_T) - p_goal|^2, p the scene's first effector, p_goal
// where a run with every actuator 0.5 (N, Pa or N m) above the scene's values takes
// it; the descent starts from the scene's values. Values are kept >= 0 (cables only
// pull) by projection. Exits 0 when the loss fell below 1% of its initial value.
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

using namespace softdiff;

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s SCENE.yaml [STEPS] [ITERATIONS]\n", argv[0]);
    return 2;
  }
  try {
    const long T = argc > 2 ? std::atol(argv[2]) : 20;
    const int iterations = argc > 3 ? std::atoi(argv[3]) : 5;
    const Model model = io::build_model(io::load_scene(argv[1], {}));
    if (model.actuation.effectors.empty() || model.actuation.empty()) {
      std::fprintf(stderr, "the scene needs an effector and actuators\n");
      return 2;
    }
    const auto& effector = model.actuation.effectors[0].effector;
    const Eigen::Index na = static_cast<Eigen::Index>(model.actuation.actuators.size());

    // The actuation sequence: the scene's schedules, one column per step.
    MatX lambda(na, T);
    VecX values(na);
    for (long k = 0; k < T; ++k) {
      model.actuation.values(model.initial.t + (k + 1) * model.step.dt, values);
      lambda.col(k) = values;
    }
    Data data(model);
    diff::Tape tape;
    if (!diff::record(model, data, model.initial, T, tape, (lambda.array() + 0.5).matrix()).ok()) return 1;
    const Vec3 goal = effector.position(tape.frames.back().x);
    double first_loss = 0, last_loss = 0;

    for (int it = 0; it <= iterations; ++it) {
      if (!diff::record(model, data, model.initial, T, tape, lambda).ok()) return 1;
      const Vec3 r = effector.position(tape.frames.back().x) - goal;
      const double loss = 0.5 * r.squaredNorm();
      // dl/dx_T = J_p^T r; the adjoint carries it back to every step's actuation.
      diff::AdjointResult g;
      const auto cotangent = [&](long k, const State&, VecX& bar_x, VecX&) {
        if (k == T) effector.add_jacobian_transpose(r, 1.0, bar_x);
      };
      if (!diff::adjoint(model, data, tape, {}, cotangent, g).ok()) return 1;
      std::printf("iteration %d: loss %.6e, |dl/dlambda| %.3e, tip error %.3f mm\n", it, loss, g.lambda_a.norm(),
                  1e3 * r.norm());
      if (it == 0) first_loss = loss;
      last_loss = loss;
      if (it == iterations) break;
      // A step of length such that the linearized loss would vanish (Gauss-Newton on
      // one residual direction), projected on lambda >= 0.
      const double gg = g.lambda_a.squaredNorm();
      if (gg == 0) break;
      lambda = (lambda - (loss / gg) * g.lambda_a).cwiseMax(0.0);
    }
    return last_loss < 0.01 * first_loss ? 0 : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  }
}
