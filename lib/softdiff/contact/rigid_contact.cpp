// Rigid bodies in the contact stage: see rigid_contact.hpp.
#include <softdiff/contact/rigid_contact.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <string>

namespace softdiff::contact {

namespace {

bool has_dofs(const rigid::RigidBody& b) { return b.joint.kind != rigid::Joint::Kind::fixed; }

}  // namespace

void add_rigid_surfaces(Model& model) {
  auto& settings = model.contact;
  auto& det = settings.detection;
  settings.rigid_node_begin.clear();
  settings.rigid_node_body.clear();
  int pseudo = model.fem.num_nodes;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& rb = model.rigid[r];
    settings.rigid_node_begin.push_back(pseudo);
    for (Eigen::Index j = 0; j < rb.surface.vertices.cols(); ++j) settings.rigid_node_body.push_back(static_cast<int>(r));
    det.surfaces.push_back(collision::make_surface(rb.name, rb.surface.triangles, pseudo));
    det.names.push_back(rb.name);
    pseudo += static_cast<int>(rb.surface.vertices.cols());
  }
}

void begin_rigid_contact(const Model& model, Data& data, const std::vector<rigid::RigidState>& in,
                         const std::vector<rigid::RigidState>& free) {
  const std::size_t R = model.rigid.size();
  SOFTDIFF_DEMAND(in.size() == R && free.size() == R, "begin_rigid_contact: expected " + std::to_string(R) +
                                                          " rigid states, got " + std::to_string(in.size()) + " and " +
                                                          std::to_string(free.size()));
  auto& rd = data.contact.rigid;
  rd.in = in;  // same size after the first step: no allocation
  rd.free = free;
  if (rd.u_free.size() != static_cast<Eigen::Index>(6 * R)) rd.u_free.resize(6 * R);
  if (rd.W.size() != R) rd.W.resize(R);
  for (std::size_t r = 0; r < R; ++r) {
    const auto& body = model.rigid[r];
    rd.u_free.segment<3>(6 * r) = free[r].velocity;
    rd.u_free.segment<3>(6 * r + 3) = free[r].angular_velocity;
    if (!has_dofs(body)) {
      rd.W[r].setZero();
      continue;
    }
    SOFTDIFF_DEMAND(!body.joint.limits, "begin_rigid_contact: rigid body '" + body.name +
                                            "': a joint with limits does not take part in contact");
    // W_r = A_r^{-1} with A_r = diag(m I, I_w(q_free)), I_w(q_free) = R I R^T at the free
    // step's end orientation: the symmetric linearization of the angular update (an
    // impulse changes the end momentum I_w(q_{n+1}) omega_{n+1}). step_matrix's angular
    // block dr/domega = E A - h E [A omega]x J_r equals it at omega = 0 and differs by
    // O(h |omega|) otherwise (the gyroscopic term); it is not symmetric, and the NCP
    // solvers need a symmetric G (ADMM factors G + rho I by Cholesky). docs/method.md
    // "Rigid bodies in contact".
    const Mat3 R = free[r].orientation.toRotationMatrix();
    if (body.joint.kind == rigid::Joint::Kind::free) {
      rd.W[r].setZero();
      rd.W[r].topLeftCorner<3, 3>() = Mat3::Identity() / body.mass;
      rd.W[r].bottomRightCorner<3, 3>() = R * body.inertia.inverse() * R.transpose();
      continue;
    }
    // Hinge, slider: the motion (v, omega) = T cdot with T = joint_motion_basis at the
    // start of the step (where the pseudo-nodes are posed), so W_r = T a^{-1} T^T with
    // a = T^T A_r T (the joint's inertia I_a: m for a slider, n.I_w n + m |n x r|^2 for
    // a hinge), and u_free = T cdot_free, cdot_free the free step's joint rate.
    rigid::Mat6 A = rigid::Mat6::Zero();
    A.topLeftCorner<3, 3>() = body.mass * Mat3::Identity();
    A.bottomRightCorner<3, 3>() = rigid::world_inertia(body, free[r].orientation);
    const rigid::Vec6 T = rigid::joint_motion_basis(body, in[r]).col(0);
    const double a = T.dot(A * T);
    rd.W[r] = T * T.transpose() / a;
    const Vec3 n = body.joint.axis;
    const double rate = body.joint.kind == rigid::Joint::Kind::hinge ? n.dot(free[r].angular_velocity)
                                                                    : n.dot(free[r].velocity);
    rd.u_free.segment<6>(6 * r) = rate * T;
  }
  rd.u = rd.u_free;
}

void extend_for_detection(const Model& model, Data& data, const VecX& x, const VecX& v_previous, const VecX& v_free) {
  auto& rd = data.contact.rigid;
  const Eigen::Index n3 = x.size();
  const Eigen::Index total = n3 + 3 * static_cast<Eigen::Index>(model.contact.rigid_node_body.size());
  if (rd.x.size() != total) {
    rd.x.resize(total);
    rd.v_previous.resize(total);
    rd.v_free.resize(total);
  }
  rd.x.head(n3) = x;
  rd.v_previous.head(n3) = v_previous;
  rd.v_free.head(n3) = v_free;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& body = model.rigid[r];
    const auto& s = rd.in[r];
    const Mat3 Rot = s.orientation.toRotationMatrix();
    const Vec3 v_free_r = rd.u_free.segment<3>(6 * r), w_free_r = rd.u_free.segment<3>(6 * r + 3);
    const Eigen::Index begin = 3 * static_cast<Eigen::Index>(model.contact.rigid_node_begin[r]);
    for (Eigen::Index j = 0; j < body.surface.vertices.cols(); ++j) {
      const Vec3 rho = Rot * body.surface.vertices.col(j);
      rd.x.segment<3>(begin + 3 * j) = s.position + rho;
      rd.v_previous.segment<3>(begin + 3 * j) = s.velocity + s.angular_velocity.cross(rho);
      rd.v_free.segment<3>(begin + 3 * j) = v_free_r + w_free_r.cross(rho);
    }
  }
}

