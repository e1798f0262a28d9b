// Derivatives of the step through contact with rigid bodies (issue 21;
// contact/rigid_contact_derivatives.hpp, integrator/implicit_euler_derivatives.cpp) against
// central finite differences of integrator::time_step itself: a random direction in every
// input at once (soft x, v; each rigid body's 12-tangent; its mass and inertia), the
// outputs compared in the tangent space of the unperturbed output (rigid::tangent_between);
// and the dot-product test of the JVP against the VJP. Scenes: a rigid box sliding on a
// plane obstacle, a block sticking on an incline, a rigid cube on a soft slab (soft-rigid
// contact: vertex-face pairs both ways), a hinged bar resting on a support and a block on
// a slider. Then a trajectory (12 steps): forward sensitivities and the adjoint against
// whole-run central differences.
#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>
#include <softdiff/diff/parameters.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>
#include <rigid/rigid_scenes.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <string>

using namespace softdiff;

namespace rigid_contact_derivatives_test {

constexpr double g0 = 9.81;

// A soft anchor far away with every node fixed (build_model needs a soft body); it takes
// part in no contact pair.
Model anchored(double h) { return test::rigid_scenes::anchored(h, g0); }

// Tight NCP: the polish then solves the mode equations to round-off, so that the finite
// differences see the exact solution of each perturbed problem.
contact::NcpOptions tight() { return test::rigid_scenes::tight_ncp(1e-12); }

// The contact backends (as in validation_rigid_contact.cpp). dense: G with the rigid
// part h H_r W_r H_r^T (add_rigid_delassus), the derivative on the record's G. sparse:
// the NCP on the operator (its small working sets on their dense G_W), the derivative's
// mode-fixed system on the dense G_AA of these few active contacts, formed by
// ContactStageDerivative from H_A and the rigid rows Kt (issue 21: the rigid part was
// missing there). operator: dense_max_contacts = 0 (ADMM on the operator) and the
// derivative's crossovers derivative_(mixed_)dense_max_active = 0: the mode-fixed system
// on the operator (PCG when every active contact sticks, GMRES with the reduced
// preconditioner otherwise), its scale and preconditioner with the rigid rows too.
enum class Backend { dense, sparse, op };
std::string backend_name(Backend b) { return b == Backend::dense ? "dense" : b == Backend::sparse ? "sparse" : "operator"; }
Model on_backend(Model m, Backend b) {
  auto& o = m.contact.ncp;
  o.backend = b == Backend::dense ? contact::NcpBackend::dense : contact::NcpBackend::sparse;
  if (b == Backend::op) {
    o.dense_max_contacts = 0;
    o.derivative_dense_max_active = 0;
    o.derivative_mixed_dense_max_active = 0;
  }
  return m;
}

// Runs `steps` steps from model.initial (asserting each) and returns the last state.
State warm_up(const Model& model, long steps) {
  Data data(model);
  State a = model.initial, b;
  for (long k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::time_step(model, data, a, nullptr, b, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    std::swap(a, b);
  }
  return a;
}

// One step from `in` with a fresh workspace (no warm start: every run solves the same way).
State step_from(const Model& model, const State& in, std::unique_ptr<Data>& data) {
  data = std::make_unique<Data>(model);
  State out;
  const StepStatus st = integrator::time_step(model, *data, in, nullptr, out, 1);
  EXPECT_TRUE(st.ok()) << describe(model, st);
  return out;
}

struct Direction {
  VecX x, v, rigid, rigid_p;
};

Direction random_direction(const Model& model, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> N;
  const Eigen::Index n3 = 3L * model.fem.num_nodes, R = static_cast<Eigen::Index>(model.rigid.size());
  Direction d;
  d.x = VecX::NullaryExpr(n3, [&] { return N(rng); });
  d.v = VecX::NullaryExpr(n3, [&] { return N(rng); });
  d.rigid = VecX::NullaryExpr(12 * R, [&] { return N(rng); });
  d.rigid_p.resize(7 * R);
  for (Eigen::Index r = 0; r < R; ++r) {
    // Parameters on their own scale: the mass times 1, each inertia component times the
    // trace / 3 (so that a step e keeps the inertia positive definite).
    const auto& b = model.rigid[static_cast<std::size_t>(r)];
    d.rigid_p[7 * r] = b.mass * N(rng);
    for (int k = 1; k < 7; ++k) d.rigid_p[7 * r + k] = b.inertia.trace() / 3 * N(rng);
  }
  return d;
}

// The state and model moved along d by e.
State moved(const Model& model, const State& in, const Direction& d, double e, Model& m) {
  m = model;
  State s = in;
  s.x += e * d.x;
  s.v += e * d.v;
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const auto ri = static_cast<Eigen::Index>(r);
    s.rigid[r] = rigid::retract(in.rigid[r], d.rigid.segment<12>(12 * ri), e);
    for (int k = 0; k < 7; ++k)
      rigid::set_parameter(m.rigid[r], k, rigid::get_parameter(model.rigid[r], k) + e * d.rigid_p[7 * ri + k]);
  }
  return s;
}

// Central differences of the step along a random direction (every input at once) against
// the JVP, then the dot-product test of the VJP. eps: the step along the direction (its
// entries are O(1) in m, m/s, rad, and the parameters on their own scale); the tolerance
// is relative to the largest entry of the finite difference (see each scene).
// jv_out: the JVP (for the comparison between backends); sparse: whether the step must
// have taken the sparse contact backend (checked).
void check_step(const Model& model, const State& in, double eps, double tol, unsigned seed = 5,
                integrator::StateTangent* jv_out = nullptr, unsigned mask = 15) {
  std::unique_ptr<Data> data;
  const State out = step_from(model, in, data);
  const int nc = data->contact.contacts.size();
  ASSERT_GT(nc, 0);
  EXPECT_EQ(data->contact.result.sparse, model.contact.ncp.backend == contact::NcpBackend::sparse);
  const std::vector<contact::Mode> modes = data->contact.modes;
  int sliding = 0, sticking = 0;
  for (auto m : modes) sliding += m == contact::Mode::sliding, sticking += m == contact::Mode::sticking;
  Direction d = random_direction(model, seed);
  // mask: which inputs the direction moves (1 soft x, 2 soft v, 4 rigid tangent, 8 rigid
  // parameters); 15 every one at once.
  if (!(mask & 1)) d.x.setZero();
  if (!(mask & 2)) d.v.setZero();
  if (!(mask & 4)) d.rigid.setZero();
  if (!(mask & 8)) d.rigid_p.setZero();
  integrator::StepDerivatives D(model, {});
  integrator::StepTangent t;
  t.x = d.x;
  t.v = d.v;
  t.rigid = d.rigid;
  t.rigid_p = d.rigid_p;
  integrator::StateTangent jv;
  ASSERT_TRUE(D.jvp(model, *data, in, out, t, jv));
  ASSERT_EQ(jv.rigid.size(), 12 * static_cast<Eigen::Index>(model.rigid.size()));
  if (jv_out) *jv_out = jv;

  Model mp, mm;
  std::unique_ptr<Data> dp, dm;
  const State sp = step_from(mp, moved(model, in, d, eps, mp), dp);
  const State sm = step_from(mm, moved(model, in, d, -eps, mm), dm);
  // The same contacts and modes on both sides: the derivative is that of one smooth piece.
  ASSERT_EQ(dp->contact.contacts.size(), nc);
  ASSERT_EQ(dm->contact.contacts.size(), nc);
  ASSERT_EQ(dp->contact.modes, modes);
  ASSERT_EQ(dm->contact.modes, modes);
  VecX fd(jv.x.size() + jv.v.size() + jv.rigid.size()), an(fd.size());
  fd.head(jv.x.size()) = (sp.x - sm.x) / (2 * eps);
  fd.segment(jv.x.size(), jv.v.size()) = (sp.v - sm.v) / (2 * eps);
  for (std::size_t r = 0; r < model.rigid.size(); ++r)
    fd.segment<12>(jv.x.size() + jv.v.size() + 12 * static_cast<Eigen::Index>(r)) =
        (rigid::tangent_between(out.rigid[r], sp.rigid[r]) - rigid::tangent_between(out.rigid[r], sm.rigid[r])) /
        (2 * eps);
  an << jv.x, jv.v, jv.rigid;
  const double scale = fd.cwiseAbs().maxCoeff();
  const double err = (an - fd).cwiseAbs().maxCoeff();
  std::cout << "contacts " << nc << " (sticking " << sticking << ", sliding " << sliding << "): max |JVP - FD| " << err
            << " of max |FD| " << scale << "; rigid rows JVP " << jv.rigid.transpose() << "\n";
  EXPECT_LT(err, tol * scale);
  // The rigid rows alone (small beside a soft body's): relative to their own scale.
  const VecX fd_r = fd.tail(jv.rigid.size()), an_r = an.tail(jv.rigid.size());
  EXPECT_LT((an_r - fd_r).cwiseAbs().maxCoeff(), tol * fd_r.cwiseAbs().maxCoeff());

  // Dot-product test: <bar, J t> = <J^T bar, t> for a random cotangent: exact algebra, to
  // round-off (1e-10 relative to the products' magnitudes).
  const Direction b = random_direction(model, seed + 100);
  integrator::StateTangent bar;
  bar.x = b.x;
  bar.v = b.v;
  bar.rigid = b.rigid;
  integrator::StepCotangent cot;
  ASSERT_TRUE(D.vjp(model, *data, in, out, bar, cot));
  const double lhs = bar.x.dot(jv.x) + bar.v.dot(jv.v) + bar.rigid.dot(jv.rigid);
  const double rhs = cot.x.dot(t.x) + cot.v.dot(t.v) + cot.rigid.dot(t.rigid) + cot.rigid_p.dot(t.rigid_p);
  const double mag = std::abs(bar.x.cwiseProduct(jv.x).sum()) + bar.v.cwiseAbs().dot(jv.v.cwiseAbs()) +
                     bar.rigid.cwiseAbs().dot(jv.rigid.cwiseAbs());
  EXPECT_NEAR(lhs, rhs, 1e-10 * mag) << "lhs " << lhs << ", rhs " << rhs;
}

// A tetrahedron (base triangle (0,0,0), (0.1,0,0), (0,0.08,0), apex (0.03,0.03,0.05) m)
// sliding on its base along a plane at 0.5 m/s with mu = 0.3 and spinning about z: three
// contacts, all sliding. (Three, not a box's four: four corners on a plane make the
// normal forces statically indeterminate, rank 3 of 4, and with friction their split,
// which the solver picks, moves the friction torque; the derivative takes the
// minimum-norm split, a finite difference the solver's. Three are determinate.)
rigid::Shape wedge() { return test::rigid_scenes::wedge_shape(); }

// The scenes (dense backend; `in`: the state of the step differentiated).
Model wedge_scene(State& in) {
  Model model = anchored(1e-3);
  test::rigid_scenes::add_sliding_wedge(model);
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0, "floor")}, {{"wedge", "floor", 0.3}}, 1e-3, tight());
  model.contact.ncp.backend = contact::NcpBackend::dense;
  in = warm_up(model, 5);
  return model;
}

