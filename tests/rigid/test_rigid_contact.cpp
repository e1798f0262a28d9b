// Rigid bodies in the contact stage (contact/rigid_contact.hpp; docs/method.md "Rigid
// bodies in contact"): the lever-arm Jacobian by central differences of a contact
// point's velocity, the rigid Delassus block against an explicit h H A^{-1} H^T, the
// correction against the NCP's sigma, and the pseudo-node layout.
#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/data.hpp>
#include <softdiff/rigid/rotation.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;

namespace rigid_contact_unit {

// A fixed soft anchor (a 1x1x1-box mesh, every node fixed, far away) and one free box.
Model anchor_and_box(const rigid::RigidState& s) {
  test::BodySpec spec;
  spec.fixed = [](const Vec3&) { return true; };
  mesh::TetMesh m = test::box_mesh(1, 1, 1, 0.01, 0.01, 0.01);
  for (Eigen::Index i = 0; i < m.X.cols(); ++i) m.X.col(i) += Vec3(5, 5, 5);
  Model model = test::make_model(m, spec, Vec3(0, 0, -9.81), 1e-3);
  test::add_rigid_body(model, "box", test::box_shape(Vec3(0.05, 0.03, 0.02)), 800, s);
  contact::NcpOptions ncp;
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0)}, {{"box", "floor", 0.5}}, 1e-3, ncp);
  return model;
}

rigid::RigidState tumbling_state() {
  rigid::RigidState s;
  s.position = Vec3(0.1, -0.2, 0.3);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Vec3(1, 2, -0.5).normalized()));
  s.velocity = Vec3(0.3, -0.1, 0.2);
  s.angular_velocity = Vec3(2, -1, 3);
  return s;
}

// Three contacts on the box's vertices 0, 3, 6 with arbitrary frames, vertex-obstacle.
collision::ContactSet three_contacts(const Model& model) {
  collision::ContactSet set;
  std::mt19937 rng(7);
  std::normal_distribution<double> N;
  for (int j : {0, 3, 6}) {
    collision::Contact c;
    c.kind = collision::ContactKind::vertex_obstacle;
    c.count = 1;
    c.nodes = {model.contact.rigid_node_begin[0] + j, -1, -1, -1};
    c.weights = {1, 0, 0, 0};
    c.frame = collision::frame_from_normal(Vec3(N(rng), N(rng), N(rng)).normalized());
    set.contacts.push_back(c);
  }
  return set;
}

TEST(RigidContact, PseudoNodesFollowTheSoftNodes) {
  const Model model = anchor_and_box(tumbling_state());
  ASSERT_EQ(model.contact.rigid_node_begin.size(), 1u);
  EXPECT_EQ(model.contact.rigid_node_begin[0], model.fem.num_nodes);
  EXPECT_EQ(static_cast<Eigen::Index>(model.contact.rigid_node_body.size()), model.rigid[0].surface.vertices.cols());
  EXPECT_EQ(model.contact.detection.names, (std::vector<std::string>{"body", "box", "floor"}));
  ASSERT_EQ(model.contact.detection.surfaces.size(), 2u);
  EXPECT_EQ(model.contact.detection.surfaces[1].triangles.minCoeff(), model.fem.num_nodes);
}

// H_r u = C^T (v + omega x (x_k - p)) for each contact; checked against the central
// difference of the vertex's world position along the motion p(t) = p + t v,
// q(t) = exp(t [omega]) q: (x_k(e) - x_k(-e)) / 2e = v + omega x rho + O(e^2 |omega|^2 |rho|).
// e = 1e-5: truncation ~1e-10 |omega|^2 |rho| ~ 1e-10 m/s, round-off ~1e-16 / 1e-5 = 1e-11;
// tolerance 1e-8 m/s against point speeds ~0.5 m/s.
TEST(RigidContact, JacobianIsTheLeverArmByCentralDifferences) {
  const rigid::RigidState s = tumbling_state();
  const Model model = anchor_and_box(s);
  const auto& body = model.rigid[0];
  const collision::ContactSet set = three_contacts(model);
  MatX Ht;
  contact::rigid_jacobian_transpose(model, set, model.initial.rigid, Ht);
  ASSERT_EQ(Ht.rows(), 6);
  ASSERT_EQ(Ht.cols(), 9);
  rigid::Vec6 u;
  u << s.velocity, s.angular_velocity;
  const VecX Hu = Ht.transpose() * u;
  const double e = 1e-5;
  auto vertex_at = [&](int j, double t) {
    const Eigen::Quaterniond q = rigid::quaternion_exp(t * s.angular_velocity) * s.orientation;
    return Vec3(s.position + t * s.velocity + q * body.surface.vertices.col(j));
  };
  for (int i = 0; i < 3; ++i) {
    const auto& c = set.contacts[i];
    const int j = c.nodes[0] - model.contact.rigid_node_begin[0];
    const Vec3 fd = (vertex_at(j, e) - vertex_at(j, -e)) / (2 * e);
    const Vec3 expected = c.frame.transpose() * fd;
    EXPECT_LT((Hu.segment<3>(3 * i) - expected).norm(), 1e-8) << "contact " << i;
  }
  // A fixed body has no dofs: no rows.
  Model fixed = model;
  fixed.rigid[0].joint.kind = rigid::Joint::Kind::fixed;
  contact::rigid_jacobian_transpose(fixed, set, fixed.initial.rigid, Ht);
  EXPECT_EQ(Ht.norm(), 0.0);
}

