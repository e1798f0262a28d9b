// Validation of the shipped Finger scene (configs/finger.yaml): pulling a cable bends
// the finger towards the cable's side, more with more tension.
//
// The finger hangs along -z from its base (z = 0); both cables run at y = 15.3 mm,
// above the sections' centroids (y = 10 mm in the segments, 5.7 mm at the joints where
// only the 6 mm underside plate and the bellows remain),
// at x = -5 mm (cable1) and x = +5 mm (cable2). A tension shortens the top fibres:
// the tip rises (+y) and leans to the pulled cable's x side.
//
// Equilibria come from dynamic relaxation (support/relax.hpp) with the scene's dt,
// gravity off (it acts along the finger's axis, upstream [0, 0, -9810] mm/s^2, and
// would only add a micrometre-scale stretch to subtract) and rayleigh_stiffness 0.02
// instead of the upstream 0.1: the equilibrium does not depend on damping, and 0.1
// overdamps the first bending mode so much that rest takes ~3x more steps.
// Tensions stay at or below 2 N: at 4 N, with dt = 0.01, the finger no longer comes
// to rest (the cable force is explicit in x and its stiffness is not in the system
// matrix, as for the Trunk; see configs/finger.yaml).
#include <support/relax.hpp>

#include <cstdio>
#include <filesystem>
#include <gtest/gtest.h>
#include <sstream>

using namespace softdiff;
namespace fs = std::filesystem;

namespace {

const fs::path kScene = fs::path(SOFTDIFF_SOURCE_DIR) / "configs/finger.yaml";
constexpr double kResidualTol = 1e-6;  // force imbalance / cable load at equilibrium

struct Bend {
  Vec3 tip = Vec3::Zero();   // tip displacement (m)
  double shortening = 0;     // rest length - length of the pulled cable (m)
};

Bend pull(const std::string& cable, double tension) {
  std::ostringstream f;
  f.precision(17);
  f << "bodies.finger.actuators." << cable << ".force=" << tension;
  const Model model = test::load_model(
      kScene, {"simulation.gravity=[0,0,0]", "bodies.finger.actuators.cable1.schedule=null",
               "bodies.finger.actuators.cable2.schedule=null",
               "bodies.finger.damping.rayleigh_stiffness=0.02", f.str()});
  State start = model.initial;
  start.v.setZero();
  const test::Rest r = test::relax(model, start, 1e-6, kResidualTol, 1000);
  EXPECT_TRUE(r.ok) << "no equilibrium after " << r.steps << " steps: max |v| = " << r.max_v
                    << " m/s, relative residual " << r.residual;
  Bend b;
  b.tip = test::effector(model, r.state, "tip") - test::effector(model, model.initial, "tip");
  for (const auto& a : model.actuation.actuators)
    if (a.name == cable) b.shortening = a.measure(model.initial.x) - a.measure(r.state.x);
  std::printf("  %s %g N: %ld steps, residual %.2e, tip displacement [%.5g, %.5g, %.5g] mm, shortening %.5g mm\n",
              cable.c_str(), tension, r.steps, r.residual, 1e3 * b.tip.x(), 1e3 * b.tip.y(), 1e3 * b.tip.z(),
              1e3 * b.shortening);
  return b;
}

}  // namespace

// (c) cable1 (x = -5 mm): the tip rises and leans to -x, monotonically in the
// tension; cable2 (x = +5 mm) mirrors it.
TEST(FingerScene, CableBendsTheFingerTowardsItsSide) {
  Bend previous, at_1N;
  for (double tension : {0.5, 1.0, 2.0}) {
    SCOPED_TRACE("cable1 tension " + std::to_string(tension) + " N");
    const Bend b = pull("cable1", tension);
    EXPECT_GT(b.tip.y(), 1e-3);                    // rises by more than 1 mm
    EXPECT_LT(b.tip.x(), -0.1 * b.tip.y());        // leans to the cable's side (-x)
    EXPECT_GT(b.tip.y(), 1.5 * previous.tip.y());  // more with more tension (x2 each time)
    EXPECT_LT(b.tip.x(), 1.5 * previous.tip.x());
    EXPECT_GT(b.shortening, previous.shortening);
    if (tension == 1.0) at_1N = b;
    previous = b;
  }
  const Bend b2 = pull("cable2", 1.0);
  EXPECT_GT(b2.tip.y(), 1e-3);
  EXPECT_GT(b2.tip.x(), 0.1 * b2.tip.y());  // leans to +x
  // Mirror images up to the mesh's asymmetry (gmsh meshes the whole solid; 0.1% measured).
  EXPECT_NEAR(b2.tip.x(), -at_1N.tip.x(), 0.02 * std::abs(at_1N.tip.x()));
  EXPECT_NEAR(b2.tip.y(), at_1N.tip.y(), 0.02 * at_1N.tip.y());
}
