// Static obstacles: validation, exact signed distances, bounding boxes, and the
// triangle-surface reader for mesh obstacles.
//
// Feature indices (ClosestPoint::feature):
//   box:      face 2 a + s (a = axis 0..2, s = 0 for the -a side, 1 for +a): 0..5
//             = (-x, +x, -y, +y, -z, +z);
//             edge 6 + 4 a + 2 s1 + s2: the edge parallel to axis a, at the sides
//             s1, s2 (0: -, 1: +) of the two other axes in increasing order;
//             vertex 18 + sx + 2 sy + 4 sz.
//   cylinder: 0 the side (smooth), 1 the -z cap, 2 the +z cap (faces), 3 the -z rim,
//             4 the +z rim (edges).
//   plane, sphere, capsule: 0.   mesh: the triangle index (kind: its face, edge or vertex).
// Points inside take the nearest surface feature; ties go to the lowest axis / the
// cap over the side, so that the answer is deterministic.
//
// Mesh obstacles: a median-split AABB tree over the triangles (built once in
// prepare) with an exact point-triangle kernel at the leaves, i.e. an exact nearest
// triangle (FCL's BVH distance goes through GJK on a radius-0 sphere, which is
// neither exact nor signed; an exact query on our own small tree is simpler). The
// sign is that of (p - q) . N, N the angle-weighted pseudo-normal of the nearest
// feature (Baerentzen & Aanaes 2005), exact for closed, consistently oriented surfaces.
#include <softdiff/collision/distance.hpp>
#include <softdiff/core/format.hpp>
#include <softdiff/collision/obstacle.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/io/gmsh_msh.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <numeric>
#include <sstream>
#include <vector>

