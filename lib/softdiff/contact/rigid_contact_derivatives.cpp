// Derivatives of the contact stage with rigid bodies: see rigid_contact_derivatives.hpp.
#include <softdiff/contact/rigid_contact_derivatives.hpp>

#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/LU>

#include <cmath>

namespace softdiff::contact {

namespace {
using Vec6 = rigid::Vec6;
using Row19 = Eigen::Matrix<double, 1, 19>;
constexpr int P = 0, TH = 3, V = 6, W = 9, MASS = 12, INERTIA = 13;  // columns of z_r (12 state, 7 parameters)

bool has_dofs(const rigid::RigidBody& b) { return b.joint.kind != rigid::Joint::Kind::fixed; }

Eigen::Matrix<double, 19, 1> gather(const VecX& z, const VecX& zp, Eigen::Index r) {
  Eigen::Matrix<double, 19, 1> out = Eigen::Matrix<double, 19, 1>::Zero();
  if (z.size()) out.head<12>() = z.segment<12>(12 * r);
  if (zp.size()) out.tail<7>() = zp.segment<7>(7 * r);
  return out;
}
}  // namespace

int RigidContactDerivative::body_of(const Model& model, int node) const {
  return model.contact.rigid_node_body[static_cast<std::size_t>(node - model.fem.num_nodes)];
}

void RigidContactDerivative::prepare(const Model& model, const Data& data, const std::vector<rigid::RigidState>& out,
                                     double h, const MatX* G_contacts) {
  const auto& cd = data.contact;
  const auto& rd = cd.rigid;
  const int n = model.fem.num_nodes;
  const std::size_t R = model.rigid.size();
  ++prepares_;
  h_ = h;
  contacts_ = cd.contacts.size() > 0;
  bodies_.resize(R);
  const Eigen::Index pseudo = static_cast<Eigen::Index>(model.contact.rigid_node_body.size());
  if (F_.size() != 3 * pseudo) F_.resize(3 * pseudo);
  F_.setZero();
  for (int i = 0; contacts_ && i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
    const Vec3 Cl = c.frame * cd.lambda.segment<3>(3 * i);
    for (int k = 0; k < c.count; ++k)
      if (c.nodes[k] >= n) F_.segment<3>(3 * (c.nodes[k] - n)) += h * c.weights[k] * Cl;
  }
  // rho_k = R_r X_k at the start of the step (the lever arms and the detection's pose).
  if (rho_.size() != 3 * pseudo) rho_.resize(3 * pseudo);
  for (Eigen::Index k = 0; k < pseudo; ++k) {
    const auto r = static_cast<std::size_t>(model.contact.rigid_node_body[static_cast<std::size_t>(k)]);
    rho_.segment<3>(3 * k) = rd.in[r].orientation * model.rigid[r].surface.vertices.col(n + k - model.contact.rigid_node_begin[r]);
  }
  prepare_limits(model, data, h, G_contacts);
  const Mat3 I3 = Mat3::Identity();
  for (std::size_t r = 0; r < R; ++r) {
    const auto& body = model.rigid[r];
    Body& B = bodies_[r];
    const auto& in = rd.in[r];
    const auto& fr = rd.free[r];
    rigid::StepJacobian J;
    rigid::step_jacobian(body, in, fr, data.rigid[r], h, model.step.gravity, Vec3::Zero(), J);
    B.Jf << J.state, J.params;
    // A limited hinge or slider: u_free is the free step WITHOUT its limits
    // (begin_rigid_contact), so du_free is that step's Jacobian (Ju); W keeps the clamped
    // free step's orientation (Jf). Unlimited: the same step.
    Mat12x19 Ju = B.Jf;
    double free_rate = 0;
    {
      const bool hinge = body.joint.kind == rigid::Joint::Kind::hinge;
      const rigid::RigidState* f = &fr;
      rigid::RigidState unclamped;
      if (body.joint.limits && (hinge || body.joint.kind == rigid::Joint::Kind::slider)) {
        const rigid::StepInfo info = rigid::step(body, in, h, model.step.gravity, Vec3::Zero(),
                                                 Vec3::Zero(), unclamped, false);
        rigid::StepJacobian JU;
        rigid::step_jacobian(body, in, unclamped, info, h, model.step.gravity, Vec3::Zero(), JU);
        Ju << JU.state, JU.params;
        f = &unclamped;
      }
      free_rate = body.joint.axis.dot(hinge ? f->angular_velocity : f->velocity);
    }
    B.dofs = has_dofs(body);
    B.K0.setZero();
    B.Q.setZero();
    B.E_in.setZero();
    B.E_u.setZero();
    B.W = rd.W[r];
    B.omega.setZero();
    if (!B.dofs) continue;
    const Eigen::Index o = 6 * static_cast<Eigen::Index>(r);
    const Vec6 u = rd.u.segment<6>(o);
    B.omega = u.tail<3>();
    // P_r = h H_r^T lambda and Q_r = [0; sum_k [F_k][rho_k]] (d(rho x F) = [F][rho] dtheta).
    const Vec6 Pr = contacts_ ? Vec6(h * (Ht_.middleRows<6>(o) * lambda_)) : Vec6::Zero();
    const int begin = model.contact.rigid_node_begin[r];
    for (Eigen::Index j = 0; j < body.surface.vertices.cols(); ++j) {
      const Eigen::Index k = begin - n + j;
      B.Q.bottomRows<3>() += rigid::hat(F_.segment<3>(3 * k)) * rigid::hat(rho_.segment<3>(3 * k));
    }
    const Vec3 Pv = Pr.head<3>(), Pw = Pr.tail<3>();
    const Mat3 Rf = fr.orientation.toRotationMatrix();
    const double m = body.mass;
    const Vec3 nax = body.joint.axis;
    switch (body.joint.kind) {
      case rigid::Joint::Kind::free: {
        // u_free = (v_free, omega_free); W = diag(I / m, R_f I^-1 R_f^T): with q_f ->
        // exp(dtheta_f) q_f, d(W_w) P_w = (W_w [P_w] - [W_w P_w]) dtheta_f.
        B.K0.topRows<3>() = B.Jf.middleRows<3>(V);
        B.K0.bottomRows<3>() = B.Jf.middleRows<3>(W);
        const Mat3 Iinv = body.inertia.inverse();
        const Mat3 Ww = Rf * Iinv * Rf.transpose();
        B.K0.bottomRows<3>() += (Ww * rigid::hat(Pw) - rigid::hat(Ww * Pw)) * B.Jf.middleRows<3>(TH);
        B.K0.block<3, 1>(0, MASS) += -Pv / (m * m);
        for (int k = 0; k < 6; ++k)
          B.K0.block<3, 1>(3, INERTIA + k) += -Rf * Iinv * rigid::inertia_unit(k) * Iinv * Rf.transpose() * Pw;
        break;
      }
      case rigid::Joint::Kind::hinge: {
        // T = [n x (p - a); n] at the start, u_free = (n.omega_free) T, W = T T^T / a_s with
        // a_s = m |n x r|^2 + n.I_w n (I_w at q_f): d(W P) = dT s / a_s + T (dT.P) / a_s -
        // T s da_s / a_s^2, s = T.P, dT = [n x dp; 0].
        const Vec3 r_arm = in.position - body.joint.anchor, nr = nax.cross(r_arm);
        Vec6 T;
        T << nr, nax;
        const double rate = free_rate;
        B.K0 = T * (nax.transpose() * Ju.middleRows<3>(W));
        B.K0.block<3, 3>(0, P) += rate * rigid::hat(nax);
        const Mat3 Iw = Rf * body.inertia * Rf.transpose();
        // a_s - h_f^2 Q'(delta_u) (begin_rigid_contact: the implicit gravity torque's
        // tangent at the free end delta_u = h_f rate, h_f the free step's own h), with
        // -Q'(delta) = c1 sin(delta) + c2 cos(delta), c1 = F.(n x r_perp), c2 = F.r_perp,
        // F = m g: dc1 = (F x n).dp, dc2 = F_perp.dp, both proportional to m;
        // d delta = h_f n.d omega_u (the unlimited free step's Jacobian Ju).
        const double hf = data.rigid[r].bdf2 ? 2.0 * model.step.dt / 3.0 : model.step.dt;
        const Vec3 r_perp = r_arm - nax.dot(r_arm) * nax, F = m * model.step.gravity, F_perp = F - nax.dot(F) * nax;
        const double c1 = F.dot(nax.cross(r_perp)), c2 = F.dot(r_perp), delta = hf * rate;
        const double sd = std::sin(delta), cd_ = std::cos(delta);
        const double a = m * nr.squaredNorm() + nax.dot(Iw * nax) + hf * hf * (c1 * sd + c2 * cd_), s = T.dot(Pr);
        B.K0.block<3, 3>(0, P) += rigid::hat(nax) * (s / a);
        B.K0.block<6, 3>(0, P) += T * Pv.cross(nax).transpose() / a;
        Row19 da = Row19::Zero();
        da.segment<3>(P) += 2 * m * nr.transpose() * rigid::hat(nax);
        da += 2 * (Iw * nax).cross(nax).transpose() * B.Jf.middleRows<3>(TH);
        da(MASS) += nr.squaredNorm();
        da.segment<3>(P) += hf * hf * (sd * F.cross(nax) + cd_ * F_perp).transpose();
        da(MASS) += hf * hf * (c1 * sd + c2 * cd_) / m;
        da += hf * hf * (c1 * cd_ - c2 * sd) * hf * nax.transpose() * Ju.middleRows<3>(W);
        for (int k = 0; k < 6; ++k) da(INERTIA + k) += nax.dot(Rf * rigid::inertia_unit(k) * Rf.transpose() * nax);
        B.K0 -= T * da * (s / (a * a));
        break;
      }
      case rigid::Joint::Kind::slider: {
        // T = [n; 0], u_free = (n.v_free) T, W = T T^T / m.
        Vec6 T;
        T << nax, Vec3::Zero();
        B.K0 = T * (nax.transpose() * Ju.middleRows<3>(V));
        B.K0.col(MASS) += -T * T.dot(Pr) / (m * m);
        break;
      }
      case rigid::Joint::Kind::fixed: break;
    }
    // The end pose from (in, u): see rigid_contact.cpp end_rigid_contact.
    const auto& e = out[r];
    switch (body.joint.kind) {
      case rigid::Joint::Kind::free: {
        const Vec3 w1 = u.tail<3>();
        const Mat3 E = rigid::quaternion_exp(h * w1).toRotationMatrix();
        B.E_in.block<3, 3>(P, P) = I3;
        B.E_in.block<3, 3>(TH, TH) = E;
        B.E_u.block<3, 3>(P, 0) = h * I3;
        B.E_u.block<3, 3>(TH, 3) = h * E * rigid::right_jacobian(h * w1);
        B.E_u.block<3, 3>(V, 0) = I3;
        B.E_u.block<3, 3>(W, 3) = I3;
        break;
      }
      case rigid::Joint::Kind::hinge: {
        // delta = h n.omega_u; p' = a + Rd (p - a), q' = exp(delta n) q, omega' = delta / h n,
        // v' = omega' x (p' - a).
        const double delta = h * nax.dot(u.tail<3>());
        const Mat3 Rd = Eigen::AngleAxisd(delta, nax).toRotationMatrix();
        const Vec3 t = nax.cross(e.position - body.joint.anchor);
        Eigen::Matrix<double, 1, 6> gd = Eigen::Matrix<double, 1, 6>::Zero();
        gd.tail<3>() = h * nax.transpose();
        B.E_in.block<3, 3>(P, P) = Rd;
        B.E_in.block<3, 3>(TH, TH) = Rd;
        B.E_in.block<3, 3>(V, P) = delta / h * rigid::hat(nax) * Rd;
        B.E_u.middleRows<3>(P) = t * gd;
        B.E_u.middleRows<3>(TH) = nax * gd;
        B.E_u.middleRows<3>(W) = nax * gd / h;
        B.E_u.middleRows<3>(V) = t * gd / h + delta / h * rigid::hat(nax) * t * gd;
        break;
      }
      case rigid::Joint::Kind::slider: {
        Eigen::Matrix<double, 1, 6> gd = Eigen::Matrix<double, 1, 6>::Zero();
        gd.head<3>() = nax.transpose();
        B.E_in.block<3, 3>(P, P) = I3;
        B.E_in.block<3, 3>(TH, TH) = I3;
        B.E_u.middleRows<3>(P) = h * nax * gd;
        B.E_u.middleRows<3>(V) = nax * gd;
        break;
      }
      case rigid::Joint::Kind::fixed: break;
    }
  }
}

void RigidContactDerivative::pseudo_position_jvp(const Model& model, const VecX& z, VecX& dX) const {
  const int n = model.fem.num_nodes;
  const Eigen::Index pseudo = static_cast<Eigen::Index>(model.contact.rigid_node_body.size());
  for (Eigen::Index k = 0; k < pseudo; ++k) {
    if (!z.size()) {
      dX.segment<3>(3 * (n + k)).setZero();
      continue;
    }
    const Eigen::Index o = 12 * static_cast<Eigen::Index>(model.contact.rigid_node_body[static_cast<std::size_t>(k)]);
    // x_k = p + R X_k: dx_k = dp + dtheta x rho_k.
    dX.segment<3>(3 * (n + k)) = z.segment<3>(o + P) + z.segment<3>(o + TH).cross(rho_.segment<3>(3 * k));
  }
}

void RigidContactDerivative::add_pseudo_position_vjp(const Model& model, const VecX& bar_X, VecX& bar_z) const {
  const int n = model.fem.num_nodes;
  const Eigen::Index pseudo = static_cast<Eigen::Index>(model.contact.rigid_node_body.size());
  for (Eigen::Index k = 0; k < pseudo; ++k) {
    const Eigen::Index o = 12 * static_cast<Eigen::Index>(model.contact.rigid_node_body[static_cast<std::size_t>(k)]);
    const Vec3 bx = bar_X.segment<3>(3 * (n + k));
    bar_z.segment<3>(o + P) += bx;
    bar_z.segment<3>(o + TH) += rho_.segment<3>(3 * k).cross(bx);  // (-[rho])^T bx
  }
}

void RigidContactDerivative::impulse_jvp(const Model& model, const VecX& z, const VecX& zp, const VecX& r,
                                         VecX& du0) const {
  const int n = model.fem.num_nodes;
  du0.setZero(6 * static_cast<Eigen::Index>(model.rigid.size()));
  for (std::size_t b = 0; b < model.rigid.size(); ++b) {
    const Body& B = bodies_[b];
    if (!B.dofs) continue;
    const auto rb = static_cast<Eigen::Index>(b);
    const Eigen::Matrix<double, 19, 1> zb = gather(z, zp, rb);
    // dP = sum_k [df_k; rho_k x df_k] + Q dtheta.
    Vec6 dP = B.Q * zb.segment<3>(TH);
    const int begin = model.contact.rigid_node_begin[b];
    for (Eigen::Index j = 0; j < model.rigid[b].surface.vertices.cols(); ++j) {
      const Eigen::Index k = begin - n + j;
      const Vec3 df = r.segment<3>(3 * (begin + j));
      dP.head<3>() += df;
      dP.tail<3>() += rho_.segment<3>(3 * k).cross(df);
    }
    // The limit rows' impulses on this body: h lambda_l dj[dp].
    for (const Limit& l : limits_)
      if (l.body == static_cast<int>(b)) dP += h_ * l.lambda * (l.Mj * zb.segment<3>(P));
    du0.segment<6>(6 * rb) = B.K0 * zb + B.W * dP;
  }
}

void RigidContactDerivative::impulse_vjp(const Model& model, const VecX& bar_du0, VecX& bar_z, VecX& bar_zp,
                                         VecX& y) const {
  const int n = model.fem.num_nodes;
  for (std::size_t b = 0; b < model.rigid.size(); ++b) {
    const Body& B = bodies_[b];
    const int begin = model.contact.rigid_node_begin[b];
    const Eigen::Index nv = model.rigid[b].surface.vertices.cols();
    if (!B.dofs) {
      y.segment(3 * begin, 3 * nv).setZero();
      continue;
    }
    const auto rb = static_cast<Eigen::Index>(b);
    const Vec6 bdu = bar_du0.segment<6>(6 * rb);
    const Eigen::Matrix<double, 19, 1> bz = B.K0.transpose() * bdu;
    const Vec6 bP = B.W.transpose() * bdu;
    bar_z.segment<12>(12 * rb) += bz.head<12>();
    bar_zp.segment<7>(7 * rb) += bz.tail<7>();
    bar_z.segment<3>(12 * rb + TH) += B.Q.transpose() * bP;
    for (const Limit& l : limits_)
      if (l.body == static_cast<int>(b)) bar_z.segment<3>(12 * rb + P) += h_ * l.lambda * (l.Mj.transpose() * bP);
    for (Eigen::Index j = 0; j < nv; ++j) {
      const Eigen::Index k = begin - n + j;
      // df -> [df; rho x df]: bar_df = bar_P_v + (-[rho])^T... = bar_P_v - rho x bar_P_w.
      y.segment<3>(3 * (begin + j)) = bP.head<3>() - rho_.segment<3>(3 * k).cross(bP.tail<3>());
    }
  }
}

void RigidContactDerivative::add_sigma_jvp(const Model& model, const ContactData& cd, const VecX& du0, const VecX& z,
                                           VecX& b) const {
  const int n = model.fem.num_nodes;
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
    Vec3 dV = Vec3::Zero();
    for (int k = 0; k < c.count; ++k) {
      const int node = c.nodes[k];
      if (node < n || c.weights[k] == 0) continue;
      const int r = body_of(model, node);
      const Body& B = bodies_[static_cast<std::size_t>(r)];
      if (!B.dofs) continue;
      const Vec3 rho_k = rho_.segment<3>(3 * (node - n));
      // The pseudo-node's velocity change: du_v + du_w x rho + omega x (dtheta x rho).
      Vec3 d = du0.segment<3>(6 * r) + du0.segment<3>(6 * r + 3).cross(rho_k);
      if (z.size()) d += B.omega.cross(Vec3(z.segment<3>(12 * r + TH)).cross(rho_k));
      dV += c.weights[k] * d;
    }
    b.segment<3>(3 * i) += c.frame.transpose() * dV;
  }
}

