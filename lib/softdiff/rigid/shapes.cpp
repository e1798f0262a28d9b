// Rigid shapes: mass properties (closed forms; the divergence theorem for meshes) and
// closed, outward tessellations (docs/method.md "Rigid bodies").
#include <softdiff/rigid/rigid_body.hpp>
#include <softdiff/core/format.hpp>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <utility>
#include <vector>

namespace softdiff::rigid {
namespace {

constexpr double pi = std::numbers::pi;

std::string num(double x) { return format_number(x, 6); }

void require_positive(const char* what, double value) {
  if (!(value > 0) || !std::isfinite(value))
    throw std::invalid_argument(std::string("rigid shape: ") + what + " must be positive and finite, got " + num(value));
}

void check_shape(const Shape& s) {
  switch (s.kind) {
    case Shape::Kind::box:
      for (int k = 0; k < 3; ++k) require_positive("box half_extents", s.half_extents[k]);
      break;
    case Shape::Kind::sphere: require_positive("sphere radius", s.radius); break;
    case Shape::Kind::capsule:
      require_positive("capsule radius", s.radius);
      if (!(s.length >= 0) || !std::isfinite(s.length))
        throw std::invalid_argument("rigid shape: capsule length must be >= 0 and finite, got " + num(s.length));
      break;
    case Shape::Kind::cylinder:
      require_positive("cylinder radius", s.radius);
      require_positive("cylinder length", s.length);
      break;
    case Shape::Kind::mesh: break;
  }
}

// A mesh surface must be closed and consistently oriented: every directed edge (a, b)
// appears exactly once and its reverse (b, a) exactly once.
void check_mesh_closed(const Shape& s) {
  const Eigen::Index nv = s.mesh_vertices.cols(), nt = s.mesh_triangles.cols();
  if (nv < 4 || nt < 4)
    throw std::invalid_argument("rigid mesh: a closed surface needs at least 4 vertices and 4 triangles, got " +
                                std::to_string(nv) + " and " + std::to_string(nt));
  if (!s.mesh_vertices.allFinite()) throw std::invalid_argument("rigid mesh: a vertex is not finite");
  std::vector<std::pair<int, int>> edges;
  edges.reserve(3 * static_cast<size_t>(nt));
  for (Eigen::Index t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const int a = s.mesh_triangles(k, t), b = s.mesh_triangles((k + 1) % 3, t);
      if (a < 0 || a >= nv || b < 0 || b >= nv)
        throw std::invalid_argument("rigid mesh: triangle " + std::to_string(t) + " has a vertex index out of range [0, " +
                                    std::to_string(nv) + ")");
      if (a == b) throw std::invalid_argument("rigid mesh: triangle " + std::to_string(t) + " repeats a vertex");
      edges.emplace_back(a, b);
    }
  std::sort(edges.begin(), edges.end());
  for (size_t k = 0; k < edges.size(); ++k) {
    const auto [a, b] = edges[k];
    if (k + 1 < edges.size() && edges[k + 1] == edges[k])
      throw std::invalid_argument("rigid mesh: the directed edge (" + std::to_string(a) + ", " + std::to_string(b) +
                                  ") appears twice: the surface is not consistently oriented or not manifold");
    if (!std::binary_search(edges.begin(), edges.end(), std::make_pair(b, a)))
      throw std::invalid_argument("rigid mesh: the edge (" + std::to_string(a) + ", " + std::to_string(b) +
                                  ") has no opposite: the surface is open or not consistently oriented");
  }
}

MassProperties mesh_mass_properties(const Shape& s, double density) {
  check_mesh_closed(s);
  // Signed tetrahedra (0, a, b, c) over the surface: volume det/6, first moment
  // det/24 (a + b + c), second moment (covariance about the origin)
  // det/120 (a a^T + b b^T + c c^T + (a + b + c)(a + b + c)^T); exact for a polyhedron.
  double six_volume = 0;
  Vec3 moment = Vec3::Zero();
  Mat3 second = Mat3::Zero();
  for (Eigen::Index t = 0; t < s.mesh_triangles.cols(); ++t) {
    const Vec3 a = s.mesh_vertices.col(s.mesh_triangles(0, t));
    const Vec3 b = s.mesh_vertices.col(s.mesh_triangles(1, t));
    const Vec3 c = s.mesh_vertices.col(s.mesh_triangles(2, t));
    const double det = a.dot(b.cross(c));
    const Vec3 sum = a + b + c;
    six_volume += det;
    moment += det * sum;
    second += det * (a * a.transpose() + b * b.transpose() + c * c.transpose() + sum * sum.transpose());
  }
  const double volume = six_volume / 6;
  const double scale = s.mesh_vertices.cwiseAbs().maxCoeff();
  if (!(volume > 1e-12 * scale * scale * scale))
    throw std::invalid_argument("rigid mesh: the enclosed volume is " + num(volume) +
                                " (not positive): the surface is inside-out (triangles must be oriented outward)");
  MassProperties p;
  p.mass = density * volume;
  p.centre = moment / 24 / volume;
  const Mat3 C = density * second / 120 - p.mass * p.centre * p.centre.transpose();  // about the centre
  p.inertia = C.trace() * Mat3::Identity() - C;
  p.inertia = 0.5 * (p.inertia + p.inertia.transpose()).eval();
  return p;
}

// A surface of revolution about z from a profile (rho_i, z_i) running from the bottom
// pole (rho = 0) to the top pole (rho = 0), with n_theta vertices per ring.
Surface revolve(const std::vector<std::pair<double, double>>& profile, int n_theta) {
  const int rings = static_cast<int>(profile.size()) - 2;
  Surface s;
  s.vertices.resize(3, 2 + static_cast<Eigen::Index>(rings) * n_theta);
  s.triangles.resize(3, 2 * static_cast<Eigen::Index>(n_theta) * rings);
  s.vertices.col(0) = Vec3(0, 0, profile.front().second);
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < n_theta; ++j) {
      const double th = 2 * pi * j / n_theta;
      const auto [rho, z] = profile[static_cast<size_t>(i) + 1];
      s.vertices.col(1 + i * n_theta + j) = Vec3(rho * std::cos(th), rho * std::sin(th), z);
    }
  const int top = 1 + rings * n_theta;
  s.vertices.col(top) = Vec3(0, 0, profile.back().second);
  const auto ring = [&](int i, int j) { return 1 + i * n_theta + (j % n_theta); };
  Eigen::Index t = 0;
  for (int j = 0; j < n_theta; ++j) s.triangles.col(t++) = Eigen::Vector3i(0, ring(0, j + 1), ring(0, j));
  for (int i = 0; i + 1 < rings; ++i)
    for (int j = 0; j < n_theta; ++j) {
      s.triangles.col(t++) = Eigen::Vector3i(ring(i, j), ring(i, j + 1), ring(i + 1, j + 1));
      s.triangles.col(t++) = Eigen::Vector3i(ring(i, j), ring(i + 1, j + 1), ring(i + 1, j));
    }
  for (int j = 0; j < n_theta; ++j) s.triangles.col(t++) = Eigen::Vector3i(top, ring(rings - 1, j), ring(rings - 1, j + 1));
  return s;
}

int pieces(double length, double max_edge, int at_least) {
  const double n = std::ceil(length / max_edge);
  if (!(n < 1e5)) throw std::invalid_argument("rigid tessellation: max_edge " + num(max_edge) + " is too small for the shape");
  return std::max(at_least, static_cast<int>(n));
}

// Appends the straight segment to (rho, z), subdivided (the start is the profile's last point).
void line_to(std::vector<std::pair<double, double>>& p, double rho, double z, double max_edge) {
  const auto [r0, z0] = p.back();
  const double len = std::hypot(rho - r0, z - z0);
  if (len == 0) return;
  const int n = pieces(len, max_edge, 1);
  for (int k = 1; k <= n; ++k) p.emplace_back(r0 + (rho - r0) * k / n, z0 + (z - z0) * k / n);
}

// Appends the arc of radius r about (0, zc) from latitude phi0 to phi1 (the start is the
// profile's last point).
void arc_to(std::vector<std::pair<double, double>>& p, double r, double zc, double phi0, double phi1, double max_edge) {
  const int n = pieces(r * (phi1 - phi0), max_edge, 2);
  for (int k = 1; k <= n; ++k) {
    const double phi = phi0 + (phi1 - phi0) * k / n;
    p.emplace_back(k == n && phi1 == pi / 2 ? 0.0 : r * std::cos(phi), zc + r * std::sin(phi));
  }
}

}  // namespace

