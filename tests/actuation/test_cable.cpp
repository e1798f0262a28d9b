// Cable actuator: H_a = -dL/dx and d(H_a^T lambda)/dx against central finite
// differences, virtual work to second order, force balance, zero-length segments.
//
// FD step: positions are O(0.03 m) and segments O(0.01 m), so L has curvature
// O(1/0.01 m); with h = 1e-6 x (element size 0.01 m) = 1e-8 m the truncation error is
// O(h^2 / l^2) = 1e-12 relative and the round-off O(eps L / h) ~ 1e-16 x 0.05 / 1e-8
// ~ 5e-10 relative to the O(1) gradient: both far below the 1e-6 tolerance.
#include <softdiff/actuation/cable.hpp>
#include <softdiff/actuation/actuation_model.hpp>
#include <softdiff/fem/assembly.hpp>

#include <Eigen/Eigenvalues>

#include "helpers.hpp"
#include <support/fd.hpp>

#include <gtest/gtest.h>

using namespace softdiff;
using namespace softdiff::actuation;

namespace {

constexpr double kEdge = 0.01;
constexpr double kStep = 1e-6 * kEdge;

struct Fixture {
  mesh::TetMesh m;
  int offset = 5;  // global index of the body's node 0 (other bodies' nodes around it)
  VecX x_rest, x;
  std::vector<EmbeddedPoint> points;
};

// A 3 x 2 x 2 box of 1 cm cells; a cable zig-zagging through it, one point slightly
// outside (extrapolated weights), pull point outside the body.
Fixture make_fixture(std::mt19937& rng) {
  Fixture f;
  f.m = test::jittered_box(3, 2, 2, 0.03, 0.02, 0.02, 0.2, rng);
  const PointLocator locator(f.m.X, f.m.tets);
  const std::vector<Vec3> P = {{0.001, 0.01, 0.01},   {0.008, 0.004, 0.013}, {0.015, 0.017, 0.006},
                               {0.022, 0.0105, 0.0203}, {0.029, 0.003, 0.009}};  // 4th is 0.3 mm outside
  for (const Vec3& p : P) {
    const LocateResult r = locator.locate(p);
    EXPECT_NE(r.status, LocateStatus::too_far);
    f.points.push_back(embedded_point(r.embedding, f.m.tets, f.offset));
  }
  f.x_rest = VecX::Zero(3 * (f.m.num_nodes() + f.offset + 3));
  f.x_rest.segment(3 * f.offset, 3 * f.m.num_nodes()) = test::flatten(f.m.X);
  f.x = test::deform(f.x_rest, 1e-3, rng);
  return f;
}

VecX force(const Cable& c, const VecX& x, double lambda) {
  VecX f = VecX::Zero(x.size());
  c.add_force(x, lambda, 1.0, f);
  return f;
}

}  // namespace

TEST(Cable, LengthAtRest) {
  std::mt19937 rng(10);
  Fixture f = make_fixture(rng);
  const Vec3 q(-0.01, 0.01, 0.01);
  const Cable c(f.points, q);
  const std::vector<Vec3> P = {{0.001, 0.01, 0.01},   {0.008, 0.004, 0.013}, {0.015, 0.017, 0.006},
                               {0.022, 0.0105, 0.0203}, {0.029, 0.003, 0.009}};
  double L = (P[0] - q).norm();
  for (size_t k = 1; k < P.size(); ++k) L += (P[k] - P[k - 1]).norm();
  EXPECT_NEAR(c.length(f.x_rest), L, 1e-15);
}

TEST(Cable, GradientMatchesFiniteDifferencesOfLength) {
  std::mt19937 rng(11);
  Fixture f = make_fixture(rng);
  for (bool pull : {true, false}) {
    const Cable c(f.points, pull ? std::optional<Vec3>(Vec3(-0.01, 0.012, 0.009)) : std::nullopt);
    VecX H(f.x.size());
    c.gradient(f.x, H);
    const VecX g = test::fd_gradient([&](const VecX& y) { return c.length(y); }, f.x, kStep);
    const auto cmp = test::compare(H, -g);
    EXPECT_LT(cmp.rel_error, 1e-6) << cmp.str();
    EXPECT_GT(H.norm(), 1.0);
    std::printf("cable (pull point %d): H_a vs FD of L: %s\n", pull, cmp.str().c_str());
    // add_force = scale lambda H; sparse form = H on nodes().
    EXPECT_LT((force(c, f.x, 3.5) - 3.5 * H).norm(), 1e-14 * H.norm());
    Mat3X values(3, c.nodes().size());
    c.gradient_sparse(f.x, values);
    VecX H2 = VecX::Zero(f.x.size());
    for (size_t j = 0; j < c.nodes().size(); ++j) H2.segment<3>(3 * c.nodes()[j]) = values.col(j);
    EXPECT_LT((H2 - H).norm(), 1e-15 * H.norm());
  }
}