namespace softdiff::collision {

struct MeshAccel {
  struct Node {
    Eigen::AlignedBox3d box;
    int left = -1, right = -1;  // children (internal node)
    int begin = 0, end = 0;     // range in `order` (leaf: left == -1)
  };
  std::vector<Node> nodes;
  std::vector<int> order;                   // triangle indices, leaf ranges
  std::vector<Vec3> face_normal;            // unit
  std::vector<std::array<Vec3, 3>> edge_normal;  // per triangle, edges ab, bc, ca (unit)
  std::vector<Vec3> vertex_normal;          // angle-weighted (unit)
  Eigen::AlignedBox3d box;
};

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

[[noreturn]] void fail(const Obstacle& o, const std::string& message) {
  throw InputError("obstacle '" + o.name + "': " + message);
}

std::string num(double v) { return format_number(v, 17); }

Vec3 unit_or(const Vec3& v, const Vec3& fallback) {
  const double n = v.norm();
  return n > 0 ? Vec3(v / n) : fallback;
}

// ----------------------------------------------------------------------------------
// Analytic shapes. q is the query in local coordinates; results in local coordinates.

void box_local(const Vec3& q, const Vec3& h, ClosestPoint& out) {
  bool outside = false;
  for (int i = 0; i < 3; ++i) outside = outside || std::abs(q[i]) > h[i];
  if (outside) {
    Vec3 c = q;
    int clamped = 0, axes[3], sides[3];
    int free_axis = -1;
    for (int i = 0; i < 3; ++i) {
      if (q[i] > h[i]) {
        c[i] = h[i];
        axes[clamped] = i;
        sides[clamped++] = 1;
      } else if (q[i] < -h[i]) {
        c[i] = -h[i];
        axes[clamped] = i;
        sides[clamped++] = 0;
      } else {
        free_axis = i;
      }
    }
    const Vec3 d = q - c;
    const double dist = d.norm();
    out.distance = dist;
    out.point = c;
    out.normal = d / dist;
    if (clamped == 1) {
      out.feature_kind = Feature::face;
      out.feature = 2 * axes[0] + sides[0];
    } else if (clamped == 2) {
      out.feature_kind = Feature::edge;
      out.feature = 6 + 4 * free_axis + 2 * sides[0] + sides[1];
    } else {
      out.feature_kind = Feature::vertex;
      out.feature = 18 + sides[0] + 2 * sides[1] + 4 * sides[2];
    }
    return;
  }
  // Inside (or on the surface): the nearest face.
  int axis = 0;
  double best = h[0] - std::abs(q[0]);
  for (int i = 1; i < 3; ++i) {
    const double g = h[i] - std::abs(q[i]);
    if (g < best) {
      best = g;
      axis = i;
    }
  }
  const int side = q[axis] >= 0 ? 1 : 0;
  out.distance = -best;
  out.point = q;
  out.point[axis] = side ? h[axis] : -h[axis];
  out.normal = Vec3::Zero();
  out.normal[axis] = side ? 1 : -1;
  out.feature_kind = Feature::face;
  out.feature = 2 * axis + side;
}

void sphere_local(const Vec3& q, double r, ClosestPoint& out) {
  const double l = q.norm();
  out.normal = unit_or(q, Vec3(0, 0, 1));
  out.distance = l - r;
  out.point = r * out.normal;
  out.feature_kind = Feature::smooth;
  out.feature = 0;
}

void capsule_local(const Vec3& q, double r, double hl, ClosestPoint& out) {
  const double z = std::clamp(q[2], -hl, hl);
  const Vec3 axis_point(0, 0, z);
  const Vec3 d = q - axis_point;
  const double l = d.norm();
  out.normal = unit_or(d, Vec3(1, 0, 0));
  out.distance = l - r;
  out.point = axis_point + r * out.normal;
  out.feature_kind = Feature::smooth;
  out.feature = 0;
}

void cylinder_local(const Vec3& q, double r, double hl, ClosestPoint& out) {
  const double rho = std::hypot(q[0], q[1]);
  const Vec3 radial = rho > 0 ? Vec3(q[0] / rho, q[1] / rho, 0) : Vec3(1, 0, 0);
  const double dr = rho - r;
  const double dz = std::abs(q[2]) - hl;
  const int top = q[2] >= 0 ? 1 : 0;
  const double zs = top ? hl : -hl;
  if (dr > 0 && dz > 0) {  // the rim
    out.point = r * radial + Vec3(0, 0, zs);
    const Vec3 d = q - out.point;
    out.distance = d.norm();
    out.normal = d / out.distance;
    out.feature_kind = Feature::edge;
    out.feature = 3 + top;
  } else if (dr > 0 || (dz <= 0 && dr > dz)) {  // the side (outside radially, or nearest inside)
    out.distance = dr;
    out.point = r * radial + Vec3(0, 0, q[2]);
    out.normal = radial;
    out.feature_kind = Feature::smooth;
    out.feature = 0;
  } else {  // a cap
    out.distance = dz;
    out.point = Vec3(q[0], q[1], zs);
    out.normal = Vec3(0, 0, top ? 1 : -1);
    out.feature_kind = Feature::face;
    out.feature = 1 + top;
  }
}

// ----------------------------------------------------------------------------------
// Triangle surfaces.

// Why the surface is not a closed, manifold, consistently oriented triangle surface;
// empty if it is.
std::string surface_problem(const TriangleSurface& s) {
  const long nv = s.vertices.cols(), nt = s.triangles.cols();
  if (nt == 0) return "no triangles";
  for (long i = 0; i < nv; ++i)
    if (!s.vertices.col(i).allFinite()) return "vertex " + std::to_string(i) + " is not finite";
  struct HalfEdge {
    int lo, hi, forward, tri;
  };
  std::vector<HalfEdge> he;
  he.reserve(static_cast<std::size_t>(3 * nt));
  for (long t = 0; t < nt; ++t) {
    for (int k = 0; k < 3; ++k) {
      const int a = s.triangles(k, t), b = s.triangles((k + 1) % 3, t);
      if (a < 0 || a >= nv || b < 0 || b >= nv) return "triangle " + std::to_string(t) + " has a vertex index out of range";
      if (a == b) return "triangle " + std::to_string(t) + " is degenerate (repeated vertex " + std::to_string(a) + ")";
      he.push_back({std::min(a, b), std::max(a, b), a < b ? 1 : 0, static_cast<int>(t)});
    }
  }
  std::sort(he.begin(), he.end(), [](const HalfEdge& x, const HalfEdge& y) {
    return std::tie(x.lo, x.hi, x.tri) < std::tie(y.lo, y.hi, y.tri);
  });
  auto vtx = [&](int i) {
    const Vec3 p = s.vertices.col(i);
    return std::to_string(i) + " (" + num(p[0]) + ", " + num(p[1]) + ", " + num(p[2]) + ")";
  };
  for (std::size_t i = 0; i < he.size();) {
    std::size_t j = i;
    while (j < he.size() && he[j].lo == he[i].lo && he[j].hi == he[i].hi) ++j;
    const std::size_t count = j - i;
    const std::string edge = "edge " + vtx(he[i].lo) + " - " + vtx(he[i].hi);
    if (count == 1)
      return "not closed: " + edge + " belongs to only one triangle (" + std::to_string(he[i].tri) + ")";
    if (count > 2) return "not manifold: " + edge + " belongs to " + std::to_string(count) + " triangles";
    if (he[i].forward == he[i + 1].forward)
      return "not consistently oriented: triangles " + std::to_string(he[i].tri) + " and " +
             std::to_string(he[i + 1].tri) + " traverse " + edge + " in the same direction";
    i = j;
  }
  return {};
}

double signed_volume(const TriangleSurface& s) {
  double v = 0;
  for (long t = 0; t < s.triangles.cols(); ++t) {
    const Vec3 a = s.vertices.col(s.triangles(0, t)), b = s.vertices.col(s.triangles(1, t)),
               c = s.vertices.col(s.triangles(2, t));
    v += a.dot(b.cross(c));
  }
  return v / 6;
}

std::shared_ptr<MeshAccel> build_accel(const TriangleSurface& s) {
  auto acc = std::make_shared<MeshAccel>();
  const int nt = static_cast<int>(s.triangles.cols()), nv = static_cast<int>(s.vertices.cols());
  auto P = [&](int t, int k) { return Vec3(s.vertices.col(s.triangles(k, t))); };
  acc->face_normal.resize(nt);
  acc->vertex_normal.assign(nv, Vec3::Zero());
  for (int t = 0; t < nt; ++t) {
    const Vec3 n = (P(t, 1) - P(t, 0)).cross(P(t, 2) - P(t, 0));
    acc->face_normal[t] = unit_or(n, Vec3::Zero());
    for (int k = 0; k < 3; ++k) {
      const Vec3 e1 = P(t, (k + 1) % 3) - P(t, k), e2 = P(t, (k + 2) % 3) - P(t, k);
      const double angle = std::atan2(e1.cross(e2).norm(), e1.dot(e2));
      acc->vertex_normal[s.triangles(k, t)] += angle * acc->face_normal[t];
    }
  }
  for (auto& n : acc->vertex_normal) n = unit_or(n, Vec3::Zero());
  // Edge pseudo-normals: the sum of the two adjacent face normals.
  std::map<std::pair<int, int>, Vec3> edge_sum;
  for (int t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const int a = s.triangles(k, t), b = s.triangles((k + 1) % 3, t);
      auto [it, inserted] = edge_sum.try_emplace({std::min(a, b), std::max(a, b)}, Vec3::Zero());
      it->second += acc->face_normal[t];
    }
  acc->edge_normal.resize(nt);
  for (int t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const int a = s.triangles(k, t), b = s.triangles((k + 1) % 3, t);
      acc->edge_normal[t][k] = unit_or(edge_sum.at({std::min(a, b), std::max(a, b)}), acc->face_normal[t]);
    }
  // Median-split AABB tree, leaves of at most 4 triangles.
  std::vector<Eigen::AlignedBox3d> tri_box(nt);
  std::vector<Vec3> centroid(nt);
  for (int t = 0; t < nt; ++t) {
    tri_box[t].setEmpty();
    for (int k = 0; k < 3; ++k) tri_box[t].extend(P(t, k));
    centroid[t] = tri_box[t].center();
  }
  acc->order.resize(nt);
  std::iota(acc->order.begin(), acc->order.end(), 0);
  acc->nodes.reserve(2 * nt);
  struct Build {
    MeshAccel& acc;
    const std::vector<Eigen::AlignedBox3d>& tri_box;
    const std::vector<Vec3>& centroid;
    int make(int begin, int end) {
      const int id = static_cast<int>(acc.nodes.size());
      acc.nodes.emplace_back();
      Eigen::AlignedBox3d box, cbox;
      box.setEmpty();
      cbox.setEmpty();
      for (int i = begin; i < end; ++i) {
        box.extend(tri_box[acc.order[i]]);
        cbox.extend(centroid[acc.order[i]]);
      }
      acc.nodes[id].box = box;
      acc.nodes[id].begin = begin;
      acc.nodes[id].end = end;
      if (end - begin <= 4) return id;
      int axis;
      cbox.sizes().maxCoeff(&axis);
      const int mid = (begin + end) / 2;
      std::nth_element(acc.order.begin() + begin, acc.order.begin() + mid, acc.order.begin() + end, [&](int x, int y) {
        return centroid[x][axis] < centroid[y][axis] || (centroid[x][axis] == centroid[y][axis] && x < y);
      });
      const int l = make(begin, mid);
      const int r = make(mid, end);
      acc.nodes[id].left = l;
      acc.nodes[id].right = r;
      return id;
    }
  } build{*acc, tri_box, centroid};
  build.make(0, nt);
  acc->box = acc->nodes[0].box;
  return acc;
}

double box_distance2(const Eigen::AlignedBox3d& b, const Vec3& p) {
  double d2 = 0;
  for (int i = 0; i < 3; ++i) {
    const double d = std::max({b.min()[i] - p[i], 0.0, p[i] - b.max()[i]});
    d2 += d * d;
  }
  return d2;
}

void mesh_closest(const Obstacle& o, const Vec3& p, ClosestPoint& out) {
  const MeshAccel& acc = *o.accel;
  const auto& s = o.mesh;
  double best = kInf;
  PointTriangleResult best_r;
  int best_t = -1;
  int stack[128];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const MeshAccel::Node& node = acc.nodes[stack[--top]];
    if (box_distance2(node.box, p) > best) continue;
    if (node.left < 0) {
      for (int i = node.begin; i < node.end; ++i) {
        const int t = acc.order[i];
        const PointTriangleResult r =
            point_triangle_closest(p, s.vertices.col(s.triangles(0, t)), s.vertices.col(s.triangles(1, t)),
                                   s.vertices.col(s.triangles(2, t)));
        if (r.dist2 < best || (r.dist2 == best && t < best_t)) {
          best = r.dist2;
          best_r = r;
          best_t = t;
        }
      }
      continue;
    }
    // Nearer child last (popped first).
    const int l = node.left, r = node.right;
    const double dl = box_distance2(acc.nodes[l].box, p), dr = box_distance2(acc.nodes[r].box, p);
    if (dl <= dr) {
      stack[top++] = r;
      stack[top++] = l;
    } else {
      stack[top++] = l;
      stack[top++] = r;
    }
  }
  Vec3 pseudo;
  switch (best_r.feature) {
    case Feature::face: pseudo = acc.face_normal[best_t]; break;
    case Feature::edge: pseudo = acc.edge_normal[best_t][best_r.local]; break;
    default: pseudo = acc.vertex_normal[s.triangles(best_r.local, best_t)]; break;
  }
  const Vec3 d = p - best_r.point;
  const double dist = std::sqrt(best);
  const double side = d.dot(pseudo) < 0 ? -1.0 : 1.0;
  out.point = best_r.point;
  out.distance = side * dist;
  out.normal = dist > 0 ? Vec3(side * d / dist) : pseudo;
  if (dist > 0 && dist < 1e-12 * (acc.box.diagonal().norm() + 1)) out.normal = pseudo;  // direction lost in round-off
  // A closest point inside a triangle: d is along its face normal in exact arithmetic,
  // and d / |d| carries round-off ~eps |p| / |d| across it (docs/method.md "Contact
  // normals at tiny gaps"): the face normal itself (normal_derivative: zero for a face).
  if (best_r.feature == Feature::face) out.normal = pseudo;
  out.feature_kind = best_r.feature;
  out.feature = best_t;
}

