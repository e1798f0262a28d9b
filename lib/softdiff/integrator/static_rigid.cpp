// Rigid bodies in the static solver: see static_rigid.hpp.
#include <softdiff/integrator/static_rigid.hpp>

#include <softdiff/contact/contact_step.hpp>
#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <utility>

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
  data.contact.serial = contact::next_record_serial();  // a new record (ContactData::serial)
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

void static_limits_without_contact(const Model& model, Data& data) {
  auto& rd = data.contact.rigid;
  rd.limit_rows.clear();  // capacity kept
  const int slots = contact::num_limit_slots(model);
  if (rd.limit_lambda.size() != slots) rd.limit_lambda.resize(slots);
  rd.limit_lambda.setZero();
  int slot = 0;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& body = model.rigid[r];
    if (!limited(body)) continue;
    const Eigen::Index o = 6 * static_cast<Eigen::Index>(r);
    const rigid::Vec6 T = rigid::joint_motion_basis(body, rd.in[r]).col(0);
    // a = T^T A_r T from begin_static_rigid's L_r = T / sqrt(a).
    const double a = T.squaredNorm() / rd.L[r].col(0).squaredNorm();
    const double dc_free = T.dot(rd.u_free.segment<6>(o)) / T.squaredNorm();
    const double c = rigid::joint_coordinate(body, rd.in[r]);
    const double gap[2] = {c - body.joint.limits->first, body.joint.limits->second - c};
    double dc = dc_free;
    for (int side = 0; side < 2; ++side) {
      const double sign = side == 0 ? 1.0 : -1.0;
      if (gap[side] + sign * dc_free < 0) {  // the free increment crosses this limit: stop on it
        dc = -sign * gap[side];
        rd.limit_lambda[slot + side] = a * (dc - dc_free) * sign;  // >= 0
        rd.limit_rows.push_back({static_cast<int>(r), side, slot + side});
        break;
      }
    }
    rd.u.segment<6>(o) = T * dc;
    slot += 2;
  }
  // The record's corrected velocities and limit rows changed: a new serial, as the contact
  // stage gives it (ContactData::serial; a derivative keyed by it sees a new record).
  data.contact.serial = contact::next_record_serial();
}

int static_rigid_unsupported(const Model& model, const Data& data) {
  const auto& cd = data.contact;
  const auto& rd = cd.rigid;
  const bool any = cd.contacts.size() > 0 && rd.Ht.rows() == 6 * static_cast<Eigen::Index>(model.rigid.size());
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    if (model.rigid[r].joint.kind == rigid::Joint::Kind::fixed) continue;
    const Eigen::Index o = 6 * static_cast<Eigen::Index>(r);
    if (rd.u_free.segment<6>(o).squaredNorm() == 0) continue;  // no load on its dofs
    // A limited joint has a limit on each side: the load drives it onto one, which holds
    // it (a far limit is reached over several iterations, |dc_free| each).
    if (limited(model.rigid[r])) continue;
    if (!any || rd.Ht.middleRows<6>(o).squaredNorm() == 0) return static_cast<int>(r);
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

void extended_positions(const Model& model, const VecX& x, const std::vector<rigid::RigidState>& poses, VecX& e) {
  if (!model.contact.enabled || !model.contact.with_rigid()) {
    e = x;
    return;
  }
  const Eigen::Index n3 = x.size();
  e.resize(n3 + 3 * static_cast<Eigen::Index>(model.contact.rigid_node_body.size()));
  e.head(n3) = x;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& body = model.rigid[r];
    const Mat3 Rot = poses[r].orientation.toRotationMatrix();
    const Eigen::Index begin = 3 * static_cast<Eigen::Index>(model.contact.rigid_node_begin[r]);
    for (Eigen::Index j = 0; j < body.surface.vertices.cols(); ++j)
      e.segment<3>(begin + 3 * j) = poses[r].position + Rot * body.surface.vertices.col(j);
  }
}

void record_load_step_start(const Model& model, Data& data, const VecX& x, const std::vector<rigid::RigidState>& poses) {
  data.static_load_step_start = x;
  // The extended positions are read only under static.friction load_step (static_slip_offset,
  // the static derivative's slip terms, check-grad's count): not posed otherwise.
  if (model.step.static_friction == StaticFriction::load_step)
    extended_positions(model, x, poses, data.static_load_step_start_extended);
  else
    data.static_load_step_start_extended.resize(0);
}

void contact_slips(const collision::ContactSet& contacts, const VecX& from, const VecX& to, VecX& slip) {
  SOFTDIFF_DEMAND(from.size() == to.size(), "contact_slips: positions of different sizes");
  const int nc = contacts.size();
  slip.setZero(3 * nc);
  for (int i = 0; i < nc; ++i) {
    const auto& c = contacts.contacts[static_cast<std::size_t>(i)];
    Vec3 d = Vec3::Zero();
    for (int k = 0; k < c.count; ++k) {
      const Eigen::Index o = 3 * static_cast<Eigen::Index>(c.nodes[static_cast<std::size_t>(k)]);
      d += c.weights[static_cast<std::size_t>(k)] * (to.segment<3>(o) - from.segment<3>(o));
    }
    slip[3 * i] = c.frame.col(0).dot(d);
    slip[3 * i + 1] = c.frame.col(1).dot(d);
  }
}

