#pragma once
// Rigid bodies (issue 21): shapes, tessellation, mass properties and one implicit step
// with joints to the world (fixed, hinge, slider) and exact limits. A pure library: the
// scene, Model/State and output hooks live elsewhere. docs/method.md "Rigid bodies"
// documents the parametrization and the step equations.
#include <softdiff/core/types.hpp>
#include <Eigen/Geometry>
#include <optional>
#include <string>
#include <utility>

namespace softdiff::rigid {

using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

struct Shape {
  enum class Kind { box, sphere, capsule, cylinder, mesh } kind = Kind::box;
  Vec3 half_extents = Vec3::Zero();  // box
  double radius = 0;                 // sphere, capsule, cylinder
  double length = 0;                 // capsule (of the segment), cylinder: along body z
  Mat3X mesh_vertices;               // mesh: a closed, outward-oriented triangle surface,
  Triangles mesh_triangles;          //   in body axes as read (after mesh_scale)
};

struct MassProperties {
  double mass = 0;
  Vec3 centre = Vec3::Zero();        // centre of mass in the shape's axes (0 for primitives)
  Mat3 inertia = Mat3::Zero();       // about the centre of mass, body axes
};
// Uniform density. mesh: divergence theorem over the closed surface. Throws
// std::invalid_argument with a clear message for an open or inside-out mesh surface
// (non-positive volume).
MassProperties mass_properties(const Shape& shape, double density);

struct Surface {                     // body axes, centre of mass at the origin
  Mat3X vertices;
  Triangles triangles;               // outward
};
// A closed triangulation of the shape (mesh: its own triangles shifted by -centre);
// max_edge sets the resolution of curved primitives.
Surface tessellate(const Shape& shape, const Vec3& centre, double max_edge);

struct Joint {
  enum class Kind { free, fixed, hinge, slider } kind = Kind::free;
  Vec3 anchor = Vec3::Zero();        // world, at t = 0
  Vec3 axis = Vec3::UnitZ();         // world, at t = 0, unit (hinge, slider)
  std::optional<std::pair<double, double>> limits;  // rad (hinge) or m (slider)
};

struct RigidState {
  Vec3 position = Vec3::Zero();      // centre of mass, world
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();  // body to world
  Vec3 velocity = Vec3::Zero();      // of the centre of mass, world
  Vec3 angular_velocity = Vec3::Zero();  // world
};

struct RigidBody {
  std::string name;
  Shape shape;
  Surface surface;
  double mass = 0;
  Mat3 inertia = Mat3::Zero();       // about the centre of mass, body axes, SPD
  Joint joint;
  // Set by initialize(): the joint's anchor and axis in body axes, the reference
  // orientation/position for the joint coordinate (angle or slide) measured from t = 0.
  Vec3 anchor_body = Vec3::Zero();
  Vec3 axis_body = Vec3::UnitZ();
  RigidState reference;
  // Set by initialize() for a hinge: the largest distance of a surface vertex from the
  // axis (m; invariant: the body turns about that axis), 0 without a surface. The contact
  // stage's limit rows convert the detection margin into an angle with it
  // (contact/rigid_contact.hpp select_limit_rows).
  double joint_reach = 0;
};
// Checks (mass > 0, inertia SPD, unit quaternion within 1e-9 after normalization is the
// caller's job), computes the joint's body-frame data, and projects the initial
// velocity onto the joint's motion (throws std::invalid_argument if the initial
// state violates the joint beyond 1e-9 or lies outside its limits).
void initialize(RigidBody& body, const RigidState& initial);

// The joint coordinate (hinge angle in rad, slider travel in m) of a state; 0 at t = 0.
double joint_coordinate(const RigidBody& body, const RigidState& state);

// angle + 2 pi k in [centre - pi, centre + pi) (a hinge angle wrapped into the window
// about centre; BDF2's angle differences use centre 0).
double wrap_angle(double angle, double centre);

struct StepInfo {
  bool at_limit = false;             // a joint limit was active at the end of the step
  // The branch the step took (rigid::bdf2_step, rigid_bdf2.hpp): true for BDF2 (rigid::step
  // of 2h/3 from the extrapolated state), false for implicit Euler of size h (rigid::step
  // itself; bdf2_step's first step, restart, or BDF2 end reaching a limit). The step's
  // derivatives read it (rigid_bdf2_derivatives.hpp): the branch is never decided again.
  bool bdf2 = false;
  // Hinge, slider: the joint rate the step would end with without its limits (the
  // unconstrained root / h, before the clamp; the end rate when no limit acted). The
  // contact stage's free rate of a limited joint, whose limits are rows of the NCP
  // (contact/rigid_contact.hpp begin_rigid_contact). 0 for free and fixed bodies.
  double free_rate = 0;
  Vec3 constraint_force = Vec3::Zero();   // joint reaction on the body, world (N)
  Vec3 constraint_torque = Vec3::Zero();  // about the centre of mass, world (N m)
};
// One implicit step of length h under gravity and an external wrench (world, force at the
// centre of mass). Joint constraints (fixed, hinge, slider) and limits (unilateral, exact:
// no penalty, no springs) are enforced at the end of the step. The state out must not alias in.
// Free: implicit Euler on (v, omega) with the gyroscopic term implicit (Newton on omega).
// Hinge, slider: implicit Euler in the joint coordinate (the body moves exactly on the
// joint), a limit clamps the coordinate (the exact solution of the size-1 LCP); the
// reaction is the momentum change over h minus the applied loads. Throws
// std::invalid_argument for a bad call (h <= 0, out aliasing in) and softdiff's
// ComputationError naming the body for a non-finite state or load or a Newton solve that
// does not converge (the caller adds the step number).
// enforce_limits = false steps a limited joint as if it had none (the contact stage's
// free step: there the limit is a row of the NCP, contact/rigid_contact.hpp).
StepInfo step(const RigidBody& body, const RigidState& in, double h, const Vec3& gravity,
              const Vec3& force, const Vec3& torque, RigidState& out, bool enforce_limits = true);

// The end of a hinge or slider step that moves the joint coordinate by delta over h: the
// body exactly on its joint (hinge: q = exp(delta n / 2) q_n, x = anchor + exp(delta n)
// (x_n - anchor); slider: x = x_n + delta n, q = q_n) with the joint rate delta / h.
// Shared by step and the contact stage's end (contact/rigid_contact.hpp). Other joints:
// a precondition violation.
void move_along_joint(const RigidBody& body, const RigidState& in, double delta, double h, RigidState& out);

// Every entry of the state finite (pose, orientation, velocities).
bool finite(const RigidState& s);
// The inertia about the centre of mass in world axes at orientation q: R I R^T.
Mat3 world_inertia(const RigidBody& b, const Eigen::Quaterniond& q);

// The body's surface vertices in world coordinates for a state (output, XDMF).
Mat3X world_vertices(const RigidBody& body, const RigidState& state);

// Extensions (for the contact rows of later increments; docs/method.md "Rigid bodies").
// The 6x6 Newton matrix A of the unconstrained step's velocity update, at the step
// in -> out: rows and columns are (linear velocity, angular velocity), world axes;
// A = diag(m I, dr/domega) with r(omega) = exp(h [omega]) I_w(q_n) omega - L_n - h tau
// the angular residual. A contact impulse p (6) changes the end velocities by A^{-1} p,
// so the Delassus block of a contact Jacobian H_r (k x 6) is H_r A^{-1} H_r^T; with a
// joint, reduce A by the joint's motion basis T (joint_motion_basis): T^T A T.
Mat6 step_matrix(const RigidBody& body, const RigidState& in, const RigidState& out, double h);

// The joint's allowed velocities at a state: 6 x k, (v, omega) = T qdot. free: the 6x6
// identity; fixed: 6 x 0; hinge: [n x (x - anchor); n]; slider: [n; 0]. Fixed-size
// storage (at most 6 columns, cols() = k): no allocation, so it may be called in the
// per-limit and per-body loops of every step and derivative.
using JointBasis = Eigen::Matrix<double, 6, Eigen::Dynamic, Eigen::ColMajor, 6, 6>;
JointBasis joint_motion_basis(const RigidBody& body, const RigidState& state);

}  // namespace softdiff::rigid