bool rotation_ok(const Mat3& R) {
  return R.allFinite() && (R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff() < 1e-9 && R.determinant() > 0;
}

void positive(const Obstacle& o, const char* what, double v) {
  if (!(v > 0) || !std::isfinite(v)) fail(o, std::string(what) + " must be > 0, got " + num(v));
}

}  // namespace

// ------------------------------------------------------------------------------------

double plane_offset_at(const Obstacle& o, double t) {
  const auto& s = o.offset_schedule;
  if (s.empty()) return o.offset;
  if (t <= s.front()[0]) return s.front()[1];
  if (t >= s.back()[0]) return s.back()[1];
  for (std::size_t k = 1; k < s.size(); ++k)
    if (t <= s[k][0]) {
      const double w = (t - s[k - 1][0]) / (s[k][0] - s[k - 1][0]);
      return (1 - w) * s[k - 1][1] + w * s[k][1];
    }
  return s.back()[1];
}

void prepare(Obstacle& o) {
  if (!o.center.allFinite()) fail(o, "center is not finite");
  if (o.kind != ShapeKind::plane && !o.offset_schedule.empty())
    fail(o, "an offset schedule (a prescribed motion) is for planes only");
  switch (o.kind) {
    case ShapeKind::plane: {
      const double n = o.normal.norm();
      if (!(n > 0) || !o.normal.allFinite())
        fail(o, "plane normal must be a non-zero vector, got (" + num(o.normal[0]) + ", " + num(o.normal[1]) + ", " +
                    num(o.normal[2]) + ")");
      if (!std::isfinite(o.offset)) fail(o, "plane offset is not finite");
      for (std::size_t k = 0; k < o.offset_schedule.size(); ++k) {
        const auto& p = o.offset_schedule[k];
        if (!std::isfinite(p[0]) || !std::isfinite(p[1])) fail(o, "plane offset schedule: a time or offset is not finite");
        if (k > 0 && !(p[0] > o.offset_schedule[k - 1][0]))
          fail(o, "plane offset schedule: times must increase, got " + num(o.offset_schedule[k - 1][0]) + " then " +
                      num(p[0]));
      }
      // n . x = offset with the given n: the same plane with a unit normal.
      o.normal /= n;
      o.offset /= n;
      for (auto& p : o.offset_schedule) p[1] /= n;
      break;
    }
    case ShapeKind::box:
      for (int i = 0; i < 3; ++i) positive(o, "box half_extents", o.half_extents[i]);
      break;
    case ShapeKind::sphere: positive(o, "sphere radius", o.radius); break;
    case ShapeKind::capsule:
      positive(o, "capsule radius", o.radius);
      if (!(o.half_length >= 0) || !std::isfinite(o.half_length))
        fail(o, "capsule half_length must be >= 0, got " + num(o.half_length));
      break;
    case ShapeKind::cylinder:
      positive(o, "cylinder radius", o.radius);
      positive(o, "cylinder half_length", o.half_length);
      break;
    case ShapeKind::mesh: {
      const std::string problem = surface_problem(o.mesh);
      if (!problem.empty()) fail(o, "mesh: " + problem);
      const double v = signed_volume(o.mesh);
      const Eigen::AlignedBox3d b(o.mesh.vertices.rowwise().minCoeff(), o.mesh.vertices.rowwise().maxCoeff());
      if (!(std::abs(v) > 1e-12 * b.sizes().prod()))
        fail(o, "mesh encloses no volume (signed volume " + num(v) + ")");
      if (v < 0) o.mesh.triangles.row(1).swap(o.mesh.triangles.row(2));  // orient outward
      o.accel = build_accel(o.mesh);
      break;
    }
  }
  if (o.kind == ShapeKind::box || o.kind == ShapeKind::capsule || o.kind == ShapeKind::cylinder)
    if (!rotation_ok(o.rotation)) fail(o, "rotation is not a proper rotation matrix");
}

