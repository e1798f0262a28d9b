// Cables, pressure cavities and effectors on quadratic (10-node) bodies (issue 18):
// the embedding with the quadratic shape functions (straight and curved elements), the
// enclosed volume of a curved 6-node-triangle surface and its exact dV/dx, and every
// derivative against central finite differences.
//
// Meshes: box_mesh elevated to 10-node tets, straight (elevate_to_quadratic) or curved
// (test::curved_box: mid-edge nodes moved by up to 0.08 of the cell size, the boundary's
// included). Cell size 0.01 m.
//
// Steps and tolerances (support/fd.hpp): positions are perturbed by kStep = 1e-8 m,
// 1e-6 of the cell size. The functions checked (cable length, cavity volume, their
// gradients) have derivatives of O(1) on the cell's scale, so the central differences'
// truncation error (h^2 f''') and round-off (eps |f| / h, f ~ 1e-2 m or 1e-6 m^3 ...
// relative 1e-16 / 1e-6 = 1e-10) are both ~1e-10 relative: tolerance 1e-6 on the
// norm-wise relative error, four orders of margin, as for the linear actuators
// (test_cable.cpp, test_pressure.cpp).
#include <softdiff/actuation/cable.hpp>
#include <softdiff/actuation/effector.hpp>
#include <softdiff/actuation/embedding.hpp>
#include <softdiff/actuation/pressure.hpp>
#include <softdiff/fem/tet10.hpp>
#include <support/fd.hpp>

#include "helpers.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <random>