void RigidContactDerivative::add_sigma_vjp(const Model& model, const ContactData& cd, const VecX& bar_b,
                                           VecX& bar_du0, VecX& bar_z) const {
  const int n = model.fem.num_nodes;
  for (int i = 0; i < cd.contacts.size(); ++i) {
    const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
    const Vec3 Cb = c.frame * bar_b.segment<3>(3 * i);
    for (int k = 0; k < c.count; ++k) {
      const int node = c.nodes[k];
      if (node < n || c.weights[k] == 0) continue;
      const int r = body_of(model, node);
      const Body& B = bodies_[static_cast<std::size_t>(r)];
      if (!B.dofs) continue;
      const Vec3 rho_k = rho_.segment<3>(3 * (node - n));
      const Vec3 g = c.weights[k] * Cb;
      bar_du0.segment<3>(6 * r) += g;
      bar_du0.segment<3>(6 * r + 3) += rho_k.cross(g);  // (-[rho])^T g
      const Mat3 M = -rigid::hat(B.omega) * rigid::hat(rho_k);  // omega x (dtheta x rho) = M dtheta
      bar_z.segment<3>(12 * r + TH) += M.transpose() * g;
    }
  }
}

void RigidContactDerivative::out_jvp(const Model& model, const ContactData& /*cd*/, const VecX& z, const VecX& zp,
                                     const VecX& du0, const VecX& dlambda, VecX& d_out) const {
  const Eigen::Index R = static_cast<Eigen::Index>(model.rigid.size());
  d_out.resize(12 * R);
  for (Eigen::Index r = 0; r < R; ++r) {
    const Body& B = bodies_[static_cast<std::size_t>(r)];
    const Eigen::Matrix<double, 19, 1> zb = gather(z, zp, r);
    if (!contacts_ || !B.dofs) {
      d_out.segment<12>(12 * r) = B.Jf * zb;
      continue;
    }
    const Vec6 du = du0.segment<6>(6 * r) + h_ * (B.W * (Ht_.middleRows<6>(6 * r) * dlambda));
    d_out.segment<12>(12 * r) = B.E_in * zb.head<12>() + B.E_u * du;
  }
}

