#pragma once
// Rotation helpers of the rigid step (docs/method.md "Rigid bodies"): the hat map, the
// exact exponential map of a rotation vector, SO(3)'s right Jacobian, and the implicit
// angular update's residual and its Jacobian (tests/rigid checks it by central differences).
#include <softdiff/core/types.hpp>
#include <Eigen/Geometry>

namespace softdiff::rigid {

// [a] b = a x b.
Mat3 hat(const Vec3& a);

// The unit quaternion of the rotation by |phi| about phi / |phi| (exact; a Taylor series
// below |phi| = 1e-4 where sin(x/2)/x loses digits).
Eigen::Quaterniond quaternion_exp(const Vec3& phi);

// Its inverse: the rotation vector of a unit quaternion, |phi| <= pi (q and -q give the
// same; exact, atan2 of the vector part's norm).
Vec3 quaternion_log(Eigen::Quaterniond q);

// J_r(phi) = I - (1 - cos t)/t^2 [phi] + (t - sin t)/t^3 [phi]^2, t = |phi|:
// exp([phi + d]) = exp([phi]) exp([J_r(phi) d]) to first order in d.
Mat3 right_jacobian(const Vec3& phi);

// The angular update of the step: with A = I_w(q_n) = R_n I R_n^T and the target
// momentum L = A omega_n + h tau (+ the joint's reaction impulse),
//   r(omega) = exp(h [omega]) A omega - L  (= I_w(q_{n+1}) omega - L, since the rotation
//   exp(h [omega]) fixes omega), and
//   dr/domega = E A - h E [A omega] J_r(h omega),  E = exp(h [omega]).
Vec3 angular_residual(const Mat3& A, const Vec3& L, double h, const Vec3& omega);
Mat3 angular_residual_jacobian(const Mat3& A, double h, const Vec3& omega);

}  // namespace softdiff::rigid
