// Rigid bodies in the static solver: see static_rigid.hpp.
#include <softdiff/integrator/static_rigid.hpp>

#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>

namespace softdiff::integrator {

namespace {

bool limited(const rigid::RigidBody& b) {
  return b.joint.limits && (b.joint.kind == rigid::Joint::Kind::hinge || b.joint.kind == rigid::Joint::Kind::slider);
}

// The largest distance of a surface vertex from the centre of mass (free, slider) or
// from the hinge's axis (hinge) at `s`: the lever of the torque scale and of the move.
double reach(const rigid::RigidBody& b, const rigid::RigidState& s) {
  const Mat3 R = s.orientation.toRotationMatrix();
  double r = 0;
  for (Eigen::Index k = 0; k < b.surface.vertices.cols(); ++k) {
    Vec3 d = R * b.surface.vertices.col(k);
    if (b.joint.kind == rigid::Joint::Kind::hinge) {
      d += s.position - b.joint.anchor;
      d -= b.joint.axis.dot(d) * b.joint.axis;
    }
    r = std::max(r, d.norm());
  }
  return r;
}

}  // namespace

double static_rigid_stiffness(const Model& model, double size, bool first) {
  const double g = model.step.gravity.norm();
  (void)first;
  return (g > 0 ? g : 1.0) / (0.01 * std::max(size, 1e-12));
}

void begin_static_rigid(const Model& model, Data& data, const std::vector<rigid::RigidState>& poses, double k,
                        double load_factor) {
  const std::size_t R = model.rigid.size();
  SOFTDIFF_DEMAND(poses.size() == R, "begin_static_rigid: expected " + std::to_string(R) + " rigid states, got " +
                                         std::to_string(poses.size()));
  auto& rd = contact::size_rigid_record(data, poses, poses);  // the static step has no free step: in = free
  for (std::size_t r = 0; r < R; ++r) {
    const auto& body = model.rigid[r];
    const auto o = 6 * static_cast<Eigen::Index>(r);
    rd.u_free.segment<6>(o).setZero();
    rd.W[r].setZero();
    rd.L[r].setZero();
    rd.rank[r] = 0;
    if (body.joint.kind == rigid::Joint::Kind::fixed) continue;
    rigid::Vec6 w = rigid::Vec6::Zero();
    w.head<3>() = load_factor * body.mass * model.step.gravity;
    rigid::Mat6 A = rigid::Mat6::Zero();
    A.topLeftCorner<3, 3>() = k * body.mass * Mat3::Identity();
    A.bottomRightCorner<3, 3>() = k * rigid::world_inertia(body, poses[r].orientation);
    if (body.joint.kind == rigid::Joint::Kind::free) {
      rd.W[r].topLeftCorner<3, 3>() = Mat3::Identity() / (k * body.mass);
      rd.W[r].bottomRightCorner<3, 3>() = A.bottomRightCorner<3, 3>().inverse();
      rd.L[r] = rd.W[r].llt().matrixL();
      rd.rank[r] = 6;
      rd.u_free.segment<6>(o) = rd.W[r] * w;
      continue;
    }
    // Hinge, slider: the increment T dc, dc = T^T w / a, a = T^T A T.
    const rigid::Vec6 T = rigid::joint_motion_basis(body, poses[r]).col(0);
    const double a = T.dot(A * T);
    rd.W[r] = T * T.transpose() / a;
    rd.L[r].col(0) = T / std::sqrt(a);
    rd.rank[r] = 1;
    rd.u_free.segment<6>(o) = T * (T.dot(w) / a);
  }
  rd.u = rd.u_free;
}

StepStatus end_static_rigid(const Model& model, Data& data, std::vector<rigid::RigidState>& poses, long load_step,
                            double& moved, int& body_index) {
  StepStatus status;
  const auto& rd = data.contact.rigid;
  moved = 0;
  body_index = -1;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& body = model.rigid[r];
    if (body.joint.kind == rigid::Joint::Kind::fixed) continue;
    const Eigen::Index o = 6 * static_cast<Eigen::Index>(r);
    const rigid::RigidState s = poses[r];
    auto& e = poses[r];
    const Vec3 dp = rd.u.segment<3>(o), dtheta = rd.u.segment<3>(o + 3);
    switch (body.joint.kind) {
      case rigid::Joint::Kind::hinge:
        rigid::move_along_joint(body, s, body.joint.axis.dot(dtheta), 1.0, e);
        break;
      case rigid::Joint::Kind::slider:
        rigid::move_along_joint(body, s, body.joint.axis.dot(dp), 1.0, e);
        break;
      default:
        e.position = s.position + dp;
        e.orientation = (rigid::quaternion_exp(dtheta) * s.orientation).normalized();
    }
    e.velocity.setZero();
    e.angular_velocity.setZero();
    if (!rigid::finite(e)) {
      status.code = StepStatus::Code::non_finite;
      status.step = load_step;
      status.detail = "rigid body '" + body.name + "' has a non-finite pose after a Newton iteration of the static solve";
      return status;
    }
    // The largest move of a surface vertex (|dp| + |dtheta| x the lever bounds it).
    const double m = body.joint.kind == rigid::Joint::Kind::hinge
                         ? std::abs(body.joint.axis.dot(dtheta)) * reach(body, s)
                         : dp.norm() + dtheta.norm() * reach(body, s);
    if (m > moved) {
      moved = m;
      body_index = static_cast<int>(r);
    }
  }
  return status;
}

