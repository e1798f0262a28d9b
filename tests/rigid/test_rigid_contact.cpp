// Rigid bodies in the contact stage (contact/rigid_contact.hpp; docs/method.md "Rigid
// bodies in contact"): the lever-arm Jacobian by central differences of a contact
// point's velocity, the rigid Delassus block against an explicit h H A^{-1} H^T, the
// correction against the NCP's sigma, and the pseudo-node layout; the sparse backend's
// operator with the rigid rows (SparseDelassus::set_rigid) against the dense G.
#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/contact/sparse_delassus.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/rigid/rotation.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <random>

using namespace softdiff;

namespace rigid_contact_unit {

// A fixed soft anchor (a 1x1x1-box mesh, every node fixed, far away) and one free box.
Model anchor_and_box(const rigid::RigidState& s) {
  Model model = test::rigid_scenes::anchored(1e-3);
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
// a = T^T diag(m I, I_w) T - h^2 Q' written out.
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
  // The joint's inertia less h^2 Q'(delta): the tangent of the free step's implicit gravity
  // torque Q(c) = n.(r(c) x m g) at its end, delta = h cdot, r(c) the arm turned by c about
  // n: Q'(delta) = n.((n x r(delta)) x m g) (rigid_contact.cpp begin_rigid_contact, rbranch).
  const Vec3 r_end = Eigen::AngleAxisd(h * cdot, n) * r;
  const double Q_prime = n.dot(n.cross(r_end).cross(body.mass * model.step.gravity));
  const double a = body.mass * n.cross(r).squaredNorm() + n.dot(R * body.inertia * R.transpose() * n) - h * h * Q_prime;
  const MatX G_explicit = h * HT * HT.transpose() / a;
  EXPECT_LT((G - G_explicit).norm(), 1e-12 * G_explicit.norm());
}

// The sparse backend's operator with rigid bodies (SparseDelassus::set_rigid, the rows
// Kt = L^T H_r^T of rigid_delassus_rows) against the dense G of the same step, formed
// independently: h H_s^T A^{-1} H_s (inverse_congruence on the step's factor) plus
// h H_r^T W_r H_r over every contact column (not add_rigid_delassus's restriction to the
// body's contacts, which the dense backend's own G, also compared, uses). Scenes: a free
// cube on a soft slab (soft and rigid columns), the same cube and a hinged bar on
// obstacles only (no soft dof in any contact: the operator's soft part is 0). Every
// operation ADMM, the working set, the polish and the preconditioners use: G y, G_:W y,
// dense G_WW, (G_WW + c D)^{-1} with and without a scale D, the rotated-rows shifted solve
// of set_frames, the compliance estimate's rigid part, the largest eigenvalue. Exact
// algebra (Woodbury), so the tolerance is round-off: 1e-10 relative (G's condition number
// on these sets is < 1e4 after the shift c = 1e-2 |G|, 1e-12 per operation).
struct SparseCase {
  Model model;
  Data data;
  explicit SparseCase(Model m) : model(std::move(m)), data(model) {}
};

// Runs `steps` dense-backend steps; the last one's contact problem stays in data.
void run_dense(SparseCase& c, int steps) {
  State a = c.model.initial, b;
  for (int n = 1; n <= steps; ++n) {
    ASSERT_TRUE(integrator::time_step(c.model, c.data, a, nullptr, b, n).ok());
    std::swap(a, b);
  }
}

void expect_operations_match(contact::SparseDelassus& S, const MatX& G, std::mt19937& rng);

void expect_sparse_matches_dense(SparseCase& c, bool soft_columns) {
  auto& cd = c.data.contact;
  const int nc = cd.contacts.size();
  ASSERT_GT(nc, 3);
  EXPECT_EQ(soft_columns, cd.Ht.nonZeros() > 0);
  const double h = c.model.step.dt;
  // The reference G.
  MatX G;
  if (soft_columns) {
    ASSERT_TRUE(c.data.solver->inverse_congruence(cd.Ht, G));
    G *= h;
  } else {
    G.setZero(3 * nc, 3 * nc);
  }
  const auto& rd = cd.rigid;
  for (std::size_t r = 0; r < c.model.rigid.size(); ++r) {
    const MatX B = rd.Ht.middleRows<6>(6 * static_cast<Eigen::Index>(r));
    G += h * B.transpose() * rd.W[r] * B;
  }
  const double scale = G.norm();
  EXPECT_LT((cd.G - G).norm(), 1e-12 * scale);  // the dense backend's G (add_rigid_delassus restricted)
  contact::SparseDelassus S;
  S.bind(*c.data.solver, c.data.A, cd.Ht, h, c.model.solver);
  S.set_mass(c.model.fem.mass_diagonal);
  MatX Kt;
  VecX g = VecX::Zero(3 * nc), g_dense = VecX::Zero(3 * nc);
  contact::rigid_delassus_rows(c.model, c.data, Kt, g);
  MatX unused = MatX::Zero(3 * nc, 3 * nc);
  contact::add_rigid_delassus(c.model, c.data, h, unused, g_dense);
  EXPECT_LT((g - g_dense).norm(), 1e-14 * std::max(g.norm(), 1e-300));
  S.set_rigid(Kt);
  EXPECT_GT(S.rigid_rows(), 0);
  std::mt19937 rng(3);
  // The compliance estimate's rigid part is G_ii's exactly: with the soft part subtracted
  // (the same estimate without set_rigid), d_i = h tr(H_r,i W H_r,i^T) / 3.
  VecX d(nc), d_soft(nc);
  S.contact_compliance(d);
  contact::SparseDelassus S_soft;
  S_soft.bind(*c.data.solver, c.data.A, cd.Ht, h, c.model.solver);
  S_soft.set_mass(c.model.fem.mass_diagonal);
  S_soft.contact_compliance(d_soft);
  for (int i = 0; i < nc; ++i) {
    double rigid_part = 0;
    for (std::size_t r = 0; r < c.model.rigid.size(); ++r) {
      const MatX B = rd.Ht.block(6 * static_cast<Eigen::Index>(r), 3 * i, 6, 3);
      rigid_part += h * (B.transpose() * rd.W[r] * B).trace() / 3;
    }
    EXPECT_NEAR(d[i] - d_soft[i], rigid_part, 1e-12 * scale) << "contact " << i;
  }
  expect_operations_match(S, G, rng);
}

// Every operation of S against the dense G (3 nc' square, nc' = S.contacts()): G y, G_:W
// y, dense G_WW, (G_WW + c D)^{-1} with and without a scale D, the rotated-rows shifted
// solve of set_frames, the largest eigenvalue; on all contacts and on a subset W.
void expect_operations_match(contact::SparseDelassus& S, const MatX& G, std::mt19937& rng) {
  std::normal_distribution<double> N;
  const int nc = S.contacts();
  ASSERT_EQ(G.rows(), 3 * nc);
  const double scale = G.norm();
  VecX y(3 * nc), out(3 * nc);
  for (auto& v : y) v = N(rng);
  ASSERT_TRUE(S.apply(y, out));
  EXPECT_LT((out - G * y).norm(), 1e-10 * scale * y.norm());
  MatX D;
  ASSERT_TRUE(S.dense(D));
  EXPECT_LT((D - G).norm(), 1e-10 * scale);
  // A subset W (every other contact, and the last one): G_:W y, G_WW, the shifted solves.
  std::vector<int> W;
  for (int i = 0; i < nc; i += 2) W.push_back(i);
  if (W.back() != nc - 1) W.push_back(nc - 1);  // a limit row when there are some
  const Eigen::Index m = 3 * static_cast<Eigen::Index>(W.size());
  std::vector<int> dofs;
  for (int i : W)
    for (int k = 0; k < 3; ++k) dofs.push_back(3 * i + k);
  const MatX G_WW = G(dofs, dofs);
  const MatX G_W = G(Eigen::all, dofs);
  S.restrict_to(W);
  VecX yw(m), ow(m), full(3 * nc);
  for (auto& v : yw) v = N(rng);
  ASSERT_TRUE(S.apply(yw, ow));
  EXPECT_LT((ow - G_WW * yw).norm(), 1e-10 * scale * yw.norm());
  ASSERT_TRUE(S.apply_full(yw, full));
  EXPECT_LT((full - G_W * yw).norm(), 1e-10 * scale * yw.norm());
  ASSERT_TRUE(S.dense(D));
  EXPECT_LT((D - G_WW).norm(), 1e-10 * scale);
  const double cshift = 1e-2 * scale;
  ASSERT_TRUE(S.factorize_shifted(cshift));
  VecX r = yw;
  ASSERT_TRUE(S.solve_shifted(r));
  MatX shifted = G_WW;
  shifted.diagonal().array() += cshift;
  EXPECT_LT((shifted * r - yw).norm(), 1e-10 * yw.norm());
  // With a per-contact scale D: (G_WW + c D)^{-1}.
  VecX dw(static_cast<Eigen::Index>(W.size()));
  for (auto& v : dw) v = 0.5 + std::abs(N(rng));
  S.set_scale(dw);
  ASSERT_TRUE(S.factorize_shifted(cshift));
  r = yw;
  ASSERT_TRUE(S.solve_shifted(r));
  shifted = G_WW;
  for (Eigen::Index b = 0; b < dw.size(); ++b) shifted.diagonal().segment<3>(3 * b).array() += cshift * dw[b];
  EXPECT_LT((shifted * r - yw).norm(), 1e-10 * yw.norm());
  // The largest eigenvalue of D^-1/2 G_WW D^-1/2 (power iteration: to 1e-3, many steps).
  VecX dsi(m);
  for (Eigen::Index b = 0; b < dw.size(); ++b) dsi.segment<3>(3 * b).setConstant(1 / std::sqrt(dw[b]));
  const MatX Gs = dsi.asDiagonal() * G_WW * dsi.asDiagonal();
  const double lmax = Eigen::SelfAdjointEigenSolver<MatX>(Gs).eigenvalues().maxCoeff();
  EXPECT_NEAR(S.largest_eigenvalue(500), lmax, 1e-3 * lmax);
  // Rotated, weighted rows (set_frames, c = 1): s (I + h H~ A^-1 H~^T + h K~ K~^T)^{-1} s,
  // H~ = diag(s) R H_W, i.e. s (I + diag(s) R G_WW R^T diag(s))^{-1} s.
  std::vector<Mat3> frames;
  VecX sw(m);
  MatX Rot = MatX::Zero(m, m);
  for (std::size_t b = 0; b < W.size(); ++b) {
    frames.push_back(Eigen::Quaterniond::UnitRandom().toRotationMatrix());
    Rot.block<3, 3>(3 * static_cast<Eigen::Index>(b), 3 * static_cast<Eigen::Index>(b)) = frames.back();
    for (int k = 0; k < 3; ++k) sw[3 * static_cast<Eigen::Index>(b) + k] = (k == 1 && b % 3 == 0) ? 0.0 : 1 / std::sqrt(scale) * (1 + std::abs(N(rng)));
  }
  S.set_frames(frames, sw);
  ASSERT_TRUE(S.factorize_shifted(1.0));
  r = yw;
  ASSERT_TRUE(S.solve_shifted(r));
  MatX I_plus = sw.asDiagonal() * Rot * G_WW * Rot.transpose() * sw.asDiagonal();
  I_plus.diagonal().array() += 1;
  const VecX expected = sw.asDiagonal() * I_plus.ldlt().solve(sw.asDiagonal() * yw);
  EXPECT_LT((r - expected).norm(), 1e-10 * expected.norm());
}

// A hinged bar (0.2 x 0.04 x 0.02 m, about y at its left end x = 1.0) resting on a
// frictionless support box at x = 1.2, limits [-0.05, 0.05] when `limits`.
void add_hinged_bar(Model& model, bool limits) {
  rigid::RigidState bar;
  bar.position = Vec3(1.1, 0, 0.01);
  test::add_rigid_body(model, "bar", test::box_shape(Vec3(0.1, 0.02, 0.01)), 800, bar, 0.01, rigid::Joint::Kind::hinge);
  auto& body = model.rigid.back();
  body.joint.anchor = Vec3(1.0, 0, 0.01);
  body.joint.axis = Vec3::UnitY();
  if (limits) body.joint.limits = std::make_pair(-0.05, 0.05);
  rigid::initialize(body, bar);
}

Model cube_on_slab(bool limited_bar = false) {
  // A free cube (40 mm), slightly tilted, resting on a soft slab: soft and rigid columns.
  test::BodySpec spec;
  spec.young = 5e4;
  spec.poisson = 0.4;
  spec.density = 1000;
  spec.fixed = [](const Vec3& p) { return p.z() < 1e-9; };
  Model model = test::make_model(test::box_mesh(6, 6, 2, 0.12, 0.12, 0.01), spec, Vec3(0, 0, -9.81), 2e-3);
  rigid::RigidState s;
  s.position = Vec3(0.06, 0.06, 0.03);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.02, Vec3(1, 1, 0).normalized()));
  test::add_rigid_body(model, "cube", test::box_shape(Vec3(0.02, 0.02, 0.02)), 500, s);
  contact::NcpOptions dense;
  dense.backend = contact::NcpBackend::dense;
  if (!limited_bar) {
    test::enable_rigid_contact(model, {}, {{"body", "cube", 0.5}}, 1e-3, dense);
    return model;
  }
  add_hinged_bar(model, true);
  test::enable_rigid_contact(model, {test::box(Vec3(1.2, 0, -0.01), Vec3(0.01, 0.05, 0.01), "support")},
                             {{"body", "cube", 0.5}, {"bar", "support", 0.0}}, 1e-3, dense);
  return model;
}