TEST(RigidContactStepDerivatives, WedgeSlidingOnAPlane) {
  State in;
  const Model model = wedge_scene(in);
  // eps = 1e-6: the outputs are smooth within the piece; truncation eps^2 times their
  // curvature (the gap term phi / h: ~1 / h^2 = 1e6 relative) is ~1e-6 relative at
  // worst, round-off ~1e-16 / 1e-6 = 1e-10 of the outputs. tol 1e-5 relative to the
  // largest difference.
  check_step(model, in, 1e-6, 1e-5);
}

// A block on an incline of 20 degrees with mu = 0.6 > tan 20 = 0.36: it sticks (the
// validation's incline, rigid_contact_validation); all four contacts sticking.
Model incline_scene(State& in) {
  Model model = anchored(1e-3);
  const double a = 20 * 3.14159265358979 / 180;
  const Vec3 n(std::sin(a), 0, std::cos(a));
  rigid::RigidState s;
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(a, Vec3::UnitY()));
  s.position = 0.02 * n;
  test::add_rigid_body(model, "block", test::box_shape(Vec3(0.05, 0.03, 0.02)), 1000, s);
  test::enable_rigid_contact(model, {test::plane(n, 0, "ramp")}, {{"block", "ramp", 0.6}}, 1e-3, tight());
  model.contact.ncp.backend = contact::NcpBackend::dense;
  in = warm_up(model, 5);
  return model;
}

TEST(RigidContactStepDerivatives, BlockStickingOnAnIncline) {
  State in;
  const Model model = incline_scene(in);
  check_step(model, in, 1e-6, 1e-5);
}