// G_r = h H A^{-1} H^T with H (9 x 6) written out row by row (C^T [I, -[rho]x]) and
// A = diag(m I, R I R^T) inverted whole (full-pivot LU), against add_rigid_delassus (W from
// begin_rigid_contact's block inverse); g = H u_free. Then the correction
// u = u_free + h W H^T lambda makes H u = G lambda + g (the NCP's sigma): exact algebra,
// round-off only (tolerance 1e-12 relative).
TEST(RigidContact, DelassusBlockMatchesExplicitProduct) {
  const rigid::RigidState s = tumbling_state();
  Model model = anchor_and_box(s);
  const auto& body = model.rigid[0];
  const double h = model.step.dt;
  Data data(model);
  std::vector<rigid::RigidState> in = model.initial.rigid, free(1);
  rigid::step(body, in[0], h, model.step.gravity, Vec3::Zero(), Vec3::Zero(), free[0]);
  contact::begin_rigid_contact(model, data, in, free);
  const collision::ContactSet set = three_contacts(model);
  contact::rigid_jacobian_transpose(model, set, in, data.contact.rigid.Ht);
  MatX G = MatX::Zero(9, 9);
  VecX g = VecX::Zero(9);
  contact::add_rigid_delassus(model, data, h, G, g);

  Eigen::Matrix<double, 9, 6> H;
  for (int i = 0; i < 3; ++i) {
    const auto& c = set.contacts[i];
    const Vec3 rho = in[0].orientation * body.surface.vertices.col(c.nodes[0] - model.contact.rigid_node_begin[0]);
    Eigen::Matrix<double, 3, 6> J;
    J << Mat3::Identity(), -rigid::hat(rho);
    H.middleRows<3>(3 * i) = c.frame.transpose() * J;
  }
  // A = diag(m I, I_w(q_free)) (docs/method.md "Rigid bodies in contact").
  const Mat3 R = free[0].orientation.toRotationMatrix();
  rigid::Mat6 A = rigid::Mat6::Zero();
  A.topLeftCorner<3, 3>() = body.mass * Mat3::Identity();
  A.bottomRightCorner<3, 3>() = R * body.inertia * R.transpose();
  const rigid::Mat6 Ainv = A.fullPivLu().inverse();
  const MatX G_explicit = h * H * Ainv * H.transpose();
  rigid::Vec6 u_free;
  u_free << free[0].velocity, free[0].angular_velocity;
  const VecX g_explicit = H * u_free;
  EXPECT_LT((G - G_explicit).norm(), 1e-12 * G_explicit.norm());
  EXPECT_LT((g - g_explicit).norm(), 1e-12 * g_explicit.norm());
  EXPECT_LT((G - G.transpose()).norm(), 1e-14 * G.norm());  // symmetric: the NCP solvers need it
  // A's angular block is step_matrix's (the exact Newton matrix of the angular update) to
  // O(h |omega|) (the gyroscopic term): here h |omega| = 3.7e-3.
  const rigid::Mat6 exact = rigid::step_matrix(body, in[0], free[0], h);
  const double hw = h * free[0].angular_velocity.norm();
  const double gap = (exact.bottomRightCorner<3, 3>() - A.bottomRightCorner<3, 3>()).norm();
  const double angular_norm = A.bottomRightCorner<3, 3>().norm();
  EXPECT_LT(gap, 2 * hw * angular_norm);
  // At omega = 0 they agree to round-off.
  rigid::RigidState still = in[0], still_free;
  still.angular_velocity.setZero();
  rigid::step(body, still, h, model.step.gravity, Vec3::Zero(), Vec3::Zero(), still_free);
  const Mat3 Rs = still_free.orientation.toRotationMatrix();
  EXPECT_LT((rigid::step_matrix(body, still, still_free, h).bottomRightCorner<3, 3>() - Rs * body.inertia * Rs.transpose())
                .norm(),
            1e-14 * body.inertia.norm());

  VecX lambda(9);
  lambda << 0.1, -0.2, 1.0, 0.05, 0.0, 2.0, -0.3, 0.1, 0.5;
  contact::correct_rigid_velocities(model, data, h, lambda);
  const VecX sigma = H * data.contact.rigid.u;
  EXPECT_LT((sigma - (G * lambda + g)).norm(), 1e-12 * (G * lambda + g).norm());
}

