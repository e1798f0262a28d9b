// The three linear solvers agree on an SPD system from a real mesh and report a
// matrix that is not positive definite.
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/integrator/cholmod_congruence.hpp>
#include <support/meshes.hpp>
#include <support/model_builder.hpp>

#include <Eigen/Dense>
#include <cholmod.h>
#include <cstdlib>
#include <gtest/gtest.h>

using namespace softdiff;

namespace {

Model beam_model() {
  test::BodySpec spec;
  spec.fixed = [](const Vec3& p) { return p.x() < 1e-9; };
  return test::make_model(test::box_mesh(8, 2, 2, 0.1, 0.02, 0.02), spec);
}

TEST(LinearSolver, CholmodLdltAndCgAgree) {
  const Model model = beam_model();
  Data data(model);
  fem::evaluate(model.fem, model.initial.x, {false, true, true}, data.fem);
  integrator::assemble_system_matrix(model, 0.01, data.fem.K_values, data.fem.K_values, data);
  VecX b = VecX::LinSpaced(data.A.rows(), -1, 1);
  for (int k = 0; k < b.size(); ++k)
    if (model.fem.fixed[k]) b[k] = 0;
  const SparseMatrix full = data.A.selfadjointView<Eigen::Upper>();
  VecX reference;
  for (auto kind : {integrator::SolverKind::cholmod, integrator::SolverKind::ldlt, integrator::SolverKind::cg}) {
    integrator::SolverOptions o;
    o.kind = kind;
    o.cg_tolerance = 1e-13;
    auto solver = integrator::make_linear_solver(o);
    solver->analyze(data.A);
    ASSERT_TRUE(solver->factorize(data.A).ok) << solver->name();
    VecX x;
    ASSERT_TRUE(solver->solve(b, x)) << solver->name();
    EXPECT_LT((full * x - b).norm(), 1e-10 * b.norm()) << solver->name();
    if (reference.size() == 0) reference = x;
    EXPECT_LT((x - reference).norm(), 1e-9 * reference.norm()) << solver->name();
    // Factorize again with new values (same pattern): the symbolic analysis is reused.
    SparseMatrix B = data.A;
    B.coeffs() *= 2.0;
    ASSERT_TRUE(solver->factorize(B).ok);
    VecX y;
    solver->solve(b, y);
    EXPECT_LT((2 * y - x).norm(), 1e-9 * x.norm()) << solver->name();
  }
}

TEST(LinearSolver, NotPositiveDefiniteIsReportedWithColumn) {
  const Model model = beam_model();
  Data data(model);
  fem::evaluate(model.fem, model.initial.x, {false, true, true}, data.fem);
  integrator::assemble_system_matrix(model, 0.01, data.fem.K_values, data.fem.K_values, data);
  // Make one free diagonal entry strongly negative.
  int target = -1;
  for (int k = 0; k < data.A.cols(); ++k)
    if (!model.fem.fixed[k]) target = k;
  data.A.coeffRef(target, target) = -1e6;
  for (auto kind : {integrator::SolverKind::cholmod, integrator::SolverKind::ldlt}) {
    integrator::SolverOptions o;
    o.kind = kind;
    auto solver = integrator::make_linear_solver(o);
    solver->analyze(data.A);
    const auto status = solver->factorize(data.A);
    EXPECT_FALSE(status.ok) << solver->name();
    EXPECT_GE(status.column, 0) << solver->name();
    EXPECT_NE(status.message.find("not positive definite"), std::string::npos);
  }
}

}  // namespace

// G = B^T A^{-1} B (the Delassus matrix without h) from the factorization: CHOLMOD's
// forward solves with L only, and the other solvers' full solves, against a dense
// reference A^{-1} computed by Eigen's dense LLT of the same matrix. B is sparse
// like H_c^T (a few nonzeros per column), with more columns than one solve block
// (32 / 64) so that the block loop is exercised. Tolerance 1e-10 relative: both
// sides are backward-stable Cholesky solves of a matrix with condition ~1e4.
TEST(LinearSolver, InverseCongruenceMatchesDenseReference) {
  const Model model = beam_model();
  Data data(model);
  fem::evaluate(model.fem, model.initial.x, {false, true, true}, data.fem);
  integrator::assemble_system_matrix(model, 0.01, data.fem.K_values, data.fem.K_values, data);
  const int n = static_cast<int>(data.A.rows());
  const MatX full = MatX(SparseMatrix(data.A.selfadjointView<Eigen::Upper>()));
  const MatX Ainv = full.llt().solve(MatX::Identity(n, n));
  const int m = 100;
  std::vector<Eigen::Triplet<double, int>> t;
  std::srand(7);
  for (int j = 0; j < m; ++j)
    for (int q = 0; q < 4; ++q) {
      int row = std::rand() % n;
      while (model.fem.fixed[row]) row = std::rand() % n;
      t.emplace_back(row, j, 2.0 * std::rand() / RAND_MAX - 1.0);
    }
  SparseMatrix B(n, m);
  B.setFromTriplets(t.begin(), t.end());
  const MatX reference = MatX(B.transpose()) * Ainv * MatX(B);
  for (auto kind : {integrator::SolverKind::cholmod, integrator::SolverKind::ldlt}) {
    integrator::SolverOptions o;
    o.kind = kind;
    auto solver = integrator::make_linear_solver(o);
    solver->analyze(data.A);
    ASSERT_TRUE(solver->factorize(data.A).ok);
    MatX G;
    ASSERT_TRUE(solver->inverse_congruence(B, G));
    ASSERT_EQ(G.rows(), m);
    EXPECT_LT((G - reference).norm(), 1e-10 * reference.norm()) << solver->name();
    EXPECT_LT((G - G.transpose()).norm(), 1e-14 * G.norm()) << solver->name();
  }
}