void static_slip_offset(const Model& model, Data& data, const VecX& x) {
  auto& cd = data.contact;
  if (model.step.static_friction != StaticFriction::load_step) {
    cd.slip_offset.resize(0);
    return;
  }
  const VecX& now = model.contact.with_rigid() ? cd.rigid.x : x;
  SOFTDIFF_DEMAND(now.size() == data.static_load_step_start_extended.size(),
                  "static_slip_offset: the load step's start is not recorded (record_load_step_start)");
  contact_slips(cd.contacts, data.static_load_step_start_extended, now, cd.slip_offset);
}

StepStatus solve_static_rigid_only(const Model& model, Data& data, const State& in, State& out,
                                   const std::function<void(long, const State&)>& on_load_step) {
  const auto& settings = model.step;
  const int L = std::max(1, settings.static_load_steps);
  out = in;
  out.x.resize(0);
  out.v.resize(0);
  data.timings = {};
  for (auto& s : out.rigid) {
    s.velocity.setZero();
    s.angular_velocity.setZero();
  }
  StepStatus status;
  SOFTDIFF_DEMAND(model.contact.with_rigid() || std::all_of(model.rigid.begin(), model.rigid.end(), [](const auto& b) {
                    return b.joint.kind == rigid::Joint::Kind::fixed;
                  }),
                  "solve_static: rigid bodies with dofs need contact (the scene reader refuses the rest)");
  // The scene's size: the largest diagonal of a rigid body's surface box (body axes).
  double size = 0;
  for (const auto& b : model.rigid)
    if (b.surface.vertices.cols() > 0)
      size = std::max(size, (b.surface.vertices.rowwise().maxCoeff() - b.surface.vertices.rowwise().minCoeff()).norm());
  const double k = static_rigid_stiffness(model, size, true);
  auto& cd = data.contact;
  const bool with_contact = model.contact.with_rigid();
  if (with_contact) contact::clear_contact_record(cd);
  // static.friction load_step's offsets are this solve's: a later contact solve (a dynamic
  // step on the same Data) must not see them, whichever way this solve ends.
  const SlipOffsetGuard slip_guard{cd};
  VecX none_x, none_v, increment;  // no soft dof: empty
  int total = 0;
  double rel = 0;
  std::string worst;
  auto not_converged = [&rel](long step, int iterations, std::string detail) {
    StepStatus ns;
    ns.code = StepStatus::Code::not_converged;
    ns.step = step;
    ns.iterations = iterations;
    ns.residual = rel;
    ns.detail = std::move(detail);
    return ns;
  };
  for (long s = 1; s <= L; ++s) {
    const double factor = static_cast<double>(s) / L;
    if (with_contact) cd.detector->set_time(factor);
    record_load_step_start(model, data, none_x, out.rigid);
    bool solved = false;  // an NCP (or the limits' LCPs) ran in this load step
    for (int it = 0;; ++it) {
      rel = static_rigid_residual(model, data, out.rigid, factor, with_contact && solved, &worst);
      if (!std::isfinite(rel)) {
        status.code = StepStatus::Code::non_finite;
        status.step = s;
        status.detail = "the rigid equations' residual is not finite (rigid body '" + worst + "')";
        return status;
      }
      if (rel <= settings.static_tolerance && (!with_contact || (solved && cd.result.converged))) break;
      if (it >= settings.static_max_iterations) {
        return not_converged(s, it, "static equilibrium not reached: rigid body '" + worst +
                                        "' is out of balance (increase static.max_iterations or static.load_steps)");
      }
      begin_static_rigid(model, data, out.rigid, k, factor);
      if (with_contact) {
        // static.friction load_step: the NCP on the load step's total slip (static_slip_offset).
        contact::detect_contacts(model, data, none_x, none_v, 1.0, increment, false);
        static_slip_offset(model, data, none_x);
        const StepStatus cs = contact::solve_contact_problem(model, data, 1.0, increment, s);
        if (!cs.ok()) return cs;
        if (cd.contacts.size() == 0) static_limits_without_contact(model, data);
        const int unsupported = static_rigid_unsupported(model, data);
        if (unsupported >= 0) {
          return not_converged(s, it,
                               "rigid body '" + model.rigid[static_cast<std::size_t>(unsupported)].name +
                                   "' touches no support within contact.margin: no equilibrium under its load (rest "
                                   "it on an obstacle or another body, or fix its joint)");
        }
      }
      solved = true;
      double moved = 0;
      int body = -1;
      const StepStatus rs = end_static_rigid(model, data, out.rigid, s, moved, body);
      if (!rs.ok()) return rs;
      ++total;
      if (!(moved <= size)) {
        return not_converged(s, it,
                             "rigid body '" + model.rigid[static_cast<std::size_t>(body)].name +
                                 "' moved by more than the scene's size in one Newton iteration: its contacts do not "
                                 "hold it");
      }
    }
    out.t = factor;
    status.iterations = total;
    status.residual = rel;
    data.newton_iterations_used = total;
    data.newton_residual = rel;
    if (on_load_step) on_load_step(s, out);
  }
  return status;
}

}  // namespace softdiff::integrator