Model box_and_hinged_bar_on_obstacles(bool limits = false) {
  // A free tilted box and a hinged bar on a plane and a box obstacle: no soft dof in any contact.
  rigid::RigidState s;
  s.position = Vec3(0.1, -0.2, 0.019);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.01, Vec3(1, 2, 0).normalized()));
  Model model = anchor_and_box(s);
  add_hinged_bar(model, limits);
  contact::NcpOptions dense;
  dense.backend = contact::NcpBackend::dense;
  test::enable_rigid_contact(model,
                             {test::plane(Vec3::UnitZ(), 0), test::box(Vec3(1.2, 0, -0.01), Vec3(0.01, 0.05, 0.01), "support")},
                             {{"box", "floor", 0.5}, {"bar", "support", 0.0}}, 1e-3, dense);
  return model;
}

TEST(RigidContact, SparseOperatorWithRigidRowsMatchesDenseG) {
  SparseCase c(cube_on_slab());
  run_dense(c, 3);
  expect_sparse_matches_dense(c, true);
}

TEST(RigidContact, SparseOperatorWithRigidRowsOnObstaclesOnly) {
  SparseCase c(box_and_hinged_bar_on_obstacles());
  run_dense(c, 2);
  expect_sparse_matches_dense(c, false);
}

// The manifold reduction (rigid_contact.hpp reduce_rigid_manifolds) on hand-made
// contacts of the box's pseudo-nodes against the floor z = 0 (frame (x, y, z)): a 3 x 3
// grid of points in the plane z = 1 mm keeps its 4 corners (the centre and the edge
// midpoints are convex combinations: dropped); a point above the grid's interior (z = 2
// mm: inside in the tangent plane, not in 3D), one of another friction coefficient and
// one of a soft node (a vertex_obstacle of node 0) are kept. The order of the kept
// contacts is the input's.
TEST(RigidContactUnit, ManifoldReductionKeepsTheExtremePointsOnly) {
  rigid::RigidState s;
  s.position = Vec3(0, 0, 0.021);
  Model model = anchor_and_box(s);
  Data data(model);
  const int p0 = model.contact.rigid_node_begin[0];
  std::vector<collision::Contact> list;
  auto add = [&](int node, const Vec3& x, double mu) {
    collision::Contact c;
    c.kind = collision::ContactKind::vertex_obstacle;
    c.side_a = 1;  // the box (names: anchor, box, floor)
    c.side_b = 2;
    c.count = 1;
    c.nodes = {node, -1, -1, -1};
    c.weights = {1, 0, 0, 0};
    c.frame = Mat3::Identity();
    c.point = x;
    c.point_b = Vec3(x.x(), x.y(), 0);
    c.gap = x.z();
    c.mu = mu;
    c.feature_b = 0;
    c.kind_b = collision::Feature::face;
    list.push_back(c);
  };
  int node = p0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) add(node++, Vec3(0.01 * i - 0.01, 0.02 * j - 0.02, 1e-3), 0.5);
  add(node++, Vec3(0.002, 0.003, 2e-3), 0.5);  // above the interior: kept
  add(node++, Vec3(0.001, 0.001, 1e-3), 0.3);  // another mu: its own group of one, kept
  add(0, Vec3(0.0, 0.0, 1e-3), 0.5);           // a soft node: not a candidate
  const std::vector<collision::Contact> before = list;
  const int dropped = contact::reduce_rigid_manifolds(model, data, list);
  EXPECT_EQ(dropped, 5);
  EXPECT_EQ(data.contact.rigid.manifold_dropped, 5);
  ASSERT_EQ(list.size(), before.size() - 5);
  // Kept, in order: grid corners 0, 2, 6, 8, then the three others.
  const int expected[] = {0, 2, 6, 8, 9, 10, 11};
  for (std::size_t k = 0; k < list.size(); ++k)
    EXPECT_EQ(list[k].nodes[0], before[static_cast<std::size_t>(expected[k])].nodes[0]) << "kept contact " << k;
  // Collinear points: the ends of the segment stay, the inner ones go.
  list.clear();
  for (int i = 0; i < 5; ++i) add(p0 + i, Vec3(0.005 * i, 0.001 * i, 1e-3), 0.5);
  EXPECT_EQ(contact::reduce_rigid_manifolds(model, data, list), 3);
  ASSERT_EQ(list.size(), 2u);
  EXPECT_EQ(list[0].nodes[0], p0);
  EXPECT_EQ(list[1].nodes[0], p0 + 4);
}

