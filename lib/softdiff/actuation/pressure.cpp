#include <softdiff/actuation/pressure.hpp>
#include <softdiff/core/assert.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <tuple>

namespace softdiff::actuation {

std::string CavityStatus::message() const {
  std::ostringstream s;
  auto name = [&] {
    s << "triangle " << triangle << " (nodes " << nodes[0] << ", " << nodes[1] << ", " << nodes[2] << ") ";
  };
  switch (error) {
    case CavityError::none: s << "ok"; break;
    case CavityError::empty: s << "the cavity has no triangle"; break;
    case CavityError::bad_index: name(); s << "has a node index outside the body's nodes"; break;
    case CavityError::not_boundary:
      name();
      if (tets_sharing == 0)
        s << "is not a face of any tetrahedron of the body";
      else
        s << "is an interior face (shared by " << tets_sharing << " tetrahedra), not on the boundary";
      break;
    case CavityError::duplicate: name(); s << "is listed twice"; break;
  }
  return s.str();
}

namespace {

struct Face {
  std::array<int, 3> key;      // sorted nodes
  std::array<int, 3> outward;  // oriented with the normal out of its tet
  bool operator<(const Face& o) const { return key < o.key; }
};

std::array<int, 3> sorted(std::array<int, 3> a) {
  std::sort(a.begin(), a.end());
  return a;
}

}  // namespace

namespace {

// The 6-point degree-4 rule on the reference triangle (0,0), (1,0), (0,1) (Strang and
// Fix, table 4.1; Dunavant 1985, degree 4): two orbits of 3 points (a, a, 1 - 2a),
// weights summing to 1/2 (the reference area).
constexpr double kQa1 = 0.445948490915965, kQw1 = 0.223381589678011 / 2;
constexpr double kQa2 = 0.091576213509771, kQw2 = 0.109951743655322 / 2;
// Barycentric (l0, l1, l2) of the points; (xi, eta) = (l1, l2).
constexpr double kQuad[6][4] = {
    {kQa1, kQa1, 1 - 2 * kQa1, kQw1}, {kQa1, 1 - 2 * kQa1, kQa1, kQw1}, {1 - 2 * kQa1, kQa1, kQa1, kQw1},
    {kQa2, kQa2, 1 - 2 * kQa2, kQw2}, {kQa2, 1 - 2 * kQa2, kQa2, kQw2}, {1 - 2 * kQa2, kQa2, kQa2, kQw2},
};

// The 6-node triangle's shape functions and their (xi, eta) derivatives at the rule's
// points, tabulated once.
struct Tri6Table {
  double N[6][6];    // [point][node]
  double dxi[6][6];  // dN/dxi
  double deta[6][6]; // dN/deta
  double w[6];
  Tri6Table() {
    for (int q = 0; q < 6; ++q) {
      const double l[3] = {kQuad[q][0], kQuad[q][1], kQuad[q][2]};
      // dl/dxi = (-1, 1, 0), dl/deta = (-1, 0, 1).
      static constexpr double dl[2][3] = {{-1, 1, 0}, {-1, 0, 1}};
      for (int a = 0; a < 3; ++a) {
        N[q][a] = l[a] * (2 * l[a] - 1);
        dxi[q][a] = (4 * l[a] - 1) * dl[0][a];
        deta[q][a] = (4 * l[a] - 1) * dl[1][a];
      }
      for (int k = 0; k < 3; ++k) {  // node 3 + k: edge (k, k + 1)
        const int i = k, j = (k + 1) % 3;
        N[q][3 + k] = 4 * l[i] * l[j];
        dxi[q][3 + k] = 4 * (dl[0][i] * l[j] + l[i] * dl[0][j]);
        deta[q][3 + k] = 4 * (dl[1][i] * l[j] + l[i] * dl[1][j]);
      }
      w[q] = kQuad[q][3];
    }
  }
};
const Tri6Table kTri6;

// The weighted area vector w_q (dx/dxi x dx/deta) of 6-node triangle `tri` (its node
// indices) at the rule's point q: the point's share of the integral of n dA.
template <class Nodes>
Vec3 tri6_area_vector(const VecX& x, const Nodes& tri, int q) {
  Vec3 a_xi = Vec3::Zero(), a_eta = Vec3::Zero();
  for (int i = 0; i < 6; ++i) {
    a_xi += kTri6.dxi[q][i] * x.segment<3>(3 * tri(i));
    a_eta += kTri6.deta[q][i] * x.segment<3>(3 * tri(i));
  }
  return kTri6.w[q] * a_xi.cross(a_eta);
}

}  // namespace

CavityStatus Cavity::create(const Mat3X& X, const Tets& tets, const Triangles& triangles, int node_offset,
                            Cavity& out, const Eigen::Matrix<int, 6, Eigen::Dynamic>* quadratic) {
  out = Cavity();
  CavityStatus status;
  const int n = static_cast<int>(X.cols()), k = static_cast<int>(triangles.cols());
  if (k == 0) {
    status.error = CavityError::empty;
    return status;
  }
  auto fail = [&](CavityError e, int t) {
    status.error = e;
    status.triangle = t;
    for (int a = 0; a < 3; ++a) status.nodes[a] = triangles(a, t);
    return status;
  };
  for (int t = 0; t < k; ++t)
    for (int a = 0; a < 3; ++a)
      if (triangles(a, t) < 0 || triangles(a, t) >= n) return fail(CavityError::bad_index, t);

  // Every tet face, oriented outward by geometry (robust to the tets' orientation).
  static constexpr int faces[4][4] = {{1, 2, 3, 0}, {0, 3, 2, 1}, {0, 1, 3, 2}, {0, 2, 1, 3}};  // face, opposite
  std::vector<Face> all;
  all.reserve(4 * static_cast<size_t>(tets.cols()));
  for (int e = 0; e < tets.cols(); ++e)
    for (int a = 0; a < 4; ++a) SOFTDIFF_DEMAND(tets(a, e) >= 0 && tets(a, e) < n, "tet node index out of range");
  for (int e = 0; e < tets.cols(); ++e)
    for (const auto& f : faces) {
      std::array<int, 3> tri = {tets(f[0], e), tets(f[1], e), tets(f[2], e)};
      const Vec3 a = X.col(tri[0]);
      const Vec3 normal = (X.col(tri[1]) - a).cross(X.col(tri[2]) - a);
      if (normal.dot(X.col(tets(f[3], e)) - a) > 0) std::swap(tri[1], tri[2]);
      all.push_back({sorted(tri), tri});
    }
  std::sort(all.begin(), all.end());

  // Cavity triangles: boundary faces (exactly one tet), distinct.
  std::vector<std::pair<std::array<int, 3>, int>> keys(k);
  for (int t = 0; t < k; ++t) keys[t] = {sorted({triangles(0, t), triangles(1, t), triangles(2, t)}), t};
  std::sort(keys.begin(), keys.end());
  for (int i = 1; i < k; ++i)
    if (keys[i].first == keys[i - 1].first)
      return fail(CavityError::duplicate, std::max(keys[i].second, keys[i - 1].second));

  out.triangles_.resize(3, k);
  for (int t = 0; t < k; ++t) {
    const Face probe{sorted({triangles(0, t), triangles(1, t), triangles(2, t)}), {}};
    const auto [lo, hi] = std::equal_range(all.begin(), all.end(), probe);
    if (hi - lo != 1) {
      out = Cavity();
      fail(CavityError::not_boundary, t);
      status.tets_sharing = static_cast<int>(hi - lo);
      return status;
    }
    // Into the solid: the reverse of the outward orientation.
    out.triangles_(0, t) = lo->outward[0] + node_offset;
    out.triangles_(1, t) = lo->outward[2] + node_offset;
    out.triangles_(2, t) = lo->outward[1] + node_offset;
  }

  // Closed: every directed edge (i, j) is matched by exactly one (j, i) and no other.
  std::vector<std::tuple<int, int, int>> edges;  // (min, max, +1 if min -> max else -1)
  edges.reserve(3 * static_cast<size_t>(k));
  for (int t = 0; t < k; ++t)
    for (int a = 0; a < 3; ++a) {
      const int i = out.triangles_(a, t), j = out.triangles_((a + 1) % 3, t);
      edges.emplace_back(std::min(i, j), std::max(i, j), i < j ? 1 : -1);
    }
  std::sort(edges.begin(), edges.end());
  for (size_t b = 0; b < edges.size();) {
    size_t e = b;
    while (e < edges.size() && std::get<0>(edges[e]) == std::get<0>(edges[b]) &&
           std::get<1>(edges[e]) == std::get<1>(edges[b]))
      ++e;
    const bool paired = e - b == 2 && std::get<2>(edges[b]) != std::get<2>(edges[b + 1]);
    if (!paired) ++out.num_open_edges_;
    b = e;
  }

  const int per = quadratic ? 6 : 3;
  if (quadratic) {
    SOFTDIFF_DEMAND(quadratic->cols() == k, "Cavity::create: one 6-node triangle per triangle");
    out.triangles6_.resize(6, k);
    for (int t = 0; t < k; ++t) {
      // The mid-edge node of the (unordered) edge (i, j) of the given 6-node triangle.
      auto mid = [&](int i, int j) {
        for (int e = 0; e < 3; ++e) {
          const int a = (*quadratic)(e, t) + node_offset, b = (*quadratic)((e + 1) % 3, t) + node_offset;
          if ((a == i && b == j) || (a == j && b == i)) return (*quadratic)(3 + e, t);
        }
        return -1;
      };
      for (int a = 0; a < 3; ++a) out.triangles6_(a, t) = out.triangles_(a, t);
      for (int e = 0; e < 3; ++e) {
        const int m = mid(out.triangles_(e, t), out.triangles_((e + 1) % 3, t));
        if (m < 0 || m >= n) {
          out = Cavity();
          return fail(CavityError::bad_index, t);
        }
        out.triangles6_(3 + e, t) = m + node_offset;
      }
    }
  }
  for (int t = 0; t < k; ++t)
    for (int a = 0; a < per; ++a) out.nodes_.push_back(quadratic ? out.triangles6_(a, t) : out.triangles_(a, t));
  std::sort(out.nodes_.begin(), out.nodes_.end());
  out.nodes_.erase(std::unique(out.nodes_.begin(), out.nodes_.end()), out.nodes_.end());
  out.slots_.resize(k);
  for (int t = 0; t < k; ++t)
    for (int a = 0; a < per; ++a)
      out.slots_[t][a] = static_cast<int>(
          std::lower_bound(out.nodes_.begin(), out.nodes_.end(), quadratic ? out.triangles6_(a, t) : out.triangles_(a, t)) -
          out.nodes_.begin());
  out.min_size_ = 3L * (out.nodes_.back() + 1);
  return status;
}

void Cavity::check_sizes(const VecX& x, const VecX& out) const {
  SOFTDIFF_DEMAND(triangles_.cols() > 0, "the cavity was not created");
  SOFTDIFF_DEMAND(x.size() >= min_size_ && x.size() % 3 == 0, "x is too short for the cavity's nodes");
  SOFTDIFF_DEMAND(out.size() == x.size(), "output vector must be sized like x");
}

double Cavity::volume(const VecX& x) const {
  SOFTDIFF_DEMAND(closed(), "the volume of an open cavity is not defined");
  SOFTDIFF_DEMAND(x.size() >= min_size_, "x is too short for the cavity's nodes");
  if (order() == 2) return volume6(x);
  // Tetrahedra from a reference point o on the surface: the same V for a closed
  // surface, with less cancellation than from the origin.
  const Vec3 o = x.segment<3>(3 * triangles_(0, 0));
  double V = 0;
  for (int t = 0; t < triangles_.cols(); ++t) {
    const Vec3 a = x.segment<3>(3 * triangles_(0, t)) - o;
    const Vec3 b = x.segment<3>(3 * triangles_(1, t)) - o;
    const Vec3 c = x.segment<3>(3 * triangles_(2, t)) - o;
    V += a.dot(b.cross(c));
  }
  return V / 6;
}

void Cavity::add_force(const VecX& x, double p, double scale, VecX& f) const {
  check_sizes(x, f);
  if (order() == 2) return add_force6(x, p, scale, f);
  const double s = scale * p / 6;  // n/3 = (b - a) x (c - a) / 6
  for (int t = 0; t < triangles_.cols(); ++t) {
    const Vec3 a = x.segment<3>(3 * triangles_(0, t));
    const Vec3 g = s * (x.segment<3>(3 * triangles_(1, t)) - a).cross(x.segment<3>(3 * triangles_(2, t)) - a);
    for (int i = 0; i < 3; ++i) f.segment<3>(3 * triangles_(i, t)) += g;
  }
}

void Cavity::gradient(const VecX& x, VecX& H) const {
  check_sizes(x, H);
  H.setZero();
  add_force(x, 1.0, 1.0, H);
}

void Cavity::gradient_sparse(const VecX& x, Mat3X& values) const {
  SOFTDIFF_DEMAND(x.size() >= min_size_, "x is too short for the cavity's nodes");
  SOFTDIFF_DEMAND(values.cols() == static_cast<Eigen::Index>(nodes_.size()), "values must be (3, nodes().size())");
  values.setZero();
  if (order() == 2) {
    for (int t = 0; t < triangles6_.cols(); ++t)
      for (int q = 0; q < 6; ++q) {
        const Vec3 n = tri6_area_vector(x, triangles6_.col(t), q);
        for (int i = 0; i < 6; ++i) values.col(slots_[t][i]) += kTri6.N[q][i] * n;
      }
    return;
  }
  for (int t = 0; t < triangles_.cols(); ++t) {
    const Vec3 a = x.segment<3>(3 * triangles_(0, t));
    const Vec3 g = (x.segment<3>(3 * triangles_(1, t)) - a).cross(x.segment<3>(3 * triangles_(2, t)) - a) / 6;
    for (int i = 0; i < 3; ++i) values.col(slots_[t][i]) += g;
  }
}

void Cavity::add_force_derivative(const VecX& x, double p, const VecX& dx, VecX& out) const {
  check_sizes(x, out);
  SOFTDIFF_DEMAND(dx.size() == x.size(), "dx must be sized like x");
  if (order() == 2) return add_force_derivative6(x, p, dx, out);
  const double s = p / 6;
  for (int t = 0; t < triangles_.cols(); ++t) {
    const int i0 = 3 * triangles_(0, t), i1 = 3 * triangles_(1, t), i2 = 3 * triangles_(2, t);
    const Vec3 e1 = x.segment<3>(i1) - x.segment<3>(i0), e2 = x.segment<3>(i2) - x.segment<3>(i0);
    const Vec3 de1 = dx.segment<3>(i1) - dx.segment<3>(i0), de2 = dx.segment<3>(i2) - dx.segment<3>(i0);
    const Vec3 g = s * (de1.cross(e2) + e1.cross(de2));
    out.segment<3>(i0) += g;
    out.segment<3>(i1) += g;
    out.segment<3>(i2) += g;
  }
}

void Cavity::add_force_derivative_transpose(const VecX& x, double p, const VecX& y, VecX& out) const {
  check_sizes(x, out);
  SOFTDIFF_DEMAND(y.size() == x.size(), "y must be sized like x");
  if (order() == 2) return add_force_derivative_transpose6(x, p, y, out);
  const double s = p / 6;
  for (int t = 0; t < triangles_.cols(); ++t) {
    const int i0 = 3 * triangles_(0, t), i1 = 3 * triangles_(1, t), i2 = 3 * triangles_(2, t);
    const Vec3 e1 = x.segment<3>(i1) - x.segment<3>(i0), e2 = x.segment<3>(i2) - x.segment<3>(i0);
    const Vec3 Y = y.segment<3>(i0) + y.segment<3>(i1) + y.segment<3>(i2);
    const Vec3 g1 = s * e2.cross(Y), g2 = s * Y.cross(e1);  // d/d(de1), d/d(de2)
    out.segment<3>(i1) += g1;
    out.segment<3>(i2) += g2;
    out.segment<3>(i0) -= g1 + g2;
  }
}

// Order 2 (pressure.hpp): the 6-point degree-4 rule, exact for every integrand below.
// Per rule point q of triangle t: x_xi, x_eta (the surface's tangents) and the
// area-vector density n = x_xi x x_eta (times the weight).
double Cavity::volume6(const VecX& x) const {
  const Vec3 o = x.segment<3>(3 * triangles6_(0, 0));
  double V = 0;
  for (int t = 0; t < triangles6_.cols(); ++t)
    for (int q = 0; q < 6; ++q) {
      Vec3 xs = Vec3::Zero(), a_xi = Vec3::Zero(), a_eta = Vec3::Zero();
      for (int i = 0; i < 6; ++i) {
        const Vec3 xi = x.segment<3>(3 * triangles6_(i, t)) - o;
        xs += kTri6.N[q][i] * xi;
        a_xi += kTri6.dxi[q][i] * xi;
        a_eta += kTri6.deta[q][i] * xi;
      }
      V += kTri6.w[q] * xs.dot(a_xi.cross(a_eta));
    }
  return V / 3;
}

void Cavity::add_force6(const VecX& x, double p, double scale, VecX& f) const {
  const double s = scale * p;
  for (int t = 0; t < triangles6_.cols(); ++t)
    for (int q = 0; q < 6; ++q) {
      const Vec3 n = s * tri6_area_vector(x, triangles6_.col(t), q);
      for (int i = 0; i < 6; ++i) f.segment<3>(3 * triangles6_(i, t)) += kTri6.N[q][i] * n;
    }
}

void Cavity::add_force_derivative6(const VecX& x, double p, const VecX& dx, VecX& out) const {
  for (int t = 0; t < triangles6_.cols(); ++t)
    for (int q = 0; q < 6; ++q) {
      Vec3 a_xi = Vec3::Zero(), a_eta = Vec3::Zero(), d_xi = Vec3::Zero(), d_eta = Vec3::Zero();
      for (int i = 0; i < 6; ++i) {
        const int r = 3 * triangles6_(i, t);
        a_xi += kTri6.dxi[q][i] * x.segment<3>(r);
        a_eta += kTri6.deta[q][i] * x.segment<3>(r);
        d_xi += kTri6.dxi[q][i] * dx.segment<3>(r);
        d_eta += kTri6.deta[q][i] * dx.segment<3>(r);
      }
      const Vec3 dn = (p * kTri6.w[q]) * (d_xi.cross(a_eta) + a_xi.cross(d_eta));
      for (int i = 0; i < 6; ++i) out.segment<3>(3 * triangles6_(i, t)) += kTri6.N[q][i] * dn;
    }
}

// Transpose: y . sum_i N_i dn = Y . dn with Y = sum_i N_i y_i at the point, and
// Y . (d_xi x a_eta + a_xi x d_eta) = d_xi . (a_eta x Y) + d_eta . (Y x a_xi), with
// d_xi = sum_j dN_j/dxi dx_j (and likewise d_eta).
void Cavity::add_force_derivative_transpose6(const VecX& x, double p, const VecX& y, VecX& out) const {
  for (int t = 0; t < triangles6_.cols(); ++t)
    for (int q = 0; q < 6; ++q) {
      Vec3 a_xi = Vec3::Zero(), a_eta = Vec3::Zero(), Y = Vec3::Zero();
      for (int i = 0; i < 6; ++i) {
        const int r = 3 * triangles6_(i, t);
        a_xi += kTri6.dxi[q][i] * x.segment<3>(r);
        a_eta += kTri6.deta[q][i] * x.segment<3>(r);
        Y += kTri6.N[q][i] * y.segment<3>(r);
      }
      const double s = p * kTri6.w[q];
      const Vec3 g_xi = s * a_eta.cross(Y), g_eta = s * Y.cross(a_xi);
      for (int j = 0; j < 6; ++j)
        out.segment<3>(3 * triangles6_(j, t)) += kTri6.dxi[q][j] * g_xi + kTri6.deta[q][j] * g_eta;
    }
}

}  // namespace softdiff::actuation
