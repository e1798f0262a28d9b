// Servo actuator: translation resultant = lambda d; rotation: moment about the axis
// = lambda for random node sets, the documented resultant force and off-axis moment,
// derivative vs central finite differences, nodes on the axis, error statuses.
//
// FD step: 1e-8 m on positions O(0.03 m); f_i is a smooth rational function of x with
// relative curvature O(1/|r|^2), |r| ~ 1 cm: truncation ~ (1e-8/1e-2)^2 = 1e-12,
// round-off ~ 1e-16 / 1e-6 = 1e-10 (relative).
#include <softdiff/actuation/servo.hpp>

#include "helpers.hpp"
#include <support/fd.hpp>

#include <gtest/gtest.h>

using namespace softdiff;
using namespace softdiff::actuation;

namespace {

VecX force(const Servo& s, const VecX& x, double lambda) {
  VecX f = VecX::Zero(x.size());
  s.add_force(x, lambda, 1.0, f);
  return f;
}

std::vector<int> random_nodes(int n, int count, std::mt19937& rng) {
  std::vector<int> all(n);
  for (int i = 0; i < n; ++i) all[i] = i;
  std::shuffle(all.begin(), all.end(), rng);
  all.resize(count);
  return all;
}

Vec3 random_unit(std::mt19937& rng) {
  std::normal_distribution<double> g;
  return Vec3(g(rng), g(rng), g(rng)).normalized();
}

}  // namespace

TEST(Servo, TranslationResultantIsLambdaD) {
  std::mt19937 rng(30);
  const mesh::TetMesh m = test::box_mesh(3, 3, 3, 0.03, 0.03, 0.03);
  const VecX x = test::flatten(m.X);
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<int> nodes = random_nodes(m.num_nodes(), 1 + trial * 3, rng);
    nodes.push_back(nodes[0]);  // duplicates are removed
    const Vec3 d = random_unit(rng);
    Servo s;
    ASSERT_TRUE(Servo::translation(nodes, 2.5 * d, x, s).ok());  // any length: normalized
    EXPECT_FALSE(s.is_rotation());
    EXPECT_EQ(static_cast<int>(s.nodes().size()), 1 + trial * 3);
    const double lambda = 0.37;
    const VecX f = force(s, x, lambda);
    Vec3 R = Vec3::Zero();
    for (Eigen::Index i = 0; i < m.num_nodes(); ++i) R += f.segment<3>(3 * i);
    EXPECT_LT((R - lambda * d).norm(), 1e-15 * lambda);
    VecX dd = VecX::Zero(x.size());
    s.add_force_derivative(x, lambda, VecX::Random(x.size()), dd);
    EXPECT_EQ(dd.norm(), 0);
    Mat3X values(3, s.nodes().size());
    s.gradient_sparse(x, values);
    EXPECT_LT((values.rowwise().sum() - d).norm(), 1e-14);
  }
}

TEST(Servo, RotationMomentAboutAxisIsLambda) {
  std::mt19937 rng(31);
  const mesh::TetMesh m = test::box_mesh(3, 3, 3, 0.03, 0.03, 0.03);
  const VecX x_rest = test::flatten(m.X);
  std::uniform_real_distribution<double> u(-0.02, 0.05);
  double worst = 0, worst_force = 0;
  for (int trial = 0; trial < 50; ++trial) {
    const std::vector<int> nodes = random_nodes(m.num_nodes(), 2 + trial, rng);
    const Vec3 a = random_unit(rng), c(u(rng), u(rng), u(rng));
    Servo s;
    ASSERT_TRUE(Servo::rotation(nodes, a, c, x_rest, s).ok());
    const VecX x = test::deform(x_rest, 1e-3, rng);
    const double lambda = 0.01 + 0.1 * trial;
    const VecX f = force(s, x, lambda);
    Vec3 M = Vec3::Zero(), R = Vec3::Zero(), rbar = Vec3::Zero(), off = Vec3::Zero();
    double S = 0;
    for (int i : s.nodes()) {
      const Vec3 y = x.segment<3>(3 * i) - c, r = y - a * a.dot(y);
      M += y.cross(f.segment<3>(3 * i));
      R += f.segment<3>(3 * i);
      rbar += r / static_cast<double>(s.nodes().size());
      off += a.dot(y) * r;
      S += r.squaredNorm();
      EXPECT_LT(std::abs(f.segment<3>(3 * i).dot(a)), 1e-15 * lambda / 0.01) << "tangential";
    }
    worst = std::max(worst, std::abs(M.dot(a) - lambda) / lambda);
    // Documented: resultant force lambda N (a x rbar)/S; off-axis moment -lambda sum s_i r_i / S.
    const double N = static_cast<double>(s.nodes().size());
    worst_force = std::max(worst_force, (R - lambda * N * a.cross(rbar) / S).norm() / R.norm());
    const Vec3 M_perp = M - a * a.dot(M);
    EXPECT_LT((M_perp + lambda * (off - a * a.dot(off)) / S).norm(), 1e-12 * lambda);
  }
  EXPECT_LT(worst, 1e-12);
  EXPECT_LT(worst_force, 1e-12);
  std::printf("rotation servo: worst relative error of the axial moment %.2e, of the resultant force %.2e\n", worst,
              worst_force);
}