// Joint limits as rows of the operator (issue 21; rigid_contact.hpp "limit rows"): the
// limit rows' columns are columns of Kt (coupled with the body's contacts), their
// tangential diagonals 2 more rows of Kt, Ht padded with zero columns. After dense steps
// (the bar resting on its support, both limits selected: all = true), the extended
// system (3 (nc + 2)) three ways: the dense backend's (append_limit_rows, add_rigid_delassus,
// finish_limit_rows), an independent h H_s A^{-1} H_s^T + h sum_r B_r^T W_r B_r over the
// extended rigid columns with the limits' tangential diagonals set to their normal one,
// and the operator (every operation, as above). With and without soft columns. Exact
// algebra: tolerances of round-off as above; g's to 1e-14 (the same sums).
void expect_limit_rows_match(SparseCase& c, bool soft_columns) {
  auto& cd = c.data.contact;
  auto& rd = cd.rigid;
  const int nc = cd.contacts.size();
  ASSERT_GT(nc, 3);
  EXPECT_EQ(soft_columns, cd.Ht.nonZeros() > 0);
  const double h = c.model.step.dt;
  const int L = contact::select_limit_rows(c.model, c.data, h, true);
  ASSERT_EQ(L, 2);
  const int n1 = 3 * (nc + L);
  MatX G_soft = MatX::Zero(3 * nc, 3 * nc);
  if (soft_columns) {
    ASSERT_TRUE(c.data.solver->inverse_congruence(cd.Ht, G_soft));
    G_soft *= h;
  }
  VecX g_dense = VecX::Zero(3 * nc);
  MatX G_dense = G_soft;
  contact::append_limit_rows(c.model, c.data, nc, &G_dense, g_dense);
  contact::add_rigid_delassus(c.model, c.data, h, G_dense, g_dense);
  contact::finish_limit_rows(c.model, c.data, h, nc, &G_dense, g_dense);
  ASSERT_EQ(G_dense.rows(), n1);
  ASSERT_EQ(rd.Ht.cols(), n1);
  MatX G = MatX::Zero(n1, n1);
  G.topLeftCorner(3 * nc, 3 * nc) = G_soft;
  for (std::size_t r = 0; r < c.model.rigid.size(); ++r) {
    const MatX B = rd.Ht.middleRows<6>(6 * static_cast<Eigen::Index>(r));
    G += h * B.transpose() * rd.W[r] * B;
  }
  for (int l = 0; l < L; ++l) {
    const int o = 3 * (nc + l);
    EXPECT_GT(G(o + 2, o + 2), 0);
    G(o, o) = G(o + 1, o + 1) = G(o + 2, o + 2);
  }
  // The limit rows couple with the bar's contacts (what the operator must keep).
  EXPECT_GT(G.bottomLeftCorner(3 * L, 3 * nc).norm(), 0);
  const double scale = G.norm();
  EXPECT_LT((G_dense - G).norm(), 1e-12 * scale);
  // The sparse backend's path (contact_step.cpp): no dense G.
  VecX g = VecX::Zero(3 * nc);
  contact::append_limit_rows(c.model, c.data, nc, nullptr, g);
  MatX Kt;
  contact::rigid_delassus_rows(c.model, c.data, Kt, g);
  contact::finish_limit_rows(c.model, c.data, h, nc, nullptr, g);
  EXPECT_LT((g - g_dense).norm(), 1e-14 * std::max(g.norm(), 1e-300));
  contact::SparseDelassus S;
  S.bind(*c.data.solver, c.data.A, cd.Ht, h, c.model.solver);
  S.set_mass(c.model.fem.mass_diagonal);
  S.set_rigid(Kt);
  ASSERT_EQ(S.contacts(), nc + L);
  // The compliance estimate of a limit row (no soft dof) is exact: tr(G_ii) / 3.
  VecX d(nc + L);
  S.contact_compliance(d);
  for (int l = 0; l < L; ++l) {
    const int o = 3 * (nc + l);
    EXPECT_NEAR(d[nc + l], (G.block<3, 3>(o, o).trace() / 3), 1e-12 * scale) << "limit row " << l;
  }
  std::mt19937 rng(5);
  expect_operations_match(S, G, rng);
}

TEST(RigidContact, SparseOperatorWithLimitRowsMatchesDenseG) {
  SparseCase c(cube_on_slab(true));
  run_dense(c, 3);
  expect_limit_rows_match(c, true);
}

TEST(RigidContact, SparseOperatorWithLimitRowsOnObstaclesOnly) {
  SparseCase c(box_and_hinged_bar_on_obstacles(true));
  run_dense(c, 2);
  expect_limit_rows_match(c, false);
}

}  // namespace rigid_contact_unit