void RigidContactDerivative::out_vjp(const Model& model, const ContactData& /*cd*/, const VecX& bar_out, VecX& bar_z,
                                     VecX& bar_zp, VecX& bar_du0, VecX& bar_lambda) const {
  const Eigen::Index R = static_cast<Eigen::Index>(model.rigid.size());
  bar_z.setZero(12 * R);
  bar_zp.setZero(7 * R);
  bar_du0.setZero(6 * R);
  for (Eigen::Index r = 0; r < R; ++r) {
    const Body& B = bodies_[static_cast<std::size_t>(r)];
    const rigid::Vec12 bo = bar_out.size() ? rigid::Vec12(bar_out.segment<12>(12 * r)) : rigid::Vec12::Zero();
    if (!contacts_ || !B.dofs) {
      const Eigen::Matrix<double, 19, 1> bz = B.Jf.transpose() * bo;
      bar_z.segment<12>(12 * r) += bz.head<12>();
      bar_zp.segment<7>(7 * r) += bz.tail<7>();
      continue;
    }
    bar_z.segment<12>(12 * r) += B.E_in.transpose() * bo;
    const Vec6 bdu = B.E_u.transpose() * bo;
    bar_du0.segment<6>(6 * r) = bdu;
    bar_lambda.noalias() += h_ * (Ht_.middleRows<6>(6 * r).transpose() * (B.W.transpose() * bdu));
  }
}

