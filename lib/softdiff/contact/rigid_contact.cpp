// Rigid bodies in the contact stage: see rigid_contact.hpp.
#include <softdiff/contact/rigid_contact.hpp>

#include <softdiff/contact/contact_step.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/Cholesky>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <utility>

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
    collision::mark_planar_edges(det.surfaces.back(), rb.surface.vertices, pseudo);
    det.names.push_back(rb.name);
    pseudo += static_cast<int>(rb.surface.vertices.cols());
  }
}

ContactData::Rigid& size_rigid_record(Data& data, const std::vector<rigid::RigidState>& in,
                                      const std::vector<rigid::RigidState>& free) {
  const std::size_t R = in.size();
  auto& rd = data.contact.rigid;
  rd.in = in;  // same size after the first step: no allocation
  rd.free = free;
  if (rd.u_free.size() != static_cast<Eigen::Index>(6 * R)) rd.u_free.resize(6 * R);
  if (rd.W.size() != R) {
    rd.W.resize(R);
    rd.L.resize(R);
    rd.rank.resize(R);
  }
  return rd;
}

void begin_rigid_contact(const Model& model, Data& data, const std::vector<rigid::RigidState>& in,
                         const std::vector<rigid::RigidState>& free) {
  const std::size_t nr = model.rigid.size();
  SOFTDIFF_DEMAND(in.size() == nr && free.size() == nr, "begin_rigid_contact: expected " + std::to_string(nr) +
                                                          " rigid states, got " + std::to_string(in.size()) + " and " +
                                                          std::to_string(free.size()));
  auto& rd = size_rigid_record(data, in, free);
  for (std::size_t r = 0; r < nr; ++r) {
    const auto& body = model.rigid[r];
    rd.u_free.segment<3>(6 * r) = free[r].velocity;
    rd.u_free.segment<3>(6 * r + 3) = free[r].angular_velocity;
    rd.L[r].setZero();
    rd.rank[r] = 0;
    if (!has_dofs(body)) {
      rd.W[r].setZero();
      continue;
    }
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
      rd.L[r] = rd.W[r].llt().matrixL();  // W symmetric positive definite (m > 0, I > 0)
      rd.rank[r] = 6;
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
    double a = T.dot(A * T);
    const Vec3 n = body.joint.axis;
    const bool hinge = body.joint.kind == rigid::Joint::Kind::hinge;
    // A limited joint: the free rate without its limits (they are rows of the NCP), which
    // the free step recorded (rigid::StepInfo::free_rate; integrator::step_rigid_bodies
    // fills data.rigid): no second step.
    double rate = hinge ? n.dot(free[r].angular_velocity) : n.dot(free[r].velocity);
    if (body.joint.limits || hinge)
      SOFTDIFF_DEMAND(data.rigid.size() == model.rigid.size(), "begin_rigid_contact: a hinge or limited joint needs the "
                                              "free step's info (data.rigid, integrator::step_rigid_bodies)");
    if (body.joint.limits) rate = data.rigid[r].free_rate;
    // A hinge: the free step is implicit in the gravity torque Q(c) (rigid::step's joint
    // equation, rigid/joint_equation.hpp), so an impulse P changes the end rate by
    // T.P / (I_a - h^2 Q'(c_u)), the tangent of that equation at the free (unlimited) end
    // c_u = c_n + h rate: the consistent linearization of the implicit step (2026-12-03,
    // rbranch; docs/method.md "Scenes of rigid bodies only", *The hinge's limit reaction*).
    // h: the free step's own (2h/3 on its BDF2 branch, data.rigid's record). A slider's
    // load does not depend on its travel (Q' = 0).
    if (hinge) {
      const double h = data.rigid[r].bdf2 ? 2.0 * model.step.dt / 3.0 : model.step.dt;
      const Vec3 arm = in[r].position - body.joint.anchor, r_perp = arm - n.dot(arm) * n;
      const Vec3 F = body.mass * model.step.gravity;
      const double c1 = F.dot(n.cross(r_perp)), c2 = F.dot(r_perp), delta = h * rate;
      a += h * h * (c1 * std::sin(delta) + c2 * std::cos(delta));  // - h^2 Q'(delta)
      if (!(a > 0))
        throw ComputationError("rigid body '" + body.name + "': the hinge's effective inertia I_a - h^2 Q' = " +
                               std::to_string(a) + " kg m^2 is not positive (the step is too long for the gravity torque)");
    }
    rd.W[r] = T * T.transpose() / a;
    rd.L[r].col(0) = T / std::sqrt(a);
    rd.rank[r] = 1;
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
  const Eigen::Index nc = rd.Ht.cols() / 3;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    if (!has_dofs(model.rigid[r])) continue;
    const auto B = rd.Ht.middleRows<6>(6 * static_cast<Eigen::Index>(r));
    // The body's own contacts (their rows of G): G_rr += h K^T K on those only, K = L^T B.
    rd.dofs.clear();
    for (Eigen::Index i = 0; i < nc; ++i)
      if (B.middleCols<3>(3 * i).squaredNorm() > 0)
        for (int c = 0; c < 3; ++c) rd.dofs.push_back(static_cast<int>(3 * i + c));
    if (rd.dofs.empty()) continue;  // no contact on this body
    const int k = rd.rank[r];
    rd.Kc.noalias() = rd.L[r].leftCols(k).transpose() * B(Eigen::all, rd.dofs);
    rd.Gc.noalias() = h * (rd.Kc.transpose() * rd.Kc);
    G(rd.dofs, rd.dofs) += rd.Gc;
    g.noalias() += B.transpose() * rd.u_free.segment<6>(6 * static_cast<Eigen::Index>(r));
  }
}