// The reach-restricted congruence (cholmod_congruence.hpp) on contact-like B: A is two
// decoupled copies of the beam's system matrix (two bodies), B has three columns per
// "contact" on the same 4 nodes (12 dofs, random weights), the nodes drawn from a small
// pool per body so that contacts share rows (as on a contact patch), and some contacts
// span both bodies (soft-soft). Compared with the dense inverse: agreement to 1e-12
// relative (both are exact; the measured difference is ~1e-15), exact symmetry, and the
// reach path is taken (compute() returns true). Rows not shared (r > 2m, as for a
// single vertex-triangle contact: 12 rows, 3 columns) make it decline.
TEST(LinearSolver, SupernodalCongruenceMatchesDenseReference) {
  const Model model = beam_model();
  Data data(model);
  fem::evaluate(model.fem, model.initial.x, {false, true, true}, data.fem);
  integrator::assemble_system_matrix(model, 0.01, data.fem.K_values, data.fem.K_values, data);
  const int n1 = static_cast<int>(data.A.rows()), n = 2 * n1;
  std::vector<Eigen::Triplet<double, int>> a;
  for (int k = 0; k < data.A.outerSize(); ++k)
    for (SparseMatrix::InnerIterator it(data.A, k); it; ++it) {
      a.emplace_back(it.row(), it.col(), it.value());
      a.emplace_back(it.row() + n1, it.col() + n1, it.value());
    }
  SparseMatrix A(n, n);  // upper, two bodies
  A.setFromTriplets(a.begin(), a.end());
  const MatX full = MatX(SparseMatrix(A.selfadjointView<Eigen::Upper>()));
  const MatX Ainv = full.llt().solve(MatX::Identity(n, n));

  std::vector<int> free_nodes;
  for (int i = 0; i < n1 / 3; ++i)
    if (!model.fem.fixed[3 * i]) free_nodes.push_back(i);
  std::srand(11);
  auto contact_like = [&](int contacts, int pool, bool share) {
    std::vector<Eigen::Triplet<double, int>> t;
    int fresh = 0;
    for (int c = 0; c < contacts; ++c) {
      for (int q = 0; q < 4; ++q) {
        const int body = (c % 5 == 0) ? q % 2 : c % 2;  // every 5th contact spans both bodies
        const int node = share ? free_nodes[std::rand() % pool] : free_nodes[fresh++ % free_nodes.size()];
        for (int r = 0; r < 3; ++r)
          for (int d = 0; d < 3; ++d)
            t.emplace_back(body * n1 + 3 * node + d, 3 * c + r, 2.0 * std::rand() / RAND_MAX - 1.0);
      }
    }
    SparseMatrix B(n, 3 * contacts);
    B.setFromTriplets(t.begin(), t.end());
    return B;
  };

  cholmod_common common;
  cholmod_start(&common);
  common.supernodal = CHOLMOD_SUPERNODAL;
  common.final_ll = 1;
  cholmod_sparse view{};
  view.nrow = view.ncol = n;
  view.nzmax = A.nonZeros();
  view.p = A.outerIndexPtr();
  view.i = A.innerIndexPtr();
  view.x = A.valuePtr();
  view.nz = nullptr;
  view.z = nullptr;
  view.stype = 1;
  view.itype = CHOLMOD_INT;
  view.xtype = CHOLMOD_REAL;
  view.dtype = CHOLMOD_DOUBLE;
  view.sorted = 1;
  view.packed = 1;
  cholmod_factor* L = cholmod_analyze(&view, &common);
  ASSERT_NE(L, nullptr);
  ASSERT_TRUE(cholmod_factorize(&view, L, &common));
  ASSERT_EQ(common.status, CHOLMOD_OK);
  ASSERT_TRUE(L->is_super);

  integrator::SupernodalCongruence congruence;
  for (int contacts : {20, 60}) {  // r <= 72 rows (2 x 12 nodes x 3) <= 2 m
    SCOPED_TRACE(contacts);
    const SparseMatrix B = contact_like(contacts, 12, true);
    const MatX reference = MatX(B.transpose()) * Ainv * MatX(B);
    MatX G;
    ASSERT_TRUE(congruence.compute(L, B, G));
    ASSERT_EQ(G.rows(), B.cols());
    EXPECT_LT((G - reference).cwiseAbs().maxCoeff(), 1e-12 * reference.cwiseAbs().maxCoeff());
    EXPECT_EQ((G - G.transpose()).cwiseAbs().maxCoeff(), 0.0);
  }
  // 40 contacts on 160 distinct nodes: r = 480 > 2 m = 240, declined.
  MatX G;
  EXPECT_FALSE(congruence.compute(L, contact_like(40, 0, false), G));
  cholmod_free_factor(&L, &common);
  cholmod_finish(&common);
}