void RigidContactDerivative::extended_velocities(const Model& model, const ContactData& cd, const VecX& v,
                                                 VecX& U) const {
  const int n = model.fem.num_nodes;
  const Eigen::Index pseudo = static_cast<Eigen::Index>(model.contact.rigid_node_body.size());
  U.resize(3 * (n + pseudo));
  U.head(3 * n) = v;
  for (Eigen::Index k = 0; k < pseudo; ++k) {
    const int r = model.contact.rigid_node_body[static_cast<std::size_t>(k)];
    const Vec6 u = cd.rigid.u.segment<6>(6 * r);
    U.segment<3>(3 * (n + k)) = u.head<3>() + u.tail<3>().cross(rho_.segment<3>(3 * k));
  }
}

void RigidContactDerivative::prepare_limits(const Model& model, const Data& data, double h, const MatX* G_contacts) {
  const auto& cd = data.contact;
  const auto& rd = cd.rigid;
  const int nc = contacts_ ? cd.contacts.size() : 0;
  const int L = contacts_ ? static_cast<int>(rd.limit_rows.size()) : 0;
  nc_ = nc;
  u_ = rd.u;
  limits_.resize(static_cast<std::size_t>(L));
  const Eigen::Index n0 = 3 * static_cast<Eigen::Index>(nc), n1 = n0 + 3 * static_cast<Eigen::Index>(L);
  Ht_.resize(6 * static_cast<Eigen::Index>(model.rigid.size()), n1);
  lambda_.resize(n1);
  if (nc > 0) {
    Ht_.leftCols(n0) = rd.Ht;
    lambda_.head(n0) = cd.lambda.head(n0);
  }
  if (L == 0) return;
  // The dense backend's record holds G; the sparse one's the rigid rows Kt (rpsp: the
  // extended Kt below instead of the extended G). Newton gives the contacts' G with the
  // converged tangent (G_contacts) on either backend.
  const bool on_operator = !G_contacts && cd.G.rows() == 0 && n0 > 0 && rd.Kt.cols() == n0;
  const MatX& G = G_contacts ? *G_contacts : cd.G;
  SOFTDIFF_DEMAND(((G.rows() == n0 && G.cols() == n0) || on_operator) && rd.limit_lambda.size() == num_limit_slots(model),
                  "rigid contact derivative: joint limits in contact need the record's G (dense backend), the "
                  "contacts' G (Newton) or its rigid rows Kt (sparse backend)");
  Ht_.rightCols(3 * L).setZero();
  lambda_.tail(3 * L).setZero();
  for (int l = 0; l < L; ++l) {
    const auto& row = rd.limit_rows[static_cast<std::size_t>(l)];
    const auto r = static_cast<std::size_t>(row.body);
    const auto& body = model.rigid[r];
    const bool hinge = body.joint.kind == rigid::Joint::Kind::hinge;
    Limit& lim = limits_[static_cast<std::size_t>(l)];
    lim.body = row.body;
    lim.s = row.side == 0 ? 1.0 : -1.0;
    // j = s T / |T|^2 (append_limit_rows), T = [n x (p - a); n] (hinge) or [n; 0].
    const rigid::Vec6 T = rigid::joint_motion_basis(body, rd.in[r]).col(0);
    const double T2 = T.squaredNorm();
    lim.j = lim.s * T / T2;
    lim.Mj.setZero();
    if (hinge) {
      // dj = s / |T|^2 (I - 2 T T^T / |T|^2) dT, dT = [n x dp; 0].
      Eigen::Matrix<double, 6, 3> dT = Eigen::Matrix<double, 6, 3>::Zero();
      dT.topRows<3>() = rigid::hat(body.joint.axis);
      lim.Mj = lim.s / T2 * (rigid::Mat6::Identity() - 2 * T * T.transpose() / T2) * dT;
    }
    lim.coordinate_block = hinge ? TH : P;
    lim.axis = body.joint.axis;
    lim.lambda = rd.limit_lambda[row.slot];
    Ht_.col(n0 + 3 * l + 2).segment<6>(6 * static_cast<Eigen::Index>(r)) = lim.j;
    lambda_[n0 + 3 * l + 2] = lim.lambda;
  }
  if (on_operator) {
    G_ext_.resize(0, 0);
    extended_rigid_rows(data);
  } else {
    Kt_ext_.resize(0, 0);
    // The solve's G on the extended rows: the record's G (contacts; Newton: G_contacts,
    // with the converged tangent), then each limit column h H_r^T W_r j over every row
    // (only its body's rows are nonzero; rigid only, so the same with any soft tangent),
    // mirrored.
    G_ext_.setZero(n1, n1);
    G_ext_.topLeftCorner(n0, n0) = G;
    for (int l = 0; l < L; ++l) {
      const Limit& lim = limits_[static_cast<std::size_t>(l)];
      const Eigen::Index o = 6 * static_cast<Eigen::Index>(lim.body), col = n0 + 3 * l + 2;
      G_ext_.col(col) = h * (Ht_.middleRows<6>(o).transpose() * (rd.W[static_cast<std::size_t>(lim.body)] * lim.j));
    }
    for (int l = 0; l < L; ++l) {
      const Eigen::Index o = n0 + 3 * l;
      G_ext_.row(o + 2) = G_ext_.col(o + 2).transpose();
      G_ext_(o, o) = G_ext_(o + 1, o + 1) = G_ext_(o + 2, o + 2);  // finish_limit_rows
    }
  }
  mu_ext_.setZero(nc + L);
  mu_ext_.head(nc) = cd.mu.head(nc);
  sigma_ext_.setZero(n1);
  sigma_ext_.head(n0) = cd.sigma.head(n0);
  modes_ext_.assign(cd.modes.begin(), cd.modes.begin() + nc);
  for (int l = 0; l < L; ++l) {
    const Limit& lim = limits_[static_cast<std::size_t>(l)];
    const auto r = static_cast<std::size_t>(lim.body);
    const auto& body = model.rigid[r];
    const auto& row = rd.limit_rows[static_cast<std::size_t>(l)];
    const double c = rigid::joint_coordinate(body, rd.in[r]);
    const double gap = row.side == 0 ? c - body.joint.limits->first : body.joint.limits->second - c;
    sigma_ext_[n0 + 3 * l + 2] = lim.j.dot(rd.u.segment<6>(6 * static_cast<Eigen::Index>(r))) + gap / h;
    // By contact mode: an active limit is a bilateral row, an inactive one drops.
    modes_ext_.push_back(lim.lambda > 0 ? Mode::sticking : Mode::breaking);
  }
}

