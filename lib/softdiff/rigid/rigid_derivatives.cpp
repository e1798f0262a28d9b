// Derivatives of the rigid step: see rigid_derivatives.hpp and docs/method.md
// "Derivatives", "Rigid bodies".
#include <softdiff/rigid/rigid_derivatives.hpp>
#include <softdiff/rigid/joint_equation.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <cmath>
#include <stdexcept>

namespace softdiff::rigid {
namespace {

constexpr int P = 0, TH = 3, V = 6, W = 9;  // blocks of a 12-tangent

// The inertia component `k` (0..5: xx, yy, zz, xy, xz, yz) as a unit symmetric matrix.
constexpr int kRow[6] = {0, 1, 2, 0, 0, 1}, kCol[6] = {0, 1, 2, 1, 2, 2};

}  // namespace

Mat3 inertia_unit(int k) {
  Mat3 S = Mat3::Zero();
  S(kRow[k], kCol[k]) = 1;
  S(kCol[k], kRow[k]) = 1;
  return S;
}

std::string rigid_parameter_name(int index) {
  static const char* names[kRigidParameters] = {"mass",       "inertia.xx", "inertia.yy", "inertia.zz",
                                                "inertia.xy", "inertia.xz", "inertia.yz"};
  return index >= 0 && index < kRigidParameters ? names[index] : "?";
}

double get_parameter(const RigidBody& body, int index) {
  if (index == 0) return body.mass;
  if (index < 1 || index >= kRigidParameters) throw std::invalid_argument("rigid parameter: no such index");
  return body.inertia(kRow[index - 1], kCol[index - 1]);
}

void set_parameter(RigidBody& body, int index, double value) {
  const std::string who = "rigid body '" + body.name + "': ";
  if (index == 0) {
    if (!(value > 0) || !std::isfinite(value)) throw std::invalid_argument(who + "mass must be positive and finite");
    body.mass = value;
    return;
  }
  if (index < 1 || index >= kRigidParameters) throw std::invalid_argument("rigid parameter: no such index");
  Mat3 I = body.inertia;
  I(kRow[index - 1], kCol[index - 1]) = value;
  I(kCol[index - 1], kRow[index - 1]) = value;
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(I, Eigen::EigenvaluesOnly);
  if (!std::isfinite(value) || !(eig.eigenvalues()[0] > 0))
    throw std::invalid_argument(who + rigid_parameter_name(index) + " = " + std::to_string(value) +
                                " makes the inertia not positive definite");
  body.inertia = I;
}

void step_jacobian(const RigidBody& body, const RigidState& in, const RigidState& out, const StepInfo& info, double h,
                   const Vec3& gravity, const Vec3& force, StepJacobian& J) {
  J.state.setZero();
  J.params.setZero();
  const Mat3 I3 = Mat3::Identity();
  const double m = body.mass;
  const Vec3 F = m * gravity + force;
  const Mat3 R = in.orientation.toRotationMatrix();
  const Mat3 A = R * body.inertia * R.transpose();
  switch (body.joint.kind) {
    case Joint::Kind::free: {
      // v' = v + h (g + f/m), p' = p + h v'.
      J.state.block<3, 3>(V, V) = I3;
      J.params.block<3, 1>(V, 0) = -h * force / (m * m);
      J.state.block<3, 3>(P, P) = I3;
      J.state.block<3, 3>(P, V) = h * I3;
      J.params.block<3, 1>(P, 0) = h * J.params.block<3, 1>(V, 0);
      // r(omega', A, omega) = E(h omega') A omega' - A omega - h tau = 0 (the implicit
      // function theorem): D dw' = -(dr/dA)[dA] + A dw, D = dr/domega' at omega'. With
      // q -> exp(dtheta) q, dA x = dtheta x (A x) - A (dtheta x x) = (A [x] - [A x]) dtheta.
      const Vec3& w = in.angular_velocity;
      const Vec3& w1 = out.angular_velocity;
      const Mat3 E = quaternion_exp(h * w1).toRotationMatrix();
      const Eigen::PartialPivLU<Mat3> D(angular_residual_jacobian(A, h, w1));
      const Mat3 dr_dtheta = E * (A * hat(w1) - hat(A * w1)) - (A * hat(w) - hat(A * w));
      const Mat3 dw_dtheta = -D.solve(dr_dtheta);
      const Mat3 dw_dw = D.solve(A);
      // q' = exp(h omega') q: exp(h (omega' + dw')) exp(dtheta) q = exp(E (dtheta + h J_r(h omega') dw')) q'.
      const Mat3 B = h * E * right_jacobian(h * w1);
      J.state.block<3, 3>(W, TH) = dw_dtheta;
      J.state.block<3, 3>(W, W) = dw_dw;
      J.state.block<3, 3>(TH, TH) = E + B * dw_dtheta;
      J.state.block<3, 3>(TH, W) = B * dw_dw;
      for (int k = 0; k < 6; ++k) {
        const Mat3 dA = R * inertia_unit(k) * R.transpose();
        const Vec3 dw = -D.solve(Vec3(E * (dA * w1) - dA * w));
        J.params.block<3, 1>(W, 1 + k) = dw;
        J.params.block<3, 1>(TH, 1 + k) = B * dw;
      }
      break;
    }
    case Joint::Kind::fixed:
      // The pose is carried over, the velocities are zero.
      J.state.block<3, 3>(P, P) = I3;
      J.state.block<3, 3>(TH, TH) = I3;
      break;
    case Joint::Kind::hinge:
    case Joint::Kind::slider: {
      // delta = c_{n+1} - c_n and its gradients (1 x 12 state, 1 x 7 parameters).
      const Vec3 n = body.joint.axis;
      const bool hinge = body.joint.kind == Joint::Kind::hinge;
      const double delta = hinge ? h * n.dot(out.angular_velocity) : n.dot(out.position - in.position);
      Eigen::Matrix<double, 1, 12> gs = Eigen::Matrix<double, 1, 12>::Zero();
      Eigen::Matrix<double, 1, 7> gp = Eigen::Matrix<double, 1, 7>::Zero();
      if (info.at_limit) {
        // c_{n+1} = limit: d delta = -d c_n; c_n = n.(p - p_0) (slider), the angle of
        // q q_0^-1 about n (hinge: d c_n = n.dtheta on the joint).
        gs.segment<3>(hinge ? TH : P) = -n.transpose();
      } else if (!hinge) {
        // delta = h n.v + h^2 n.(g + f/m).
        gs.segment<3>(V) = h * n.transpose();
        gp(0) = -h * h * n.dot(force) / (m * m);
      } else {
        // g(delta) = I_a (delta/h - cdot) - h (Q0 + c1 cos delta - c2 sin delta) = 0.
        const Mat3 Pn = I3 - n * n.transpose();
        const Vec3 r_perp = Pn * (in.position - body.joint.anchor);
        const double I_a = n.dot(A * n) + m * r_perp.squaredNorm();
        const double cdot = n.dot(in.angular_velocity);
        const double c1 = F.dot(n.cross(r_perp)), c2 = F.dot(r_perp);
        const double dg = JointEquation{I_a, cdot, 0, c1, c2, h}.dg(delta);  // (Q0 does not enter dg)
        const double g_Ia = delta / h - cdot, g_cdot = -I_a, g_c1 = -h * std::cos(delta), g_c2 = h * std::sin(delta);
        // dI_a = 2 m r_perp.dp + 2 ((A n) x n).dtheta + |r_perp|^2 dm + n.(R dI R^T) n;
        // dcdot = n.domega; dc1 = (Pn (F x n)).dp + g.(n x r_perp) dm; dc2 = (Pn F).dp + g.r_perp dm.
        gs.segment<3>(P) = -(g_Ia * 2 * m * r_perp + g_c1 * Pn * F.cross(n) + g_c2 * Pn * F).transpose() / dg;
        gs.segment<3>(TH) = -(g_Ia * 2 * (A * n).cross(n)).transpose() / dg;
        gs.segment<3>(W) = -(g_cdot * n).transpose() / dg;
        gp(0) = -(g_Ia * r_perp.squaredNorm() + g_c1 * gravity.dot(n.cross(r_perp)) + g_c2 * gravity.dot(r_perp)) / dg;
        for (int k = 0; k < 6; ++k) gp(1 + k) = -g_Ia * n.dot(R * inertia_unit(k) * R.transpose() * n) / dg;
      }
      if (hinge) {
        // q' = exp(delta n) q, p' = a + exp(delta n)(p - a), omega' = delta/h n,
        // v' = omega' x (p' - a).
        const Mat3 Rd = Eigen::AngleAxisd(delta, n).toRotationMatrix();
        const Vec3 t = n.cross(out.position - body.joint.anchor);
        J.state.block<3, 12>(P, 0) = t * gs;
        J.state.block<3, 3>(P, P) += Rd;
        J.state.block<3, 12>(TH, 0) = n * gs;
        J.state.block<3, 3>(TH, TH) += Rd;
        J.state.block<3, 12>(W, 0) = n * gs / h;
        J.state.block<3, 12>(V, 0) = t * gs / h + delta / h * hat(n) * J.state.block<3, 12>(P, 0);
        J.params.block<3, 7>(P, 0) = t * gp;
        J.params.block<3, 7>(TH, 0) = n * gp;
        J.params.block<3, 7>(W, 0) = n * gp / h;
        J.params.block<3, 7>(V, 0) = t * gp / h + delta / h * hat(n) * J.params.block<3, 7>(P, 0);
      } else {
        // p' = p + delta n, v' = delta/h n, q' = q, omega' = 0.
        J.state.block<3, 12>(P, 0) = n * gs;
        J.state.block<3, 3>(P, P) += I3;
        J.state.block<3, 3>(TH, TH) = I3;
        J.state.block<3, 12>(V, 0) = n * gs / h;
        J.params.block<3, 7>(P, 0) = n * gp;
        J.params.block<3, 7>(V, 0) = n * gp / h;
      }
      break;
    }
  }
}

Vec12 step_jvp(const StepJacobian& J, const Vec12& d_in, const Vec7& d_params) {
  return J.state * d_in + J.params * d_params;
}

void step_vjp(const StepJacobian& J, const Vec12& bar_out, Vec12& bar_in, Vec7& bar_params) {
  bar_in.noalias() = J.state.transpose() * bar_out;
  bar_params.noalias() = J.params.transpose() * bar_out;
}

RigidState retract(const RigidState& s, const Vec12& d, double e) {
  RigidState r = s;
  r.position += e * d.segment<3>(P);
  r.orientation = (quaternion_exp(e * d.segment<3>(TH)) * s.orientation).normalized();
  r.velocity += e * d.segment<3>(V);
  r.angular_velocity += e * d.segment<3>(W);
  return r;
}

Vec12 tangent_between(const RigidState& base, const RigidState& s) {
  Eigen::Quaterniond dq = s.orientation * base.orientation.conjugate();
  if (dq.w() < 0) dq.coeffs() = -dq.coeffs();  // the shorter way round
  const Vec3 u = dq.vec();
  const double sn = u.norm();
  const Vec3 rotvec = sn > 0 ? Vec3(2 * std::atan2(sn, dq.w()) / sn * u) : Vec3(2 * u);
  Vec12 d;
  d << s.position - base.position, rotvec, s.velocity - base.velocity, s.angular_velocity - base.angular_velocity;
  return d;
}

}  // namespace softdiff::rigid