TEST(Cable, ForceDerivativeMatchesFiniteDifferences) {
  std::mt19937 rng(12);
  Fixture f = make_fixture(rng);
  const double lambda = 2.7;
  for (bool pull : {true, false}) {
    const Cable c(f.points, pull ? std::optional<Vec3>(Vec3(-0.01, 0.012, 0.009)) : std::nullopt);
    // Full Jacobian d(H_a^T lambda)/dx, column by column.
    const MatX J_fd = test::fd_jacobian([&](const VecX& y) { return force(c, y, lambda); }, f.x, kStep);
    MatX J(f.x.size(), f.x.size());
    VecX e = VecX::Zero(f.x.size()), col(f.x.size());
    for (Eigen::Index j = 0; j < f.x.size(); ++j) {
      e[j] = 1;
      col.setZero();
      c.add_force_derivative(f.x, lambda, e, col);
      J.col(j) = col;
      e[j] = 0;
    }
    const auto cmp = test::compare(J, J_fd);
    EXPECT_LT(cmp.rel_error, 1e-6) << cmp.str();
    EXPECT_GT(J.norm(), 10.0);
    EXPECT_LT((J - J.transpose()).norm(), 1e-13 * J.norm()) << "-lambda d2L/dx2 is symmetric";
    std::printf("cable (pull point %d): d(H^T lambda)/dx vs FD: %s\n", pull, cmp.str().c_str());
    // A random direction, and linearity in lambda.
    const VecX dx = VecX::Random(f.x.size());
    VecX d1 = VecX::Zero(f.x.size());
    c.add_force_derivative(f.x, lambda, dx, d1);
    const VecX d_fd = (force(c, f.x + kStep * dx, lambda) - force(c, f.x - kStep * dx, lambda)) / (2 * kStep);
    EXPECT_LT(test::compare(d1, d_fd).rel_error, 1e-6);
  }
}

TEST(Cable, VirtualWorkIsSecondOrder) {
  std::mt19937 rng(13);
  Fixture f = make_fixture(rng);
  const Cable c(f.points, Vec3(-0.01, 0.012, 0.009));
  VecX H(f.x.size());
  c.gradient(f.x, H);
  const VecX u = VecX::Random(f.x.size()).normalized();
  // err(t) = |H du + (L(x + du) - L(x))| with du = t u: O(t^2) (the d2L term).
  std::vector<double> err;
  for (double t : {1e-4, 1e-5, 1e-6}) {
    const VecX du = t * u;
    err.push_back(std::abs(H.dot(du) + (c.length(f.x + du) - c.length(f.x))));
  }
  for (size_t i = 1; i < err.size(); ++i) {
    const double ratio = err[i - 1] / err[i];  // 100 for a second-order error
    EXPECT_GT(ratio, 70) << "step " << i;
    EXPECT_LT(ratio, 140) << "step " << i;
  }
  std::printf("cable virtual work error at |du| = 1e-4, 1e-5, 1e-6: %.3e %.3e %.3e\n", err[0], err[1], err[2]);
}