// A rigid cube (0.02 m, 500 kg/m^3) on a soft slab (4 x 4 x 1 tets' boxes, 0.06 x 0.06 x
// 0.01 m, bottom fixed): the slab's top vertices against the cube's bottom triangles and
// the cube's corners against the slab's top faces (vertex-face both ways), so the
// geometry derivative runs through the soft nodes and the pseudo-nodes together.
Model cube_scene(State& in) {
  const test::BodySpec spec = test::rigid_scenes::damped_slab_spec();
  const mesh::TetMesh m = test::box_mesh(4, 4, 1, 0.06, 0.06, 0.01);
  Model model = test::make_model(m, spec, Vec3(0, 0, -g0), 2e-3);
  rigid::RigidState s;
  // Between the slab's node lines and turned by 0.1 rad about z, so that every soft vertex
  // under it and every corner of it lies inside a face, more than the margin (1 mm) from
  // any edge or diagonal: the feature pairs do not switch under the perturbation.
  // It lands: 0.3 mm above the slab at 0.3 m/s down, so that in the step differentiated
  // the contacts are well inside their modes (at rest, many carry no force at zero gap:
  // degenerate complementarity, where the modes flip under any perturbation).
  s.position = Vec3(0.0375, 0.0375, 0.01 + 0.01 + 3e-4);
  s.velocity = Vec3(0.05, 0, -0.3);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Vec3::UnitZ()));
  test::add_rigid_body(model, "cube", test::box_shape(Vec3(0.01, 0.01, 0.01)), 500, s);
  test::enable_rigid_contact(model, {}, {{"body", "cube", 0.5}}, 1e-3, tight());
  model.contact.ncp.backend = contact::NcpBackend::dense;
  in = model.initial;
  return model;
}

TEST(RigidContactStepDerivatives, CubeOnASoftSlab) {
  State in;
  const Model model = cube_scene(in);
  // eps = 5e-9: the soft positions' direction (every node moved, elements deformed) has a
  // large curvature in this landing step: the difference's error measured 2.5 at eps =
  // 1e-7 and 0.025 at 1e-8 against outputs of 5.6e3 (eps^2 truncation, 4e-4 and 4e-6
  // relative), so 1.1e-6 at 5e-9; round-off 1e-16 / 5e-9 = 2e-8 relative. tol 1e-5.
  check_step(model, in, 5e-9, 1e-5);
}

// A rigid sphere (r 8 mm, 1000 kg/m^3, tessellated as build_model does: max edge r / 4,
// 26 segments around, 314 vertices) landing on the soft slab of cube_scene: 0.3 mm above
// it at 0.3 m/s down and 0.05 m/s along x, its pole vertex over a slab face away from
// its edges (the pole at (31.3, 28.7) mm, the slab's node lines every 15 mm): one
// sticking contact (the pole against the face) and 87 within the margin, breaking.
// Issue 21 (2026-12-04, rsph): "a rigid sphere on the soft beam fails check-grad".
Model sphere_scene(State& in) {
  const test::BodySpec spec = test::rigid_scenes::damped_slab_spec();
  const mesh::TetMesh m = test::box_mesh(4, 4, 1, 0.06, 0.06, 0.01);
  Model model = test::make_model(m, spec, Vec3(0, 0, -g0), 2e-3);
  rigid::RigidState s;
  s.position = Vec3(0.0313, 0.0287, 0.01 + 0.008 + 3e-4);
  s.velocity = Vec3(0.05, 0, -0.3);
  rigid::Shape sh;
  sh.kind = rigid::Shape::Kind::sphere;
  sh.radius = 0.008;
  test::add_rigid_body(model, "ball", sh, 1000, s, 0.25 * sh.radius);
  test::enable_rigid_contact(model, {}, {{"body", "ball", 0.5}}, 1e-3, tight());
  model.contact.ncp.backend = contact::NcpBackend::dense;
  in = model.initial;
  return model;
}

TEST(RigidContactStepDerivatives, SphereOnASoftSlab) {
  State in;
  const Model model = sphere_scene(in);
  // Each input alone (mask 1 soft x, 2 soft v, 4 the sphere's 12-tangent, 8 its mass and
  // inertia) and all at once: a wrong geometric term of one input is not hidden by the
  // others' larger columns. eps 5e-9 and tol 1e-5 as CubeOnASoftSlab (the same slab, the
  // same landing: truncation ~1e-6 relative, round-off ~2e-8); measured 1.2e-9 relative
  // at worst (2.3e-6 of 1.9e3).
  for (unsigned mask : {15u, 1u, 2u, 4u, 8u}) {
    std::cout << "mask " << mask << "\n";
    check_step(model, in, 5e-9, 1e-5, 5, nullptr, mask);
  }
}

// The scene of the report (issue 21, 2026-12-04, rsph): configs/beam_cantilever.yaml's beam
// (meshes/beam.msh, clamped) and a rigid sphere (r 8 mm, 1000 kg/m^3, build_model's
// tessellation) 0.2 mm above its top face at (101.3, 11.7) mm, v (0.05, 0, -0.1) m/s, pair
// mu 0.4; one step of 0.01 s: the pole sticks on a beam face, every other contact in the
// margin breaks. `margin` (m): the contact margin (the speculative margin 2 h max|v| is
// added per surface).
Model sphere_beam_scene(State& in, const std::string& margin) {
  const std::string text = test::rigid_scenes::clamped_beam_yaml(1) +
                           "  - name: ball\n    type: rigid\n    shape: {type: sphere, radius: 0.008}\n"
                           "    density: 1000\n    position: [0.1013, 0.0117, 0.0282]\n"
                           "    velocity: [0.05, 0.0, -0.1]\n"
                           "contact:\n  pairs: [[beam, ball, 0.4]]\n  margin: " +
                           margin + "\n  tolerance: 1.0e-12\n  max_iterations: 5000\n";
  Model model = test::rigid_scenes::load_scene_text("rsph", "sphere_beam", text);
  model.contact.ncp.backend = contact::NcpBackend::dense;
  in = model.initial;
  return model;
}

// Margin 7e-4 m (347 contacts, one sticking): the step's JVP along each input alone and
// all at once against central differences (eps 5e-9, tol 1e-5 as CubeOnASoftSlab: a
// landing of a soft body, truncation ~1e-6 relative at this eps, round-off ~2e-8);
// measured 5.1e-8 relative at worst (2.9e-4 of 5.6e3, soft x).
TEST(RigidContactStepDerivatives, SphereOnTheBeam) {
  State in;
  const Model model = sphere_beam_scene(in, "7.0e-4");
  for (unsigned mask : {15u, 1u, 2u, 4u, 8u}) {
    std::cout << "mask " << mask << "\n";
    check_step(model, in, 5e-9, 1e-5, 5, nullptr, mask);
  }
}

