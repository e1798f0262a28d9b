#pragma once
// The joint's scalar step equation (docs/method.md "Rigid bodies", Joints): the end of
// step motion along a joint coordinate c is c_{n+1} = c_n + delta with delta = h cdot_{n+1},
//   g(delta) = I_a (delta / h - cdot_n) - h Q(delta) = 0,
// where the generalized force Q(delta) = Q0 + c1 cos(delta) - c2 sin(delta) (hinge: the
// torque about the axis, with c1 = F.(n x r_perp), c2 = F.r_perp) or Q0 (slider).
// g is increasing when h^2 sqrt(c1^2 + c2^2) < I_a (any step that resolves the
// pendulum's swing); its root then lies within h^2 Q_max / I_a of h cdot_n.
#include <cmath>

namespace softdiff::rigid {

struct JointEquation {
  double I_a = 0, cdot = 0, Q0 = 0, c1 = 0, c2 = 0, h = 0;
  double Q(double d) const { return Q0 + c1 * std::cos(d) - c2 * std::sin(d); }
  double g(double d) const { return I_a * (d / h - cdot) - h * Q(d); }
  double dg(double d) const { return I_a / h + h * (c1 * std::sin(d) + c2 * std::cos(d)); }
};

}  // namespace softdiff::rigid