TEST(Servo, RotationDerivativeMatchesFiniteDifferences) {
  std::mt19937 rng(32);
  const mesh::TetMesh m = test::box_mesh(2, 2, 2, 0.03, 0.03, 0.03);
  VecX x_rest = test::flatten(m.X);
  const Vec3 a = random_unit(rng), c(0.012, 0.017, 0.011);
  std::vector<int> nodes = random_nodes(m.num_nodes(), 12, rng);
  x_rest.segment<3>(3 * nodes[3]) = c + 0.004 * a;  // a node on the axis (r = 0)
  Servo s;
  ASSERT_TRUE(Servo::rotation(nodes, a, c, x_rest, s).ok());
  const double lambda = 0.8;
  for (bool deformed : {false, true}) {
    VecX x = deformed ? test::deform(x_rest, 1e-3, rng) : x_rest;
    const VecX f = force(s, x, lambda);
    EXPECT_TRUE(f.allFinite());
    if (!deformed) {
      // r = 0 up to the rounding of (I - a a^T)(x - c): no force, up to that rounding.
      EXPECT_LT(f.segment<3>(3 * nodes[3]).norm(), 1e-13 * f.norm()) << "node on the axis: no force";
    }
    const MatX J_fd = test::fd_jacobian([&](const VecX& y) { return force(s, y, lambda); }, x, 1e-8);
    MatX J(x.size(), x.size());
    VecX e = VecX::Zero(x.size()), col(x.size());
    for (Eigen::Index j = 0; j < x.size(); ++j) {
      e[j] = 1;
      col.setZero();
      s.add_force_derivative(x, lambda, e, col);
      J.col(j) = col;
      e[j] = 0;
    }
    const auto cmp = test::compare(J, J_fd);
    EXPECT_LT(cmp.rel_error, 1e-6) << cmp.str();
    EXPECT_GT(J.norm(), 1.0);
    std::printf("rotation servo (%s): d(H^T lambda)/dx vs FD: %s\n", deformed ? "deformed" : "rest",
                cmp.str().c_str());
    // gradient / gradient_sparse agree with add_force.
    VecX H(x.size());
    s.gradient(x, H);
    EXPECT_LT((lambda * H - f).norm(), 1e-15 * f.norm());
    Mat3X values(3, s.nodes().size());
    s.gradient_sparse(x, values);
    for (size_t j = 0; j < s.nodes().size(); ++j)
      EXPECT_LT((values.col(j) - H.segment<3>(3 * s.nodes()[j])).norm(), 1e-15 * H.norm());
  }
}

TEST(Servo, ErrorStatuses) {
  const mesh::TetMesh m = test::box_mesh(2, 2, 2, 0.02, 0.02, 0.02);
  const VecX x = test::flatten(m.X);
  Servo s;
  EXPECT_EQ(Servo::translation({}, Vec3::UnitX(), x, s).error, ServoError::empty);
  EXPECT_EQ(Servo::translation({0, 1}, Vec3::Zero(), x, s).error, ServoError::zero_direction);
  const ServoStatus bad = Servo::translation({0, 27}, Vec3::UnitX(), x, s);
  EXPECT_EQ(bad.error, ServoError::bad_index);
  EXPECT_EQ(bad.node, 27);
  // Nodes 0, 1, 2 lie on the x axis through the origin.
  const ServoStatus axis = Servo::rotation({0, 1, 2}, Vec3::UnitX(), Vec3::Zero(), x, s);
  EXPECT_EQ(axis.error, ServoError::all_on_axis);
  EXPECT_NE(axis.message().find("axis"), std::string::npos);
  EXPECT_TRUE(Servo::rotation({0, 1, 2, 3}, Vec3::UnitX(), Vec3::Zero(), x, s).ok());
}