bool closest_point(const Obstacle& o, const Vec3& p, double max_distance, ClosestPoint& out) {
  switch (o.kind) {
    case ShapeKind::plane: {
      const double d = o.normal.dot(p) - o.offset;
      if (d > max_distance) return false;
      out.distance = d;
      out.point = p - d * o.normal;
      out.normal = o.normal;
      out.feature_kind = Feature::face;
      out.feature = 0;
      return true;
    }
    case ShapeKind::sphere: {
      sphere_local(p - o.center, o.radius, out);
      if (out.distance > max_distance) return false;
      out.point += o.center;
      return true;
    }
    case ShapeKind::box:
    case ShapeKind::capsule:
    case ShapeKind::cylinder: {
      const Vec3 q = o.rotation.transpose() * (p - o.center);
      if (o.kind == ShapeKind::box)
        box_local(q, o.half_extents, out);
      else if (o.kind == ShapeKind::capsule)
        capsule_local(q, o.radius, o.half_length, out);
      else
        cylinder_local(q, o.radius, o.half_length, out);
      if (out.distance > max_distance) return false;
      out.point = o.rotation * out.point + o.center;
      out.normal = o.rotation * out.normal;
      return true;
    }
    case ShapeKind::mesh: {
      if (!o.accel) return false;
      if (std::isfinite(max_distance) && box_distance2(o.accel->box, p) > max_distance * max_distance) return false;
      mesh_closest(o, p, out);
      return out.distance <= max_distance;
    }
  }
  return false;
}

