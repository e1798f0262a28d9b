// BDF2 for a rigid body: see rigid_bdf2.hpp.
#include <softdiff/rigid/rigid_bdf2.hpp>

#include <softdiff/core/error.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/Cholesky>
#include <cmath>
#include <numbers>
#include <stdexcept>

namespace softdiff::rigid {
void bdf2_extrapolate(const RigidBody& body, const RigidState& in, const RigidState& previous, RigidState& hat) {
  if (&hat == &in || &hat == &previous)
    throw std::invalid_argument("rigid body '" + body.name + "': bdf2_extrapolate's hat must not alias its inputs");
  constexpr double c = 1.0 / 3.0;
  hat = in;
  const Joint& j = body.joint;
  switch (j.kind) {
    case Joint::Kind::free: {
      hat.position = (1 + c) * in.position - c * previous.position;
      hat.velocity = (1 + c) * in.velocity - c * previous.velocity;
      const Vec3 phi_prev = quaternion_log(previous.orientation * in.orientation.conjugate());
      hat.orientation = (quaternion_exp(-c * phi_prev) * in.orientation).normalized();
      const Vec3 L = (1 + c) * (world_inertia(body, in.orientation) * in.angular_velocity) -
                     c * (world_inertia(body, previous.orientation) * previous.angular_velocity);
      hat.angular_velocity = world_inertia(body, hat.orientation).llt().solve(L);
      break;
    }
    case Joint::Kind::fixed: break;
    case Joint::Kind::hinge:
    case Joint::Kind::slider: {
      const bool hinge = j.kind == Joint::Kind::hinge;
      const Vec3 n = j.axis;
      double dc = joint_coordinate(body, in) - joint_coordinate(body, previous);
      if (hinge) dc = wrap_angle(dc, 0);
      const double rate_n = n.dot(hinge ? in.angular_velocity : in.velocity);
      const double rate_p = n.dot(hinge ? previous.angular_velocity : previous.velocity);
      const double rate = (1 + c) * rate_n - c * rate_p;
      move_along_joint(body, in, c * dc, 1.0, hat);
      if (hinge) {
        hat.angular_velocity = rate * n;
        hat.velocity = rate * n.cross(hat.position - j.anchor);
      } else {
        hat.velocity = rate * n;
      }
      break;
    }
  }
  if (!finite(hat))
    throw ComputationError("rigid body '" + body.name + "': the BDF2 extrapolation is not finite");
}

StepInfo bdf2_step(const RigidBody& body, const RigidState& in, const RigidState* previous, double h,
                   const Vec3& gravity, const Vec3& force, const Vec3& torque, RigidState& hat, RigidState& out,
                   bool enforce_limits, bool restart, double* h_used) {
  if (previous && !restart) {
    bdf2_extrapolate(body, in, *previous, hat);
    const double h2 = 2.0 * h / 3.0;
    StepInfo info = step(body, hat, h2, gravity, force, torque, out, enforce_limits);
    if (!info.at_limit) {
      if (h_used) *h_used = h2;
      info.bdf2 = true;  // the step's record of its branch (StepInfo::bdf2)
      return info;
    }
  }
  // Implicit Euler of size h: the first step, a restart, or the step reaching a limit.
  hat = in;
  if (h_used) *h_used = h;
  return step(body, in, h, gravity, force, torque, out, enforce_limits);
}

}  // namespace softdiff::rigid