// The margin of the report, 1e-3 m: build_model's default randomized smoothing of the
// detection derivatives (contact.smoothing: 16 samples, sigma = margin / 10 = 1e-4 m) then
// sees the sticking pole contact 0.28 mm from the diagonal of the beam's top-face
// triangle it lies in (2.8 sigma): a sample crosses it, and the contact's geometry
// derivative is the smoothed estimate (the mean of both triangles' weight derivatives),
// by design not the derivative of this step (measured: max |JVP - FD| 464 of 5587 along
// every input, 200 soft x, 265 the sphere's tangent; the central differences identical
// to margin 7e-4's). With smoothing off (samples 0) the same step matches the central
// differences as above (measured 5.1e-8 relative); with it on, the step reports smoothed
// contacts (the JVP is not compared there: an estimate, docs/method.md "Randomized smoothing").
TEST(RigidContactStepDerivatives, SphereOnTheBeamWithTheReportedMarginIsSmoothedNearTheDiagonal) {
  State in;
  Model model = sphere_beam_scene(in, "1.0e-3");
  ASSERT_EQ(model.contact.smoothing.samples, 16);
  ASSERT_DOUBLE_EQ(model.contact.smoothing.sigma, 1e-4);
  {
    std::unique_ptr<Data> data;
    const State out = step_from(model, in, data);
    integrator::StepDerivatives D(model, {});
    integrator::StepTangent t;
    t.x = VecX::Zero(in.x.size());
    t.v = VecX::Zero(in.v.size());
    t.rigid = VecX::Zero(12);
    t.rigid_p = VecX::Zero(7);
    integrator::StateTangent jv;
    ASSERT_TRUE(D.jvp(model, *data, in, out, t, jv));
    // Measured 138 of 391: the pole's and breaking ones (zero force: no effect) near features.
    EXPECT_GT(D.smoothed_contacts(), 0);
  }
  model.contact.smoothing.samples = 0;
  for (unsigned mask : {15u, 1u, 4u}) {
    std::cout << "mask " << mask << "\n";
    check_step(model, in, 5e-9, 1e-5, 5, nullptr, mask);
  }
}

// The hinged bar of rigid_contact_validation resting on a support under one of its free
// corners, and a block on a vertical slider resting on a support under one corner: one
// contact each (a joint has one dof: two contacts on it would be indeterminate).
Model hinge_scene(State& in) {
  Model model = anchored(1e-3);
  rigid::RigidState bar;
  bar.position = Vec3(0.1, 0, 0.01);
  test::add_rigid_body(model, "bar", test::box_shape(Vec3(0.1, 0.02, 0.01)), 800, bar, 0.01, rigid::Joint::Kind::hinge);
  model.rigid[0].joint.anchor = Vec3(0, 0, 0.01);
  model.rigid[0].joint.axis = Vec3::UnitY();
  rigid::initialize(model.rigid[0], bar);
  model.initial.rigid[0] = model.rigid[0].reference;
  rigid::RigidState block;
  block.position = Vec3(1, 0, 0.02);
  test::add_rigid_body(model, "block", test::box_shape(Vec3(0.02, 0.02, 0.02)), 500, block, 0.01,
                       rigid::Joint::Kind::slider);
  model.rigid[1].joint.anchor = block.position;
  model.rigid[1].joint.axis = Vec3::UnitZ();
  rigid::initialize(model.rigid[1], block);
  test::enable_rigid_contact(
      model,
      {test::box(Vec3(0.2, 0.02, -0.01), Vec3(0.01, 0.005, 0.01), "support"),
       test::box(Vec3(1.02, 0.02, -0.01), Vec3(0.005, 0.005, 0.01), "post")},
      {{"bar", "support", 0.0}, {"block", "post", 0.0}}, 1e-3, tight());
  model.contact.ncp.backend = contact::NcpBackend::dense;
  in = warm_up(model, 5);
  return model;
}

TEST(RigidContactStepDerivatives, HingedBarAndSliderOnSupports) {
  State in;
  const Model model = hinge_scene(in);
  // eps, tol as for the wedge.
  check_step(model, in, 1e-6, 1e-5);
}

// The hinge's W_r with the gravity torque's tangent (rigid_contact.cpp begin_rigid_contact,
// rbranch: a = I_a - h^2 Q'(delta_u)) and its derivative (rigid_contact_derivatives.cpp:
// through the start position, the mass and the free step's rate). A hinged body alone on
// one active row does not show W (the row fixes its one dof's velocity), so the bar here
// shares its contacts with a soft pad (rigid_scenes.hpp bar_on_pad's pad and bar, the bar
// and its anchor moved by (3, 3, 0) mm so that no bar vertex lies on a pad triangle's edge:
// there a difference of 1e-6 changes the contact set), the impulse splitting between the
// pad and the bar by their W; and gravity is tilted, (-9.81, 0, -4) m/s^2, so that the
// level bar's torque has a tangent: Q' = -m g.r_perp = 0.98 m N m/rad, h^2 Q' / I_a =
// 1.8e-3 at h = 5 ms (with vertical gravity Q' = 0 for a level bar). Two states (5 and 20
// steps after the release), eps 1e-6 as for the wedge. Measured: the JVP against the
// differences 6.2e-8 and 5.6e-8 of the largest entry (1039); without the tangent's
// derivative (the three terms of d(a) in rigid_contact_derivatives.cpp removed) 1.4e-6 and
// 1.2e-6: tol 3e-7 tells them apart (the wedge's 1e-5 would not).
TEST(RigidContactStepDerivatives, HingedBarOnASoftPadWithTheGravityTorquesTangent) {
  Model model = test::rigid_scenes::bar_on_pad(5e-3);
  const Vec3 shift(0.003, 0.003, 0);
  auto& bar = model.rigid[0];
  rigid::RigidState s = model.initial.rigid[0];
  s.position += shift;
  bar.joint.anchor += shift;
  rigid::initialize(bar, s);
  model.initial.rigid[0] = bar.reference;
  model.step.gravity = Vec3(-9.81, 0, -4);
  model.contact.ncp = tight();
  model.contact.ncp.backend = contact::NcpBackend::dense;
  for (long w : {5L, 20L}) {
    SCOPED_TRACE(w);
    const State in = warm_up(model, w);
    check_step(model, in, 1e-6, 3e-7);
  }
}

// The hinge's effective inertia I_a - h^2 Q' (rigid_contact.cpp begin_rigid_contact) is not
// positive when the step is too long for an overturning gravity torque: the bar of
// bar_on_pad (0.2 m from its anchor, I_a = m (0.2^2 + 0.02^2) / 12 + m 0.1^2 = 0.0134 m)
// with gravity exactly along the bar towards its anchor (-9.81 m/s^2 in x: an inverted
// pendulum at its equilibrium, so the free step from rest stays there, delta = 0, and
// -Q' = c2 = -m 9.81 x 0.1) needs h^2 x 0.981 > 0.0134, h > 0.117 s; at h = 0.2 s the
// step stops with a ComputationError naming the body, never a negative W_r. At h = 0.05 s
// the same scene steps. (With a gravity off the bar's line the free step swings the bar
// past the flip, cos(delta) < 0, and the effective inertia stays positive.)
TEST(RigidContactStep, AHingeWhoseEffectiveInertiaIsNotPositiveIsAComputationError) {
  for (const double h : {0.05, 0.2}) {
    SCOPED_TRACE(h);
    Model model = test::rigid_scenes::bar_on_pad(h);
    model.step.gravity = Vec3(-9.81, 0, 0);
    Data data(model);
    State out;
    if (h < 0.1) {
      EXPECT_NO_THROW(integrator::time_step(model, data, model.initial, nullptr, out, 1));
      continue;
    }
    try {
      integrator::time_step(model, data, model.initial, nullptr, out, 1);
      ADD_FAILURE() << "no ComputationError: the free rate " << data.rigid[0].free_rate << " rad/s, "
                    << data.contact.contacts.size() << " contacts";
    } catch (const ComputationError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("the hinge's effective inertia I_a - h^2 Q'"), std::string::npos) << what;
      EXPECT_NE(what.find("rigid body '" + model.rigid[0].name + "'"), std::string::npos) << what;
    }
  }
}

