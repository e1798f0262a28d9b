// The static solver on the shipped Trunk with cable tension: full Newton (the cable
// stiffness is in the tangent) with the line search on the total potential (cables
// are conservative) reaches equilibrium in one load step of a large deflection; the residual is checked
// independently of the solver, and the cable lifts the drooping tip.
#include <softdiff/data.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>

#include <gtest/gtest.h>

using namespace softdiff;

namespace {

// Mean y of the tip-face nodes (rest z > 0.194 m).
double tip_y(const Model& model, const State& s) {
  double y = 0;
  int n = 0;
  for (int i = 0; i < model.fem.num_nodes; ++i)
    if (model.fem.X(2, i) > 0.194) {
      y += s.x[3 * i + 1];
      ++n;
    }
  EXPECT_GT(n, 0);
  return y / n;
}

double solve(double tension, int* iterations) {
  const io::SceneDesc scene = io::load_scene(
      std::string(SOFTDIFF_SOURCE_DIR) + "/configs/trunk.yaml",
      {"simulation.integrator=static", "simulation.dt=null", "simulation.duration=null",
       "bodies.trunk.actuators.cableL0.force=" + std::to_string(tension)});
  const Model model = io::build_model(scene);
  Data data(model);
  State out;
  const StepStatus st = integrator::solve_static(model, data, model.initial, out);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  *iterations = data.newton_iterations_used;
  // Independent residual: f_int + P + H_a^T lambda on free dofs.
  fem::FemData d;
  d.resize(model.fem);
  fem::evaluate(model.fem, out.x, {false, true, false}, d);
  VecX r = d.f_int + model.fem.gravity_force;
  VecX lambda;
  model.actuation.values(1.0, lambda);
  model.actuation.add_forces(out.x, lambda, 1.0, r);
  for (int k = 0; k < r.size(); ++k)
    if (model.fem.fixed[k]) r[k] = 0;
  EXPECT_LT(r.norm(), 1e-8 * model.fem.gravity_force.norm());
  return tip_y(model, out);
}

TEST(TrunkStaticValidation, CableTensionConvergesAndLiftsTheTip) {
  int it0 = 0, it1 = 0;
  // The horizontal trunk droops ~0.16 m under gravity (its necks are very compliant):
  // one load step of large rotation takes tens of damped Newton iterations; the
  // solver's own limit (static.max_iterations = 50) is the bound.
  const double y0 = solve(0.0, &it0);
  const double y1 = solve(0.2, &it1);
  std::printf("Newton iterations: %d (gravity only), %d (cableL0 at 0.2 N); tip y %.4f -> %.4f m\n", it0, it1, y0, y1);
  EXPECT_GT(y1, y0 + 1e-3);  // cableL0 runs along +y
}

}  // namespace