TEST(Cable, ForceBalance) {
  // Without a pull point the cable's forces are internal: zero resultant and moment.
  // With one, the resultant is lambda times the unit vector from p_0 towards q.
  std::mt19937 rng(14);
  Fixture f = make_fixture(rng);
  const double lambda = 1.3;
  auto resultant = [&](const VecX& F, const VecX& x, Vec3& moment) {
    Vec3 r = Vec3::Zero();
    moment.setZero();
    for (Eigen::Index i = 0; i < x.size() / 3; ++i) {
      r += F.segment<3>(3 * i);
      moment += x.segment<3>(3 * i).cross(F.segment<3>(3 * i));
    }
    return r;
  };
  Vec3 M;
  const Cable free_cable(f.points);
  Vec3 R = resultant(force(free_cable, f.x, lambda), f.x, M);
  EXPECT_LT(R.norm(), 1e-14);
  EXPECT_LT(M.norm(), 1e-15);
  const Vec3 q(-0.01, 0.012, 0.009);
  const Cable pulled(f.points, q);
  R = resultant(force(pulled, f.x, lambda), f.x, M);
  const Vec3 expected = lambda * (q - f.points[0].position(f.x)).normalized();
  EXPECT_LT((R - expected).norm(), 1e-14);
}

TEST(Cable, ZeroLengthSegmentsGiveNoNaN) {
  std::mt19937 rng(15);
  Fixture f = make_fixture(rng);
  // A point listed twice (identical embedding): same forces as without the duplicate.
  std::vector<EmbeddedPoint> dup = f.points;
  dup.insert(dup.begin() + 2, f.points[2]);
  const Cable a(f.points, Vec3(-0.01, 0.012, 0.009)), b(dup, Vec3(-0.01, 0.012, 0.009));
  const VecX dx = VecX::Random(f.x.size());
  VecX da = VecX::Zero(f.x.size()), db = VecX::Zero(f.x.size());
  a.add_force_derivative(f.x, 1.0, dx, da);
  b.add_force_derivative(f.x, 1.0, dx, db);
  EXPECT_TRUE(force(b, f.x, 1.0).allFinite());
  EXPECT_TRUE(db.allFinite());
  EXPECT_LT((force(b, f.x, 1.0) - force(a, f.x, 1.0)).norm(), 1e-14);
  EXPECT_LT((db - da).norm(), 1e-12 * da.norm());
  EXPECT_NEAR(b.length(f.x), a.length(f.x), 1e-16);
  // A pull point on the first point; and a cable of two coincident points (L = 0).
  const Cable c(f.points, f.points[0].position(f.x));
  EXPECT_TRUE(force(c, f.x, 1.0).allFinite());
  const Cable d({f.points[1], f.points[1]});
  EXPECT_EQ(d.length(f.x), 0);
  VecX dd = VecX::Zero(f.x.size());
  d.add_force_derivative(f.x, 1.0, dx, dd);
  EXPECT_EQ(force(d, f.x, 1.0).norm(), 0);
  EXPECT_EQ(dd.norm(), 0);
  // Too few points is a programming error (the scene loader checks first).
  EXPECT_THROW(Cable({f.points[0]}), std::logic_error);
}

// The block form of the stiffness (Cable::for_each_stiffness_block) is the matrix of
// the matrix-free derivative: sum of blocks applied to dx = -add_force_derivative(dx),
// to round-off (same formula, different summation order), for random dx; symmetric
// positive semi-definite. A repeated point (zero-length segment) is skipped by both.
TEST(Cable, StiffnessBlocksMatchForceDerivative) {
  std::mt19937 rng(16);
  Fixture f = make_fixture(rng);
  const double lambda = 2.7;
  std::vector<EmbeddedPoint> dup = f.points;
  dup.insert(dup.begin() + 2, f.points[2]);
  for (int variant = 0; variant < 3; ++variant) {
    const bool pull = variant != 1;
    const Cable c(variant == 2 ? dup : f.points, pull ? std::optional<Vec3>(Vec3(-0.01, 0.012, 0.009)) : std::nullopt);
    const Eigen::Index n = f.x.size();
    MatX S = MatX::Zero(n, n);
    int calls = 0;
    c.for_each_stiffness_block(f.x, lambda, [&](int s, int a, int b, int i, int j, const Mat3& block) {
      EXPECT_GE(s, 0);
      EXPECT_LT(s, c.num_segments());
      const auto st = c.segment_stencil(s);
      EXPECT_EQ(st.nodes[a], i);
      EXPECT_EQ(st.nodes[b], j);
      S.block<3, 3>(3 * i, 3 * j) += block;
      ++calls;
    });
    // Segments: 4 between points (+1 duplicate, skipped) and the pull segment (4 nodes).
    EXPECT_EQ(calls, 4 * 64 + (pull ? 16 : 0));
    EXPECT_EQ(c.num_segments(), (variant == 2 ? 5 : 4) + (pull ? 1 : 0));
    EXPECT_LT((S - S.transpose()).norm(), 1e-15 * S.norm());
    const double min_eig = Eigen::SelfAdjointEigenSolver<MatX>(S).eigenvalues().minCoeff();
    EXPECT_GT(min_eig, -1e-12 * S.norm());
    double worst = 0;
    for (int trial = 0; trial < 5; ++trial) {
      const VecX dx = VecX::Random(n);
      VecX d = VecX::Zero(n);
      c.add_force_derivative(f.x, lambda, dx, d);
      worst = std::max(worst, (S * dx + d).norm() / d.norm());
    }
    std::printf("cable variant %d: stiffness blocks vs add_force_derivative: %.2e relative, min eigenvalue %.2e "
                "(|S| %.2e)\n",
                variant, worst, min_eig, S.norm());
    EXPECT_LT(worst, 1e-14);
    EXPECT_GT(S.norm(), 10.0);
  }
}