int static_rigid_unsupported(const Model& model, const Data& data) {
  const auto& cd = data.contact;
  const auto& rd = cd.rigid;
  const bool any = cd.contacts.size() > 0 && rd.Ht.rows() == 6 * static_cast<Eigen::Index>(model.rigid.size());
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    if (model.rigid[r].joint.kind == rigid::Joint::Kind::fixed) continue;
    if (rd.u_free.segment<6>(6 * static_cast<Eigen::Index>(r)).squaredNorm() == 0) continue;  // no load on its dofs
    if (!any || rd.Ht.middleRows<6>(6 * static_cast<Eigen::Index>(r)).squaredNorm() == 0) return static_cast<int>(r);
  }
  return -1;
}

double static_rigid_residual(const Model& model, const Data& data, const std::vector<rigid::RigidState>& poses,
                             double load_factor, bool with_contact, std::string* worst) {
  const auto& cd = data.contact;
  const auto& rd = cd.rigid;
  const bool forces = with_contact && cd.contacts.size() > 0 && rd.Ht.cols() == cd.lambda.size() &&
                      rd.Ht.rows() == 6 * static_cast<Eigen::Index>(model.rigid.size());
  double rel = 0;
  int slot = 0;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& body = model.rigid[r];
    const int slots = limited(body) ? 2 : 0;
    if (body.joint.kind == rigid::Joint::Kind::fixed) {
      slot += slots;
      continue;
    }
    rigid::Vec6 w = rigid::Vec6::Zero();
    w.head<3>() = load_factor * body.mass * model.step.gravity;
    if (forces) w += rd.Ht.middleRows<6>(6 * static_cast<Eigen::Index>(r)) * cd.lambda;
    const double weight = std::max(body.mass * model.step.gravity.norm(), 1e-300);
    const double lever = std::max(reach(body, poses[r]), 1e-12);
    double e = 0;
    if (body.joint.kind == rigid::Joint::Kind::free) {
      e = std::max(w.head<3>().norm() / weight, w.tail<3>().norm() / (weight * lever));
    } else {
      const rigid::Vec6 T = rigid::joint_motion_basis(body, poses[r]).col(0);
      double q = T.dot(w);
      // The limits' reactions on the joint coordinate (rigid_contact.hpp "limit rows":
      // T.j = s, s = +1 lower, -1 upper).
      if (with_contact && rd.limit_lambda.size() == contact::num_limit_slots(model))
        for (int side = 0; side < slots; ++side) q += (side == 0 ? 1.0 : -1.0) * rd.limit_lambda[slot + side];
      e = std::abs(q) / (body.joint.kind == rigid::Joint::Kind::hinge ? weight * lever : weight);
    }
    slot += slots;
    if (e > rel) {
      rel = e;
      if (worst) *worst = body.name;
    }
  }
  return rel;
}

}  // namespace softdiff::integrator
