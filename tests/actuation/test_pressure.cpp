// Pressure actuator: orientation into the solid, V for closed cavities (an internal
// void: +|void|; the outer boundary of a box: -|box|), H_a = dV/dx and
// d(H_a^T p)/dx against central finite differences, virtual work to second order,
// open faces, and the error statuses.
//
// FD step: h = 1e-6 x the cell size (1e-8 m for 1 cm cells); V is a cubic polynomial
// of the positions, so the central difference of V is exact up to round-off
// (O(eps V / h) ~ 1e-16 x 1e-5 / 1e-8 ~ 1e-13 against gradient entries ~ 1e-4), and
// that of the (quadratic) H_a as well.
#include <softdiff/actuation/pressure.hpp>

#include "helpers.hpp"
#include <support/fd.hpp>

#include <gtest/gtest.h>

using namespace softdiff;
using namespace softdiff::actuation;

namespace {

constexpr double kStep = 1e-8;

// Flips the orientation of every other triangle and shuffles the columns: the
// cavity must not depend on the file's orientation.
Triangles scramble(Triangles T, std::mt19937& rng) {
  std::vector<int> perm(T.cols());
  for (size_t i = 0; i < perm.size(); ++i) perm[i] = static_cast<int>(i);
  std::shuffle(perm.begin(), perm.end(), rng);
  Triangles out(3, T.cols());
  for (int t = 0; t < T.cols(); ++t) {
    out.col(t) = T.col(perm[t]);
    if (t % 2) std::swap(out(1, t), out(2, t));
  }
  return out;
}

VecX global(const mesh::TetMesh& m, int offset) {
  VecX x = VecX::Zero(3 * (m.num_nodes() + offset + 2));
  x.segment(3 * offset, 3 * m.num_nodes()) = test::flatten(m.X);
  return x;
}

Tets shifted(const Tets& T, int offset) { return (T.array() + offset).matrix(); }

VecX force(const Cavity& c, const VecX& x, double p) {
  VecX f = VecX::Zero(x.size());
  c.add_force(x, p, 1.0, f);
  return f;
}

MatX derivative_matrix(const Cavity& c, const VecX& x, double p) {
  MatX J(x.size(), x.size());
  VecX e = VecX::Zero(x.size()), col(x.size());
  for (Eigen::Index j = 0; j < x.size(); ++j) {
    e[j] = 1;
    col.setZero();
    c.add_force_derivative(x, p, e, col);
    J.col(j) = col;
    e[j] = 0;
  }
  return J;
}

// A 3 x 3 x 3 box of 1 cm cells with its center cell removed: a closed internal void.
struct Holed {
  mesh::TetMesh m;
  Triangles cavity;  // the void's boundary faces (outward from the solid, i.e. into the void)
};

Holed holed_box(std::mt19937& rng) {
  Holed h;
  mesh::TetMesh full = test::jittered_box(3, 3, 3, 0.03, 0.03, 0.03, 0.0, rng);
  std::vector<int> keep;
  for (int e = 0; e < full.num_tets(); ++e) {
    Vec3 c = Vec3::Zero();
    for (int a = 0; a < 4; ++a) c += full.X.col(full.tets(a, e)) / 4;
    if (((c.array() - 0.015).abs() > 0.005).any()) keep.push_back(e);
  }
  h.m = full;
  h.m.tets.resize(4, static_cast<int>(keep.size()));
  for (size_t k = 0; k < keep.size(); ++k) h.m.tets.col(static_cast<int>(k)) = full.tets.col(keep[k]);
  // Faces of the removed cell's tets lying on the cell's sides = the void's boundary.
  mesh::TetMesh cell = full;
  std::vector<int> removed;
  for (int e = 0; e < full.num_tets(); ++e)
    if (std::find(keep.begin(), keep.end(), e) == keep.end()) removed.push_back(e);
  cell.tets.resize(4, static_cast<int>(removed.size()));
  for (size_t k = 0; k < removed.size(); ++k) cell.tets.col(static_cast<int>(k)) = full.tets.col(removed[k]);
  cell.X.colwise() -= Vec3::Constant(0.01);  // box_boundary works on [0, size]
  h.cavity = test::box_boundary(cell, Vec3::Constant(0.01));
  return h;
}

}  // namespace

