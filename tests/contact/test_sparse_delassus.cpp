// The sparse contact backend (docs/method.md "Contact at scale"): the Delassus
// operator of sparse_delassus.hpp against the dense G = h H A^{-1} H^T of the same
// step, its symbolic analyses, and the NCP solved on it against the dense solver.
//
// Scenes: a slab on a plane (vertex-obstacle contacts: H^T H inside A's pattern) and a
// small box resting on a larger one on a plane (soft-soft vertex-triangle contacts:
// H^T H couples nodes of two bodies, outside A's pattern). One step with the dense
// backend gives the reference G from the same factorization.
//
// Tolerances: G and the operator use the same factor; their products differ by
// round-off of a few solves, ~1e-15 relative; 1e-11 leaves room for the condition of
// A (~1e4 here) without hiding a wrong term (a missing h or a missing contact changes
// the result at O(1)). The shifted solve (G + c I)^{-1} r by Woodbury cancels about
// ||G|| / c digits: with c >= 1e-3 ||G||, 1e-9.
#include <softdiff/contact/ncp.hpp>
#include <softdiff/contact/sparse_delassus.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <support/contact.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <random>

using namespace softdiff;

namespace sparse_delassus_test {

constexpr double kG = 9.81;

Model slab_model() {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.rayleigh_stiffness = 1e-3;
  Model model = test::make_model(test::box_mesh(6, 5, 1, 0.06, 0.05, 0.01), spec, Vec3(0, 0, -kG), 0.005, 3);
  test::ContactSpec cs;
  cs.mu = 0.4;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  cs.ncp.backend = contact::NcpBackend::dense;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  return model;
}

// A 0.04 m cube (2x2x2 cells) resting 0.2 mm above a 0.1 x 0.1 x 0.02 slab that rests
// on the plane; the cube's vertices touch the slab's top triangles.
Model stack_model() {
  test::BodySpec spec;
  spec.young = 1e5;
  spec.rayleigh_stiffness = 1e-3;
  mesh::TetMesh bottom = test::box_mesh(4, 4, 1, 0.1, 0.1, 0.02);
  mesh::TetMesh top = test::box_mesh(2, 2, 2, 0.04, 0.04, 0.04);
  top.X.row(0).array() += 0.031;
  top.X.row(1).array() += 0.027;
  top.X.row(2).array() += 0.0202;
  Model model = test::make_model({{bottom, spec, "slab"}, {top, spec, "cube"}}, Vec3(0, 0, -kG), 0.005, 3);
  test::ContactSpec cs;
  cs.mu = 0.3;
  cs.ncp.tolerance = 1e-10;
  cs.ncp.max_iterations = 5000;
  cs.ncp.backend = contact::NcpBackend::dense;
  test::enable_contact(model, {test::plane(Vec3(0, 0, 1), 0)}, cs);
  model.contact.detection.pairs.push_back({1, 0, 0.3});  // cube on slab
  return model;
}

// Steps until contacts exist (at most model.step.steps); data then holds that step's
// factorization, H_c^T and dense G.
void step_to_contact(const Model& model, Data& data) {
  State s = model.initial, next;
  for (long k = 1; k <= model.step.steps; ++k) {
    const StepStatus st = integrator::implicit_euler_step(model, data, s, next, k);
    ASSERT_TRUE(st.ok()) << describe(model, st);
    std::swap(s, next);
    if (data.contact.contacts.size() > 0 && k >= 2) return;
  }
}

VecX random_vector(Eigen::Index n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  VecX v(n);
  for (Eigen::Index k = 0; k < n; ++k) v[k] = u(rng);
  return v;
}

// Every operation of the operator against the dense G of the same step.
void expect_operator_matches_dense(const Model& model, Data& data, const char* what) {
  const auto& cd = data.contact;
  const int nc = cd.contacts.size();
  ASSERT_GT(nc, 3) << what;
  ASSERT_EQ(cd.G.rows(), 3 * nc) << what;
  const MatX& G = cd.G;
  const double Gnorm = G.norm();
  contact::SparseDelassus op;
  op.bind(*data.solver, data.A, cd.Ht, model.step.dt, model.solver);
  ASSERT_EQ(op.contacts(), nc);

  // All contacts: G y.
  const VecX y = random_vector(3 * nc, 1);
  VecX Gy(3 * nc);
  ASSERT_TRUE(op.apply(y, Gy));
  EXPECT_LE((Gy - G * y).norm(), 1e-11 * Gnorm * y.norm()) << what;

  // A subset W (every other contact): G_WW y, G_:W y, dense G_WW.
  std::vector<int> W;
  for (int i = 0; i < nc; i += 2) W.push_back(i);
  const Eigen::Index m = 3 * static_cast<Eigen::Index>(W.size());
  MatX G_WW(m, m), G_W(3 * nc, m);
  for (std::size_t b = 0; b < W.size(); ++b) {
    G_W.middleCols<3>(3 * b) = G.middleCols<3>(3 * W[b]);
    for (std::size_t a = 0; a < W.size(); ++a) G_WW.block<3, 3>(3 * a, 3 * b) = G.block<3, 3>(3 * W[a], 3 * W[b]);
  }
  op.restrict_to(W);
  EXPECT_EQ(op.size(), static_cast<int>(W.size()));
  const VecX yw = random_vector(m, 2);
  VecX out(m), out_full(3 * nc);
  ASSERT_TRUE(op.apply(yw, out));
  ASSERT_TRUE(op.apply_full(yw, out_full));
  EXPECT_LE((out - G_WW * yw).norm(), 1e-11 * Gnorm * yw.norm()) << what;
  EXPECT_LE((out_full - G_W * yw).norm(), 1e-11 * Gnorm * yw.norm()) << what;
  MatX D;
  ASSERT_TRUE(op.dense(D));
  EXPECT_LE((D - G_WW).norm(), 1e-11 * Gnorm) << what;

  // (G_WW + c I)^{-1} r for two shifts (two numeric factorizations, one analysis).
  // The power iteration's L: a Rayleigh-type estimate from below, converging at the
  // rate of the ratio of the two largest eigenvalues (close on a slab); ADMM needs only
  // its scale: within a factor 2.
  const double L = op.largest_eigenvalue(50);
  const Eigen::SelfAdjointEigenSolver<MatX> eig(G_WW, Eigen::EigenvaluesOnly);
  const double lmax = eig.eigenvalues().maxCoeff();
  EXPECT_LE(L, lmax * (1 + 1e-12)) << what;
  EXPECT_GE(L, 0.5 * lmax) << what;
  for (const double c : {1e-3 * L, 1.0 * L}) {
    ASSERT_TRUE(op.factorize_shifted(c)) << what;
    MatX shifted = G_WW;
    shifted.diagonal().array() += c;
    const VecX r = random_vector(m, 3);
    const VecX expected = shifted.llt().solve(r);
    VecX x = r;
    ASSERT_TRUE(op.solve_shifted(x));
    EXPECT_LE((x - expected).norm(), 1e-9 * expected.norm()) << what << " c = " << c;
  }
  EXPECT_EQ(op.analyses(), 1) << what;
  EXPECT_EQ(op.factorizations(), 2) << what;
  // Another subset whose H^T H lies in the analyzed pattern: no new analysis, and the
  // same accuracy on it.
  std::vector<int> V;
  for (int i = 0; i < nc; i += 4) V.push_back(i);
  const Eigen::Index mv = 3 * static_cast<Eigen::Index>(V.size());
  MatX G_VV(mv, mv);
  for (std::size_t b = 0; b < V.size(); ++b)
    for (std::size_t a = 0; a < V.size(); ++a) G_VV.block<3, 3>(3 * a, 3 * b) = G.block<3, 3>(3 * V[a], 3 * V[b]);
  op.restrict_to(V);
  ASSERT_TRUE(op.factorize_shifted(L));
  EXPECT_EQ(op.analyses(), 1) << what;
  G_VV.diagonal().array() += L;
  const VecX r = random_vector(mv, 4);
  const VecX expected = G_VV.llt().solve(r);
  VecX x = r;
  ASSERT_TRUE(op.solve_shifted(x));
  EXPECT_LE((x - expected).norm(), 1e-9 * expected.norm()) << what << " on a second subset";
}

TEST(SparseDelassus, MatchesTheDenseDelassusWithObstacleContacts) {
  const Model model = slab_model();
  Data data(model);
  step_to_contact(model, data);
  expect_operator_matches_dense(model, data, "slab on a plane");
}

TEST(SparseDelassus, MatchesTheDenseDelassusWithSoftSoftContacts) {
  const Model model = stack_model();
  Data data(model);
  step_to_contact(model, data);
  int soft_soft = 0;
  for (const auto& c : data.contact.contacts.contacts) soft_soft += c.kind != collision::ContactKind::vertex_obstacle;
  ASSERT_GT(soft_soft, 0) << "the cube must touch the slab";
  expect_operator_matches_dense(model, data, "cube on slab");
}

// Vertex-obstacle contacts only: B's pattern is A's, whatever the contact set; the
// soft-soft contacts need more than A's pattern (so that test exercises the growth).
TEST(SparseDelassus, PatternIsTheSystemsForObstacleContactsAndGrowsForSoftSoft) {
  for (const bool soft : {false, true}) {
    const Model model = soft ? stack_model() : slab_model();
    Data data(model);
    step_to_contact(model, data);
    contact::SparseDelassus op;
    op.bind(*data.solver, data.A, data.contact.Ht, model.step.dt, model.solver);
    ASSERT_TRUE(op.factorize_shifted(1.0));
    if (soft)
      EXPECT_GT(op.pattern_nonzeros(), data.A.nonZeros());
    else
      EXPECT_EQ(op.pattern_nonzeros(), data.A.nonZeros());
  }
}

// The NCP on the operator against the dense solver on G, both to 1e-10: the working
// set's reduced problems on the operator (dense_max_contacts 0: ADMM on the operator;
// large: the dense G_W of the set) and on G. The slab's G has full rank (one node per
// contact): lambda is unique, and 1e-6 relative is what 1e-10 on the scaled residuals
// guarantees with its condition number (< 1e4). The stack's soft-soft G is rank
// deficient: sigma is compared, and the residuals recomputed from the dense G.
// The per-contact scale (ADMM's rho_i = rho d_i, sparse_delassus.hpp): the lumped-mass
// estimate d_i = h tr(H_i M^-1 H_i^T) / 3 against its definition (from H_c^T and the
// masses) and against the bound it is, tr(G_ii) / 3 <= d_i (A >= M); the shifted solve
// (G_WW + c D)^{-1} r and the largest eigenvalue of D^-1/2 G_WW D^-1/2 against the
// dense matrices. Tolerances as above: the scaled shift cancels ||G~|| / c digits, with
// c >= 1e-3 L~ 1e-9; the estimate is a sum of a few products (1e-12); the bound holds
// exactly in exact arithmetic, 1e-9 relative covers the solves behind the dense G.
TEST(SparseDelassus, ScaledShiftedSolveMatchesTheDense) {
  for (const bool soft : {false, true}) {
    const Model model = soft ? stack_model() : slab_model();
    const char* what = soft ? "stack" : "slab";
    Data data(model);
    step_to_contact(model, data);
    const auto& cd = data.contact;
    const int nc = cd.contacts.size();
    ASSERT_GT(nc, 3) << what;
    const double h = model.step.dt;
    contact::SparseDelassus op;
    op.bind(*data.solver, data.A, cd.Ht, h, model.solver);
    VecX d(nc);
    op.contact_compliance(d);
    EXPECT_EQ(d, VecX::Ones(nc)) << what << ": without masses, no scale";
    op.set_mass(model.fem.mass_diagonal);
    op.contact_compliance(d);
    const VecX& m = model.fem.mass_diagonal;
    for (int i = 0; i < nc; ++i) {
      double expected = 0;
      for (int r = 0; r < 3; ++r)
        for (Eigen::Index k = 0; k < cd.Ht.rows(); ++k) expected += cd.Ht.coeff(k, 3 * i + r) * cd.Ht.coeff(k, 3 * i + r) / m[k];
      expected *= h / 3;
      EXPECT_NEAR(d[i], expected, 1e-12 * expected) << what << " contact " << i;
      const double tr3 = cd.G.block<3, 3>(3 * i, 3 * i).trace() / 3;
      EXPECT_LE(tr3, d[i] * (1 + 1e-9)) << what << " contact " << i;
      EXPECT_GT(d[i], 0) << what << " contact " << i;
    }
    // A subset W with a scale spread over 1e6 (a mass ratio's).
    std::vector<int> W;
    for (int i = 0; i < nc; i += 2) W.push_back(i);
    const int nw = static_cast<int>(W.size());
    const Eigen::Index mw = 3 * static_cast<Eigen::Index>(nw);
    op.restrict_to(W);
    VecX dw(nw), d3(mw);
    for (int b = 0; b < nw; ++b) {
      dw[b] = b % 2 ? 1.0 : 1e-6;
      d3.segment<3>(3 * b).setConstant(dw[b]);
    }
    op.set_scale(dw);
    MatX G_WW(mw, mw);
    for (int b = 0; b < nw; ++b)
      for (int a = 0; a < nw; ++a) G_WW.block<3, 3>(3 * a, 3 * b) = cd.G.block<3, 3>(3 * W[a], 3 * W[b]);
    const VecX s = d3.cwiseSqrt().cwiseInverse();
    const MatX Gs = s.asDiagonal() * G_WW * s.asDiagonal();
    const double L = op.largest_eigenvalue(50);
    const double lmax = Eigen::SelfAdjointEigenSolver<MatX>(Gs, Eigen::EigenvaluesOnly).eigenvalues().maxCoeff();
    EXPECT_LE(L, lmax * (1 + 1e-9)) << what;
    EXPECT_GE(L, 0.5 * lmax) << what;
    for (const double c : {1e-3 * L, 1.0 * L}) {
      ASSERT_TRUE(op.factorize_shifted(c)) << what;
      MatX shifted = G_WW;
      shifted.diagonal() += c * d3;
      const VecX r = random_vector(mw, 5);
      const VecX expected = shifted.llt().solve(r);
      VecX x = r;
      ASSERT_TRUE(op.solve_shifted(x));
      // Relative to the scaled problem's solution norm (the unscaled one mixes 1e6 scales).
      EXPECT_LE((s.cwiseInverse().cwiseProduct(x - expected)).norm(),
                1e-9 * s.cwiseInverse().cwiseProduct(expected).norm())
          << what << " c = " << c;
    }
    EXPECT_EQ(op.analyses(), 1) << what;  // a scale changes values, not the pattern
  }
}

// The dense solve the operator's are compared with: the scene's options at tolerance 1e-10
// (within round-off of the exact forces at these sizes) and a budget it does not reach.
contact::NcpOptions reference_options(const Model& model) {
  contact::NcpOptions o = model.contact.ncp;
  o.tolerance = 1e-10;
  o.max_iterations = 20000;
  return o;
}
// Its forces, and its contact velocities in `sigma` if given.
VecX dense_reference(const ContactData& cd, const contact::NcpOptions& o, VecX* sigma_out = nullptr) {
  VecX lambda = VecX::Zero(cd.g.size()), sigma;
  std::vector<contact::Mode> modes;
  contact::NcpSolver reference;
  EXPECT_TRUE(reference.solve(cd.G, cd.g, cd.mu, o, lambda, sigma, modes).converged) << "the dense reference";
  if (sigma_out) *sigma_out = sigma;
  return lambda;
}

// The scaled ADMM (admm_scaling) on the operator and on the dense G: converged, and
// the same contact velocities as the unscaled dense solve (tolerance as below).
TEST(SparseNcp, ScaledAdmmAgreesWithTheDenseSolver) {
  for (const bool soft : {false, true}) {
    const Model model = soft ? stack_model() : slab_model();
    Data data(model);
    step_to_contact(model, data);
    const auto& cd = data.contact;
    const int nc = cd.contacts.size();
    contact::NcpOptions o = reference_options(model);
    std::vector<contact::Mode> modes;
    VecX sig_d;
    const VecX lam_d = dense_reference(cd, o, &sig_d);
    o.admm_scaling = true;
    o.dense_max_contacts = 0;  // every reduced problem by ADMM on the operator
    for (const bool sparse : {false, true}) {
      const std::string what = std::string(soft ? "stack" : "slab") + (sparse ? ", operator" : ", dense");
      VecX lam = VecX::Zero(3 * nc), sig;
      contact::NcpSolver solver;
      contact::SparseDelassus op;
      op.bind(*data.solver, data.A, cd.Ht, model.step.dt, model.solver);
      op.set_mass(model.fem.mass_diagonal);
      const auto r = sparse ? solver.solve(op, cd.g, cd.mu, o, lam, sig, modes)
                            : solver.solve(cd.G, cd.g, cd.mu, o, lam, sig, modes);
      EXPECT_TRUE(r.converged) << what << " residual " << r.residuals.max();
      EXPECT_LE(contact::ncp_residuals(cd.G, cd.g, cd.mu, lam).max(), 1e-10) << what;
      EXPECT_LE((sig - sig_d).norm(), 1e-6 * std::max(sig_d.norm(), cd.g.norm())) << what;
    }
  }
}

TEST(SparseNcp, AgreesWithTheDenseSolver) {
  for (const bool soft : {false, true}) {
    const Model model = soft ? stack_model() : slab_model();
    Data data(model);
    step_to_contact(model, data);
    const auto& cd = data.contact;
    const int nc = cd.contacts.size();
    contact::NcpOptions o = model.contact.ncp;
    o.tolerance = 1e-10;
    o.max_iterations = 20000;
    VecX lam_d = VecX::Zero(3 * nc), sig_d;
    std::vector<contact::Mode> modes_d, modes_s;
    contact::NcpSolver dense_solver;
    const auto rd = dense_solver.solve(cd.G, cd.g, cd.mu, o, lam_d, sig_d, modes_d);
    ASSERT_TRUE(rd.converged);
    for (const int dense_max : {0, 1000}) {
      for (const bool working_set : {true, false}) {
        const std::string what = std::string(soft ? "stack" : "slab") + ", dense_max_contacts " +
                                 std::to_string(dense_max) + (working_set ? ", working set" : "");
        o.dense_max_contacts = dense_max;
        o.working_set = working_set;
        contact::SparseDelassus op;
        op.bind(*data.solver, data.A, cd.Ht, model.step.dt, model.solver);
        VecX lam = VecX::Zero(3 * nc), sig;
        contact::NcpSolver solver;
        const auto r = solver.solve(op, cd.g, cd.mu, o, lam, sig, modes_s);
        EXPECT_TRUE(r.sparse) << what;
        EXPECT_TRUE(r.converged) << what << " residual " << r.residuals.max();
        EXPECT_EQ(r.sparse_rounds > 0, dense_max == 0) << what;
        // The solver's sigma is G lambda + g, and its residuals are the true ones.
        EXPECT_LE((sig - (cd.G * lam + cd.g)).norm(), 1e-11 * (cd.G.norm() * lam.norm() + cd.g.norm())) << what;
        EXPECT_LE(contact::ncp_residuals(cd.G, cd.g, cd.mu, lam).max(), 1e-10) << what;
        EXPECT_LE((sig - sig_d).norm(), 1e-6 * std::max(sig_d.norm(), cd.g.norm())) << what;
        if (!soft) {
          EXPECT_LE((lam - lam_d).norm(), 1e-6 * lam_d.norm()) << what;
          EXPECT_EQ(modes_s, modes_d) << what;
        }
      }
    }
  }
}

// The polish on the operator (beyond polish_max_active active contacts) runs by default
// only where ADMM did not reach the tolerance by itself; polish_at_scale_always runs it
// after every operator solve. polish_max_active 0 puts every active set beyond the dense
// polish; the slab's ADMM converges (no stall), so the default leaves its solution as is.
TEST(SparseNcp, PolishAtScaleOnlyWhereAdmmDidNotConvergeUnlessAlways) {
  const Model model = slab_model();
  Data data(model);
  step_to_contact(model, data);
  const auto& cd = data.contact;
  const int nc = cd.contacts.size();
  contact::NcpOptions o = model.contact.ncp;
  o.tolerance = 1e-8;
  o.max_iterations = 20000;
  o.dense_max_contacts = 0;
  o.polish_max_active = 0;
  std::vector<contact::Mode> modes;
  contact::NcpResult r[2];
  for (const bool always : {false, true}) {
    o.polish_at_scale_always = always;
    contact::SparseDelassus op;
    op.bind(*data.solver, data.A, cd.Ht, model.step.dt, model.solver);
    VecX lam = VecX::Zero(3 * nc), sig;
    contact::NcpSolver solver;
    r[always] = solver.solve(op, cd.g, cd.mu, o, lam, sig, modes);
    EXPECT_TRUE(r[always].converged) << always << " residual " << r[always].residuals.max();
    EXPECT_LE(contact::ncp_residuals(cd.G, cd.g, cd.mu, lam).max(), o.tolerance) << always;
  }
  EXPECT_GT(r[0].sparse_rounds, 0);
  EXPECT_EQ(r[0].operator_polishes, 0);
  EXPECT_FALSE(r[0].polished);
  EXPECT_GT(r[1].operator_polishes, 0);
  EXPECT_EQ(r[1].iterations, r[0].iterations);  // the same ADMM before the polish
}

// Warm-started from the solution, the sparse solve is one round with nothing to do.
TEST(SparseNcp, WarmStartFromTheSolution) {
  const Model model = slab_model();
  Data data(model);
  step_to_contact(model, data);
  const auto& cd = data.contact;
  contact::NcpOptions o = model.contact.ncp;
  o.dense_max_contacts = 0;
  contact::SparseDelassus op;
  op.bind(*data.solver, data.A, cd.Ht, model.step.dt, model.solver);
  VecX lam = cd.lambda, sig;
  std::vector<contact::Mode> modes;
  contact::NcpSolver solver;
  const auto r = solver.solve(op, cd.g, cd.mu, o, lam, sig, modes);
  EXPECT_TRUE(r.converged);
  EXPECT_EQ(r.iterations, 0);
  EXPECT_EQ(r.working_set_rounds, 1);
  EXPECT_LE((lam - cd.lambda).norm(), 1e-12 * cd.lambda.norm());
}

// A whole trajectory with the sparse backend (the automatic choice forced by a
// crossover of 0) against the dense one: the same steps within the NCP tolerance.
// Both solve each step's NCP to 1e-10 relative (velocities |g| ~ 0.1 m/s, dt 5 ms):
// positions agree to ~1e-10 * 0.1 * 0.005 per step; 1e-9 m over 20 steps.
TEST(SparseNcp, TrajectoryMatchesTheDenseBackend) {
  for (const bool soft : {false, true}) {
    Model dense = soft ? stack_model() : slab_model();
    dense.step.steps = 20;
    Model sparse = dense;
    sparse.contact.ncp.backend = contact::NcpBackend::automatic;
    sparse.contact.ncp.dense_max_contacts = 0;
    Data dd(dense), ds(sparse);
    State a = dense.initial, b = sparse.initial, na, nb;
    double worst = 0;
    int sparse_steps = 0;
    for (long k = 1; k <= dense.step.steps; ++k) {
      ASSERT_TRUE(integrator::implicit_euler_step(dense, dd, a, na, k).ok());
      ASSERT_TRUE(integrator::implicit_euler_step(sparse, ds, b, nb, k).ok());
      EXPECT_TRUE(ds.contact.result.converged) << "step " << k;
      sparse_steps += ds.contact.result.sparse;
      EXPECT_EQ(ds.contact.G.size(), 0) << "the sparse backend formed G";
      std::swap(a, na);
      std::swap(b, nb);
      worst = std::max(worst, (a.x - b.x).cwiseAbs().maxCoeff());
    }
    EXPECT_GT(sparse_steps, 10) << (soft ? "stack" : "slab");
    EXPECT_LT(worst, 1e-9) << (soft ? "stack" : "slab");
  }
}

// The split of the step's contact time (docs/performance.md "Contact"): on the
// operator, forming contact-system matrices (B's pattern and values, the dense G_W) is
// the assembly of the contact system (timings.delassus), B's factorizations are NCP
// time and counted apart (NcpResult::factorization_seconds). Bookkeeping only: which
// counter holds a time, never how long it took (a clock reading of a CHOLMOD
// factorization or of a sparse product is positive; a counter that was not fed is 0).
TEST(SparseDelassus, BooksTheSystemsAssemblyApartFromItsFactorizations) {
  Model model = slab_model();
  model.contact.ncp.backend = contact::NcpBackend::dense;
  Data data(model);
  step_to_contact(model, data);
  contact::SparseDelassus op;
  op.bind(*data.solver, data.A, data.contact.Ht, model.step.dt, model.solver);
  EXPECT_EQ(op.assembly_seconds(), 0);
  EXPECT_EQ(op.factorization_seconds(), 0);
  ASSERT_TRUE(op.factorize_shifted(1.0));  // B's pattern and values, then its factorization
  const double assembled = op.assembly_seconds(), factorized = op.factorization_seconds();
  EXPECT_GT(assembled, 0);
  EXPECT_GT(factorized, 0);
  ASSERT_TRUE(op.factorize_shifted(2.0));  // the same pattern: a factorization only
  EXPECT_EQ(op.assembly_seconds(), assembled);
  EXPECT_GT(op.factorization_seconds(), factorized);
  MatX G;
  ASSERT_TRUE(op.dense(G));  // a dense G_W is an assembly
  EXPECT_GT(op.assembly_seconds(), assembled);
  op.bind(*data.solver, data.A, data.contact.Ht, model.step.dt, model.solver);  // a new step
  EXPECT_EQ(op.assembly_seconds(), 0);
  EXPECT_EQ(op.factorization_seconds(), 0);

  // A step on the operator: its B assembly is booked as the contact system's, and the
  // NCP reports its factorizations of B (ADMM refactorizes at least once per step).
  Model sparse = slab_model();
  sparse.contact.ncp.backend = contact::NcpBackend::sparse;
  sparse.contact.ncp.dense_max_contacts = 0;
  Data ds(sparse);
  step_to_contact(sparse, ds);
  const auto& cd = ds.contact;
  ASSERT_TRUE(cd.result.sparse);
  ASSERT_GT(cd.result.rho_updates, 0);
  EXPECT_GT(cd.result.factorization_seconds, 0);
  EXPECT_GE(cd.result.factorization_seconds, cd.sparse.factorization_seconds());  // (+ any dense fallback's)
  EXPECT_GT(cd.sparse.assembly_seconds(), 0);
  EXPECT_GE(ds.timings.delassus, cd.sparse.assembly_seconds());
  EXPECT_GE(ds.timings.ncp, cd.result.factorization_seconds);

  // The dense backend times its factorizations of G + rho I in the NCP's result too.
  Data dd(model);
  step_to_contact(model, dd);
  ASSERT_FALSE(dd.contact.result.sparse);
  ASSERT_GT(dd.contact.result.rho_updates, 0);  // ADMM factorizes G + rho I at least once
  EXPECT_GT(dd.contact.result.factorization_seconds, 0);
  EXPECT_GE(dd.timings.ncp, dd.contact.result.factorization_seconds);
}

}  // namespace sparse_delassus_test

