// Derivatives of the rigid BDF2 step: see rigid_bdf2_derivatives.hpp.
#include <softdiff/rigid/rigid_bdf2_derivatives.hpp>
#include <softdiff/rigid/rigid_bdf2.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/LU>

#include <stdexcept>
#include <tuple>

namespace softdiff::rigid {
namespace {
constexpr int P = 0, TH = 3, V = 6, W = 9;  // blocks of a 12-tangent
constexpr double c = 1.0 / 3.0;
// d(A x) for q -> exp(dtheta) q: (A [x] - [A x]) dtheta.
Mat3 inertia_turn(const Mat3& A, const Vec3& x) { return A * hat(x) - hat(A * x); }
}  // namespace

void extrapolation_jacobian(const RigidBody& body, const RigidState& in, const RigidState& previous,
                            const RigidState& hat_state, ExtrapolationJacobian& E) {
  E.in.setZero();
  E.previous.setZero();
  E.params.setZero();
  const Mat3 I3 = Mat3::Identity();
  const Joint& j = body.joint;
  switch (j.kind) {
    case Joint::Kind::free: {
      E.in.block<3, 3>(P, P) = (1 + c) * I3;
      E.previous.block<3, 3>(P, P) = -c * I3;
      E.in.block<3, 3>(V, V) = (1 + c) * I3;
      E.previous.block<3, 3>(V, V) = -c * I3;
      const Vec3 phi = quaternion_log(previous.orientation * in.orientation.conjugate());
      // d phi = Jl_inv b - Jr_inv a; dtheta^ = R(-c phi) a - c J_l(-c phi) d phi.
      const Mat3 Jr_inv = right_jacobian(phi).inverse(), Jl_inv = right_jacobian(-phi).inverse();
      const Mat3 Jl_c = right_jacobian(c * phi);  // J_l(-c phi) = J_r(c phi)
      const Mat3 Rc = quaternion_exp(-c * phi).toRotationMatrix();
      const Mat3 th_a = Rc + c * Jl_c * Jr_inv, th_b = -c * Jl_c * Jl_inv;
      E.in.block<3, 3>(TH, TH) = th_a;
      E.previous.block<3, 3>(TH, TH) = th_b;
      // omega^ = A^-1 L^.
      const Mat3 Rn = in.orientation.toRotationMatrix(), Rp = previous.orientation.toRotationMatrix(),
                 Rh = hat_state.orientation.toRotationMatrix();
      const Mat3 An = Rn * body.inertia * Rn.transpose(), Ap = Rp * body.inertia * Rp.transpose(),
                 Ah = Rh * body.inertia * Rh.transpose();
      const Eigen::PartialPivLU<Mat3> Ah_lu(Ah);
      const Vec3& wn = in.angular_velocity;
      const Vec3& wp = previous.angular_velocity;
      const Vec3& wh = hat_state.angular_velocity;
      const Mat3 turn_h = inertia_turn(Ah, wh);
      // dL^ - turn_h dtheta^, by input block.
      E.in.block<3, 3>(W, W) = Ah_lu.solve(Mat3((1 + c) * An));
      E.previous.block<3, 3>(W, W) = Ah_lu.solve(Mat3(-c * Ap));
      E.in.block<3, 3>(W, TH) = Ah_lu.solve(Mat3((1 + c) * inertia_turn(An, wn) - turn_h * th_a));
      E.previous.block<3, 3>(W, TH) = Ah_lu.solve(Mat3(-c * inertia_turn(Ap, wp) - turn_h * th_b));
      for (int k = 0; k < 6; ++k) {
        const Mat3 S = inertia_unit(k);
        const Vec3 rhs = (1 + c) * (Rn * S * Rn.transpose() * wn) - c * (Rp * S * Rp.transpose() * wp) -
                         Rh * S * Rh.transpose() * wh;
        E.params.block<3, 1>(W, 1 + k) = Ah_lu.solve(rhs);
      }
      break;
    }
    case Joint::Kind::fixed: E.in.setIdentity(); break;
    case Joint::Kind::hinge:
    case Joint::Kind::slider: {
      const bool hinge = j.kind == Joint::Kind::hinge;
      const Vec3 n = j.axis;
      // e = c (c_n - c_{n-1}), d c = n.dtheta (hinge) or n.dp (slider): 1 x 12 rows.
      Eigen::Matrix<double, 1, 12> de_in = Eigen::Matrix<double, 1, 12>::Zero(), de_prev = de_in;
      de_in.segment<3>(hinge ? TH : P) = c * n.transpose();
      de_prev.segment<3>(hinge ? TH : P) = -c * n.transpose();
      // rate = (1 + c) n.omega_n - c n.omega_{n-1} (n.v for a slider).
      Eigen::Matrix<double, 1, 12> dr_in = Eigen::Matrix<double, 1, 12>::Zero(), dr_prev = dr_in;
      dr_in.segment<3>(hinge ? W : V) = (1 + c) * n.transpose();
      dr_prev.segment<3>(hinge ? W : V) = -c * n.transpose();
      if (hinge) {
        const double e = c * wrap_angle(joint_coordinate(body, in) - joint_coordinate(body, previous), 0);
        const Mat3 Re = Eigen::AngleAxisd(e, n).toRotationMatrix();
        const Vec3 t = n.cross(hat_state.position - j.anchor);
        const double rate = n.dot(hat_state.angular_velocity);
        for (auto [Ex, de, dr, own] : {std::tuple{&E.in, de_in, dr_in, true}, std::tuple{&E.previous, de_prev, dr_prev, false}}) {
          Mat12& M = *Ex;
          M.block<3, 12>(P, 0) = t * de;
          M.block<3, 12>(TH, 0) = n * de;
          if (own) {
            M.block<3, 3>(P, P) += Re;
            M.block<3, 3>(TH, TH) += Re;
          }
          M.block<3, 12>(W, 0) = n * dr;
          // v^ = rate n x (p^ - a).
          M.block<3, 12>(V, 0) = t * dr + rate * hat(n) * M.block<3, 12>(P, 0);
        }
      } else {
        for (auto [Ex, de, dr, own] : {std::tuple{&E.in, de_in, dr_in, true}, std::tuple{&E.previous, de_prev, dr_prev, false}}) {
          Mat12& M = *Ex;
          M.block<3, 12>(P, 0) = n * de;
          M.block<3, 12>(V, 0) = n * dr;
          if (own) {
            M.block<3, 3>(P, P) += I3;
            M.block<3, 3>(TH, TH) = I3;  // q^ = q_n; omega^ = 0 (move_along_joint)
          }
        }
      }
      break;
    }
  }
}

void bdf2_step_jacobian(const RigidBody& body, const RigidState& in, const RigidState* previous,
                        const RigidState& hat_state, const RigidState& out, const StepInfo& info, double h,
                        const Vec3& gravity, Bdf2StepJacobian& J) {
  J.bdf2 = info.bdf2;  // the branch the step recorded (rigid_bdf2.cpp)
  if (J.bdf2 && !previous)
    throw std::invalid_argument("rigid body '" + body.name + "': a BDF2 step's Jacobian needs the previous state");
  J.h_used = J.bdf2 ? 2.0 * h / 3.0 : h;
  step_jacobian(body, J.bdf2 ? hat_state : in, out, info, J.h_used, gravity, Vec3::Zero(), J.step);
  if (!J.bdf2) {
    J.extrapolation.in.setIdentity();
    J.extrapolation.previous.setZero();
    J.extrapolation.params.setZero();
    J.state = J.step.state;
    J.previous.setZero();
    J.params = J.step.params;
    return;
  }
  extrapolation_jacobian(body, in, *previous, hat_state, J.extrapolation);
  J.state.noalias() = J.step.state * J.extrapolation.in;
  J.previous.noalias() = J.step.state * J.extrapolation.previous;
  J.params = J.step.params;
  J.params.noalias() += J.step.state * J.extrapolation.params;
}

}  // namespace softdiff::rigid