void rigid_jacobian_transpose(const Model& model, const collision::ContactSet& contacts,
                              const std::vector<rigid::RigidState>& in, MatX& Ht) {
  const int n = model.fem.num_nodes;
  const int nc = contacts.size();
  const Eigen::Index R = static_cast<Eigen::Index>(model.rigid.size());
  Ht.setZero(6 * R, 3 * nc);
  for (int i = 0; i < nc; ++i) {
    const auto& c = contacts.contacts[static_cast<std::size_t>(i)];
    for (int k = 0; k < c.count; ++k) {
      const int node = c.nodes[static_cast<std::size_t>(k)];
      const double w = c.weights[static_cast<std::size_t>(k)];
      if (node < n || w == 0) continue;
      const int r = model.contact.rigid_node_body[static_cast<std::size_t>(node - n)];
      const auto& body = model.rigid[static_cast<std::size_t>(r)];
      if (!has_dofs(body)) continue;
      const auto& s = in[static_cast<std::size_t>(r)];
      const int j = node - model.contact.rigid_node_begin[static_cast<std::size_t>(r)];
      const Vec3 rho = s.orientation * body.surface.vertices.col(j);  // x_k - p_r
      for (int a = 0; a < 3; ++a) {
        const Vec3 axis = c.frame.col(a);
        // axis . (v + omega x rho) = axis . v + omega . (rho x axis)
        Ht.block<3, 1>(6 * r, 3 * i + a) += w * axis;
        Ht.block<3, 1>(6 * r + 3, 3 * i + a) += w * rho.cross(axis);
      }
    }
  }
}

void add_rigid_delassus(const Model& model, Data& data, double h, MatX& G, VecX& g) {
  auto& rd = data.contact.rigid;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    if (!has_dofs(model.rigid[r])) continue;
    const auto B = rd.Ht.middleRows<6>(6 * static_cast<Eigen::Index>(r));
    if (B.squaredNorm() == 0) continue;  // no contact on this body
    rd.WHt.noalias() = rd.W[r] * B;
    G.noalias() += h * (B.transpose() * rd.WHt);
    g.noalias() += B.transpose() * rd.u_free.segment<6>(6 * static_cast<Eigen::Index>(r));
  }
}

void correct_rigid_velocities(const Model& model, Data& data, double h, const VecX& lambda) {
  auto& rd = data.contact.rigid;
  rd.u = rd.u_free;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    if (!has_dofs(model.rigid[r])) continue;
    const Eigen::Index o = 6 * static_cast<Eigen::Index>(r);
    const rigid::Vec6 impulse = h * (rd.Ht.middleRows<6>(o) * lambda);
    rd.u.segment<6>(o) += rd.W[r] * impulse;
  }
}

StepStatus end_rigid_contact(const Model& model, Data& data, std::vector<rigid::RigidState>& out, double h,
                             long step_index) {
  StepStatus status;
  const auto& rd = data.contact.rigid;
  if (data.contact.contacts.size() == 0) return status;  // out is the free step
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    if (!has_dofs(model.rigid[r])) continue;
    const Eigen::Index o = 6 * static_cast<Eigen::Index>(r);
    const auto& s = rd.in[r];
    auto& e = out[r];
    const auto& body = model.rigid[r];
    const Vec3 n = body.joint.axis;
    switch (body.joint.kind) {
      case rigid::Joint::Kind::hinge: {  // along the joint exactly, as rigid::step
        const double delta = h * n.dot(rd.u.segment<3>(o + 3));
        const Eigen::Quaterniond dq(Eigen::AngleAxisd(delta, n));
        e.orientation = (dq * s.orientation).normalized();
        e.position = body.joint.anchor + dq * (s.position - body.joint.anchor);
        e.angular_velocity = delta / h * n;
        e.velocity = e.angular_velocity.cross(e.position - body.joint.anchor);
        break;
      }
      case rigid::Joint::Kind::slider: {
        const double rate = n.dot(rd.u.segment<3>(o));
        e.position = s.position + h * rate * n;
        e.orientation = s.orientation;
        e.velocity = rate * n;
        e.angular_velocity.setZero();
        break;
      }
      default:
        e.velocity = rd.u.segment<3>(o);
        e.angular_velocity = rd.u.segment<3>(o + 3);
        e.position = s.position + h * e.velocity;
        e.orientation = (rigid::quaternion_exp(h * e.angular_velocity) * s.orientation).normalized();
    }
    if (!rigid::finite(e)) {
      status.code = StepStatus::Code::non_finite;
      status.step = step_index;
      status.detail = "rigid body '" + model.rigid[r].name + "' has a non-finite pose or velocity after the contact stage";
      return status;
    }
  }
  return status;
}

}  // namespace softdiff::contact