void rigid_body_rows(const Model& model, const ContactData::Rigid& rd, MatX& Kt) {
  Eigen::Index rows = 0;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) rows += rd.rank[r];
  Kt.resize(rows, rd.Ht.cols());
  rows = 0;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const int k = rd.rank[r];
    if (k == 0) continue;  // a fixed body
    // zero rows without contact: set_rigid drops them
    Kt.middleRows(rows, k).noalias() = rd.L[r].leftCols(k).transpose() * rd.Ht.middleRows<6>(6 * static_cast<Eigen::Index>(r));
    rows += k;
  }
}

void rigid_delassus_rows(const Model& model, Data& data, MatX& Kt, VecX& g) {
  auto& rd = data.contact.rigid;
  rigid_body_rows(model, rd, Kt);
  const Eigen::Index rows = Kt.rows();
  for (std::size_t r = 0; r < model.rigid.size(); ++r)
    if (rd.rank[r] > 0)
      g.noalias() += rd.Ht.middleRows<6>(6 * static_cast<Eigen::Index>(r)).transpose() *
                     rd.u_free.segment<6>(6 * static_cast<Eigen::Index>(r));
  // The limit rows' tangential diagonals: one row per tangential column (header).
  const Eigen::Index L = static_cast<Eigen::Index>(rd.limit_rows.size());
  if (L == 0) return;
  const Eigen::Index n0 = rd.Ht.cols() - 3 * L;
  Kt.conservativeResize(rows + 2 * L, Eigen::NoChange);
  Kt.bottomRows(2 * L).setZero();
  for (Eigen::Index l = 0; l < L; ++l) {
    const Eigen::Index o = n0 + 3 * l;
    const double d = Kt.col(o + 2).head(rows).norm();
    Kt(rows + 2 * l, o) = d;
    Kt(rows + 2 * l + 1, o + 1) = d;
  }
}

void correct_rigid_velocities(const Model& model, Data& data, double h, const VecX& lambda) {
  auto& rd = data.contact.rigid;
  data.contact.serial = next_record_serial();  // the record's corrected velocities change
  rd.u = rd.u_free;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    if (!has_dofs(model.rigid[r])) continue;
    const Eigen::Index o = 6 * static_cast<Eigen::Index>(r);
    const rigid::Vec6 impulse = h * (rd.Ht.middleRows<6>(o) * lambda);
    rd.u.segment<6>(o) += rd.W[r] * impulse;
  }
}

namespace {
bool limited(const rigid::RigidBody& b) {
  return b.joint.limits && (b.joint.kind == rigid::Joint::Kind::hinge || b.joint.kind == rigid::Joint::Kind::slider);
}
// The joint rate of a body's (v, omega) (hinge: n.omega; slider: n.v).
double joint_rate(const rigid::RigidBody& b, const rigid::Vec6& u) {
  return b.joint.kind == rigid::Joint::Kind::hinge ? b.joint.axis.dot(u.tail<3>()) : b.joint.axis.dot(u.head<3>());
}
// Distance to the limit on `side` (0: lower, 1: upper) at the start of the step.
double limit_gap(const rigid::RigidBody& b, const rigid::RigidState& s, int side) {
  const double c = rigid::joint_coordinate(b, s);
  return side == 0 ? c - b.joint.limits->first : b.joint.limits->second - c;
}
}  // namespace