// A hinge body: u_free = T cdot_free and W = T a^{-1} T^T (begin_rigid_contact), so
// H u_free is the contact velocity of the pseudo-nodes turning about the hinge:
// C^T (d/dt of anchor + exp(t cdot n)(x_k - anchor)), by central differences (e = 1e-5:
// truncation e^2 cdot^2 |r| ~ 1e-10, tolerance 1e-8 m/s); and G = h (H T)(H T)^T / a with
// a = T^T diag(m I, I_w) T written out.
TEST(RigidContact, HingeBodyMovesAboutItsAxis) {
  rigid::RigidState s = tumbling_state();
  s.velocity.setZero();
  s.angular_velocity.setZero();
  Model model = anchor_and_box(s);
  auto& body = model.rigid[0];
  body.joint.kind = rigid::Joint::Kind::hinge;
  body.joint.anchor = s.position + Vec3(0.03, -0.01, 0.02);
  body.joint.axis = Vec3(1, 2, 2).normalized();
  rigid::RigidState spun = s;
  const double rate = 1.5;
  spun.angular_velocity = rate * body.joint.axis;
  spun.velocity = spun.angular_velocity.cross(s.position - body.joint.anchor);
  rigid::initialize(body, spun);
  const std::vector<rigid::RigidState> in{body.reference};
  std::vector<rigid::RigidState> free(1);
  const double h = model.step.dt;
  rigid::step(body, in[0], h, model.step.gravity, Vec3::Zero(), Vec3::Zero(), free[0]);
  Data data(model);
  contact::begin_rigid_contact(model, data, in, free);
  const collision::ContactSet set = three_contacts(model);
  contact::rigid_jacobian_transpose(model, set, in, data.contact.rigid.Ht);
  MatX G = MatX::Zero(9, 9);
  VecX g = VecX::Zero(9);
  contact::add_rigid_delassus(model, data, h, G, g);
  const double cdot = body.joint.axis.dot(free[0].angular_velocity);
  const double e = 1e-5;
  auto vertex_at = [&](int j, double t) {
    const Eigen::AngleAxisd turn(t * cdot, body.joint.axis);
    const Vec3 x = in[0].position + in[0].orientation * body.surface.vertices.col(j);
    return Vec3(body.joint.anchor + turn * (x - body.joint.anchor));
  };
  Eigen::Matrix<double, 9, 1> HT;  // H T: contact velocity per unit joint rate
  for (int i = 0; i < 3; ++i) {
    const auto& c = set.contacts[i];
    const int j = c.nodes[0] - model.contact.rigid_node_begin[0];
    const Vec3 fd = (vertex_at(j, e) - vertex_at(j, -e)) / (2 * e);
    EXPECT_LT((g.segment<3>(3 * i) - c.frame.transpose() * fd).norm(), 1e-8) << "contact " << i;
    const Vec3 x = in[0].position + in[0].orientation * body.surface.vertices.col(j);
    HT.segment<3>(3 * i) = c.frame.transpose() * body.joint.axis.cross(x - body.joint.anchor);
  }
  const Mat3 R = free[0].orientation.toRotationMatrix();
  const Vec3 n = body.joint.axis, r = in[0].position - body.joint.anchor;
  const double a = body.mass * n.cross(r).squaredNorm() + n.dot(R * body.inertia * R.transpose() * n);
  const MatX G_explicit = h * HT * HT.transpose() / a;
  EXPECT_LT((G - G_explicit).norm(), 1e-12 * G_explicit.norm());
}

}  // namespace rigid_contact_unit