Mat3 normal_derivative(const Obstacle& o, const Vec3& p, const ClosestPoint& cp) {
  const Vec3& n = cp.normal;
  const Mat3 I = Mat3::Identity();
  const Mat3 Pn = I - n * n.transpose();
  auto edge_term = [&](const Vec3& e, double d) -> Mat3 {
    return d > 0 ? Mat3((Pn - e * e.transpose()) / d) : Mat3::Zero();
  };
  auto point_term = [&](double d) -> Mat3 { return d > 0 ? Mat3(Pn / d) : Mat3::Zero(); };
  switch (o.kind) {
    case ShapeKind::plane: return Mat3::Zero();
    case ShapeKind::sphere: return point_term((p - o.center).norm());
    case ShapeKind::box:
    case ShapeKind::capsule:
    case ShapeKind::cylinder: {
      const Mat3& R = o.rotation;
      const Vec3 q = R.transpose() * (p - o.center);
      const Vec3 nl = R.transpose() * n;
      const Mat3 Pl = I - nl * nl.transpose();
      Mat3 local = Mat3::Zero();
      if (o.kind == ShapeKind::box) {
        if (cp.feature_kind == Feature::edge) {
          const int free_axis = (cp.feature - 6) / 4;
          local = (Pl - I.col(free_axis) * I.col(free_axis).transpose()) / (p - cp.point).norm();
        } else if (cp.feature_kind == Feature::vertex) {
          local = Pl / (p - cp.point).norm();
        }
      } else if (o.kind == ShapeKind::capsule) {
        const bool side = std::abs(q[2]) < o.half_length;
        const Vec3 axis_point(0, 0, std::clamp(q[2], -o.half_length, o.half_length));
        const double d = (q - axis_point).norm();
        if (d > 0) local = (side ? Mat3(Pl - I.col(2) * I.col(2).transpose()) : Pl) / d;
      } else {
        const double rho = std::hypot(q[0], q[1]);
        if (cp.feature_kind == Feature::smooth && rho > 0) {
          local = (Pl - I.col(2) * I.col(2).transpose()) / rho;
        } else if (cp.feature_kind == Feature::edge && rho > 0) {
          // The rim: closest point c = r u + zs e_z, u = (q_x, q_y, 0) / rho, so
          // dc/dq = (r / rho) (I - u u^T - e_z e_z^T); n = (q - c) / |q - c|.
          const Vec3 u(q[0] / rho, q[1] / rho, 0);
          const Mat3 dc = (o.radius / rho) * (I - u * u.transpose() - I.col(2) * I.col(2).transpose());
          const Vec3 c = o.radius * u + Vec3(0, 0, q[2] >= 0 ? o.half_length : -o.half_length);
          local = Pl * (I - dc) / (q - c).norm();
        }
      }
      return R * local * R.transpose();
    }
    case ShapeKind::mesh: {
      if (cp.feature_kind == Feature::face) return Mat3::Zero();
      const double d = (p - cp.point).norm();
      // The sign of n relative to p - point (inside: n = -(p - point)/d).
      const double s = n.dot(p - cp.point) < 0 ? -1.0 : 1.0;
      const auto& T = o.mesh.triangles;
      const int t = cp.feature;
      const Vec3 a = o.mesh.vertices.col(T(0, t)), b = o.mesh.vertices.col(T(1, t)), c = o.mesh.vertices.col(T(2, t));
      const PointTriangleResult r = point_triangle_closest(p, a, b, c);
      if (cp.feature_kind == Feature::vertex) return s * point_term(d);
      const Vec3 v[3] = {a, b, c};
      const Vec3 e = (v[(r.local + 1) % 3] - v[r.local]).normalized();
      return s * edge_term(e, d);
    }
  }
  return Mat3::Zero();
}

