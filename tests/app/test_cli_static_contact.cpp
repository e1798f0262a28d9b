// `softdiff simulate` of a static scene with contact (configs/beam_supports_static.yaml):
// the /contact/* datasets of output.md for the equilibrium frame; its derivatives
// (check-grad against differences of whole static solves, simulate --jacobian); and bad
// input: a free body outside every contact pair gives exit 2, a message, and no output
// file.
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <string>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace cli_static_contact {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_static_contact";
const std::string kScene = "'" + (kRoot / "configs/beam_supports_static.yaml").string() + "'";

TEST(CliStaticContact, SimulateWritesTheContactDatasets) {
  const fs::path dir = fresh_dir(kWork, "simulate");
  const CliRun r = run_cli("simulate " + kScene + " -o out.h5 --quiet", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const hid_t f = H5Fopen((dir / "out.h5").string().c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  // Frame 0 (rest, no contacts) and the equilibrium of the one load step.
  EXPECT_EQ(h5_shape(f, "/time"), (std::vector<hsize_t>{2}));
  EXPECT_EQ(h5_shape(f, "/contact/offsets"), (std::vector<hsize_t>{3}));
  const auto force_shape = h5_shape(f, "/contact/force");
  ASSERT_EQ(force_shape.size(), 2u);
  EXPECT_GT(force_shape[0], 0u);
  EXPECT_EQ(force_shape[1], 3u);
  for (const char* d : {"/contact/point", "/contact/frame", "/contact/mode", "/contact/pair"})
    EXPECT_EQ(h5_shape(f, d)[0], force_shape[0]) << d;
  EXPECT_EQ(h5_shape(f, "/bodies/beam/contact_force"), (std::vector<hsize_t>{2, 1025, 3}));
  EXPECT_EQ(h5_shape(f, "/solver/contact_residual"), (std::vector<hsize_t>{2}));
  // The normal forces (frame component n; the supports' top faces are horizontal) carry
  // the weight rho g V = 1070 * 9.81 * 0.2 * 0.02 * 0.02 N, to the solver's tolerance
  // (1e-8 relative on the residual norm; its sum over 3075 dofs: < 1e-6 relative).
  const std::vector<double> force = h5_read(f, "/contact/force");
  double normal = 0;
  for (std::size_t i = 2; i < force.size(); i += 3) normal += force[i];
  const double weight = 1070 * 9.81 * 0.2 * 0.02 * 0.02;
  EXPECT_NEAR(normal, weight, 1e-6 * weight);
  H5Fclose(f);
}

// The shipped beam (0.2 x 0.02 x 0.02 m) resting on a plane with no fixed node, mu = 2
// (every contact inside its cone: sticking, the case whose derivative is exact; docs/
// method.md "Static equilibrium with contact"): check-grad of the equilibrium with
// respect to young and friction through the contacts (measured: young 1.1e-8). The solve is converged
// to a residual of 1e-12 and the NCP to 1e-12 (a looser solve would put its error
// divided by eps into every difference); eps 1e-4 (check-grad's default): truncation
// ~1e-8, the solves' error ~1e-12 / 1e-4 = 1e-8, far below the default tolerance 1e-5.
// (friction: no effect where every contact sticks; check-grad compares a zero column.)
const std::string kRestingBeam =
    "softdiff: 1\n"
    "simulation:\n"
    "  integrator: static\n"
    "  static: {tolerance: 1.0e-12, max_iterations: 100, load_steps: 1}\n"
    "bodies:\n"
    "  - name: beam\n"
    "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
    "    material: {law: corotational, young: 1.0e5, poisson: 0.3, density: 1000}\n"
    "obstacles:\n"
    "  - {name: floor, type: plane, normal: [0, 0, 1], offset: 0}\n"
    "contact:\n"
    "  friction: 2.0\n"
    "  margin: 0.001\n"
    "  tolerance: 1.0e-12\n"
    "  max_iterations: 20000\n";

TEST(CliStaticContact, CheckGradThroughStaticContact) {
  const fs::path dir = fresh_dir(kWork, "check_grad");
  write_text(dir / "scene.yaml", kRestingBeam);
  const CliRun r = run_cli("check-grad scene.yaml --wrt young,friction --quiet", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  for (const char* block : {"young", "friction"})
    EXPECT_NE(r.out.find(std::string("\n") + block + " "), std::string::npos) << r.out;
  // Every contact sticks from the first iterate (none slid along the path): no
  // path-dependence is claimed, so a failure here would be a verdict on the derivative.
  EXPECT_NE(r.out.find("decided by the solver's path: 0 sliding, 0 stuck after sliding\n"), std::string::npos)
      << r.out;
}

// static.friction load_step (2026-12-04, branch sfric; docs/method.md "Static equilibrium
// with contact", *Load-step-anchored friction*): the same resting beam with mu 0.3, where
// the default (iterate) is path-dependent (measured: young 3.4e-2, friction 0.78; 25
// contacts sliding, 64 stuck after sliding), passes with load_step (measured: young
// 1.1e-8, friction 4.6e-8; the same eps and solves as above): each Newton iteration's
// contact solve acts on the slip since the load step's start, so the equilibrium is a
// function of theta, and check-grad reports no path dependence (one load step).
TEST(CliStaticContact, CheckGradWithLoadStepFriction) {
  const fs::path dir = fresh_dir(kWork, "check_grad_load_step");
  std::string scene = kRestingBeam;
  scene.replace(scene.find("friction: 2.0"), 13, "friction: 0.3");
  scene.replace(scene.find("load_steps: 1}"), 14, "load_steps: 1, friction: load_step}");
  write_text(dir / "scene.yaml", scene);
  const CliRun r = run_cli("check-grad scene.yaml --wrt young,friction --quiet", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("frictional contacts: slip from the load step's start (static.friction load_step), 0 moved "
                       "in earlier load steps\n"),
            std::string::npos)
      << r.out;
  EXPECT_EQ(r.err.find("path-dependent"), std::string::npos) << r.err;
}

// configs/beam_supports_static.yaml with static.friction load_step has no equilibrium
// within reach of the solver (docs/method.md *Load-step-anchored friction*): every loaded
// contact slides (both ends outwards, 10 contacts), the beam's translation along x is
// resisted only by the difference of the two ends' friction forces (~1.5e-6 of the load),
// and the iterates drift along it by 2.5e-8 m per iteration with 2.5e-4 m to go: not
// converged, said so (exit 1), the frame of the start written.
TEST(CliStaticContact, ShippedBeamOnSupportsWithLoadStepFrictionDoesNotConverge) {
  const fs::path dir = fresh_dir(kWork, "supports_load_step");
  const CliRun r = run_cli("simulate " + kScene + " -o out.h5 --quiet --set simulation.static.friction=load_step", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("load step 1: Newton did not converge in 50 iterations"), std::string::npos) << r.err;
}

// Bad input: an unknown static.friction is refused, exit 2, naming the choices.
TEST(CliStaticContact, UnknownStaticFrictionIsRefused) {
  const fs::path dir = fresh_dir(kWork, "static_friction_bad");
  const CliRun r = run_cli("simulate " + kScene + " -o out.h5 --set simulation.static.friction=sticky", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("simulation.static.friction: must be one of: iterate, load_step; got 'sticky'"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));
}

// A wrong derivative still fails on a path-independent scene (2026-12-04, branch sgrad):
// the young block multiplied by 1.001 (SOFTDIFF_CHECK_GRAD_FAULT, docs/cli.md) gives a
// relative error of 1e-3 > 1e-5, exit 1, and no path-dependence message.
TEST(CliStaticContact, CheckGradStillFailsAWrongStaticDerivative) {
  const fs::path dir = fresh_dir(kWork, "check_grad_fault");
  write_text(dir / "scene.yaml", kRestingBeam);
  ::setenv("SOFTDIFF_CHECK_GRAD_FAULT", "young:1.001", 1);
  const CliRun r = run_cli("check-grad scene.yaml --wrt young --quiet", dir);
  ::unsetenv("SOFTDIFF_CHECK_GRAD_FAULT");
  EXPECT_EQ(r.code, 1) << r.out << r.err;
  EXPECT_NE(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("path-dependent"), std::string::npos) << r.out;
  EXPECT_EQ(r.err.find("path-dependent"), std::string::npos) << r.err;
}

// The shipped configs/beam_supports_static.yaml (mu 0.5; 2026-12-04, branch sgrad): the
// beam's ends slid outwards along the Newton iterates; at the equilibrium the right
// support's 5 contacts slide (force on the cone) and the left's 5 stick at 0.9997-0.9999
// of the cone after sliding ~0.23 mm. The solves at young 1e6 -/+ 100 Pa end with the
// same modes, and the stuck node 34 at x = -0.085230099506 / -0.085230056980 m: 2.1e-10
// m/Pa, the same at eps 1e-3 to 1e-6 and static tolerances 1e-8 and 1e-10 (not the
// solver's noise: the path's own dependence on young), where the derivative, which
// holds the stuck point, has 0. check-grad must not pass it (exit 1) and must say why:
// the verdict path-dependent, with the counts, naming issue 21.
TEST(CliStaticContact, CheckGradSaysTheShippedFrictionalSceneIsPathDependent) {
  const fs::path dir = fresh_dir(kWork, "check_grad_path");
  const CliRun r = run_cli("check-grad " + kScene + " --wrt young --json --quiet", dir);
  EXPECT_EQ(r.code, 1) << r.out << r.err;
  EXPECT_NE(r.out.find("\"path_dependent\":true"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("\"path_dependent_contacts\":{\"sliding\":5,\"stuck_after_sliding\":5,\"static_friction\":\"iterate\","
                       "\"moved_in_earlier_load_steps\":0}"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("\"worst_row\":\"x[beam node 34].x\""), std::string::npos) << r.out;
  EXPECT_NE(r.err.find("is path-dependent here: 5 contact(s) slide and 5 stick after sliding"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("issue 21"), std::string::npos) << r.err;
  // The smoothing warning is not given: the same difference with contact.smoothing off.
  EXPECT_EQ(r.err.find("smoothed contact derivatives"), std::string::npos) << r.err;
}

// The shipped static scene (its contacts on the supports' edges slide: the derivative
// is the straight-slip-path one there) with --jacobian: exit 0 and the dataset.
const std::string kTight =
    " --set simulation.static.tolerance=1e-12 --set contact.tolerance=1e-12 --set contact.max_iterations=20000";

TEST(CliStaticContact, JacobianOfStaticContact) {
  const fs::path dir = fresh_dir(kWork, "jacobian");
  const CliRun r = run_cli("simulate " + kScene + " -o out.h5 --quiet --jacobian young" + kTight, dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const hid_t f = H5Fopen((dir / "out.h5").string().c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  EXPECT_EQ(h5_shape(f, "/jacobians/young"), (std::vector<hsize_t>{3 * 1025, 1}));
  // A stiffer beam sags less: the midspan underside moves up with young (dz/dE > 0
  // wherever the beam sags; the largest entry of the column is positive).
  const std::vector<double> J = h5_read(f, "/jacobians/young");
  double largest = 0;
  for (std::size_t k = 2; k < J.size(); k += 3)
    if (std::abs(J[k]) > std::abs(largest)) largest = J[k];
  EXPECT_GT(largest, 0);
  H5Fclose(f);
}

TEST(CliStaticContact, FreeBodyWithoutContactIsRefused) {
  const fs::path dir = fresh_dir(kWork, "free");
  const CliRun r = run_cli("simulate " + kScene + " -o out.h5 --set contact.enabled=false", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("a static scene needs fixed nodes on every body not in a contact pair: body 'beam' is free"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir / "out.h5"));
}

// A derivative whose contact mode-fixed system cannot be set up (the scale's power
// iteration on G_AA does not converge, contact_step_derivatives.cpp; forced here by
// contact.derivative_scale_iterations: 1, a cap under which no two estimates can be
// compared, with the operator path at any size, derivative_dense_max_active: 0) is a
// computation failure (docs/cli.md): exit 1, the reason on stderr prefixed as the
// integrator's other failures, with its load step (static) or step (dynamic), and the
// file finished as diverged, never a silent Jacobian.
TEST(CliStaticContact, NonConvergingDerivativeScaleIsAnError) {
  const std::string force = " --set contact.derivative_dense_max_active=0 --set contact.derivative_scale_iterations=1";
  {
    const fs::path dir = fresh_dir(kWork, "scale_static");
    write_text(dir / "scene.yaml", kRestingBeam);
    const CliRun r = run_cli("simulate scene.yaml -o out.h5 --quiet --jacobian young" + force, dir);
    EXPECT_EQ(r.code, 1) << r.err;
    EXPECT_NE(r.err.find("softdiff: error: load step 1: linear solver failed: the derivative of the equilibrium failed: "
                         "the scale of the contact derivative's mode-fixed system: the power iteration on G_AA ("),
              std::string::npos)
        << r.err;
    EXPECT_NE(r.err.find("did not converge in 1 products"), std::string::npos) << r.err;
  }
  {
    // The same beam resting on the plane, one implicit Euler step.
    std::string dynamic = kRestingBeam;
    const std::string from = "  integrator: static\n  static: {tolerance: 1.0e-12, max_iterations: 100, load_steps: 1}\n";
    ASSERT_NE(dynamic.find(from), std::string::npos);
    dynamic.replace(dynamic.find(from), from.size(), "  integrator: implicit_euler\n  dt: 0.002\n  steps: 1\n");
    const fs::path dir = fresh_dir(kWork, "scale_dynamic");
    write_text(dir / "scene.yaml", dynamic);
    // The sparse backend: no dense G is recorded, so the step's derivative forms G_AA.
    const CliRun r = run_cli("simulate scene.yaml -o out.h5 --quiet --jacobian young --set contact.backend=sparse "
                             "--set contact.dense_max_contacts=0" + force,
                             dir);
    EXPECT_EQ(r.code, 1) << r.err;
    EXPECT_NE(r.err.find("softdiff: error: step 1: linear solver failed: the derivative of the step failed: the scale "
                         "of the contact derivative's mode-fixed system: the power iteration on G_AA ("),
              std::string::npos)
        << r.err;
  }
}

}  // namespace cli_static_contact