// The sparse backend's extended rigid rows (contact/rigid_contact.cpp rigid_delassus_rows
// with the limit columns, before remove_limit_rows cut them): the record's Kt (the
// contacts' columns, sum of the bodies' ranks rows), each limit's normal column L_r^T j in
// its body's rows, and two rows per limit holding its tangential diagonals |L_r^T j| (h
// times their square: the normal diagonal h j W_r j, as finish_limit_rows).
void RigidContactDerivative::extended_rigid_rows(const Data& data) {
  const auto& rd = data.contact.rigid;
  const Eigen::Index n0 = 3 * static_cast<Eigen::Index>(nc_), L = static_cast<Eigen::Index>(limits_.size());
  const Eigen::Index k0 = rd.Kt.rows();
  Kt_ext_.setZero(k0 + 2 * L, n0 + 3 * L);
  Kt_ext_.topLeftCorner(k0, n0) = rd.Kt;
  for (Eigen::Index l = 0; l < L; ++l) {
    const Limit& lim = limits_[static_cast<std::size_t>(l)];
    Eigen::Index row = 0;  // the body's first row of Kt
    for (int r = 0; r < lim.body; ++r) row += rd.rank[static_cast<std::size_t>(r)];
    const int k = rd.rank[static_cast<std::size_t>(lim.body)];
    const Eigen::Index o = n0 + 3 * l;
    Kt_ext_.block(row, o + 2, k, 1) = rd.L[static_cast<std::size_t>(lim.body)].leftCols(k).transpose() * lim.j;
    const double d = Kt_ext_.col(o + 2).head(k0).norm();
    Kt_ext_(k0 + 2 * l, o) = d;
    Kt_ext_(k0 + 2 * l + 1, o + 1) = d;
  }
}

