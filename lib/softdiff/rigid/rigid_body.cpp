// The rigid step: implicit Euler for a free body (the gyroscopic term implicit), and the
// joints to the world in their own coordinate with exact limits (docs/method.md
// "Rigid bodies").
#include <softdiff/core/error.hpp>
#include <softdiff/core/format.hpp>
#include <softdiff/rigid/joint_equation.hpp>
#include <softdiff/rigid/rigid_body.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>

namespace softdiff::rigid {
namespace {

constexpr double pi = std::numbers::pi;

std::string num(double x) { return format_number(x, 9); }

std::string who(const RigidBody& b) { return "rigid body '" + b.name + "'"; }

const char* joint_name(Joint::Kind k) {
  switch (k) {
    case Joint::Kind::free: return "free";
    case Joint::Kind::fixed: return "fixed";
    case Joint::Kind::hinge: return "hinge";
    case Joint::Kind::slider: return "slider";
  }
  return "?";
}


// The centre of the window the hinge angle is wrapped into: the middle of its limits.
double angle_window_centre(const Joint& j) { return j.limits ? 0.5 * (j.limits->first + j.limits->second) : 0.0; }


}  // namespace

double wrap_angle(double angle, double centre) {
  return angle - 2 * pi * std::floor((angle - centre + pi) / (2 * pi));
}

namespace {

// Safeguarded Newton on the bracket [lo, hi] where g changes sign.
double solve_joint(const JointEquation& e, const RigidBody& b) {
  const double centre = e.h * e.cdot;
  const double reach = e.h * e.h * (std::abs(e.Q0) + std::hypot(e.c1, e.c2)) / e.I_a;
  // Padded for the round-off of d / h - cdot (a fast joint under a tiny load).
  const double pad = 1e-9 * reach + 1e-12 * std::abs(centre) + 1e-300;
  double lo = centre - reach - pad, hi = centre + reach + pad;
  // Q constant (a slider, a hinge without lever arm): the update is linear.
  if (reach == 0 || (e.c1 == 0 && e.c2 == 0)) return e.h * (e.cdot + e.h * e.Q0 / e.I_a);
  double glo = e.g(lo), ghi = e.g(hi);
  if (glo > 0 || ghi < 0)
    throw ComputationError(who(b) + ": the joint equation has no bracketed root (step " + num(e.h) +
                           " s too long for the joint's generalized force)");
  double d = centre;
  const double scale = e.I_a * (std::abs(e.cdot) + reach / e.h) + e.h * (std::abs(e.Q0) + std::hypot(e.c1, e.c2));
  for (int it = 0; it < 100; ++it) {
    const double gd = e.g(d);
    if (std::abs(gd) <= 1e-15 * scale) return d;
    if (gd < 0) lo = d; else hi = d;
    double next = d - gd / e.dg(d);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (next == d || hi - lo <= 4 * std::numeric_limits<double>::epsilon() * (std::abs(d) + reach)) return next;
    d = next;
  }
  return d;
}

// The joint's limit as an LCP of size 1 (c = c_n + delta in [lower, upper], the limit's
// reaction lambda >= 0 on the side it acts, lambda (distance to the limit) = 0): with g
// increasing, the solution is the unconstrained root clamped to the limits.
double clamp_to_limits(const Joint& j, double c_n, double delta, bool& at_limit) {
  at_limit = false;
  if (!j.limits) return delta;
  if (c_n + delta > j.limits->second) {
    at_limit = true;
    return j.limits->second - c_n;
  }
  if (c_n + delta < j.limits->first) {
    at_limit = true;
    return j.limits->first - c_n;
  }
  return delta;
}

}  // namespace

Mat3 hat(const Vec3& a) {
  Mat3 m;
  m << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
  return m;
}

Eigen::Quaterniond quaternion_exp(const Vec3& phi) {
  const double t = phi.norm();
  // sin(t/2)/t = 1/2 - t^2/48 + t^4/3840: below 1e-4 the next term is under 1e-20.
  const double s = t < 1e-4 ? 0.5 - t * t / 48 : std::sin(0.5 * t) / t;
  Eigen::Quaterniond q(std::cos(0.5 * t), s * phi.x(), s * phi.y(), s * phi.z());
  q.normalize();
  return q;
}

Vec3 quaternion_log(Eigen::Quaterniond q) {
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  const double s = q.vec().norm();
  if (s == 0) return Vec3::Zero();
  return (2 * std::atan2(s, q.w()) / s) * q.vec();
}

Mat3 right_jacobian(const Vec3& phi) {
  const double t = phi.norm();
  const Mat3 P = hat(phi);
  double a, b;  // (1 - cos t)/t^2, (t - sin t)/t^3
  if (t < 1e-3) {
    a = 0.5 - t * t / 24 + t * t * t * t / 720;
    b = 1.0 / 6 - t * t / 120 + t * t * t * t / 5040;
  } else {
    a = (1 - std::cos(t)) / (t * t);
    b = (t - std::sin(t)) / (t * t * t);
  }
  return Mat3::Identity() - a * P + b * P * P;
}

Vec3 angular_residual(const Mat3& A, const Vec3& L, double h, const Vec3& omega) {
  return quaternion_exp(h * omega) * (A * omega) - L;
}

Mat3 angular_residual_jacobian(const Mat3& A, double h, const Vec3& omega) {
  const Mat3 E = quaternion_exp(h * omega).toRotationMatrix();
  return E * A - h * E * hat(A * omega) * right_jacobian(h * omega);
}

void initialize(RigidBody& body, const RigidState& initial) {
  const std::string w = who(body);
  if (!(body.mass > 0) || !std::isfinite(body.mass))
    throw std::invalid_argument(w + ": mass must be positive and finite, got " + num(body.mass));
  if (!body.inertia.allFinite() || (body.inertia - body.inertia.transpose()).norm() > 1e-9 * body.inertia.norm())
    throw std::invalid_argument(w + ": inertia must be a finite symmetric matrix");
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(body.inertia, Eigen::EigenvaluesOnly);
  if (!(eig.eigenvalues()[0] > 0))
    throw std::invalid_argument(w + ": inertia must be positive definite, its smallest eigenvalue is " +
                                num(eig.eigenvalues()[0]));
  if (!finite(initial)) throw std::invalid_argument(w + ": the initial state is not finite");
  if (std::abs(initial.orientation.norm() - 1) > 1e-9)
    throw std::invalid_argument(w + ": the orientation quaternion must be unit (within 1e-9), its norm is " +
                                num(initial.orientation.norm()));
  Joint& j = body.joint;
  const char* jn = joint_name(j.kind);
  if (j.limits) {
    if (j.kind != Joint::Kind::hinge && j.kind != Joint::Kind::slider)
      throw std::invalid_argument(w + ": a " + std::string(jn) + " joint takes no limits");
    const auto [lo, hi] = *j.limits;
    if (!std::isfinite(lo) || !std::isfinite(hi) || !(lo <= hi))
      throw std::invalid_argument(w + ": joint limits must be finite with lower <= upper, got [" + num(lo) + ", " +
                                  num(hi) + "]");
    if (j.kind == Joint::Kind::hinge && !(hi - lo < 2 * pi))
      throw std::invalid_argument(w + ": hinge limits must span less than 2 pi, got [" + num(lo) + ", " + num(hi) + "]");
    if (lo > 0 || hi < 0)
      throw std::invalid_argument(w + ": the initial state lies outside the joint limits [" + num(lo) + ", " + num(hi) +
                                  "] (the joint coordinate is 0 at t = 0)");
  }
  if (j.kind == Joint::Kind::hinge || j.kind == Joint::Kind::slider) {
    if (!j.axis.allFinite() || std::abs(j.axis.norm() - 1) > 1e-9)
      throw std::invalid_argument(w + ": the " + std::string(jn) + " axis must be a unit vector (within 1e-9), its norm is " +
                                  num(j.axis.norm()));
    if (!j.anchor.allFinite()) throw std::invalid_argument(w + ": the joint anchor is not finite");
  }
  RigidState s = initial;
  s.orientation.normalize();
  const Mat3 R = s.orientation.toRotationMatrix();
  body.anchor_body = R.transpose() * (j.anchor - s.position);
  body.axis_body = R.transpose() * j.axis;
  // The initial velocity projected onto the joint's motion in the kinetic-energy metric
  // (the velocity an impulsive joint constraint leaves: the momentum along the allowed
  // motion is kept).
  switch (j.kind) {
    case Joint::Kind::free: break;
    case Joint::Kind::fixed:
      s.velocity.setZero();
      s.angular_velocity.setZero();
      break;
    case Joint::Kind::hinge: {
      const Vec3 n = j.axis, t = n.cross(s.position - j.anchor);
      const double I_a = n.dot(world_inertia(body, s.orientation) * n) + body.mass * t.squaredNorm();
      const double rate = (body.mass * t.dot(s.velocity) + n.dot(world_inertia(body, s.orientation) * s.angular_velocity)) / I_a;
      s.velocity = rate * t;
      s.angular_velocity = rate * n;
      break;
    }
    case Joint::Kind::slider:
      s.velocity = j.axis.dot(s.velocity) * j.axis;
      s.angular_velocity.setZero();
      break;
  }
  body.reference = s;
  body.joint_reach = 0;
  if (j.kind == Joint::Kind::hinge)
    for (Eigen::Index k = 0; k < body.surface.vertices.cols(); ++k) {
      const Vec3 d = s.position + R * body.surface.vertices.col(k) - j.anchor;
      body.joint_reach = std::max(body.joint_reach, (d - j.axis.dot(d) * j.axis).norm());
    }
}

double joint_coordinate(const RigidBody& body, const RigidState& state) {
  const Joint& j = body.joint;
  switch (j.kind) {
    case Joint::Kind::hinge: {
      const Eigen::Quaterniond rel = state.orientation * body.reference.orientation.conjugate();
      return wrap_angle(2 * std::atan2(j.axis.dot(rel.vec()), rel.w()), angle_window_centre(j));
    }
    case Joint::Kind::slider: return j.axis.dot(state.position - body.reference.position);
    default: return 0;
  }
}

StepInfo step(const RigidBody& body, const RigidState& in, double h, const Vec3& gravity, const Vec3& force,
              const Vec3& torque, RigidState& out, bool enforce_limits) {
  if (&in == &out) throw std::invalid_argument(who(body) + ": step's out must not alias in");
  if (!(h > 0) || !std::isfinite(h)) throw std::invalid_argument(who(body) + ": step length must be positive, got " + num(h));
  if (!finite(in) || !gravity.allFinite() || !force.allFinite() || !torque.allFinite())
    throw ComputationError(who(body) + ": non-finite state or load at the start of the step");
  StepInfo info;
  const Joint& j = body.joint;
  const double m = body.mass;
  const Vec3 F = m * gravity + force;  // the applied force at the centre of mass
  const Mat3 A = world_inertia(body, in.orientation);
  out = in;
  switch (j.kind) {
    case Joint::Kind::free: {
      out.velocity = in.velocity + h / m * F;
      out.position = in.position + h * out.velocity;
      const Vec3 L = A * in.angular_velocity + h * torque;
      Vec3 w = in.angular_velocity;
      // Newton on r(omega) = 0 from omega_n, with backtracking on |r| (the full step is
      // taken whenever it decreases |r|). Converged: |r| within 1e-14 of the momentum's
      // size (round-off of E A omega is about 1e-16 of it).
      const double tol = 1e-14 * (L.norm() + A.norm() * in.angular_velocity.norm() + h * torque.norm());
      double res = angular_residual(A, L, h, w).norm();
      for (int it = 0; it < 50 && res > tol; ++it) {
        const Vec3 dw = angular_residual_jacobian(A, h, w).partialPivLu().solve(-angular_residual(A, L, h, w));
        double alpha = 1, trial = res;
        for (int ls = 0; ls < 30; ++ls, alpha *= 0.5) {
          trial = angular_residual(A, L, h, w + alpha * dw).norm();
          if (trial < res) break;
        }
        if (!(trial < res)) break;  // no decrease: at round-off
        w += alpha * dw;
        res = trial;
      }
      if (!(res <= 100 * tol))
        throw ComputationError(who(body) + ": the rotational Newton did not converge (residual " + num(res) +
                               " N m s, momentum " + num(L.norm()) + " N m s)");
      out.angular_velocity = w;
      out.orientation = (quaternion_exp(h * w) * in.orientation).normalized();
      break;
    }
    case Joint::Kind::fixed:
      out.velocity.setZero();
      out.angular_velocity.setZero();
      break;
    case Joint::Kind::hinge: {
      const Vec3 n = j.axis, r = in.position - j.anchor;
      const Vec3 r_perp = r - n.dot(r) * n;
      JointEquation e;
      e.h = h;
      e.I_a = n.dot(A * n) + m * r_perp.squaredNorm();
      e.cdot = n.dot(in.angular_velocity);
      e.Q0 = n.dot(torque);
      e.c1 = F.dot(n.cross(r_perp));
      e.c2 = F.dot(r_perp);
      const double c_n = joint_coordinate(body, in);
      const double unclamped = solve_joint(e, body);
      info.free_rate = unclamped / h;
      const double delta = enforce_limits ? clamp_to_limits(j, c_n, unclamped, info.at_limit) : unclamped;
      move_along_joint(body, in, delta, h, out);
      break;
    }
    case Joint::Kind::slider: {
      const Vec3 n = j.axis;
      JointEquation e;
      e.h = h;
      e.I_a = m;
      e.cdot = n.dot(in.velocity);
      e.Q0 = n.dot(F);
      const double c_n = joint_coordinate(body, in);
      const double unclamped = solve_joint(e, body);
      info.free_rate = unclamped / h;
      const double delta = enforce_limits ? clamp_to_limits(j, c_n, unclamped, info.at_limit) : unclamped;
      move_along_joint(body, in, delta, h, out);
      break;
    }
  }
  if (j.kind != Joint::Kind::free) {
    // The reaction: what the momentum balance of the step needs beyond the applied loads.
    info.constraint_force = m * (out.velocity - in.velocity) / h - F;
    info.constraint_torque =
        (world_inertia(body, out.orientation) * out.angular_velocity - A * in.angular_velocity) / h - torque;
  }
  if (!finite(out) || !info.constraint_force.allFinite() || !info.constraint_torque.allFinite())
    throw ComputationError(who(body) + ": the step produced a non-finite state (h = " + num(h) + ")");
  return info;
}

void move_along_joint(const RigidBody& body, const RigidState& in, double delta, double h, RigidState& out) {
  const Joint& j = body.joint;
  const Vec3 n = j.axis;
  const double rate = delta / h;
  if (j.kind == Joint::Kind::hinge) {
    const Eigen::Quaterniond dq(Eigen::AngleAxisd(delta, n));
    out.orientation = (dq * in.orientation).normalized();
    out.position = j.anchor + dq * (in.position - j.anchor);
    out.angular_velocity = rate * n;
    out.velocity = rate * n.cross(out.position - j.anchor);
  } else if (j.kind == Joint::Kind::slider) {
    out.position = in.position + delta * n;
    out.orientation = in.orientation;
    out.velocity = rate * n;
    out.angular_velocity.setZero();
  } else {
    throw std::invalid_argument(who(body) + ": move_along_joint needs a hinge or a slider");
  }
}

Mat3X world_vertices(const RigidBody& body, const RigidState& state) {
  return (state.orientation.toRotationMatrix() * body.surface.vertices).colwise() + state.position;
}

Mat6 step_matrix(const RigidBody& body, const RigidState& in, const RigidState& out, double h) {
  Mat6 M = Mat6::Zero();
  M.topLeftCorner<3, 3>() = body.mass * Mat3::Identity();
  M.bottomRightCorner<3, 3>() = angular_residual_jacobian(world_inertia(body, in.orientation), h, out.angular_velocity);
  return M;
}

JointBasis joint_motion_basis(const RigidBody& body, const RigidState& state) {
  const Joint& j = body.joint;
  JointBasis T;
  switch (j.kind) {
    case Joint::Kind::free: T = Mat6::Identity(); break;
    case Joint::Kind::fixed: T.resize(6, 0); break;
    case Joint::Kind::hinge:
      T.resize(6, 1);
      T << j.axis.cross(state.position - j.anchor), j.axis;
      break;
    case Joint::Kind::slider:
      T.resize(6, 1);
      T << j.axis, Vec3::Zero();
      break;
  }
  return T;
}

bool finite(const RigidState& s) {
  return s.position.allFinite() && s.orientation.coeffs().allFinite() && s.velocity.allFinite() &&
         s.angular_velocity.allFinite();
}

// I_w = R I R^T.
Mat3 world_inertia(const RigidBody& b, const Eigen::Quaterniond& q) {
  const Mat3 R = q.toRotationMatrix();
  return R * b.inertia * R.transpose();
}

}  // namespace softdiff::rigid
