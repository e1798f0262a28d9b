#pragma once
// Static equilibria of actuated scenes by dynamic relaxation: implicit Euler steps
// until the body is at rest, then an independent check of the static residual.
//
// A rest state of the linearized implicit Euler step (v_i = 0 and dv = 0) is a
// static equilibrium: the step's right-hand side is then h (P + f_int(x) + f_act(x)),
// so it vanishes exactly when the forces balance, whatever the damping and dt. The
// damping only decides how fast the run gets there; the tests choose it for speed
// (and say why) and check the equilibrium with relative_residual(), which does not
// depend on the step at all.
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>

#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <vector>

namespace softdiff::test {

inline Model load_model(const std::filesystem::path& scene, const std::vector<std::string>& overrides) {
  return io::build_model(io::load_scene(scene, overrides));
}

// ||Pi (f_int(x) + P + sum_a lambda_a(t) H_a(x)^T)|| / ||Pi sum_a lambda_a(t) H_a(x)^T||
// (Pi: the free dofs): the force imbalance relative to the actuation load. Uses
// data.fem as scratch.
inline double relative_residual(const Model& model, Data& data, const State& s) {
  EXPECT_TRUE(fem::evaluate(model.fem, s.x, {false, true, false}, data.fem));
  VecX lambda, f_act = VecX::Zero(s.x.size());
  model.actuation.values(s.t, lambda);
  model.actuation.add_forces(s.x, lambda, 1.0, f_act);
  VecX r = data.fem.f_int + model.fem.gravity_force + f_act;
  for (int k = 0; k < r.size(); ++k)
    if (model.fem.fixed[k]) r[k] = f_act[k] = 0;
  return r.norm() / f_act.norm();
}

struct Rest {
  State state;
  long steps = 0;         // implicit Euler steps taken
  double max_v = 0;       // max |v_k| at the end (m/s)
  double residual = 0;    // relative_residual at the end
  bool ok = false;        // every step succeeded and both tolerances are met
};

// Implicit Euler from `start` (its velocity is kept) until max_k |v_k| <= v_tol and
// relative_residual <= residual_tol (the residual is checked once the velocity is
// small: a small velocity alone allows a residual ~ h K v in stiff modes), at most
// max_steps steps.
inline Rest relax(const Model& model, const State& start, double v_tol, double residual_tol, long max_steps) {
  Data data(model);
  Rest r;
  r.state = start;
  State next;
  for (long k = 1; k <= max_steps; ++k) {
    const StepStatus status = integrator::implicit_euler_step(model, data, r.state, next, k);
    if (!status.ok()) {
      ADD_FAILURE() << describe(model, status);
      return r;
    }
    std::swap(r.state, next);
    r.steps = k;
    r.max_v = r.state.v.cwiseAbs().maxCoeff();
    if (r.max_v <= v_tol) {
      r.residual = relative_residual(model, data, r.state);
      if (r.residual <= residual_tol) {
        r.ok = true;
        break;
      }
    }
  }
  if (!r.ok) r.residual = relative_residual(model, data, r.state);
  return r;
}

inline Vec3 effector(const Model& model, const State& s, const std::string& name) {
  for (const auto& e : model.actuation.effectors)
    if (e.name == name) return e.effector.position(s.x);
  ADD_FAILURE() << "no effector " << name;
  return Vec3::Zero();
}

}  // namespace softdiff::test