// Each scene on the sparse backend and on the operator: the JVP against central
// differences and the dot-product test (check_step, the dense scenes' eps and tol), and
// the JVP equal to the dense backend's from the same state. That last tolerance: both
// steps solve the NCP to 1e-12 relative (tight(); the polish to round-off) and the
// operator's mode-fixed system to cg_tolerance 1e-12 / GMRES 1e-13 relative, amplified
// by the mode-fixed system's conditioning (kappa of G_AA over these scenes' masses and
// lever arms <= 1e3): 1e-8 relative to the largest entry of the dense JVP. Before the
// fix (issue 21) the sparse JVPs missed h Kt^T Kt: the wedge's rigid rows were off by O(1).
class RigidContactDerivativesOnBackend : public ::testing::TestWithParam<Backend> {};

void check_backend(const Model& dense, const State& in, Backend b, double eps, double tol) {
  const Model model = on_backend(dense, b);
  integrator::StateTangent jv, jd;
  check_step(model, in, eps, tol, 5, &jv);
  check_step(dense, in, eps, tol, 5, &jd);
  ASSERT_EQ(jv.x.size(), jd.x.size());
  ASSERT_EQ(jv.rigid.size(), jd.rigid.size());
  VecX a(jv.x.size() + jv.v.size() + jv.rigid.size()), d(a.size());
  a << jv.x, jv.v, jv.rigid;
  d << jd.x, jd.v, jd.rigid;
  const double err = (a - d).cwiseAbs().maxCoeff(), mag = d.cwiseAbs().maxCoeff();
  std::cout << backend_name(b) << ": max |JVP - dense JVP| " << err << " of " << mag << "\n";
  EXPECT_LT(err, 1e-8 * mag);
}

TEST_P(RigidContactDerivativesOnBackend, WedgeSlidingOnAPlane) {
  State in;
  const Model dense = wedge_scene(in);
  check_backend(dense, in, GetParam(), 1e-6, 1e-5);
}

TEST_P(RigidContactDerivativesOnBackend, BlockStickingOnAnIncline) {
  State in;
  const Model dense = incline_scene(in);
  check_backend(dense, in, GetParam(), 1e-6, 1e-5);
}

TEST_P(RigidContactDerivativesOnBackend, CubeOnASoftSlab) {
  State in;
  const Model dense = cube_scene(in);
  check_backend(dense, in, GetParam(), 5e-9, 1e-5);
}

TEST_P(RigidContactDerivativesOnBackend, HingedBarAndSliderOnSupports) {
  State in;
  const Model dense = hinge_scene(in);
  check_backend(dense, in, GetParam(), 1e-6, 1e-5);
}

INSTANTIATE_TEST_SUITE_P(, RigidContactDerivativesOnBackend, ::testing::Values(Backend::sparse, Backend::op),
                         [](const ::testing::TestParamInfo<Backend>& p) { return backend_name(p.param); });

// Newton (newton_iterations 8, docs/method.md "Newton with rigid contact") on the sparse
// backend: the implicit function theorem at the converged step (G_AA with the converged
// tangent A_f plus the rigid rows h Kt^T Kt), the cube landing on the soft slab. Newton
// converges to newton_tolerance 1e-12 (1e-14 is below the equations' round-off floor,
// measured 1.0e-12 relative): its error on the outputs, ~1e-12 of |v| ~ 0.1 m/s, divided
// by eps = 5e-9 is ~2e-5 against max |FD| ~4e3, 5e-9 relative, far below tol; eps and
// tol otherwise as CubeOnASoftSlab.
TEST(RigidContactStepDerivatives, NewtonCubeOnASoftSlab) {
  State in;
  Model model = on_backend(cube_scene(in), Backend::sparse);
  model.step.newton_iterations = 20;
  model.step.newton_tolerance = 1e-12;
  check_step(model, in, 5e-9, 1e-5);
}

// The same on the dense backend (rnewtd): the record's G is the last Newton
// factorization's, one iterate before v_f; the derivative recomputes G_AA with A_f and
// the rigid rows Kt formed from the record's H_r^T and L_r (ContactStageDerivative::
// rigid_rows). eps and tol as above; then the dense JVP equal to the sparse one from the
// same state (check_backend's 1e-8 relative: both Newton steps converge to 1e-12 and
// their NCPs to round-off after the polish).
TEST(RigidContactStepDerivatives, NewtonCubeOnASoftSlabDense) {
  State in;
  Model model = cube_scene(in);
  model.step.newton_iterations = 20;
  model.step.newton_tolerance = 1e-12;
  check_backend(model, in, Backend::sparse, 5e-9, 1e-5);
}

// Newton with joint limits in the contact solve (rnewtd; dense backend): the limit rows'
// extended G built from the contacts' G with the converged tangent A_f
// (ContactStageDerivative::full_G), not the record's. The limits scene below
// (LimitsCarryingContactLoads), declared here; eps and tol as there.
Model limit_scene(State& in, long warm, double upper = 0.0);
VecX limit_forces(const Model& model, const State& in);

TEST(RigidContactStepDerivatives, NewtonLimitsCarryingContactLoads) {
  State in0;
  Model model = limit_scene(in0, 300);
  // Newton to 1e-10: at rest the equations' round-off floor is ~2e-12 relative (1e-12 was
  // missed, measured 1.8-5.8e-12), and Newton's quadratic convergence leaves the accepted
  // iterate far below the tolerance it passed.
  model.step.newton_iterations = 20;
  model.step.newton_tolerance = 1e-10;
  model.initial = in0;
  const State in = warm_up(model, 20);  // from the settled state: 20 Newton steps
  const VecX lim = limit_forces(model, in);
  std::cout << "limit forces " << lim.transpose() << "\n";
  ASSERT_EQ(lim.size(), 4);
  EXPECT_GT(lim[1], 0);
  EXPECT_GT(lim[2], 0);
  check_step(model, in, 1e-8, 1e-5);
}

}  // namespace rigid_contact_derivatives_test

