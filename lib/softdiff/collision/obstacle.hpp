#pragma once
// Static rigid obstacles (scene.md `obstacles`) and exact signed-distance queries.
//
// Every query returns the signed distance from a point to the obstacle's surface
// (< 0 inside), the closest point on the surface, and the unit outward normal
// there, which points from the obstacle towards the query point (the contact
// normal n of method.md). Plane, box, sphere, capsule and cylinder are closed
// form. A mesh obstacle is a closed, consistently oriented triangle surface
// (read from .msh triangles or .stl); its nearest triangle is found through a
// bounding-volume hierarchy built once (FCL), and the sign through the
// angle-weighted pseudo-normal of the nearest feature (exact for closed surfaces).
#include <softdiff/collision/contact_set.hpp>
#include <softdiff/core/types.hpp>

#include <Eigen/Geometry>
#include <array>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace softdiff::collision {

enum class ShapeKind { plane, box, sphere, capsule, cylinder, mesh };

// A closed triangle surface, in world coordinates, triangles oriented outward.
struct TriangleSurface {
  Mat3X vertices;
  Triangles triangles;
};

struct MeshAccel;  // opaque: the BVH and the pseudo-normals of a mesh obstacle

struct Obstacle {
  std::string name;
  ShapeKind kind = ShapeKind::plane;
  // Pose of box, capsule, cylinder: world = rotation * local + center. The local
  // axis of capsule and cylinder is z. Sphere: center only.
  Mat3 rotation = Mat3::Identity();
  Vec3 center = Vec3::Zero();
  Vec3 normal{0, 0, 1};          // plane: unit normal into the free side
  double offset = 0;             // plane: normal . x = offset
  // plane (extension): a prescribed motion along the normal, offset(t) piecewise linear
  // through (t_k, offset_k) (times increasing), held constant outside; empty: static.
  // The detector sets `offset` from it at each step's end time (CollisionDetector::set_time).
  std::vector<std::array<double, 2>> offset_schedule;
  Vec3 half_extents = Vec3::Zero();  // box
  double radius = 0;             // sphere, capsule, cylinder
  double half_length = 0;        // capsule (segment half length), cylinder (half height)
  TriangleSurface mesh;          // mesh (world coordinates, after mesh_scale)
  std::shared_ptr<const MeshAccel> accel;  // mesh: built by prepare()
};

struct ClosestPoint {
  double distance = 0;          // signed: < 0 inside the obstacle
  Vec3 point = Vec3::Zero();    // closest point on the obstacle's surface
  Vec3 normal{0, 0, 1};         // unit outward normal at `point`, from the obstacle towards the query
  Feature feature_kind = Feature::face;
  int feature = -1;             // box: face 0..5 (-x,+x,-y,+y,-z,+z), edge 6..17, vertex 18..25;
                                // mesh: triangle index; others: 0
};

// Checks the parameters (unit normal, positive sizes, closed and oriented mesh)
// and builds the mesh BVH. Throws InputError naming the obstacle and the problem.
void prepare(Obstacle& obstacle);

// A plane's offset at time t: its schedule's piecewise-linear value (held constant
// outside the schedule's times), or `offset` without a schedule.
double plane_offset_at(const Obstacle& obstacle, double t);

// The exact signed distance query. Returns false (and leaves `out` unspecified)
// only when the point is certainly farther than max_distance from the surface
// (a fast reject); otherwise fills `out`. Points inside are never rejected.
bool closest_point(const Obstacle& obstacle, const Vec3& p, double max_distance, ClosestPoint& out);

// dn/dp: the derivative of the outward normal of closest_point at p (the Hessian of
// the signed distance; its gradient, the derivative of `distance`, is n itself), for
// the feature cp reports (cp = closest_point(obstacle, p)): zero on a face (plane, box
// face, cylinder cap, mesh triangle); (I - n n^T - e e^T) / d along an edge of
// direction e (box, mesh, capsule side and cylinder side about their axis) and
// (I - n n^T) / d at a vertex or a sphere (d the distance to the edge, vertex, axis or
// center; with the sign of n's orientation for a mesh point inside); the cylinder's
// rim includes the turning of its closest point on the circle.
Mat3 normal_derivative(const Obstacle& obstacle, const Vec3& p, const ClosestPoint& cp);

// World bounding box of the obstacle (planes: unbounded, i.e. +-infinity
// on the unbounded axes).
Eigen::AlignedBox3d bounding_box(const Obstacle& obstacle);

// Reads a closed triangle surface from .stl (ASCII or binary) or .msh (its
// triangles, all physical groups), scaled by `scale`. Throws InputError
// "FILE: message" for unreadable, empty, open or non-manifold surfaces.
TriangleSurface read_triangle_surface(const std::filesystem::path& file, double scale);

}  // namespace softdiff::collision