void RigidContactDerivative::limit_sigma_jvp(const VecX& z, const VecX& du0, VecX& b) const {
  const Eigen::Index n0 = 3 * static_cast<Eigen::Index>(nc_);
  for (std::size_t l = 0; l < limits_.size(); ++l) {
    const Limit& lim = limits_[l];
    const Eigen::Index o = n0 + 3 * static_cast<Eigen::Index>(l), r = lim.body;
    double bn = lim.j.dot(du0.segment<6>(6 * r));
    if (z.size()) {
      const Vec6 u = u_.segment<6>(6 * r);
      bn += u.dot(lim.Mj * z.segment<3>(12 * r + P));
      bn += lim.s * lim.axis.dot(z.segment<3>(12 * r + lim.coordinate_block)) / h_;
    }
    b[o] = b[o + 1] = 0;
    b[o + 2] = bn;
  }
}

void RigidContactDerivative::add_limit_sigma_vjp(const VecX& bar_b, VecX& bar_du0, VecX& bar_z) const {
  const Eigen::Index n0 = 3 * static_cast<Eigen::Index>(nc_);
  for (std::size_t l = 0; l < limits_.size(); ++l) {
    const Limit& lim = limits_[l];
    const Eigen::Index r = lim.body;
    const double beta = bar_b[n0 + 3 * static_cast<Eigen::Index>(l) + 2];
    bar_du0.segment<6>(6 * r) += beta * lim.j;
    bar_z.segment<3>(12 * r + P) += beta * (lim.Mj.transpose() * u_.segment<6>(6 * r));
    bar_z.segment<3>(12 * r + lim.coordinate_block) += beta * lim.s / h_ * lim.axis;
  }
}

}  // namespace softdiff::contact