MassProperties mass_properties(const Shape& shape, double density) {
  require_positive("density", density);
  check_shape(shape);
  MassProperties p;
  const double r = shape.radius, L = shape.length;
  switch (shape.kind) {
    case Shape::Kind::box: {
      const Vec3 e = shape.half_extents, e2 = e.cwiseProduct(e);
      p.mass = density * 8 * e.prod();
      p.inertia.diagonal() = p.mass / 3 * Vec3(e2.y() + e2.z(), e2.x() + e2.z(), e2.x() + e2.y());
      break;
    }
    case Shape::Kind::sphere:
      p.mass = density * 4.0 / 3 * pi * r * r * r;
      p.inertia.diagonal().setConstant(0.4 * p.mass * r * r);
      break;
    case Shape::Kind::cylinder:
      p.mass = density * pi * r * r * L;
      p.inertia.diagonal() = Vec3::Constant(p.mass * (3 * r * r + L * L) / 12);
      p.inertia(2, 2) = 0.5 * p.mass * r * r;
      break;
    case Shape::Kind::capsule: {
      // The cylinder plus two hemispheres (each of mass m_h, centroid 3r/8 from its
      // flat face, transverse inertia 83/320 m_h r^2 about its centroid).
      const double m_c = density * pi * r * r * L, m_h = density * 2.0 / 3 * pi * r * r * r;
      const double d = L / 2 + 3 * r / 8;
      p.mass = m_c + 2 * m_h;
      const double transverse = m_c * (3 * r * r + L * L) / 12 + 2 * (83.0 / 320 * m_h * r * r + m_h * d * d);
      p.inertia.diagonal() = Vec3(transverse, transverse, 0.5 * m_c * r * r + 2 * 0.4 * m_h * r * r);
      break;
    }
    case Shape::Kind::mesh: return mesh_mass_properties(shape, density);
  }
  return p;
}