int num_limit_slots(const Model& model) {
  int L = 0;
  for (const auto& b : model.rigid) L += limited(b) ? 2 : 0;
  return L;
}

int select_limit_rows(const Model& model, Data& data, double h, bool all) {
  auto& rd = data.contact.rigid;
  rd.limit_rows.clear();  // capacity kept: no allocation after the first step
  const double margin = model.contact.detection.margin;
  int slot = 0;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& body = model.rigid[r];
    if (!limited(body)) continue;
    // The margin in the joint coordinate: the detection margin (m) for a slider; for a
    // hinge, the angle that moves the surface vertex farthest from the axis by it.
    // The reach is invariant (the body turns about the axis): rigid::initialize's.
    double scale = 1;
    if (body.joint.kind == rigid::Joint::Kind::hinge) scale = body.joint_reach > 0 ? 1 / body.joint_reach : 0;
    const double speed = std::max(std::abs(joint_rate(body, rd.u_free.segment<6>(6 * static_cast<Eigen::Index>(r)))),
                                  std::abs(joint_rate(body, (rigid::Vec6() << rd.in[r].velocity, rd.in[r].angular_velocity).finished())));
    for (int side = 0; side < 2; ++side, ++slot)
      if (all || limit_gap(body, rd.in[r], side) < margin * scale + 2 * h * speed)
        rd.limit_rows.push_back({static_cast<int>(r), side, slot});
  }
  return static_cast<int>(rd.limit_rows.size());
}

void append_limit_rows(const Model& model, Data& data, int nc, MatX* G, VecX& g) {
  auto& rd = data.contact.rigid;
  const int L = static_cast<int>(rd.limit_rows.size());
  const auto& mu = data.contact.mu;
  rd.mu_ext.resize(nc + L);
  rd.mu_ext.head(nc) = mu;
  if (L == 0) return;
  rd.mu_ext.tail(L).setZero();
  const Eigen::Index n0 = 3 * static_cast<Eigen::Index>(nc), n1 = n0 + 3 * L;
  rd.Ht.conservativeResize(Eigen::NoChange, n1);
  rd.Ht.rightCols(3 * L).setZero();
  if (G) {
    G->conservativeResize(n1, n1);
    G->rightCols(3 * L).setZero();
    G->bottomRows(3 * L).setZero();
  }
  g.conservativeResize(n1);
  g.tail(3 * L).setZero();
  for (int l = 0; l < L; ++l) {
    const auto& row = rd.limit_rows[static_cast<std::size_t>(l)];
    const auto& body = model.rigid[static_cast<std::size_t>(row.body)];
    // The limit's row on the body's (v, omega): any j with T.j = s gives s cdot on the
    // joint's motion (v, omega) = T cdot, and W_r j = T (T.j) / a = s T / a, the joint
    // rate change per unit impulse s / a; j = s T / |T|^2 (s = +1 lower, -1 upper).
    const rigid::Vec6 T = rigid::joint_motion_basis(body, rd.in[static_cast<std::size_t>(row.body)]).col(0);
    const double s = row.side == 0 ? 1.0 : -1.0;
    rd.Ht.col(n0 + 3 * l + 2).segment<6>(6 * static_cast<Eigen::Index>(row.body)) = s * T / T.squaredNorm();
  }
}

void finish_limit_rows(const Model& model, Data& data, double h, int nc, MatX* G, VecX& g) {
  const auto& rd = data.contact.rigid;
  for (std::size_t l = 0; l < rd.limit_rows.size(); ++l) {
    const auto& row = rd.limit_rows[l];
    const auto r = static_cast<std::size_t>(row.body);
    const Eigen::Index o = 3 * (static_cast<Eigen::Index>(nc) + static_cast<Eigen::Index>(l));
    g[o + 2] += limit_gap(model.rigid[r], rd.in[r], row.side) / h;
    if (G) (*G)(o, o) = (*G)(o + 1, o + 1) = (*G)(o + 2, o + 2);
  }
}

bool unselected_limit_crossed(const Model& model, const Data& data, double h) {
  const auto& rd = data.contact.rigid;
  int slot = 0;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto& body = model.rigid[r];
    if (!limited(body)) continue;
    const double rate = joint_rate(body, rd.u.segment<6>(6 * static_cast<Eigen::Index>(r)));
    for (int side = 0; side < 2; ++side, ++slot) {
      bool selected = false;
      for (const auto& row : rd.limit_rows) selected = selected || row.slot == slot;
      const double s = side == 0 ? 1.0 : -1.0;
      if (!selected && limit_gap(body, rd.in[r], side) + h * s * rate < 0) return true;
    }
  }
  return false;
}