namespace rigid_contact_derivatives_test {

// The state moved along a column of x0 / v0 (soft rows, then 6 per rigid body: position
// and rotation vector, or velocity and angular velocity) by e.
State moved_initial(const Model& model, const State& s0, const VecX& dx0, const VecX& dv0, double e) {
  const Eigen::Index n3 = 3L * model.fem.num_nodes;
  State s = s0;
  s.x += e * dx0.head(n3);
  s.v += e * dv0.head(n3);
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const Eigen::Index o = n3 + 6 * static_cast<Eigen::Index>(r);
    rigid::Vec12 d;
    d << dx0.segment<6>(o), dv0.segment<6>(o);
    s.rigid[r] = rigid::retract(s0.rigid[r], d, e);
  }
  return s;
}

State run_steps(const Model& model, const State& s0, long steps) {
  Data data(model);
  State a = s0, b;
  for (long k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::time_step(model, data, a, nullptr, b, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    std::swap(a, b);
  }
  return a;
}

// The final state's rows as the sensitivities have them: soft x, then per rigid body
// (position, rotation vector) as tangents from `base`; likewise v and (v, omega).
void rows_from(const Model& model, const State& base, const State& s, VecX& x_rows, VecX& v_rows) {
  const Eigen::Index n3 = 3L * model.fem.num_nodes, R = static_cast<Eigen::Index>(model.rigid.size());
  x_rows.resize(n3 + 6 * R);
  v_rows.resize(n3 + 6 * R);
  x_rows.head(n3) = s.x - base.x;
  v_rows.head(n3) = s.v - base.v;
  for (Eigen::Index r = 0; r < R; ++r) {
    const rigid::Vec12 t = rigid::tangent_between(base.rigid[static_cast<std::size_t>(r)], s.rigid[static_cast<std::size_t>(r)]);
    x_rows.segment<6>(n3 + 6 * r) = t.head<6>();
    v_rows.segment<6>(n3 + 6 * r) = t.tail<6>();
  }
}

// 12 steps of the wedge sliding and spinning on the plane (three sliding contacts all
// along): forward sensitivities with respect to one random direction of x0, one of v0
// (soft and rigid rows), the wedge's mass and its inertia zz, against central differences
// of whole runs; then the adjoint of a loss on the final state (soft and rigid) against
// the same sensitivities (exact algebra: 1e-9 relative).
// On each backend (the sparse ones: issue 21).
class RigidContactTrajectoryDerivatives : public ::testing::TestWithParam<Backend> {};

TEST_P(RigidContactTrajectoryDerivatives, SensitivitiesAndAdjointOfASlidingWedge) {
  Model model = anchored(1e-3);
  const rigid::Shape shape = wedge();
  const rigid::MassProperties mp = rigid::mass_properties(shape, 800);
  rigid::RigidState s;
  s.position = Vec3(0, 0, mp.centre.z());
  s.velocity = Vec3(0.5, 0.1, 0);
  s.angular_velocity = Vec3(0, 0, 0.8);
  test::add_rigid_body(model, "wedge", shape, 800, s);
  test::enable_rigid_contact(model, {test::plane(Vec3::UnitZ(), 0, "floor")}, {{"wedge", "floor", 0.3}}, 1e-3, tight());
  model = on_backend(model, GetParam());
  model.initial = warm_up(model, 3);
  const long T = 12;
  const Eigen::Index n3 = 3L * model.fem.num_nodes, rows = n3 + 6;
  std::mt19937 rng(3);
  std::normal_distribution<double> N;
  diff::ThetaLayout theta;
  theta.x0 = theta.v0 = true;
  theta.x0_basis = MatX::NullaryExpr(rows, 1, [&] { return N(rng); });
  theta.v0_basis = MatX::NullaryExpr(rows, 1, [&] { return N(rng); });
  theta.rigid_parameters = {{0, 0}, {0, 3}};
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, T, theta, final, dx, dv).ok());
  ASSERT_EQ(dx.cols(), 4);
  // Central differences of whole runs along the unit-scale directions (the parameters:
  // times the mass, and the inertia's trace / 3). eps = 1e-6, but 1e-8 for x0: its
  // direction moves and tilts the 5 cm wedge by O(1) m and rad per unit, and the
  // difference's error measured 5.3e-3, 5.3e-5, 1.8e-7 at eps = 1e-6, 1e-7, 1e-8 (eps^2
  // truncation; at 1e-5 a contact changes mode) against entries of 2.2. Round-off
  // ~1e-16 / eps of the outputs. tol 1e-5 relative to each column's largest entry.
  const VecX zero = VecX::Zero(rows);
  for (int c = 0; c < 4; ++c) {
    const double eps = c == 0 ? 1e-8 : 1e-6;
    double scale = 1;
    State sp, sm;
    if (c < 2) {
      const VecX d0 = c == 0 ? VecX(theta.x0_basis.col(0)) : zero, e0 = c == 1 ? VecX(theta.v0_basis.col(0)) : zero;
      sp = run_steps(model, moved_initial(model, model.initial, d0, e0, eps), T);
      sm = run_steps(model, moved_initial(model, model.initial, d0, e0, -eps), T);
    } else {
      const int index = c == 2 ? 0 : 3;
      scale = c == 2 ? model.rigid[0].mass : model.rigid[0].inertia.trace() / 3;
      Model mpl = model, mmi = model;
      rigid::set_parameter(mpl.rigid[0], index, rigid::get_parameter(model.rigid[0], index) + eps * scale);
      rigid::set_parameter(mmi.rigid[0], index, rigid::get_parameter(model.rigid[0], index) - eps * scale);
      sp = run_steps(mpl, model.initial, T);
      sm = run_steps(mmi, model.initial, T);
    }
    VecX xp, vp, xm, vm;
    rows_from(model, final, sp, xp, vp);
    rows_from(model, final, sm, xm, vm);
    VecX fd(2 * rows), an(2 * rows);
    fd << (xp - xm) / (2 * eps), (vp - vm) / (2 * eps);
    an << dx.col(c) * scale, dv.col(c) * scale;
    const double err = (an - fd).cwiseAbs().maxCoeff(), mag = fd.cwiseAbs().maxCoeff();
    std::cout << "column " << c << ": max |sensitivity - FD| " << err << " of " << mag << "\n";
    EXPECT_LT(err, 1e-5 * mag) << "column " << c;
  }
  test::rigid_scenes::expect_adjoint_matches_forward(model, T, theta, dx, dv, rng, N);
}

INSTANTIATE_TEST_SUITE_P(, RigidContactTrajectoryDerivatives,
                         ::testing::Values(Backend::dense, Backend::sparse, Backend::op),
                         [](const ::testing::TestParamInfo<Backend>& p) { return backend_name(p.param); });

}  // namespace rigid_contact_derivatives_test