// LinearSolver::solve(MatX) against one solve per column, on the beam's system matrix
// (condition ~1e4) with k = 9 right-hand sides (the Trunk's actuators): CHOLMOD's one
// supernodal solve of the n x 9 block (BLAS-3) and its column-by-column solves order the
// same products differently, so they agree to round-off, not bit for bit: 1e-12
// relative per column (both backward stable with the same factor: the difference is
// bounded by ~cond(A) u = 1e-12; measured ~1e-16). Also: the residual of every column,
// a second call with the same k writes into the same X (no new storage), and with a
// kept factor (factor reuse: PCG per column on the new matrix) the same agreement with
// the single solves, which run PCG too.
TEST(LinearSolver, SeveralRightHandSidesMatchOneSolvePerColumn) {
  const Model model = beam_model();
  Data data(model);
  fem::evaluate(model.fem, model.initial.x, {false, true, true}, data.fem);
  integrator::assemble_system_matrix(model, 0.01, data.fem.K_values, data.fem.K_values, data);
  const Eigen::Index n = data.A.rows(), k = 9;
  MatX B(n, k);
  std::srand(11);
  for (Eigen::Index j = 0; j < k; ++j)
    for (Eigen::Index i = 0; i < n; ++i) B(i, j) = model.fem.fixed[i] ? 0.0 : 2.0 * std::rand() / RAND_MAX - 1.0;
  for (bool reuse : {false, true})
    for (auto kind : {integrator::SolverKind::cholmod, integrator::SolverKind::ldlt, integrator::SolverKind::cg}) {
      if (reuse && kind != integrator::SolverKind::cholmod) continue;
      integrator::SolverOptions o;
      o.kind = kind;
      o.cg_tolerance = 1e-13;
      o.factor_reuse = reuse;
      o.pcg_tolerance = 1e-14;
      auto solver = integrator::make_linear_solver(o);
      solver->analyze(data.A);
      ASSERT_TRUE(solver->factorize(data.A).ok);
      SparseMatrix A = data.A;
      if (reuse) {  // a new matrix: the factor of data.A is kept, the solves run PCG on A
        A.coeffs() *= 1.01;
        ASSERT_TRUE(solver->factorize(A).ok);
        ASSERT_EQ(solver->counters().kept_factors, 1);
      }
      const SparseMatrix A_full = A.selfadjointView<Eigen::Upper>();
      MatX X;
      ASSERT_TRUE(solver->solve(B, X)) << solver->name();
      ASSERT_EQ(X.rows(), n);
      ASSERT_EQ(X.cols(), k);
      const double* storage = X.data();
      const long pcg_after_block = solver->counters().pcg_solves;
      for (Eigen::Index j = 0; j < k; ++j) {
        const VecX b = B.col(j);
        VecX x;
        ASSERT_TRUE(solver->solve(b, x)) << solver->name();
        EXPECT_LE((X.col(j) - x).norm(), 1e-12 * x.norm()) << solver->name() << " reuse " << reuse << " column " << j;
        EXPECT_LE((A_full * X.col(j) - b).norm(), 1e-12 * b.norm()) << solver->name() << " column " << j;
      }
      if (reuse) {
        EXPECT_EQ(pcg_after_block, k);  // the block went column by column through PCG
      }
      ASSERT_TRUE(solver->solve(B, X));
      EXPECT_EQ(X.data(), storage) << solver->name();
    }
}