void remove_limit_rows(const Model& model, Data& data, int nc, bool sparse) {
  auto& cd = data.contact;
  auto& rd = cd.rigid;
  const int slots = num_limit_slots(model);
  if (rd.limit_lambda.size() != slots) rd.limit_lambda.setZero(slots);
  rd.limit_lambda.setZero();
  const int L = static_cast<int>(rd.limit_rows.size());
  if (L == 0) return;
  const Eigen::Index n0 = 3 * static_cast<Eigen::Index>(nc);
  for (int l = 0; l < L; ++l) rd.limit_lambda[rd.limit_rows[static_cast<std::size_t>(l)].slot] = cd.lambda[n0 + 3 * l + 2];
  cd.lambda.conservativeResize(n0);
  cd.sigma.conservativeResize(n0);
  cd.modes.resize(static_cast<std::size_t>(nc));
  if (sparse) {
    rd.Kt.conservativeResize(rd.Kt.rows() - 2 * L, n0);
  } else {
    cd.G.conservativeResize(n0, n0);
  }
  cd.g.conservativeResize(n0);
  rd.Ht.conservativeResize(Eigen::NoChange, n0);
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
    switch (body.joint.kind) {
      case rigid::Joint::Kind::hinge:  // along the joint exactly, as rigid::step
        rigid::move_along_joint(body, s, h * body.joint.axis.dot(rd.u.segment<3>(o + 3)), h, e);
        break;
      case rigid::Joint::Kind::slider:
        rigid::move_along_joint(body, s, h * body.joint.axis.dot(rd.u.segment<3>(o)), h, e);
        break;
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

namespace softdiff::contact {

int reduce_rigid_manifolds(const Model& model, Data& data, std::vector<collision::Contact>& list) {
  auto& rd = data.contact.rigid;
  rd.manifold_dropped = 0;
  const int n = model.fem.num_nodes;
  // Candidates: a rigid body's pseudo-node against an obstacle's face.
  rd.manifold.clear();
  for (std::size_t i = 0; i < list.size(); ++i) {
    const auto& c = list[i];
    if (c.kind == collision::ContactKind::vertex_obstacle && c.count == 1 && c.nodes[0] >= n &&
        c.kind_b == collision::Feature::face)
      rd.manifold.push_back(static_cast<int>(i));
  }
  if (rd.manifold.size() < 3) return 0;
  rd.drop.assign(list.size(), 0);
  // Groups: same body, obstacle and face (then the same plane, frame and mu, checked below).
  auto key = [&](int i) {
    const auto& c = list[static_cast<std::size_t>(i)];
    return std::array<int, 4>{c.side_a, c.side_b, c.feature_b, i};
  };
  std::sort(rd.manifold.begin(), rd.manifold.end(), [&](int a, int b) { return key(a) < key(b); });
  auto same_plane = [&](const collision::Contact& a, const collision::Contact& b) {
    if (a.side_a != b.side_a || a.side_b != b.side_b || a.feature_b != b.feature_b || a.mu != b.mu) return false;
    if ((a.frame - b.frame).cwiseAbs().maxCoeff() > 1e-14) return false;  // unit columns: round-off only
    const Vec3 d = a.point_b - b.point_b;  // both on the face's plane: d orthogonal to n
    return std::abs(a.frame.col(2).dot(d)) <= 1e-12 * d.norm();
  };
  const std::size_t total = rd.manifold.size();
  for (std::size_t s = 0; s < total;) {
    std::size_t e = s + 1;
    const auto& first = list[static_cast<std::size_t>(rd.manifold[s])];
    while (e < total && same_plane(first, list[static_cast<std::size_t>(rd.manifold[e])])) ++e;
    const int k = static_cast<int>(e - s);
    if (k >= 3) {
      // The group's points in the tangent plane (t1, t2), sorted lexicographically.
      const Vec3 t1 = first.frame.col(0), t2 = first.frame.col(1);
      int* g = rd.manifold.data() + s;
      auto coords = [&](int i) {
        const Vec3& p = list[static_cast<std::size_t>(i)].point;
        return std::pair<double, double>(t1.dot(p), t2.dot(p));
      };
      std::sort(g, g + k, [&](int a, int b) { return coords(a) < coords(b); });
      rd.plane.resize(2 * static_cast<std::size_t>(k));
      double lo0 = 1e300, hi0 = -1e300, lo1 = 1e300, hi1 = -1e300;
      for (int j = 0; j < k; ++j) {
        const auto [u, v] = coords(g[j]);
        rd.plane[2 * j] = u;
        rd.plane[2 * j + 1] = v;
        lo0 = std::min(lo0, u), hi0 = std::max(hi0, u), lo1 = std::min(lo1, v), hi1 = std::max(hi1, v);
      }
      const double size = std::hypot(hi0 - lo0, hi1 - lo1);
      auto cross = [&](int o, int a, int b) {  // (a - o) x (b - o) in the plane
        return (rd.plane[2 * a] - rd.plane[2 * o]) * (rd.plane[2 * b + 1] - rd.plane[2 * o + 1]) -
               (rd.plane[2 * a + 1] - rd.plane[2 * o + 1]) * (rd.plane[2 * b] - rd.plane[2 * o]);
      };
      // Andrew's monotone chain; points on an edge (to round-off: turns below 1e-12
      // size^2) are not vertices (they are convex combinations of its ends). Every hull
      // vertex is kept, and another point is dropped only if the 3D check below finds it
      // a convex combination of them to 1e-12 of the group's size.
      auto& hull = rd.hull;
      hull.clear();
      const double flat = 1e-12 * size * size;
      for (int j = 0; j < k; ++j) {
        while (hull.size() >= 2 && cross(hull[hull.size() - 2], hull.back(), j) <= flat) hull.pop_back();
        hull.push_back(j);
      }
      const std::size_t lower = hull.size() + 1;
      for (int j = k - 2; j >= 0; --j) {
        while (hull.size() >= lower && cross(hull[hull.size() - 2], hull.back(), j) <= flat) hull.pop_back();
        hull.push_back(j);
      }
      hull.pop_back();  // the first point again
      const int H = static_cast<int>(hull.size());
      if (size > 0 && H < k) {
        const double tol = 1e-12 * size;
        auto point = [&](int j) -> const Vec3& { return list[static_cast<std::size_t>(g[j])].point; };
        for (int j = 0; j < k; ++j) {
          if (std::find(hull.begin(), hull.end(), j) != hull.end()) continue;
          // Barycentric weights in a fan triangle (hull[0], hull[t], hull[t + 1]), or on
          // the segment when the points are collinear (H = 2).
          bool inside = false;
          Vec3 combination = Vec3::Zero();
          if (H == 2) {
            const int a = hull[0], b = hull[1];
            const double du = rd.plane[2 * b] - rd.plane[2 * a], dv = rd.plane[2 * b + 1] - rd.plane[2 * a + 1];
            const double t = ((rd.plane[2 * j] - rd.plane[2 * a]) * du + (rd.plane[2 * j + 1] - rd.plane[2 * a + 1]) * dv) /
                             (du * du + dv * dv);
            if (t >= -1e-12 && t <= 1 + 1e-12) {
              const double c = std::clamp(t, 0.0, 1.0);
              combination = (1 - c) * point(a) + c * point(b);
              inside = true;
            }
          } else {
            for (int t = 1; t + 1 < H && !inside; ++t) {
              const int a = hull[0], b = hull[static_cast<std::size_t>(t)], c = hull[static_cast<std::size_t>(t) + 1];
              const double area = cross(a, b, c);
              if (area <= 0) continue;
              double wb = cross(a, j, c) / area, wc = cross(a, b, j) / area, wa = 1 - wb - wc;
              if (wa < -1e-12 || wb < -1e-12 || wc < -1e-12) continue;
              wa = std::max(wa, 0.0), wb = std::max(wb, 0.0), wc = std::max(wc, 0.0);
              const double sum = wa + wb + wc;
              combination = (wa * point(a) + wb * point(b) + wc * point(c)) / sum;
              inside = true;
            }
          }
          if (inside && (point(j) - combination).norm() <= tol) {
            rd.drop[static_cast<std::size_t>(g[j])] = 1;
            ++rd.manifold_dropped;
          }
        }
      }
    }
    s = e;
  }
  if (rd.manifold_dropped == 0) return 0;
  std::size_t w = 0;
  for (std::size_t i = 0; i < list.size(); ++i)
    if (!rd.drop[i]) {
      if (w != i) list[w] = list[i];
      ++w;
    }
  list.resize(w);
  return rd.manifold_dropped;
}

}  // namespace softdiff::contact