namespace sparse_delassus_test {

// Shared storage (sparse_delassus.hpp; docs/method.md "The derivative's memory"): two
// operators of one step, as the NCP's and the contact derivative's, with different Bs
// (another subset W, scale and shift) in one storage. Each one's shifted solves must be
// those of an operator with storage of its own, bit for bit, whatever the other
// factorized in between: an overwritten B is rebuilt from the same values and
// refactorized (the same factorization of the same matrix: exact equality, no
// tolerance), the pattern is analyzed once, and the refactorization is counted.
TEST(SparseDelassus, SharedStorageGivesEachOperatorItsOwnSolves) {
  for (const bool soft : {false, true}) {
    const Model model = soft ? stack_model() : slab_model();
    const char* what = soft ? "stack" : "slab";
    Data data(model);
    step_to_contact(model, data);
    const auto& cd = data.contact;
    const int nc = cd.contacts.size();
    ASSERT_GT(nc, 3) << what;
    const double h = model.step.dt;
    std::vector<int> W;
    for (int i = 0; i < nc; i += 2) W.push_back(i);
    const int nw = static_cast<int>(W.size());
    VecX dw(nw);
    for (int b = 0; b < nw; ++b) dw[b] = b % 2 ? 1.0 : 1e-3;
    // first: every contact, unscaled, c = 1; second: W, scaled, c = 1e-2.
    const auto set_up = [&](contact::SparseDelassus& op, bool first) {
      op.bind(*data.solver, data.A, cd.Ht, h, model.solver);
      if (!first) {
        op.restrict_to(W);
        op.set_scale(dw);
      }
    };
    contact::SparseDelassus own1, own2, shared1, shared2;
    set_up(own1, true);
    // own2's pattern as the shared one's (analyzed with every contact's blocks first: the
    // stack's soft-soft blocks of W alone would be a smaller pattern, another ordering).
    own2.bind(*data.solver, data.A, cd.Ht, h, model.solver);
    ASSERT_TRUE(own2.factorize_shifted(1.0)) << what;
    set_up(own2, false);
    ASSERT_TRUE(own1.factorize_shifted(1.0)) << what;
    ASSERT_TRUE(own2.factorize_shifted(1e-2)) << what;
    shared2.share_shifted_storage(shared1);
    EXPECT_TRUE(shared2.shares_shifted_storage_with(shared1)) << what;
    EXPECT_FALSE(own2.shares_shifted_storage_with(own1)) << what;
    set_up(shared1, true);
    set_up(shared2, false);
    ASSERT_TRUE(shared1.factorize_shifted(1.0)) << what;
    ASSERT_TRUE(shared2.factorize_shifted(1e-2)) << what;  // overwrites shared1's B
    const VecX r1 = random_vector(3 * nc, 11), r2 = random_vector(3 * nw, 12);
    VecX e1 = r1, e2 = r2;
    ASSERT_TRUE(own1.solve_shifted(e1)) << what;
    ASSERT_TRUE(own2.solve_shifted(e2)) << what;
    for (int round = 0; round < 2; ++round) {  // alternating: each solve takes the storage back
      VecX x1 = r1, x2 = r2;
      ASSERT_TRUE(shared1.solve_shifted(x1)) << what;
      ASSERT_TRUE(shared2.solve_shifted(x2)) << what;
      EXPECT_EQ(x1, e1) << what << " round " << round;
      EXPECT_EQ(x2, e2) << what << " round " << round;
    }
    // shared1: its factorization, then one refactorization per round (shared2 had the
    // storage); shared2: likewise. Neither analyzed the pattern twice.
    EXPECT_EQ(shared1.factorizations(), 3) << what;
    EXPECT_EQ(shared2.factorizations(), 3) << what;
    EXPECT_EQ(shared1.analyses() + shared2.analyses(), 1) << what;
    // Two solves in a row by the owner: no refactorization.
    VecX x2 = r2;
    ASSERT_TRUE(shared2.solve_shifted(x2)) << what;
    EXPECT_EQ(x2, e2) << what;
    EXPECT_EQ(shared2.factorizations(), 3) << what;
  }
}


// The operator path returns the best iterate of its solve (docs/method.md "The grip's
// operator path", 2026-12-04 opgrip): its rounds (the working set's, the retry on every
// contact, the stall fallback) may each end further from a solution than an earlier one
// or than the warm start; an unconverged solve returns the iterate with the lowest
// residual it has seen, with that iterate's residuals. Here the slab's solution
// perturbed by 1e-4 of |lambda| (random, projected on the cones as the solver does: its
// residual ~7e-5 of |g|) with a budget of one ADMM iteration, which ends at ~1e-3 to
// 5e-3 (the first iteration from a warm start moves with the unconverged multiplier z):
// every round is worse than the warm start, so the solve returns the warm start itself
// (before the fix: that iteration's 5e-3, above its own warm start). With 30 iterations
// ADMM improves on it (to ~5e-10) and that is returned. The tolerance 1e-13 is
// unreachable in either budget, so both solves end unconverged and the rule applies.
// Checks: the returned residuals are those of the returned lambda (recomputed with the
// dense G: the operator's and the dense G's sigma differ by round-off, ~1e-15 of |g|,
// so 1e-9 relative plus 1e-14), and never above the warm start's. Without the polish,
// which would reach the solution from either budget.
TEST(SparseNcp, UnconvergedSolveReturnsTheBestIterateItHasSeen) {
  const Model model = slab_model();
  Data data(model);
  step_to_contact(model, data);
  const auto& cd = data.contact;
  const int nc = cd.contacts.size();
  contact::NcpOptions o = reference_options(model);
  std::vector<contact::Mode> modes;
  const VecX lam_d = dense_reference(cd, o);
  // The warm start, on the cones (the formula of ncp.cpp's project_cone).
  VecX warm = lam_d + 1e-4 * lam_d.cwiseAbs().maxCoeff() * random_vector(3 * nc, 7);
  for (int i = 0; i < nc; ++i) {
    const double m = cd.mu[i], t = warm.segment<2>(3 * i).norm(), nn = warm[3 * i + 2];
    if (t <= m * nn) continue;
    if (m * t <= -nn) {
      warm.segment<3>(3 * i).setZero();
      continue;
    }
    const double pn = (nn + m * t) / (1 + m * m);
    warm.segment<2>(3 * i) *= m * pn / t;
    warm[3 * i + 2] = pn;
  }
  const double r_warm = contact::ncp_residuals(cd.G, cd.g, cd.mu, warm).max();
  ASSERT_GT(r_warm, 1e-6);
  o.dense_max_contacts = 0;  // every round by ADMM on the operator
  o.polish = false;          // (it would jump to the solution from either budget)
  o.tolerance = 1e-13;
  for (const int budget : {1, 30}) {
    for (const bool working_set : {true, false}) {
      const std::string what = "budget " + std::to_string(budget) + (working_set ? ", working set" : "");
      o.max_iterations = budget;
      o.working_set = working_set;
      contact::SparseDelassus op;
      op.bind(*data.solver, data.A, cd.Ht, model.step.dt, model.solver);
      VecX lam = warm, sig;
      contact::NcpSolver solver;
      const auto r = solver.solve(op, cd.g, cd.mu, o, lam, sig, modes);
      EXPECT_FALSE(r.converged) << what;
      EXPECT_GT(r.iterations, 0) << what;
      const double r_true = contact::ncp_residuals(cd.G, cd.g, cd.mu, lam).max();
      EXPECT_NEAR(r.residuals.max(), r_true, 1e-9 * r_true + 1e-14) << what;
      EXPECT_LE((sig - (cd.G * lam + cd.g)).norm(), 1e-11 * (cd.G.norm() * lam.norm() + cd.g.norm())) << what;
      EXPECT_LE(r_true, r_warm * (1 + 1e-9)) << what;
      if (budget == 1) {
        EXPECT_LE((lam - warm).norm(), 1e-14 * warm.norm()) << what << ": the warm start is the best iterate";
      } else {
        EXPECT_LT(r_true, 1e-3 * r_warm) << what << ": ADMM's iterate is the best";
      }
    }
  }
}

}  // namespace sparse_delassus_test