TEST(Pressure, InternalVoidHasPositiveVolumeAndInflates) {
  std::mt19937 rng(20);
  const Holed h = holed_box(rng);
  ASSERT_EQ(h.cavity.cols(), 12);
  const int offset = 4;
  Cavity c;
  const CavityStatus s = Cavity::create(h.m.X, h.m.tets, scramble(h.cavity, rng), offset, c);
  ASSERT_TRUE(s.ok()) << s.message();
  EXPECT_TRUE(c.closed());
  const VecX x = global(h.m, offset);
  EXPECT_NEAR(c.volume(x), 1e-6, 1e-20);  // +|void| = (1 cm)^3
  // Positive pressure pushes every wall node away from the void's center (into the solid).
  const VecX f = force(c, x, 1000.0);
  for (int j : c.nodes()) {
    const Vec3 out = x.segment<3>(3 * j) - Vec3::Constant(0.015);
    EXPECT_GT(f.segment<3>(3 * j).dot(out), 0) << "node " << j;
  }
  // The total force on a closed cavity is zero (the area vectors of a closed surface sum to 0).
  Vec3 total = Vec3::Zero();
  for (int j : c.nodes()) total += f.segment<3>(3 * j);
  EXPECT_LT(total.norm(), 1e-15);
  // H_a = dV/dx, and its derivative, at a deformed state.
  const VecX y = test::deform(x, 1e-3, rng);
  VecX H(y.size());
  c.gradient(y, H);
  const auto cmp = test::compare(H, test::fd_gradient([&](const VecX& z) { return c.volume(z); }, y, kStep));
  EXPECT_LT(cmp.rel_error, 1e-6) << cmp.str();
  std::printf("void cavity: H_a vs FD of V: %s\n", cmp.str().c_str());
  const MatX J = derivative_matrix(c, y, 1000.0);
  const auto cmpJ = test::compare(J, test::fd_jacobian([&](const VecX& z) { return force(c, z, 1000.0); }, y, kStep));
  EXPECT_LT(cmpJ.rel_error, 1e-6) << cmpJ.str();
  EXPECT_LT((J - J.transpose()).norm(), 1e-13 * J.norm()) << "p d2V/dx2 is symmetric";
  std::printf("void cavity: d(H^T p)/dx vs FD: %s\n", cmpJ.str().c_str());
}

TEST(Pressure, OuterBoundaryAsCavityHasMinusBodyVolume) {
  // The whole outer boundary of a box, oriented into the solid, points INTO the box:
  // the divergence theorem gives V = -(box volume), at rest and deformed (where the
  // box's volume is the sum of the signed tet volumes).
  std::mt19937 rng(21);
  const Vec3 size(0.02, 0.03, 0.04);
  const mesh::TetMesh m = test::jittered_box(2, 2, 2, size[0], size[1], size[2], 0.2, rng);
  const int offset = 3;
  Cavity c;
  const CavityStatus s = Cavity::create(m.X, m.tets, scramble(test::box_boundary(m, size), rng), offset, c);
  ASSERT_TRUE(s.ok()) << s.message();
  EXPECT_TRUE(c.closed());
  EXPECT_EQ(c.num_open_edges(), 0);
  const VecX x = global(m, offset);
  EXPECT_NEAR(c.volume(x), -size.prod(), 1e-15 * size.prod());
  const VecX y = test::deform(x, 1e-3, rng);
  EXPECT_NEAR(c.volume(y), -test::mesh_volume(shifted(m.tets, offset), y), 1e-14 * size.prod());

  VecX H(y.size());
  c.gradient(y, H);
  const VecX g = test::fd_gradient([&](const VecX& z) { return c.volume(z); }, y, kStep);
  const auto cmp = test::compare(H, g);
  EXPECT_LT(cmp.rel_error, 1e-6) << cmp.str();
  std::printf("outer boundary: H_a vs FD of V: %s\n", cmp.str().c_str());
  Mat3X values(3, c.nodes().size());
  c.gradient_sparse(y, values);
  VecX H2 = VecX::Zero(y.size());
  for (size_t j = 0; j < c.nodes().size(); ++j) H2.segment<3>(3 * c.nodes()[j]) = values.col(j);
  EXPECT_LT((H2 - H).norm(), 1e-15 * H.norm());

  const MatX J = derivative_matrix(c, y, 250.0);
  const auto cmpJ = test::compare(J, test::fd_jacobian([&](const VecX& z) { return force(c, z, 250.0); }, y, kStep));
  EXPECT_LT(cmpJ.rel_error, 1e-6) << cmpJ.str();
  std::printf("outer boundary: d(H^T p)/dx vs FD: %s\n", cmpJ.str().c_str());

  // Virtual work: V(x + du) - V(x) - H du = O(|du|^2).
  const VecX u = VecX::Random(y.size()).normalized();
  std::vector<double> err;
  for (double t : {1e-4, 1e-5, 1e-6}) err.push_back(std::abs(c.volume(y + t * u) - c.volume(y) - H.dot(t * u)));
  for (size_t i = 1; i < err.size(); ++i) {
    EXPECT_GT(err[i - 1] / err[i], 70);
    EXPECT_LT(err[i - 1] / err[i], 140);
  }
  std::printf("pressure virtual work error at |du| = 1e-4, 1e-5, 1e-6: %.3e %.3e %.3e\n", err[0], err[1], err[2]);
}