namespace rigid_contact_derivatives_test {

// Joint limits in contact (issue 21; rigid_contact_derivatives.hpp "Joint limits in
// contact"): the limit rows of the step's NCP, an active limit a bilateral row of the
// mode-fixed system. The set-up of validation_rigid_contact.cpp's
// LimitsCarryContactLoadsExactly, with small pads: a soft pad (8 mm cube, damped) on a
// bar (0.2 x 0.04 x 0.02 m) hinged about y at its left end and held by its upper limit
// (the "key" pressed against its stop by the pad and its weight), and a block on a
// vertical slider resting on its lower limit 0 under a second pad (the limit carries both
// weights). The rigid surfaces are coarse (max_edge 0.06: the bar's top face is four
// cells of 0.05 x 0.04 m, the block's one of 0.04 m) and each pad, turned by 0.1 rad about
// z, stands inside one triangle of them more than 1 mm (the margin) from every edge and
// diagonal, with no rigid vertex under it: its four bottom nodes are vertex-face contacts
// whose feature pairs do not switch under the perturbations (as CubeOnASoftSlab). The
// pads are frictionless (mu = 0): with mu = 0.5 the resting pads' contacts sit at the
// stick-slip boundary (no tangential load) and the solver's modes changed under
// perturbations of 1e-8 (measured), so no finite difference is of one piece there.
// `upper`: the bar's upper limit (0: it starts on it). Warmed up `warm` steps.
Model limit_scene(State& in, long warm, double upper) {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.density = 1000;
  spec.rayleigh_mass = 20;
  spec.rayleigh_stiffness = 0.005;
  const mesh::TetMesh cube = test::box_mesh(1, 1, 1, 0.008, 0.008, 0.008);
  const Mat3 turn = Eigen::AngleAxisd(0.1, Vec3::UnitZ()).toRotationMatrix();
  const auto placed = [&](const Vec3& bottom_centre) {
    mesh::TetMesh m = cube;
    for (Eigen::Index i = 0; i < m.X.cols(); ++i)
      m.X.col(i) = bottom_centre + turn * (Vec3(m.X.col(i)) - Vec3(0.004, 0.004, 0));
    return m;
  };
  const mesh::TetMesh pad_a = placed(Vec3(0.175, -0.0125, 0.02)), pad_b = placed(Vec3(1.0, -0.0125, 0.04));
  std::vector<test::BodyInput> pads{{pad_a, spec, "pad_a"}, {pad_b, spec, "pad_b"}};
  Model model = test::make_model(pads, Vec3(0, 0, -g0), 1e-3);
  test::rigid_scenes::add_limited_bar_and_block(model, upper, 0.06);
  model.initial.rigid[0] = model.rigid[0].reference;
  model.initial.rigid[1] = model.rigid[1].reference;
  test::enable_rigid_contact(model, {}, {{"pad_a", "bar", 0.0}, {"pad_b", "block", 0.0}}, 1e-3, tight());
  model.contact.ncp.backend = contact::NcpBackend::dense;
  in = warm_up(model, warm);
  return model;
}

// The limits' forces of one step from `in` (by slot: bar lower, upper; block lower, upper).
VecX limit_forces(const Model& model, const State& in) {
  std::unique_ptr<Data> data;
  step_from(model, in, data);
  return data->contact.rigid.limit_lambda;
}

TEST(RigidContactStepDerivatives, LimitsCarryingContactLoads) {
  State in;
  const Model model = limit_scene(in, 300);
  // The step differentiated: both limits active (the bar's upper, the block's lower), the
  // others out of the NCP or inactive; the same on both sides of the differences (the
  // derivative is that of one piece: check_step checks the contacts' modes).
  const VecX lim = limit_forces(model, in);
  std::cout << "limit forces " << lim.transpose() << "\n";
  ASSERT_EQ(lim.size(), 4);
  EXPECT_GT(lim[1], 0);
  EXPECT_GT(lim[2], 0);
  EXPECT_EQ(lim[0], 0);
  EXPECT_EQ(lim[3], 0);
  const Direction d = random_direction(model, 5);
  for (double e : {1e-8, -1e-8}) {
    Model m;
    const VecX l = limit_forces(m, moved(model, in, d, e, m));
    EXPECT_TRUE(l[1] > 0 && l[2] > 0 && l[0] == 0 && l[3] == 0) << "limit forces " << l.transpose();
  }
  // eps = 1e-8: the random direction moves every pad node by O(1) m per unit, and on the
  // 8 mm pads (1 g, E = 1e5) a 1e-6 m move is a strain of 1e-4, an elastic force of ~6e-4
  // N beside the friction cones' mu lambda_N ~ 1e-3 N: at eps = 1e-6 contacts slip (the
  // modes change); at 1e-8, 1e-2 of it. Truncation eps^2 times the outputs' curvature (the
  // gap term ~1 / h^2 = 1e6 relative) ~1e-10, round-off 1e-16 / 1e-8 = 1e-8 relative. tol 1e-5.
  check_step(model, in, 1e-8, 1e-5);
}


// The same step on the sparse backend (rpsp; it was refused, exit 2 naming issue 21):
// the step's operator has the limit rows as columns of the rigid rows Kt; the
// derivative's mode-fixed system takes the same extended Kt (extended_rigid_rows: the
// record's Kt, the limits' normal columns L_r^T j, two rows of tangential diagonals) with
// zero soft columns, as a dense G_AA (`sparse`) or on the operator (`sparse_operator`: the
// derivative's crossovers 0, PCG; the step keeps the sparse backend's dense working sets,
// as on the operator's ADMM this pad-on-a-limit manifold stalls at 1.5e-8, docs/method.md
// "Limit rows on the sparse backend"). check_backend: the difference check and the dot
// product of check_step (same eps and tol as on dense), and the JVP against the dense
// backend's to 1e-8 relative.
class RigidContactLimitsOnBackend : public ::testing::TestWithParam<bool> {};

TEST_P(RigidContactLimitsOnBackend, LimitsCarryingContactLoads) {
  State in;
  const Model dense = limit_scene(in, 300);
  Model model = on_backend(dense, Backend::sparse);
  if (GetParam()) {
    model.contact.ncp.derivative_dense_max_active = 0;
    model.contact.ncp.derivative_mixed_dense_max_active = 0;
  }
  {
    std::unique_ptr<Data> data;
    step_from(model, in, data);
    ASSERT_EQ(data->contact.G.rows(), 0);
    const VecX& lim = data->contact.rigid.limit_lambda;
    ASSERT_EQ(lim.size(), 4);
    EXPECT_TRUE(lim[1] > 0 && lim[2] > 0 && lim[0] == 0 && lim[3] == 0) << "limit forces " << lim.transpose();
  }
  integrator::StateTangent jv, jd;
  check_step(model, in, 1e-8, 1e-5, 5, &jv);
  check_step(dense, in, 1e-8, 1e-5, 5, &jd);
  VecX a(jv.x.size() + jv.v.size() + jv.rigid.size()), d(a.size());
  a << jv.x, jv.v, jv.rigid;
  d << jd.x, jd.v, jd.rigid;
  const double err = (a - d).cwiseAbs().maxCoeff(), mag = d.cwiseAbs().maxCoeff();
  std::cout << (GetParam() ? "sparse_operator" : "sparse") << ": max |JVP - dense JVP| " << err << " of " << mag
            << "\n";
  EXPECT_LT(err, 1e-8 * mag);
}

INSTANTIATE_TEST_SUITE_P(, RigidContactLimitsOnBackend, ::testing::Bool(),
                         [](const ::testing::TestParamInfo<bool>& p) {
                           return std::string(p.param ? "sparse_operator" : "sparse");
                         });

// 10 steps of the limit scene from its settled state (300 steps: both limits active all
// along, the pads at rest and sticking): forward sensitivities with respect to the pads'
// Young's modulus (pad_a's), a random direction of x0 and one of v0 (soft and rigid rows),
// against central differences of whole runs; then the adjoint of a loss on the final
// state (soft and rigid rows) against the same sensitivities (exact algebra: 1e-9
// relative). The bodies' masses are not columns: held by their limits, the bodies' states
// do not depend on them (only the limits' reactions do).
// newton: the same with newton_iterations 20 at tolerance 1e-10 (rnewtd; the Newton step's
// implicit-function derivative, NewtonLimitsCarryingContactLoads), the same eps and tol.
void check_limit_trajectory(bool newton, Backend backend) {
  State in;
  Model model = on_backend(limit_scene(in, 300), backend);
  model.initial = in;
  if (newton) {
    model.step.newton_iterations = 20;
    model.step.newton_tolerance = 1e-10;
  }
  const long T = 10;
  const Eigen::Index n3 = 3L * model.fem.num_nodes, rows = n3 + 12;
  std::mt19937 rng(3);
  std::normal_distribution<double> N;
  diff::ThetaLayout theta;
  theta.parameters = {{Parameter::young, 0}};
  theta.x0 = theta.v0 = true;
  theta.x0_basis = MatX::NullaryExpr(rows, 1, [&] { return N(rng); });
  theta.v0_basis = MatX::NullaryExpr(rows, 1, [&] { return N(rng); });
  Data data(model);
  State final;
  MatX dx, dv;
  ASSERT_TRUE(diff::forward_sensitivities(model, data, model.initial, T, theta, final, dx, dv).ok());
  ASSERT_EQ(dx.cols(), 3);
  EXPECT_EQ(data.contact.G.rows() == 0, backend != Backend::dense);
  const VecX active = data.contact.rigid.limit_lambda;
  ASSERT_EQ(active.size(), 4);
  EXPECT_GT(active[1], 0);
  EXPECT_GT(active[2], 0);
  // eps, measured (max |sensitivity - FD| against the column's largest entry): Young's
  // modulus (relative) 1.5e-10, 2.1e-11, 3.6e-10, 3.8e-9 of 1.5e-4 at 1e-3 ... 1e-6: the
  // outputs move by 1.5e-4 eps, so below 1e-4 the NCP's solution to 1e-12 (a force noise
  // ~1e-14 m/s in v) dominates: 1e-4. x0 (its direction moves every node and the bodies by
  // O(1) m per unit): 1.5, 6.2e-3, 6.1e-5, 3.0e-3 of 80 at 1e-5 ... 1e-8 (eps^2 truncation,
  // then that noise / eps): 1e-7. v0: 2.4e-9, 1.3e-8, 1.1e-7, 1.5e-6 of 0.38 at 1e-5 ...
  // 1e-8: 1e-5. tol 1e-5 relative to each column's largest entry.
  const VecX zero = VecX::Zero(rows);
  for (int c = 0; c < 3; ++c) {
    const double eps = c == 0 ? 1e-4 : c == 1 ? 1e-7 : 1e-5;
    double scale = 1;
    State sp, sm;
    if (c > 0) {
      const VecX d0 = c == 1 ? VecX(theta.x0_basis.col(0)) : zero, e0 = c == 2 ? VecX(theta.v0_basis.col(0)) : zero;
      sp = run_steps(model, moved_initial(model, model.initial, d0, e0, eps), T);
      sm = run_steps(model, moved_initial(model, model.initial, d0, e0, -eps), T);
    } else {
      const ParameterId young{Parameter::young, 0};
      scale = diff::get_parameter(model, young);
      Model mpl = model, mmi = model;
      diff::set_parameter(mpl, young, scale * (1 + eps));
      diff::set_parameter(mmi, young, scale * (1 - eps));
      sp = run_steps(mpl, model.initial, T);
      sm = run_steps(mmi, model.initial, T);
    }
    VecX xp, vp, xm, vm;
    rows_from(model, final, sp, xp, vp);
    rows_from(model, final, sm, xm, vm);
    VecX fd(2 * rows), an(2 * rows);
    fd << (xp - xm) / (2 * eps), (vp - vm) / (2 * eps);
    an << dx.col(c) * scale, dv.col(c) * scale;
    const double err = (an - fd).cwiseAbs().maxCoeff(), mag = fd.cwiseAbs().maxCoeff();
    Eigen::Index worst = 0;
    (an - fd).cwiseAbs().maxCoeff(&worst);
    std::cout << "column " << c << ": max |sensitivity - FD| " << err << " of " << mag << " (row " << worst << " of "
              << 2 * rows << ": " << an[worst] << " against " << fd[worst] << ")\n";
    EXPECT_LT(err, 1e-5 * mag) << "column " << c;
  }
  test::rigid_scenes::expect_adjoint_matches_forward(model, T, theta, dx, dv, rng, N);
}

TEST(RigidContactLimitTrajectoryDerivatives, SensitivitiesAndAdjointThroughLimitsInContact) {
  check_limit_trajectory(false, Backend::dense);
}

TEST(RigidContactLimitTrajectoryDerivatives, NewtonSensitivitiesAndAdjointThroughLimitsInContact) {
  check_limit_trajectory(true, Backend::dense);
}

// The same on the sparse backend (rpsp): the record has no G (checked), the limit rows'
// derivative is the extended rigid rows'; the same eps and tolerances.
TEST(RigidContactLimitTrajectoryDerivatives, SensitivitiesAndAdjointThroughLimitsInContactOnTheSparseBackend) {
  check_limit_trajectory(false, Backend::sparse);
}

// Newton on the sparse backend: the limit rows' extended G from the contacts' G with the
// converged tangent (as on the dense backend), the same eps and tolerances.
TEST(RigidContactLimitTrajectoryDerivatives, NewtonSensitivitiesAndAdjointThroughLimitsInContactOnTheSparseBackend) {
  check_limit_trajectory(true, Backend::sparse);
}

}  // namespace rigid_contact_derivatives_test