Eigen::AlignedBox3d bounding_box(const Obstacle& o) {
  switch (o.kind) {
    case ShapeKind::plane: {
      Vec3 lo = Vec3::Constant(-kInf), hi = Vec3::Constant(kInf);
      // The solid side n . x <= offset is bounded only along an axis-aligned normal.
      for (int i = 0; i < 3; ++i)
        if (std::abs(o.normal[i]) == 1) (o.normal[i] > 0 ? hi[i] : lo[i]) = o.normal[i] * o.offset;
      return {lo, hi};
    }
    case ShapeKind::box: {
      const Vec3 e = o.rotation.cwiseAbs() * o.half_extents;
      return {o.center - e, o.center + e};
    }
    case ShapeKind::sphere: return {o.center.array() - o.radius, o.center.array() + o.radius};
    case ShapeKind::capsule: {
      const Vec3 e = o.rotation.col(2).cwiseAbs() * o.half_length + Vec3::Constant(o.radius);
      return {o.center - e, o.center + e};
    }
    case ShapeKind::cylinder: {
      const Vec3 a = o.rotation.col(2);
      Vec3 e;
      for (int i = 0; i < 3; ++i) e[i] = std::abs(a[i]) * o.half_length + o.radius * std::sqrt(std::max(0.0, 1 - a[i] * a[i]));
      return {o.center - e, o.center + e};
    }
    case ShapeKind::mesh:
      if (o.mesh.vertices.cols() == 0) return {};
      return {o.mesh.vertices.rowwise().minCoeff(), o.mesh.vertices.rowwise().maxCoeff()};
  }
  return {};
}