TEST(Pressure, OpenFace) {
  std::mt19937 rng(22);
  const Vec3 size(0.02, 0.03, 0.04);
  const mesh::TetMesh m = test::jittered_box(2, 3, 2, size[0], size[1], size[2], 0.2, rng);
  Cavity c;
  const Triangles side = test::box_boundary(m, size, 1);  // the x = lx face
  ASSERT_TRUE(Cavity::create(m.X, m.tets, scramble(side, rng), 0, c).ok());
  EXPECT_FALSE(c.closed());
  EXPECT_EQ(c.num_open_edges(), 2 * (3 + 2));  // the face's perimeter: 2 (ny + nz) edges
  EXPECT_THROW(c.volume(test::flatten(m.X)), std::logic_error);
  // Into the solid: the area vectors sum to -(ly lz) e_x at rest.
  const VecX x = test::flatten(m.X);
  VecX H(x.size());
  c.gradient(x, H);
  Vec3 total = Vec3::Zero();
  for (int j : c.nodes()) total += H.segment<3>(3 * j);
  EXPECT_LT((total - Vec3(-size[1] * size[2], 0, 0)).norm(), 1e-18);
  // Derivative vs FD at a deformed state.
  const VecX y = test::deform(x, 1e-3, rng);
  const MatX J = derivative_matrix(c, y, 100.0);
  const auto cmpJ = test::compare(J, test::fd_jacobian([&](const VecX& z) { return force(c, z, 100.0); }, y, kStep));
  EXPECT_LT(cmpJ.rel_error, 1e-6) << cmpJ.str();
  std::printf("open face: d(H^T p)/dx vs FD: %s\n", cmpJ.str().c_str());
}

TEST(Pressure, ErrorStatuses) {
  const Vec3 size(0.02, 0.02, 0.02);
  const mesh::TetMesh m = test::box_mesh(2, 2, 2, size[0], size[1], size[2]);
  Cavity c;
  // Empty.
  CavityStatus s = Cavity::create(m.X, m.tets, Triangles(3, 0), 0, c);
  EXPECT_EQ(s.error, CavityError::empty);
  EXPECT_NE(s.message().find("no triangle"), std::string::npos);
  // An interior face (shared by two tets): the first face of tet 0 that is not on the boundary.
  Triangles T = test::box_boundary(m, size, 0);
  const int good = static_cast<int>(T.cols());
  Triangles bad(3, good + 1);
  bad.leftCols(good) = T;
  bool found = false;
  static constexpr int faces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  const Triangles all = test::box_boundary(m, size);
  for (const auto& f : faces) {
    std::array<int, 3> t = {m.tets(f[0], 0), m.tets(f[1], 0), m.tets(f[2], 0)};
    bool on_boundary = false;
    for (int k = 0; k < all.cols(); ++k) {
      std::array<int, 3> a = {all(0, k), all(1, k), all(2, k)}, b = t;
      std::sort(a.begin(), a.end());
      std::sort(b.begin(), b.end());
      on_boundary = on_boundary || a == b;
    }
    if (!on_boundary) {
      bad.col(good) << t[0], t[1], t[2];
      found = true;
      break;
    }
  }
  ASSERT_TRUE(found);
  s = Cavity::create(m.X, m.tets, bad, 0, c);
  EXPECT_EQ(s.error, CavityError::not_boundary);
  EXPECT_EQ(s.triangle, good);
  EXPECT_EQ(s.tets_sharing, 2);
  EXPECT_EQ(c.num_triangles(), 0) << "left empty on error";
  std::printf("message: %s\n", s.message().c_str());
  EXPECT_NE(s.message().find("triangle " + std::to_string(good)), std::string::npos);
  // Three nodes that do not form a face of any tet.
  bad.col(good) << 0, 2, 24;
  s = Cavity::create(m.X, m.tets, bad, 0, c);
  EXPECT_EQ(s.error, CavityError::not_boundary);
  EXPECT_EQ(s.tets_sharing, 0);
  std::printf("message: %s\n", s.message().c_str());
  // A face listed twice (in the other orientation).
  bad.col(good) << T(0, 1), T(2, 1), T(1, 1);
  s = Cavity::create(m.X, m.tets, bad, 0, c);
  EXPECT_EQ(s.error, CavityError::duplicate);
  EXPECT_EQ(s.triangle, good);
  // A node index out of range.
  bad.col(good) << 0, 1, m.num_nodes();
  s = Cavity::create(m.X, m.tets, bad, 0, c);
  EXPECT_EQ(s.error, CavityError::bad_index);
}
