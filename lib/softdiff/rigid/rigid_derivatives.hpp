#pragma once
// Derivatives of the rigid step (issue 21, item 4, without contact; docs/method.md
// "Derivatives", "Rigid bodies"). The step rigid::step(in) -> out of one body is
// differentiated exactly: the implicit function theorem on the angular Newton residual
// (free body), on the joint's scalar equation (hinge; a slider's is linear), and the
// exponential map's derivative for the orientation.
//
// A tangent of a RigidState has 12 entries: (dp, dtheta, dv, domega), dp the change of
// the centre of mass, dtheta the rotation vector of the orientation change in WORLD axes
// (q + dq = exp(dtheta) q, as the spec's /jacobians rows), dv, domega the velocities'
// changes (world). A body has 7 parameters: its mass, then its inertia about the centre
// of mass in body axes by component (xx, yy, zz, xy, xz, yz; an off-diagonal component
// moves both symmetric entries). Gravity is not a parameter.
//
// The step's Jacobian is a 12 x 12 block (state) and a 12 x 7 block (parameters),
// assembled in closed form from the step's record (in, out, its StepInfo): fixed-size,
// no allocation. A JVP or VJP is then one small product.
//
// Joint limits: when a limit is active at the end of the step (StepInfo::at_limit), the
// clamped joint coordinate c_{n+1} = limit does not depend on the inputs: d c_{n+1} = 0
// (one-sided derivatives at the instant of arrival differ; the step takes the clamped
// branch).
#include <softdiff/rigid/rigid_body.hpp>

#include <array>
#include <string>

namespace softdiff::rigid {

using Vec7 = Eigen::Matrix<double, 7, 1>;
using Vec12 = Eigen::Matrix<double, 12, 1>;
using Mat12 = Eigen::Matrix<double, 12, 12>;
using Mat12x7 = Eigen::Matrix<double, 12, 7>;

constexpr int kRigidParameters = 7;  // mass, inertia xx, yy, zz, xy, xz, yz
// "mass", "inertia.xx", ... (index 0..6).
std::string rigid_parameter_name(int index);

// One parameter of one rigid body (Model::rigid index).
struct RigidParameterId {
  int body = 0;
  int index = 0;  // 0 mass, 1..6 inertia xx, yy, zz, xy, xz, yz
  bool operator==(const RigidParameterId&) const = default;
};
double get_parameter(const RigidBody& body, int index);
// Throws std::invalid_argument for a mass <= 0 or an inertia that is not positive definite.
void set_parameter(RigidBody& body, int index, double value);

struct StepJacobian {
  Mat12 state = Mat12::Zero();     // d out / d in
  Mat12x7 params = Mat12x7::Zero();  // d out / d (mass, inertia)
};

// The Jacobian of step(body, in, h, gravity, force, torque, out) that returned info.
// (force and torque are held fixed: they are not inputs of the derivative. The torque
// enters the step only through its solution out: the angular residual's constant and
// the hinge's Q0, neither of which the Jacobians depend on; so it is not an argument.)
void step_jacobian(const RigidBody& body, const RigidState& in, const RigidState& out, const StepInfo& info, double h,
                   const Vec3& gravity, const Vec3& force, StepJacobian& J);

// The inertia component k (0..5: xx, yy, zz, xy, xz, yz; parameter index k + 1) as a unit
// symmetric matrix: dI / d(component k).
Mat3 inertia_unit(int k);

// d out = J.state d_in + J.params d_params.
Vec12 step_jvp(const StepJacobian& J, const Vec12& d_in, const Vec7& d_params);
// bar_in = J.state^T bar_out, bar_params = J.params^T bar_out.
void step_vjp(const StepJacobian& J, const Vec12& bar_out, Vec12& bar_in, Vec7& bar_params);

// The state moved along a tangent: p + e dp, exp(e dtheta) q, v + e dv, omega + e domega.
RigidState retract(const RigidState& s, const Vec12& d, double e);
// The tangent from `base` to `s`: (p - p_b, log(q q_b^-1), v - v_b, omega - omega_b), the
// rotation vector in world axes (finite differences of whole runs).
Vec12 tangent_between(const RigidState& base, const RigidState& s);

}  // namespace softdiff::rigid
