// Calibration with rigid bodies (issue 21; optim/calibration.hpp): the residual's
// Jacobian with rigid rows (the cube's and the spinner's poses: position, and the
// orientation error L log(q q*^-1)) and rigid parameters (mass, inertia components)
// beside the slab's young, through the soft-rigid contact, against central differences
// of whole runs; the target's orientations turned by 0.4 rad so that the orientation
// rows' J_l(delta)^-1 is far from the identity. And the workspace (the runs of
// calibrate) gives the free residual's r and J bit for bit after runs at other values
// (rigid parameters restored).
#include <optim/rigid_calibration_scene.hpp>
#include <softdiff/core/error.hpp>

#include <gtest/gtest.h>

using namespace softdiff;

namespace calibration_rigid_test {

using namespace softdiff::test::rigid_calibration;

const std::vector<ParameterId> kSoft = {{Parameter::young, 0}};
// cube: mass; spinner: inertia xx, zz (its torque-free motion depends on the ratios),
// mass (no effect on its motion: a zero column, checked as such).
const std::vector<rigid::RigidParameterId> kRigid = {{0, 0}, {1, 1}, {1, 3}, {1, 0}};

// Central differences of whole runs, column by column, at relative steps chosen from a
// sweep of 1e-2 .. 1e-7 (measured, this scene):
//   - through the contact (young of the slab, the cube's mass): the runs carry a noise of
//     about 1e-11 m in r from the contact solve (its 1e-12 tolerance; seen as a
//     difference growing as 1/h below a relative step of 1e-4); at 1e-3 it is 1e-11 /
//     (2e-3 |dr/dlog p|) = 6e-5 of the column for young (whose effect is smallest: 6.5e-5
//     m per unit log), truncation O(1e-6): measured 5.2e-5 (young), 3.3e-5 (mass).
//     Tolerance 5e-4.
//   - the spinner (no contact: the runs are smooth to round-off), relative step 1e-5:
//     truncation 1e-10, round-off 1e-16 / 1e-5 relative: measured 3e-9. Tolerance 1e-6.
// The cube's inertia is not checked here: it landing flat, its effect (8e-11 m at a 1%
// change) is below the contact solve's noise at any step (the step derivative through
// contact with inertia: tests/rigid/test_contact_derivatives.cpp).
TEST(CalibrationRigid, ResidualJacobianAgainstCentralDifferences) {
  const Model truth = cube_on_slab();
  const optim::CalibrationTarget target = poses_target(truth, true, {0, 1}, Vec3(0.3, -0.2, 0.2));
  const Model m = cube_on_slab();
  // Away from the truth: young, the cube's mass, the spinner's inertia.
  std::vector<double> values = {1.3 * 5e4};
  for (const auto& p : kRigid) values.push_back((p.body == 0 ? 1.2 : 0.8) * rigid::get_parameter(m.rigid[p.body], p.index));
  VecX r;
  MatX J;
  optim::residual(m, kSoft, kRigid, values, target, true, r, J);
  const Eigen::Index soft_rows = 3 * m.fem.num_nodes;
  ASSERT_EQ(r.size(), target.residual_size());
  ASSERT_EQ(r.size(), kCubeSteps * (soft_rows + 12));
  ASSERT_EQ(J.cols(), 5);
  const double rel[5] = {1e-3, 1e-3, 1e-5, 1e-5, 1e-5}, tol[5] = {5e-4, 5e-4, 1e-6, 1e-6, 0};
  for (Eigen::Index j = 0; j < J.cols(); ++j) {
    SCOPED_TRACE("column " + std::to_string(j));
    const auto c = static_cast<std::size_t>(j);
    const double h = rel[c] * values[c];
    std::vector<double> vp = values, vm = values;
    vp[c] += h;
    vm[c] -= h;
    VecX rp, rm;
    MatX Jp, Jm;
    optim::residual(m, kSoft, kRigid, vp, target, true, rp, Jp);
    optim::residual(m, kSoft, kRigid, vm, target, true, rm, Jm);
    const VecX fd = (rp - rm) / (2 * h);
    if (j == 4) {  // the spinner's mass: its motion does not depend on it
      EXPECT_EQ(J.col(j).norm(), 0.0);
      EXPECT_EQ(fd.norm(), 0.0);
      continue;
    }
    ASSERT_GT(fd.norm(), 0.0);
    EXPECT_LE((J.col(j) - fd).norm(), tol[c] * fd.norm()) << "analytic " << J.col(j).norm() << ", differences " << fd.norm();
    // The rigid rows alone (the orientation rows, with the 0.4 rad offset, included), to
    // the same relative accuracy: the cube's for young and its mass, the spinner's for
    // its inertia.
    double err = 0, ref = 0;
    for (Eigen::Index f = 0; f < kCubeSteps; ++f) {
      const Eigen::Index at = f * (soft_rows + 12) + soft_rows;
      err += (J.col(j).segment(at, 12) - fd.segment(at, 12)).squaredNorm();
      ref += fd.segment(at, 12).squaredNorm();
    }
    ASSERT_GT(ref, 0.0);
    EXPECT_LE(std::sqrt(err), tol[c] * std::sqrt(ref));
  }
}

// Markers fixed on rigid bodies (r = p + R b - y*): two on the spinner, one on the cube,
// observed at every frame 0.5 mm off their true positions; the Jacobian's marker rows
// (d p - [R b] d theta) against central differences, steps and tolerances as above.
TEST(CalibrationRigid, MarkersOnRigidBodiesAgainstCentralDifferences) {
  const Model truth = cube_on_slab();
  const optim::CalibrationTarget poses = poses_target(truth, false, {0, 1});
  optim::CalibrationTarget target;
  target.frames = poses.frames;
  const std::vector<std::pair<int, Vec3>> points = {
      {1, Vec3(0.019, 0.009, 0.004)}, {1, Vec3(-0.019, 0, -0.004)}, {0, Vec3(0.009, -0.009, 0.009)}};
  for (std::size_t k = 0; k < points.size(); ++k) {
    optim::Marker mk;
    mk.name = "m" + std::to_string(k);
    mk.rigid_body = points[k].first;
    mk.body_point = points[k].second;
    target.markers.push_back(mk);
  }
  for (int f = 0; f < static_cast<int>(target.frames.size()); ++f)
    for (std::size_t k = 0; k < points.size(); ++k) {
      const auto& pose = poses.rigid[static_cast<std::size_t>(points[k].first)];
      const Vec3 y = pose.position[static_cast<std::size_t>(f)] + pose.orientation[static_cast<std::size_t>(f)] * points[k].second;
      target.observations.push_back({f, static_cast<int>(k), y + Vec3(5e-4, -5e-4, 5e-4)});
    }
  const Model m = cube_on_slab();
  std::vector<double> values = {1.3 * 5e4};
  for (const auto& p : kRigid) values.push_back((p.body == 0 ? 1.2 : 0.8) * rigid::get_parameter(m.rigid[p.body], p.index));
  VecX r;
  MatX J;
  optim::residual(m, kSoft, kRigid, values, target, true, r, J);
  ASSERT_EQ(r.size(), 3 * 3 * kCubeSteps);
  const double rel[5] = {1e-3, 1e-3, 1e-5, 1e-5, 1e-5}, tol[5] = {5e-4, 5e-4, 1e-6, 1e-6, 0};
  for (Eigen::Index j = 0; j < J.cols(); ++j) {
    SCOPED_TRACE("column " + std::to_string(j));
    const auto c = static_cast<std::size_t>(j);
    const double h = rel[c] * values[c];
    std::vector<double> vp = values, vm = values;
    vp[c] += h;
    vm[c] -= h;
    VecX rp, rm;
    MatX Jp, Jm;
    optim::residual(m, kSoft, kRigid, vp, target, true, rp, Jp);
    optim::residual(m, kSoft, kRigid, vm, target, true, rm, Jm);
    const VecX fd = (rp - rm) / (2 * h);
    if (j == 4) {
      EXPECT_EQ(J.col(j).norm(), 0.0);
      EXPECT_EQ(fd.norm(), 0.0);
      continue;
    }
    ASSERT_GT(fd.norm(), 0.0);
    EXPECT_LE((J.col(j) - fd).norm(), tol[c] * fd.norm()) << "analytic " << J.col(j).norm() << ", differences " << fd.norm();
  }
}

TEST(CalibrationRigid, WorkspaceGivesTheFreeResidualBitForBit) {
  const Model m = cube_on_slab();
  const optim::CalibrationTarget target = poses_target(cube_on_slab(6e4, 600), false, {0, 1});
  const std::vector<double> a = {5e4, 0.004, 3.3e-7, 1.3e-6, 0.008};
  const std::vector<double> b = {6e4, 0.005, 3.6e-7, 1.2e-6, 0.009};
  VecX r0, r1;
  MatX J0, J1;
  optim::residual(m, kSoft, kRigid, a, target, true, r0, J0);
  optim::CalibrationWorkspace w(m, kSoft, kRigid);
  w.residual(b, target, true, r1, J1);
  w.residual(a, target, true, r1, J1);
  EXPECT_EQ((r1 - r0).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ((J1 - J0).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(w.model().rigid[0].mass, 0.004);
}

// A diagonal inertia component that makes the inertia not positive definite (here: a
// negative one, which calibrate's log scale never proposes; beside off-diagonal
// components a positive one can) is a failed run (ComputationError), which calibrate
// rejects as a trial step, not a crash.
TEST(CalibrationRigid, AnInertiaNotPositiveDefiniteIsAFailedRun) {
  const Model m = cube_on_slab();
  const optim::CalibrationTarget target = poses_target(m, false, {0});
  VecX r;
  MatX J;
  optim::CalibrationWorkspace w(m, {}, {{0, 1}});
  EXPECT_THROW(w.residual({-1e-8}, target, true, r, J), ComputationError);
}

}  // namespace calibration_rigid_test