namespace quadratic_actuators_test {

using namespace softdiff;
using namespace softdiff::actuation;

constexpr double kStep = 1e-8;  // 1e-6 of the 0.01 m cell

Eigen::Matrix<double, 3, 10> element_positions(const mesh::TetMesh& m, const VecX& x, int e) {
  Eigen::Matrix<double, 3, 10> X_e;
  for (int a = 0; a < 10; ++a) X_e.col(a) = x.segment<3>(3 * m.tets10(a, e));
  return X_e;
}

// The smallest det J of the mesh's 10-node tets at rest (valid: > 0).
double min_det(const mesh::TetMesh& m) {
  double lo = std::numeric_limits<double>::infinity();
  const VecX x = test::flatten(m.X);
  for (int e = 0; e < m.num_tets(); ++e) lo = std::min(lo, fem::tet10::min_det_jacobian(element_positions(m, x, e)));
  return lo;
}

// The volume of the 10-node tets at positions x, sum over tets of int det J: the mass
// rule (degree 5) is exact for det J (degree 3 in xi), curved or not. An independent
// reference for the cavity's surface integral (the divergence theorem).
double tets_volume(const mesh::TetMesh& m, const VecX& x) {
  double V = 0;
  for (int e = 0; e < m.num_tets(); ++e) {
    const Eigen::Matrix<double, 3, 10> X_e = element_positions(m, x, e);
    for (const auto& q : fem::tet10::kMassRule)
      V += q.weight * fem::tet10::jacobian(X_e, fem::tet10::shape_gradients_ref(q.u, q.v, q.w)).determinant();
  }
  return V;
}

// A point strictly inside the reference tet: barycentric coordinates >= 0.05.
Eigen::Vector4d random_inside(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  Eigen::Vector4d a(u(rng), u(rng), u(rng), u(rng));
  return Eigen::Vector4d::Constant(0.05) + 0.8 * a / a.sum();
}

// The whole boundary of a quadratic mesh as a closed cavity (oriented into the solid:
// V = -(the body's volume)).
Cavity boundary_cavity(const mesh::TetMesh& m, const Triangles& tris) {
  const mesh::Triangles6 tris6 = mesh::quadratic_triangles(m, tris);
  Cavity c;
  const CavityStatus st = Cavity::create(m.X, m.tets, tris, 0, c, &tris6);
  EXPECT_TRUE(st.ok()) << st.message();
  return c;
}

VecX cavity_force(const Cavity& c, const VecX& x, double p) {
  VecX f = VecX::Zero(x.size());
  c.add_force(x, p, 1.0, f);
  return f;
}

VecX cable_force(const Cable& c, const VecX& x, double lambda) {
  VecX f = VecX::Zero(x.size());
  c.add_force(x, lambda, 1.0, f);
  return f;
}

template <class Apply>
MatX dense(Eigen::Index n, Apply&& apply) {
  MatX J(n, n);
  VecX e = VecX::Zero(n), col(n);
  for (Eigen::Index j = 0; j < n; ++j) {
    e[j] = 1;
    col.setZero();
    apply(e, col);
    J.col(j) = col;
    e[j] = 0;
  }
  return J;
}

// ---------------------------------------------------------------------------
// Embedding

// On straight-sided 10-node tets the quadratic shape functions reproduce every
// quadratic field: with nodes at phi(X_a), p(x) = phi(p) exactly. The linear (vertex)
// embedding does not (it is exact for affine fields only), which shows that the test
// can tell them apart.
TEST(QuadraticEmbedding, StraightElementsReproduceQuadraticFields) {
  std::mt19937 rng(50);
  mesh::TetMesh m = test::jittered_box(3, 2, 2, 0.03, 0.02, 0.02, 0.2, rng);
  mesh::elevate_to_quadratic(m);
  const PointLocator locator(m.X, m.tets, m.tets10);
  const PointLocator linear(m.X, m.tets);
  ASSERT_EQ(locator.order(), 2);
  auto phi = [](const Vec3& X) {
    return Vec3(X.x() + 3 * X.x() * X.y() + 0.2 * X.z(), X.y() - 5 * X.z() * X.z() + 2 * X.x() * X.x(),
                X.z() + 4 * X.x() * X.z() + 0.1 * X.y());
  };
  VecX x(3 * m.num_nodes());
  for (int i = 0; i < m.num_nodes(); ++i) x.segment<3>(3 * i) = phi(m.X.col(i));
  const VecX x_rest = test::flatten(m.X);
  std::uniform_real_distribution<double> u(0.001, 0.999);
  double worst = 0, worst_linear = 0;
  for (int k = 0; k < 50; ++k) {
    const Vec3 p(0.03 * u(rng), 0.02 * u(rng), 0.02 * u(rng));
    const LocateResult r = locator.locate(p);
    ASSERT_EQ(r.status, LocateStatus::inside);
    ASSERT_EQ(r.embedding.order, 2);
    const EmbeddedPoint e = embedded_point(r.embedding, locator, 0);
    ASSERT_EQ(e.count, 10);
    EXPECT_NEAR(e.w.sum(), 1.0, 1e-14);
    EXPECT_LT((e.position(x_rest) - p).norm(), 1e-16);
    worst = std::max(worst, (e.position(x) - phi(p)).norm());
    const EmbeddedPoint l = embedded_point(linear.locate(p).embedding, m.tets, 0);
    worst_linear = std::max(worst_linear, (l.position(x) - phi(p)).norm());
  }
  std::printf("quadratic field at 50 points: quadratic embedding %.2e m, linear %.2e m\n", worst, worst_linear);
  EXPECT_LT(worst, 1e-16);  // round-off on positions of 0.03 m: a few eps
  EXPECT_GT(worst_linear, 1e-6);
}

// Curved elements: a point X_e(xi) of tet e is found in tet e with reference
// coordinates xi (Newton), and the embedded point reproduces it at rest, although
// many such points lie outside the straight tet through e's vertices.
TEST(QuadraticEmbedding, CurvedElementsFindTheirReferenceCoordinates) {
  std::mt19937 rng(51);
  const mesh::TetMesh m = test::curved_box(3, 2, 2, 0.03, 0.02, 0.02, 0.08, rng);
  ASSERT_GT(min_det(m), 0);
  const PointLocator locator(m.X, m.tets, m.tets10);
  const VecX x_rest = test::flatten(m.X);
  std::uniform_int_distribution<int> pick(0, m.num_tets() - 1);
  int outside_straight = 0;
  double worst_xi = 0, worst_p = 0;
  for (int k = 0; k < 200; ++k) {
    const int e = pick(rng);
    const Eigen::Vector4d l = random_inside(rng);
    const Vec3 p = element_positions(m, x_rest, e) * fem::tet10::shape(l[1], l[2], l[3]);
    if (barycentric_weights(m.X, m.tets, e, p).minCoeff() < 0) ++outside_straight;
    const LocateResult r = locator.locate(p);
    ASSERT_EQ(r.status, LocateStatus::inside) << "point " << k;
    ASSERT_EQ(r.embedding.tet, e) << "point " << k;
    worst_xi = std::max(worst_xi, (r.embedding.w - l).norm());
    const EmbeddedPoint ep = embedded_point(r.embedding, locator, 7);  // node offset 7
    for (int a = 0; a < 10; ++a) EXPECT_EQ(ep.nodes[a], m.tets10(a, e) + 7);
    VecX shifted = VecX::Zero(x_rest.size() + 21);
    shifted.tail(x_rest.size()) = x_rest;
    worst_p = std::max(worst_p, (ep.position(shifted) - p).norm());
  }
  std::printf("curved tets: %d of 200 points outside their straight tet; |xi - xi*| <= %.1e, |p - p*| <= %.1e m\n",
              outside_straight, worst_xi, worst_p);
  EXPECT_GT(outside_straight, 0);
  EXPECT_LT(worst_xi, 1e-12);   // Newton stops below 1e-14 in xi
  EXPECT_LT(worst_p, 1e-15);
}

// A point just outside a curved body is mapped to its nearest tet with extrapolated
// reference coordinates, and is still reproduced at rest.
TEST(QuadraticEmbedding, PointsOutsideAreExtrapolated) {
  std::mt19937 rng(52);
  const mesh::TetMesh m = test::curved_box(3, 2, 2, 0.03, 0.02, 0.02, 0.05, rng);
  const PointLocator locator(m.X, m.tets, m.tets10);
  const VecX x_rest = test::flatten(m.X);
  const Vec3 p(0.0315, 0.011, 0.009);  // 1.5 mm beyond x = 0.03 (cell 10 mm)
  const LocateResult r = locator.locate(p);
  ASSERT_EQ(r.status, LocateStatus::outside);
  EXPECT_LT(r.embedding.w.minCoeff(), 0);
  const EmbeddedPoint e = embedded_point(r.embedding, locator, 0);
  EXPECT_LT((e.position(x_rest) - p).norm(), 1e-15);
  EXPECT_EQ(locator.locate(Vec3(0.05, 0.01, 0.01)).status, LocateStatus::too_far);
}

// ---------------------------------------------------------------------------
// Effector: J (jacobian_times, add_jacobian_transpose, jacobian_triplets) is the
// derivative of the position (central differences; p is linear in x, so they are exact
// up to round-off) and J^T is its transpose.
TEST(QuadraticEffector, JacobianMatchesFiniteDifferencesAndItsTranspose) {
  std::mt19937 rng(53);
  const mesh::TetMesh m = test::curved_box(2, 2, 2, 0.02, 0.02, 0.02, 0.08, rng);
  const PointLocator locator(m.X, m.tets, m.tets10);
  const Effector eff(embedded_point(locator.locate(Vec3(0.013, 0.006, 0.011)).embedding, locator, 0));
  ASSERT_EQ(eff.num_nodes(), 10);
  const VecX x = test::deform(test::flatten(m.X), 1e-4, rng);
  const Eigen::Index n = x.size();
  std::vector<Eigen::Triplet<double>> triplets;
  eff.jacobian_triplets(0, triplets);
  EXPECT_EQ(triplets.size(), 30u);
  Eigen::SparseMatrix<double> J(3, n);
  J.setFromTriplets(triplets.begin(), triplets.end());
  const MatX J_fd = test::fd_jacobian([&](const VecX& y) { return VecX(eff.position(y)); }, x, kStep);
  const auto c = test::compare(MatX(J), J_fd);
  EXPECT_LT(c.rel_error, 1e-6) << c.str();
  const VecX dx = test::random_vector(n, 1.0, 1);
  EXPECT_LT((eff.jacobian_times(dx) - J * dx).norm(), 1e-14 * dx.norm());
  const Vec3 g(0.3, -1.2, 0.7);
  VecX JTg = VecX::Zero(n);
  eff.add_jacobian_transpose(g, 2.0, JTg);
  EXPECT_LT((JTg - 2.0 * MatX(J).transpose() * g).norm(), 1e-14 * JTg.norm());
}

// ---------------------------------------------------------------------------
// Cable

struct CableFixture {
  mesh::TetMesh m;
  VecX x;
  std::vector<EmbeddedPoint> points;
};

CableFixture cable_fixture(std::mt19937& rng) {
  CableFixture f{test::curved_box(3, 2, 2, 0.03, 0.02, 0.02, 0.08, rng), {}, {}};
  EXPECT_GT(min_det(f.m), 0);
  const PointLocator locator(f.m.X, f.m.tets, f.m.tets10);
  for (const Vec3& p : {Vec3(0.001, 0.01, 0.01), Vec3(0.008, 0.004, 0.013), Vec3(0.015, 0.017, 0.006),
                        Vec3(0.016, 0.016, 0.007), Vec3(0.029, 0.003, 0.009)})
    f.points.push_back(embedded_point(locator.locate(p).embedding, locator, 0));
  f.x = test::deform(test::flatten(f.m.X), 1e-4, rng);
  return f;
}

TEST(QuadraticCable, LengthGradientAndStiffnessMatchFiniteDifferences) {
  std::mt19937 rng(54);
  const CableFixture f = cable_fixture(rng);
  const Eigen::Index n = f.x.size();
  const double lambda = 2.7;
  for (bool pull : {true, false}) {
    const Cable c(f.points, pull ? std::optional<Vec3>(Vec3(-0.01, 0.012, 0.009)) : std::nullopt);
    // Segment stencils: 10 + 10 nodes (the pull point segment: 10).
    for (int s = 0; s < c.num_segments(); ++s) EXPECT_EQ(c.segment_stencil(s).count, pull && s == 0 ? 10 : 20);
    // H_a = -dL/dx.
    VecX H(n);
    c.gradient(f.x, H);
    const VecX g = test::fd_gradient([&](const VecX& y) { return c.length(y); }, f.x, kStep);
    const auto cg = test::compare(H, -g);
    EXPECT_LT(cg.rel_error, 1e-6) << cg.str();
    EXPECT_GT(H.norm(), 1.0);
    Mat3X values(3, c.nodes().size());
    c.gradient_sparse(f.x, values);
    VecX H2 = VecX::Zero(n);
    for (size_t j = 0; j < c.nodes().size(); ++j) H2.segment<3>(3 * c.nodes()[j]) = values.col(j);
    EXPECT_LT((H2 - H).norm(), 1e-15 * H.norm());
    // d(H_a^T lambda)/dx, symmetric, and the stiffness blocks sum to its negative.
    const MatX J = dense(n, [&](const VecX& e, VecX& out) { c.add_force_derivative(f.x, lambda, e, out); });
    const MatX J_fd = test::fd_jacobian([&](const VecX& y) { return cable_force(c, y, lambda); }, f.x, kStep);
    const auto cj = test::compare(J, J_fd);
    EXPECT_LT(cj.rel_error, 1e-6) << cj.str();
    EXPECT_GT(J.norm(), 10.0);
    EXPECT_LT((J - J.transpose()).norm(), 1e-13 * J.norm());
    MatX K = MatX::Zero(n, n);
    c.for_each_stiffness_block(f.x, lambda, [&](int, int, int, int na, int nb, const Mat3& block) {
      K.block<3, 3>(3 * na, 3 * nb) += block;
    });
    EXPECT_LT((K + J).norm(), 1e-12 * J.norm());
    std::printf("quadratic cable (pull point %d): H_a %s; dH/dx %s\n", pull, cg.str().c_str(), cj.str().c_str());
  }
}

// ---------------------------------------------------------------------------
// Cavity

// The enclosed volume of the curved quadratic surface is exact: the whole boundary of
// a curved box as a cavity encloses -(the sum of the 10-node tets' volumes), at rest
// and deformed (the divergence theorem, both sides integrated exactly).
TEST(QuadraticCavity, VolumeOfACurvedSurfaceIsExact) {
  std::mt19937 rng(55);
  const mesh::TetMesh m = test::curved_box(3, 2, 2, 0.03, 0.02, 0.02, 0.08, rng);
  ASSERT_GT(min_det(m), 0);
  const Cavity c = boundary_cavity(m, mesh::boundary_triangles(m.tets));
  ASSERT_TRUE(c.closed());
  ASSERT_EQ(c.order(), 2);
  const VecX x_rest = test::flatten(m.X);
  const VecX x = test::deform(x_rest, 1e-4, rng);
  for (const VecX* y : {&x_rest, &x}) {
    const double V = c.volume(*y), ref = -tets_volume(m, *y);
    std::printf("curved box: cavity volume %.15e, tets %.15e, relative difference %.1e\n", V, ref,
                std::abs(V / ref - 1));
    EXPECT_NEAR(V, ref, 1e-13 * std::abs(ref));
  }
  // The curvature matters: the straight (vertex) surface encloses a different volume.
  Cavity straight;
  ASSERT_TRUE(Cavity::create(m.X, m.tets, mesh::boundary_triangles(m.tets), 0, straight).ok());
  EXPECT_GT(std::abs(straight.volume(x_rest) - c.volume(x_rest)), 1e-4 * std::abs(c.volume(x_rest)));
}

// Straight 6-node triangles: the box's volume exactly, and the consistent load of a
// flat 6-node triangle (n/3 on each mid-edge node, nothing on the vertices).
TEST(QuadraticCavity, StraightBoxIsExactAndLoadsTheMidEdgeNodes) {
  mesh::TetMesh m = test::box_mesh(3, 2, 2, 0.03, 0.02, 0.02);
  const int vertices = m.num_nodes();
  mesh::elevate_to_quadratic(m);
  const Cavity c = boundary_cavity(m, mesh::boundary_triangles(m.tets));
  const VecX x = test::flatten(m.X);
  // Exact up to round-off: the rule's points and weights carry 15 significant digits,
  // and ~100 triangles x 6 points are summed: 1e-14 relative.
  EXPECT_NEAR(c.volume(x), -0.03 * 0.02 * 0.02, 1e-14 * 0.03 * 0.02 * 0.02);
  // One side, z = 0.02 (open): the load sums to the side's area vector (into the solid,
  // -z) and falls on mid-edge nodes only.
  const Cavity top = boundary_cavity(m, test::box_boundary(m, Vec3(0.03, 0.02, 0.02), 5));
  const VecX H = cavity_force(top, x, 1.0);
  EXPECT_LT((H.reshaped(3, H.size() / 3).rowwise().sum() - Vec3(0, 0, -0.03 * 0.02)).norm(), 1e-14 * 0.03 * 0.02);
  for (int i = 0; i < vertices; ++i) EXPECT_LT(H.segment<3>(3 * i).norm(), 1e-15 * H.norm()) << "vertex " << i;
}

TEST(QuadraticCavity, DerivativesMatchFiniteDifferences) {
  std::mt19937 rng(56);
  const mesh::TetMesh m = test::curved_box(2, 2, 2, 0.02, 0.02, 0.02, 0.08, rng);
  ASSERT_GT(min_det(m), 0);
  const VecX x = test::deform(test::flatten(m.X), 1e-4, rng);
  const Eigen::Index n = x.size();
  const double p = 1.3e3;  // Pa
  for (bool closed : {true, false}) {
    const Triangles tris = closed ? mesh::boundary_triangles(m.tets) : test::box_boundary(m, Vec3(0.02, 0.02, 0.02), 5);
    const Cavity c = boundary_cavity(m, tris);
    ASSERT_EQ(c.closed(), closed);
    const VecX H = cavity_force(c, x, 1.0);
    if (closed) {  // H_a = dV/dx
      const VecX g = test::fd_gradient([&](const VecX& y) { return c.volume(y); }, x, kStep);
      const auto cg = test::compare(H, g);
      EXPECT_LT(cg.rel_error, 1e-6) << cg.str();
      std::printf("quadratic cavity: H_a vs FD of V: %s\n", cg.str().c_str());
    }
    Mat3X values(3, c.nodes().size());
    c.gradient_sparse(x, values);
    VecX H2 = VecX::Zero(n);
    for (size_t j = 0; j < c.nodes().size(); ++j) H2.segment<3>(3 * c.nodes()[j]) = values.col(j);
    EXPECT_LT((H2 - H).norm(), 1e-15 * H.norm());
    const MatX J = dense(n, [&](const VecX& e, VecX& out) { c.add_force_derivative(x, p, e, out); });
    const MatX J_fd = test::fd_jacobian([&](const VecX& y) { return cavity_force(c, y, p); }, x, kStep);
    const auto cj = test::compare(J, J_fd);
    EXPECT_LT(cj.rel_error, 1e-6) << (closed ? "closed " : "open ") << cj.str();
    EXPECT_GT(J.norm(), 1.0);
    if (closed) {
      EXPECT_LT((J - J.transpose()).norm(), 1e-12 * J.norm()) << "p d2V/dx2 is symmetric";
    }
    const MatX JT = dense(n, [&](const VecX& e, VecX& out) { c.add_force_derivative_transpose(x, p, e, out); });
    EXPECT_LT((JT - J.transpose()).norm(), 1e-13 * J.norm()) << (closed ? "closed" : "open");
    std::printf("quadratic cavity (%s): dH/dx vs FD: %s\n", closed ? "closed" : "open", cj.str().c_str());
  }
}

}  // namespace quadratic_actuators_test