Surface tessellate(const Shape& shape, const Vec3& centre, double max_edge) {
  check_shape(shape);
  Surface s;
  if (shape.kind == Shape::Kind::mesh) {
    check_mesh_closed(shape);
    s.vertices = shape.mesh_vertices.colwise() - centre;
    s.triangles = shape.mesh_triangles;
    return s;
  }
  if (shape.kind == Shape::Kind::box) {
    const Vec3 e = shape.half_extents;
    s.vertices.resize(3, 8);
    for (int i = 0; i < 8; ++i)
      s.vertices.col(i) = Vec3(i & 1 ? e.x() : -e.x(), i & 2 ? e.y() : -e.y(), i & 4 ? e.z() : -e.z()) - centre;
    // Faces as quads (vertex bits), each split into two triangles, then oriented outward.
    const int quads[6][4] = {{0, 2, 6, 4}, {1, 3, 7, 5}, {0, 1, 5, 4}, {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 5, 7, 6}};
    s.triangles.resize(3, 12);
    for (int f = 0; f < 6; ++f) {
      const auto& q = quads[f];
      Eigen::Vector3i t0(q[0], q[1], q[2]), t1(q[0], q[2], q[3]);
      const Vec3 a = s.vertices.col(q[0]) + centre, b = s.vertices.col(q[1]) + centre, c = s.vertices.col(q[2]) + centre;
      if ((b - a).cross(c - a).dot(a + c) < 0) {  // the box is convex about its centre
        std::swap(t0[1], t0[2]);
        std::swap(t1[1], t1[2]);
      }
      s.triangles.col(2 * f) = t0;
      s.triangles.col(2 * f + 1) = t1;
    }
    return s;
  }
  if (!(max_edge > 0) || !std::isfinite(max_edge))
    throw std::invalid_argument("rigid tessellation: max_edge must be positive and finite, got " + num(max_edge));
  const double r = shape.radius, L = shape.length;
  const int n_theta = pieces(2 * pi * r, max_edge, 8);
  std::vector<std::pair<double, double>> profile;
  switch (shape.kind) {
    case Shape::Kind::sphere:
      profile.emplace_back(0.0, -r);
      arc_to(profile, r, 0, -pi / 2, pi / 2, max_edge);
      break;
    case Shape::Kind::capsule:
      profile.emplace_back(0.0, -L / 2 - r);
      arc_to(profile, r, -L / 2, -pi / 2, 0, max_edge);
      line_to(profile, r, L / 2, max_edge);
      arc_to(profile, r, L / 2, 0, pi / 2, max_edge);
      break;
    case Shape::Kind::cylinder:
      profile.emplace_back(0.0, -L / 2);
      line_to(profile, r, -L / 2, max_edge);
      line_to(profile, r, L / 2, max_edge);
      line_to(profile, 0, L / 2, max_edge);
      break;
    default: break;
  }
  if (static_cast<double>(profile.size()) * n_theta > 2e6)
    throw std::invalid_argument("rigid tessellation: max_edge " + num(max_edge) + " is too small for the shape");
  s = revolve(profile, n_theta);
  s.vertices.colwise() -= centre;
  return s;
}

}  // namespace softdiff::rigid