// ------------------------------------------------------------------------------------
// Reading .stl and .msh surfaces.

namespace {

struct SurfaceReader {
  std::string path;
  [[noreturn]] void fail(const std::string& message) const { throw InputError(path + ": " + message); }
};

// Triangle soup (3 points per triangle) -> indexed surface (bit-identical points merged).
TriangleSurface weld(const std::vector<Vec3>& soup) {
  const int n = static_cast<int>(soup.size());
  std::vector<int> idx(n);
  std::iota(idx.begin(), idx.end(), 0);
  auto less = [&](int a, int b) {
    const Vec3 &p = soup[a], &q = soup[b];
    return std::tie(p[0], p[1], p[2], a) < std::tie(q[0], q[1], q[2], b);
  };
  std::sort(idx.begin(), idx.end(), less);
  std::vector<int> id(n);
  std::vector<Vec3> unique;
  for (int i = 0; i < n; ++i) {
    if (i == 0 || soup[idx[i]] != soup[idx[i - 1]]) unique.push_back(soup[idx[i]]);
    id[idx[i]] = static_cast<int>(unique.size()) - 1;
  }
  TriangleSurface s;
  s.vertices.resize(3, static_cast<int>(unique.size()));
  for (std::size_t i = 0; i < unique.size(); ++i) s.vertices.col(static_cast<int>(i)) = unique[i];
  s.triangles.resize(3, n / 3);
  for (int t = 0; t < n / 3; ++t)
    for (int k = 0; k < 3; ++k) s.triangles(k, t) = id[3 * t + k];
  return s;
}

TriangleSurface read_stl(const std::string& data, const SurfaceReader& rd) {
  std::vector<Vec3> soup;
  // Binary: 80-byte header, uint32 count, 50 bytes per triangle; the size must match.
  if (data.size() >= 84) {
    std::uint32_t count = 0;
    std::memcpy(&count, data.data() + 80, 4);
    if (data.size() == 84 + 50 * static_cast<std::size_t>(count)) {
      soup.reserve(3 * static_cast<std::size_t>(count));
      for (std::uint32_t t = 0; t < count; ++t) {
        const char* rec = data.data() + 84 + 50 * static_cast<std::size_t>(t);
        for (int k = 0; k < 3; ++k) {
          float v[3];
          std::memcpy(v, rec + 12 + 12 * k, 12);
          soup.emplace_back(v[0], v[1], v[2]);
        }
      }
      if (soup.empty()) rd.fail("empty: the binary STL has no triangles");
      return weld(soup);
    }
  }
  std::istringstream in(data);
  std::string word;
  if (!(in >> word) || word != "solid")
    rd.fail("not an STL file (neither a binary STL whose size matches its triangle count, nor ASCII 'solid ...')");
  std::string line;
  std::getline(in, line);
  int in_facet = 0;
  long line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ls(line);
    if (!(ls >> word)) continue;
    if (word == "vertex") {
      Vec3 p;
      if (!(ls >> p[0] >> p[1] >> p[2])) rd.fail("line " + std::to_string(line_no) + ": bad vertex");
      soup.push_back(p);
      ++in_facet;
    } else if (word == "endfacet") {
      if (in_facet != 3) rd.fail("line " + std::to_string(line_no) + ": a facet needs exactly 3 vertices");
      in_facet = 0;
    } else if (word == "endsolid") {
      break;
    }
  }
  if (soup.empty()) rd.fail("empty: the ASCII STL has no facets");
  if (soup.size() % 3 != 0) rd.fail("truncated facet");
  return weld(soup);
}

}  // namespace

TriangleSurface read_triangle_surface(const std::filesystem::path& file, double scale) {
  SurfaceReader rd{file.string()};
  if (!(scale > 0) || !std::isfinite(scale)) rd.fail("mesh_scale must be > 0, got " + num(scale));
  std::ifstream f(file, std::ios::binary);
  if (!f) rd.fail("cannot open the file");
  std::ostringstream buf;
  buf << f.rdbuf();
  const std::string data = buf.str();
  if (data.empty()) rd.fail("empty file");
  std::string ext = file.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  TriangleSurface s;
  if (ext == ".stl") {
    s = read_stl(data, rd);
  } else if (ext == ".msh") {
    // The Gmsh reader of the bodies' meshes (all versions and encodings, its messages).
    io::GmshTriangles t = io::read_gmsh_triangles(file);
    s.vertices = std::move(t.points);
    s.triangles = std::move(t.triangles);
  } else {
    rd.fail("unknown surface format '" + ext + "' (expected .stl or .msh)");
  }
  s.vertices *= scale;
  const std::string problem = surface_problem(s);
  if (!problem.empty()) rd.fail(problem);
  return s;
}

}  // namespace softdiff::collision