// The assembled form: ActuationModel::add_stiffness through the pattern's clique
// scatter equals the dense block sum, on a FEM model built with the cables' cliques;
// without them the pattern does not fit.
TEST(Cable, StiffnessAssemblesIntoThePattern) {
  std::mt19937 rng(17);
  Fixture f = make_fixture(rng);
  // The fixture's body without the node offset.
  std::vector<EmbeddedPoint> points = f.points;
  for (auto& p : points)
    for (int& i : p.nodes) i -= f.offset;
  ActuationModel act;
  for (bool pull : {true, false}) {
    ActuatorModel a;
    a.kind = Cable(points, pull ? std::optional<Vec3>(Vec3(-0.01, 0.012, 0.009)) : std::nullopt);
    act.actuators.push_back(std::move(a));
  }
  // A non-cable actuator between them (a translation servo: constant H_a, zero
  // derivative) contributes no clique and no stiffness.
  ActuatorModel servo;
  Servo translation;
  ASSERT_TRUE(Servo::translation({0, 1, 2}, Vec3::UnitX(), f.x_rest.segment(3 * f.offset, 3 * f.m.num_nodes()),
                                 translation)
                  .ok());
  servo.kind = std::move(translation);
  act.actuators.insert(act.actuators.begin() + 1, std::move(servo));
  const VecX lambda = (VecX(3) << 2.7, 5.0, 0.9).finished();
  const auto cliques = act.stiffness_cliques();
  ASSERT_EQ(cliques.size(), 5u + 4u);

  auto build = [&](const std::vector<std::vector<int>>& extra) {
    fem::BodyModel b;
    b.name = "box";
    b.mesh = f.m;
    b.young = 1e5;
    b.poisson = 0.3;
    b.density = 1000;
    std::vector<fem::BodyModel> bodies{b};
    fem::FemModel m;
    fem::build_fem_model(std::move(bodies), std::vector<unsigned char>(3 * f.m.num_nodes(), 0), Vec3::Zero(), m,
                         extra);
    return m;
  };
  const fem::FemModel plain = build({}), model = build(cliques);
  EXPECT_FALSE(act.stiffness_fits(plain.pattern));
  ASSERT_TRUE(act.stiffness_fits(model.pattern));
  EXPECT_GT(model.pattern.nnz(), plain.pattern.nnz());
  std::printf("pattern: %ld nonzeros, %ld with the cable cliques\n", plain.pattern.nnz(), model.pattern.nnz());

  const VecX x = f.x.segment(3 * f.offset, 3 * f.m.num_nodes());
  VecX values = VecX::Zero(model.pattern.nnz());
  act.add_stiffness(x, lambda, model.pattern, values.data());
  const VecX dx = VecX::Random(x.size());
  VecX y(x.size()), d = VecX::Zero(x.size());
  fem::symmetric_multiply(model, values, dx, y);
  for (size_t a = 0; a < act.actuators.size(); ++a) act.actuators[a].add_force_derivative(x, lambda[a], dx, d);
  const double err = (y + d).norm() / d.norm();
  std::printf("assembled cable stiffness vs add_force_derivative: %.2e relative\n", err);
  EXPECT_LT(err, 1e-14);
  EXPECT_GT(d.norm(), 1.0);
}
