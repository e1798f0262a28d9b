// Rigidified parts of soft bodies: see rigidify.hpp and docs/method.md "Rigidified parts".
#include <softdiff/integrator/rigidify.hpp>
#include <softdiff/integrator/rigidify_derivatives.hpp>
#include <softdiff/integrator/rigidify_pcg.hpp>
#include <softdiff/integrator/static_rigid.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <cmath>

namespace softdiff::integrator {

void build_rigidify(const fem::FemModel& fem, RigidifyModel& r) {
  r.dof_part.clear();
  r.rigid_free.clear();
  r.rigid_rigid.clear();
  if (r.parts.empty()) return;
  const int ndof = 3 * fem.num_nodes;
  r.dof_part.assign(static_cast<std::size_t>(ndof), -1);
  for (int p = 0; p < r.size(); ++p)
    for (int i : r.parts[static_cast<std::size_t>(p)].nodes)
      for (int c = 0; c < 3; ++c) r.dof_part[static_cast<std::size_t>(3 * i + c)] = p;
  const SparseMatrix& s = fem.pattern.structure;
  const int* outer = s.outerIndexPtr();
  const int* inner = s.innerIndexPtr();
  for (int col = 0; col < ndof; ++col)
    for (int k = outer[col]; k < outer[col + 1]; ++k) {
      const int row = inner[k];
      const bool rr = r.dof_part[static_cast<std::size_t>(row)] >= 0, rc = r.dof_part[static_cast<std::size_t>(col)] >= 0;
      if (!rr && !rc) continue;
      if (rr && rc) {
        r.rigid_rigid.push_back({k, row, col});
        continue;
      }
      const int other = rr ? col : row;
      if (fem.fixed[static_cast<std::size_t>(other)]) continue;
      r.rigid_free.push_back({k, rr ? row : col, other});
    }
}

Vec3 part_centre(const Model& model, const RigidifiedPart& part, const VecX& x) {
  Vec3 c = Vec3::Zero();
  double m = 0;
  for (int i : part.nodes) {
    const double mi = model.fem.mass_diagonal[3 * i];
    c += mi * x.segment<3>(3 * i);
    m += mi;
  }
  return c / m;
}

namespace {
// The lumped-mass fit of a nodal velocity field by a rigid one about c: N u = f with
// N = sum_i m_i T_i^T T_i = [[m I, m [c_m - c]x^T], [., I_c]] (I_c the part's lumped
// inertia about c, its lower right block) and f = sum_i m_i T_i^T v_i.
Eigen::Matrix<double, 6, 1> fit(const Model& model, const RigidifiedPart& part, const VecX& x, const Vec3& c,
                                const VecX& v, Eigen::Matrix<double, 6, 6>& N) {
  N.setZero();
  Eigen::Matrix<double, 6, 1> f = Eigen::Matrix<double, 6, 1>::Zero();
  for (int i : part.nodes) {
    const double mi = model.fem.mass_diagonal[3 * i];
    const Vec3 r = x.segment<3>(3 * i) - c;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Matrix<double, 1, 6> t = rigid_row(r, k);
      N.noalias() += mi * t.transpose() * t;
      f.noalias() += (mi * v[3 * i + k]) * t.transpose();
    }
  }
  return N.ldlt().solve(f);
}
}  // namespace

Eigen::Matrix<double, 6, 1> part_velocity(const Model& model, const RigidifiedPart& part, const VecX& x,
                                          const Vec3& c, const VecX& v) {
  Eigen::Matrix<double, 6, 6> N;
  return fit(model, part, x, c, v, N);
}

namespace {
// The step's coupling values (A = (1 + h alpha) M + h beta K_d + h^2 K, the linearized
// step: K_d = K, with the part's body coefficients; the pattern couples no two bodies):
// C = A_fr T (3n x 6m) and D = T^T A_rr T (6m x 6m), at the arms of w.x, w.centre.
void coupling(const Model& model, const Data& data, const RigidifyData& w, double h, const VecX* K_damping, MatX& C,
              MatX& D) {
  const bool is_static = model.step.integrator == IntegratorKind::static_equilibrium;
  const auto& fem = model.fem;
  const RigidifyModel& rm = model.rigidify;
  const double* M = fem.mass_values.data();
  const double* K = data.fem.K_values.data();
  const double* Kd = K_damping ? K_damping->data() : K;
  auto value = [&](int k, int part) {
    if (is_static) return K[k];
    const auto& b = fem.bodies[static_cast<std::size_t>(rm.parts[static_cast<std::size_t>(part)].body)];
    return (1 + h * b.rayleigh_mass) * M[k] + h * b.rayleigh_stiffness * Kd[k] + h * h * K[k];
  };
  auto row_of = [&](int dof, int part) {
    return rigid_row(w.x.segment<3>(3 * (dof / 3)) - w.centre[static_cast<std::size_t>(part)], dof % 3);
  };
  C.setZero();
  D.setZero();
  for (const auto& e : rm.rigid_free) {
    const int p = rm.dof_part[static_cast<std::size_t>(e.rigid)];
    C.block<1, 6>(e.other, 6 * p).noalias() += value(e.value, p) * row_of(e.rigid, p);
  }
  for (const auto& e : rm.rigid_rigid) {
    const int p = rm.dof_part[static_cast<std::size_t>(e.rigid)], q = rm.dof_part[static_cast<std::size_t>(e.other)];
    const double a = value(e.value, p);
    const Eigen::Matrix<double, 1, 6> tp = row_of(e.rigid, p), tq = row_of(e.other, q);
    D.block<6, 6>(6 * p, 6 * q).noalias() += a * tp.transpose() * tq;
    if (e.rigid != e.other) D.block<6, 6>(6 * q, 6 * p).noalias() += a * tq.transpose() * tp;
  }
}

// With w.C and w.S = D set: Y = A_ff^{-1} C (one solve with 6m right-hand sides on the
// step's factor), S = D - C^T Y and its Cholesky factor.
StepStatus schur_complement(const Model& model, Data& data, long step_index) {
  RigidifyData& w = data.rigidify;
  const int m6 = 6 * model.rigidify.size();
  StepStatus status;
  if (!data.solver->solve(w.C, w.Y)) {
    status.code = StepStatus::Code::solver_failed;
    status.step = step_index;
    status.detail = "the linear solver failed on the rigidified parts' coupling columns";
    return status;
  }
  w.S.noalias() -= w.C.transpose() * w.Y;
  for (int j = 0; j < m6; ++j)  // symmetric to round-off: average in place (no temporary)
    for (int i = 0; i < j; ++i) w.S(i, j) = w.S(j, i) = 0.5 * (w.S(i, j) + w.S(j, i));
  w.S_factor.compute(w.S);
  if (w.S_factor.info() != Eigen::Success) {
    status.code = StepStatus::Code::not_positive_definite;
    status.step = step_index;
    status.detail = "the rigidified parts' reduced matrix (Schur complement, " + std::to_string(m6) + " x " +
                    std::to_string(m6) + ") is not positive definite";
  }
  return status;
}
}  // namespace

void rigidified_coupling(const Model& model, const Data& data, double h, const VecX* K_damping, MatX& C, MatX& D) {
  coupling(model, data, data.rigidify, h, K_damping, C, D);
}

StepStatus prepare_rigidified(const Model& model, Data& data, const VecX& x, double h, long step_index,
                              const VecX* K_damping) {
  const auto& fem = model.fem;
  const RigidifyModel& rm = model.rigidify;
  RigidifyData& w = data.rigidify;
  const int n = 3 * fem.num_nodes, m6 = 6 * rm.size();
  if (w.C.rows() != n || w.C.cols() != m6) {  // first use: size the workspace
    w.C.resize(n, m6);
    w.Y.resize(n, m6);
    w.S.resize(m6, m6);
    w.S_factor = Eigen::LLT<MatX>(m6);
    w.b_soft.resize(n);
    w.y.resize(n);
    w.g.resize(m6);
    w.u.resize(m6);
    w.centre.resize(rm.parts.size());
    w.reduced_pcg = false;
  }
  w.x = x;
  for (std::size_t p = 0; p < rm.parts.size(); ++p) w.centre[p] = part_centre(model, rm.parts[p], x);
  // Factor reuse with a kept factor (docs/method.md "Rigidified parts", *Factor reuse*):
  // C, Y, S stay the kept factor's (the preconditioner of solve_rigidified's PCG; they
  // were computed by the step that factorized, or by a fallback); this step's own
  // coupling only, no solve.
  w.reduced_pcg = data.solver->factor_kept();
  if (w.reduced_pcg) {
    if (w.C_step.rows() != n || w.C_step.cols() != m6) {
      w.C_step.resize(n, m6);
      w.D_step.resize(m6, m6);
      for (VecX* v : {&w.r_f, &w.z_f, &w.p_f, &w.q_f}) v->resize(n);
      for (VecX* v : {&w.r_u, &w.z_u, &w.p_u, &w.q_u}) v->resize(m6);
    }
    coupling(model, data, w, h, K_damping, w.C_step, w.D_step);
    return {};
  }
  coupling(model, data, w, h, K_damping, w.C, w.S);
  return schur_complement(model, data, step_index);
}

namespace {
// (z_f, z_u) = the kept factorization's reduced inverse applied to (r_f, r_u): the
// Schur-complement solve above with C, Y, S of the factorization (their arms then):
// y = A'^{-1} r_f (one solve with the kept factor), z_u = S'^{-1} (r_u - C'^T y),
// z_f = y - Y' z_u. Symmetric positive definite (the exact inverse of that step's
// P'^T A' P' in its reduced coordinates), so a valid PCG preconditioner.
void apply_kept_reduced_inverse(const Data& data, const VecX& r_f, const VecX& r_u, VecX& z_f, VecX& z_u, VecX& y) {
  const RigidifyData& w = data.rigidify;
  data.solver->apply_factor_as_is(r_f, y);
  z_u = r_u;
  z_u.noalias() -= w.C.transpose() * y;
  w.S_factor.solveInPlace(z_u);
  z_f = y;
  z_f.noalias() -= w.Y * z_u;
}

// (q_f, q_u) = P^T A P (p_f, p_u) in reduced coordinates (the soft dofs' rows, zero on
// the rigidified and fixed ones, then 6 per part): q_f = A p_f + C p_u, q_u = C^T p_f +
// D p_u, with this step's A (identity rows on the rigidified and fixed dofs, which p_f
// keeps zero), C_step and D_step.
void apply_reduced(const Data& data, const VecX& p_f, const VecX& p_u, VecX& q_f, VecX& q_u) {
  const RigidifyData& w = data.rigidify;
  q_f.noalias() = data.A.selfadjointView<Eigen::Upper>() * p_f;
  q_f.noalias() += w.C_step * p_u;
  q_u.noalias() = w.C_step.transpose() * p_f;
  q_u.noalias() += w.D_step * p_u;
}

double reduced_norm(const VecX& f, const VecX& u) { return std::sqrt(f.squaredNorm() + u.squaredNorm()); }
}  // namespace

// Each iteration: one solve with the kept factor, one product with A, four products with
// the 3n x 6m columns (C, Y of the factorization; C_step twice).
int reduced_pcg(const Model& model, const Data& data, const VecX& b_f, const VecX& g, VecX& f, VecX& u, bool guess,
                const ReducedPcgWork& work) {
  SOFTDIFF_DEMAND(data.rigidify.reduced_pcg, "reduced_pcg: the step did not keep a factor");
  const auto& opt = model.solver;
  auto& [r_f, z_f, p_f, q_f, r_u, z_u, p_u, q_u, y] = work;
  const double target = opt.pcg_tolerance * reduced_norm(b_f, g);
  if (target == 0) {
    f.setZero(b_f.size());
    u.setZero(g.size());
    return 0;
  }
  r_f = b_f;
  r_u = g;
  if (guess) {
    apply_reduced(data, f, u, q_f, q_u);
    r_f -= q_f;
    r_u -= q_u;
  } else {
    f.setZero(b_f.size());
    u.setZero(g.size());
  }
  int it = 0;
  bool converged = reduced_norm(r_f, r_u) <= target;
  while (!converged && it < opt.pcg_max_iterations) {
    // (Re)start from the true residual.
    apply_kept_reduced_inverse(data, r_f, r_u, z_f, z_u, y);
    p_f = z_f;
    p_u = z_u;
    double rz = r_f.dot(z_f) + r_u.dot(z_u);
    bool breakdown = false;
    while (it < opt.pcg_max_iterations) {
      apply_reduced(data, p_f, p_u, q_f, q_u);
      const double pq = p_f.dot(q_f) + p_u.dot(q_u);
      if (!(pq > 0)) {
        breakdown = true;
        break;
      }
      const double alpha = rz / pq;
      f.noalias() += alpha * p_f;
      u.noalias() += alpha * p_u;
      r_f.noalias() -= alpha * q_f;
      r_u.noalias() -= alpha * q_u;
      ++it;
      if (reduced_norm(r_f, r_u) <= target) break;
      apply_kept_reduced_inverse(data, r_f, r_u, z_f, z_u, y);
      const double rz_next = r_f.dot(z_f) + r_u.dot(z_u);
      const double beta = rz_next / rz;
      p_f = z_f + beta * p_f;
      p_u = z_u + beta * p_u;
      rz = rz_next;
    }
    if (breakdown) break;
    // The recurrence says converged (or the budget is spent): the true residual.
    apply_reduced(data, f, u, q_f, q_u);
    r_f = b_f - q_f;
    r_u = g - q_u;
    converged = reduced_norm(r_f, r_u) <= target;
  }
  data.solver->count_outside_pcg(it);
  return converged ? it : -1;
}

bool solve_rigidified(const Model& model, Data& data, const VecX& b, VecX& v) {
  const RigidifyModel& rm = model.rigidify;
  RigidifyData& w = data.rigidify;
  w.b_soft = b;
  for (const auto& part : rm.parts)
    for (int i : part.nodes) w.b_soft.segment<3>(3 * i).setZero();
  // g += T^T b_r (the parts' resultants and moments about their centres).
  auto add_part_loads = [&] {
    for (int p = 0; p < rm.size(); ++p) {
      const auto& part = rm.parts[static_cast<std::size_t>(p)];
      for (int i : part.nodes) {
        const Vec3 r = w.x.segment<3>(3 * i) - w.centre[static_cast<std::size_t>(p)];
        const Vec3 bi = b.segment<3>(3 * i);  // T_i^T b_i = (b_i, r x b_i)
        w.g.segment<3>(6 * p) += bi;
        w.g.segment<3>(6 * p + 3) += r.cross(bi);
      }
    }
  };
  bool solved = false;
  if (w.reduced_pcg) {
    w.g.setZero();
    add_part_loads();
    // Factor reuse: PCG on P^T A P from v's reduced coordinates (the previous step's
    // answer, as the soft PCG starts from it: its soft rows, and each part's rigid fit).
    const bool guess = v.size() == b.size() && v.allFinite();
    if (guess) {
      w.y = v;  // scratch: v's soft rows (w.y is the preconditioner's, written after)
      for (int p = 0; p < rm.size(); ++p) {
        const auto& part = rm.parts[static_cast<std::size_t>(p)];
        w.u.segment<6>(6 * p) = part_velocity(model, part, w.x, w.centre[static_cast<std::size_t>(p)], v);
        for (int i : part.nodes) w.y.segment<3>(3 * i).setZero();
      }
      v = w.y;
    } else {
      v.setZero(b.size());
    }
    w.pcg_iterations = reduced_pcg(model, data, w.b_soft, w.g, v, w.u, guess,
                                   {w.r_f, w.z_f, w.p_f, w.q_f, w.r_u, w.z_u, w.p_u, w.q_u, w.y});
    solved = w.pcg_iterations >= 0;
    if (!solved) {
      // Not converged after pcg_max_iterations (or p^T A p <= 0): factorize this step's
      // A now and solve directly, as the soft PCG does (a failed factorization is the
      // solver's solve_factor_status(): not_positive_definite with the dof).
      if (!data.solver->factorize_recorded().ok) return false;
      w.reduced_pcg = false;
      w.C = w.C_step;
      w.S = w.D_step;
      if (!schur_complement(model, data, -1).ok()) return false;
    }
  }
  if (!solved) {
    w.pcg_iterations = 0;
    if (!data.solver->solve(w.b_soft, w.y)) return false;
    w.g.noalias() = -w.C.transpose() * w.y;
    add_part_loads();
    w.u = w.g;
    w.S_factor.solveInPlace(w.u);
    v = w.y;
    v.noalias() -= w.Y * w.u;
  }
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    const Eigen::Matrix<double, 6, 1> up = w.u.segment<6>(6 * p);
    for (int i : part.nodes) {
      const Vec3 r = w.x.segment<3>(3 * i) - w.centre[static_cast<std::size_t>(p)];
      v.segment<3>(3 * i) = up.head<3>() + up.tail<3>().cross(r);
    }
  }
  return true;
}

void project_rigidified_residual(const Model& model, Data& data, VecX& r) {
  const RigidifyModel& rm = model.rigidify;
  const RigidifyData& w = data.rigidify;
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    const Vec3& c = w.centre[static_cast<std::size_t>(p)];
    Eigen::Matrix<double, 6, 6> N = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
    for (int i : part.nodes) {
      const double mi = model.fem.mass_diagonal[3 * i];
      const Vec3 a = w.x.segment<3>(3 * i) - c;
      for (int k = 0; k < 3; ++k) {
        const Eigen::Matrix<double, 1, 6> t = rigid_row(a, k);
        N.noalias() += mi * t.transpose() * t;
        g.noalias() += r[3 * i + k] * t.transpose();
      }
    }
    const Eigen::Matrix<double, 6, 1> u = N.ldlt().solve(g);
    for (int i : part.nodes) {
      const Vec3 a = w.x.segment<3>(3 * i) - c;
      r.segment<3>(3 * i) = model.fem.mass_diagonal[3 * i] * (u.head<3>() + u.tail<3>().cross(a));
    }
  }
}

void rigidify_extrapolated_state(const Model& model, const State& in, const State& previous, State& hat) {
  const VecX &x = in.x, &x_previous = previous.x;
  for (const auto& part : model.rigidify.parts) {
    const Vec3 c = part_centre(model, part, x), c_prev = part_centre(model, part, x_previous);
    Mat3 H = Mat3::Zero();  // sum m a b^T, a at x_{n-1}, b at x_n: b = R a
    for (int i : part.nodes)
      H.noalias() += model.fem.mass_diagonal[3 * i] * (x_previous.segment<3>(3 * i) - c_prev) *
                     (x.segment<3>(3 * i) - c).transpose();
    const Eigen::JacobiSVD<Mat3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Mat3 D = Mat3::Identity();
    D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1 : 1;
    const Mat3 R = svd.matrixV() * D * svd.matrixU().transpose();
    const Eigen::AngleAxisd aa(R);
    const Mat3 E = Eigen::AngleAxisd(aa.angle() / 3, aa.axis()).toRotationMatrix();
    const Vec3 c_hat = (4.0 / 3.0) * c - (1.0 / 3.0) * c_prev;
    for (int i : part.nodes) hat.x.segment<3>(3 * i) = c_hat + E * (x.segment<3>(3 * i) - c);
    // The velocity and the angular momentum about the centroid, extrapolated.
    Vec3 p_n = Vec3::Zero(), p_prev = Vec3::Zero(), L = Vec3::Zero();
    Mat3 I = Mat3::Zero();
    double m = 0;
    for (int i : part.nodes) {
      const double mi = model.fem.mass_diagonal[3 * i];
      const Vec3 vn = in.v.segment<3>(3 * i), vp = previous.v.segment<3>(3 * i);
      const Vec3 rn = x.segment<3>(3 * i) - c, rp = x_previous.segment<3>(3 * i) - c_prev;
      const Vec3 r = hat.x.segment<3>(3 * i) - c_hat;
      m += mi;
      p_n += mi * vn;
      p_prev += mi * vp;
      L += mi * ((4.0 / 3.0) * rn.cross(vn) - (1.0 / 3.0) * rp.cross(vp));
      I += mi * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
    }
    const Vec3 v_hat = ((4.0 / 3.0) * p_n - (1.0 / 3.0) * p_prev) / m, omega_hat = I.ldlt().solve(L);
    for (int i : part.nodes) hat.v.segment<3>(3 * i) = v_hat + omega_hat.cross(Vec3(hat.x.segment<3>(3 * i) - c_hat));
  }
}

namespace {
// w.Ht_soft = H_f^T (Ht without the parts' rows: the factor has identity rows there) and
// w.W = T^T H_r^T - Y^T H_f^T (6m x 3nc).
void coupling_columns(const Model& model, RigidifyData& w, const SparseMatrix& Ht) {
  const RigidifyModel& rm = model.rigidify;
  const int ncols = static_cast<int>(Ht.cols()), m6 = 6 * rm.size();
  w.Ht_soft = Ht;
  w.Ht_soft.prune([&](Eigen::Index row, Eigen::Index, double) { return rm.dof_part[static_cast<std::size_t>(row)] < 0; });
  w.W.resize(m6, ncols);
  w.W.noalias() = -(w.Y.transpose() * w.Ht_soft);
  for (int col = 0; col < ncols; ++col)
    for (SparseMatrix::InnerIterator it(Ht, col); it; ++it) {
      const int dof = static_cast<int>(it.row()), p = rm.dof_part[static_cast<std::size_t>(dof)];
      if (p < 0) continue;
      const Vec3 r = w.x.segment<3>(3 * (dof / 3)) - w.centre[static_cast<std::size_t>(p)];
      w.W.block<6, 1>(6 * p, col).noalias() += it.value() * rigid_row(r, dof % 3).transpose();
    }
}
}  // namespace

bool rigidified_congruence(const Model& model, Data& data, const SparseMatrix& Ht, MatX& G) {
  RigidifyData& w = data.rigidify;
  const int ncols = static_cast<int>(Ht.cols());
  coupling_columns(model, w, Ht);
  if (w.Ht_soft.nonZeros() > 0) {
    if (!data.solver->inverse_congruence(w.Ht_soft, G)) return false;
  } else {
    G.setZero(ncols, ncols);
  }
  w.SW = w.W;
  w.S_factor.solveInPlace(w.SW);
  G.noalias() += w.W.transpose() * w.SW;
  return true;
}

void rigidified_rows(const Model& model, Data& data, const SparseMatrix& Ht) {
  RigidifyData& w = data.rigidify;
  coupling_columns(model, w, Ht);
  w.SW = w.W;
  w.S_factor.matrixL().solveInPlace(w.SW);  // K_p = L_S^{-1} W: W^T S^{-1} W = K_p^T K_p
}

void place_rigidified(const Model& model, Data& data, const State& in, State& out, double h) {
  const RigidifyModel& rm = model.rigidify;
  RigidifyData& w = data.rigidify;
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    const Vec3& c = w.centre[static_cast<std::size_t>(p)];
    Eigen::Matrix<double, 6, 6> N;
    const Eigen::Matrix<double, 6, 1> u = fit(model, part, in.x, c, out.v, N);
    const Vec3 vp = u.head<3>(), omega = u.tail<3>();
    const Mat3 R = rigid::quaternion_exp(h * omega).toRotationMatrix();
    const Vec3 c_next = c + h * vp;
    // The angular momentum the solve gave, L = I_n omega (I_n about c at x_i: the fit's
    // lower right block), is kept at the new pose: omega' = I_{n+1}^{-1} L,
    // I_{n+1} = R I_n R^T (method.md).
    const Mat3 I = N.bottomRightCorner<3, 3>();
    const Vec3 omega_next = R * I.ldlt().solve(R.transpose() * (I * omega));
    for (int i : part.nodes) {
      const Vec3 r = R * (in.x.segment<3>(3 * i) - c);
      out.x.segment<3>(3 * i) = c_next + r;
      out.v.segment<3>(3 * i) = vp + omega_next.cross(r);
    }
  }
}

void rigidified_static_pose(const Model& model, Data& data, const VecX& x) {
  const RigidifyModel& rm = model.rigidify;
  RigidifyData& w = data.rigidify;
  if (w.centre.size() != rm.parts.size()) w.centre.resize(rm.parts.size());
  w.x = x;
  for (std::size_t p = 0; p < rm.parts.size(); ++p) w.centre[p] = part_centre(model, rm.parts[p], x);
}

void place_rigidified_static(const Model& model, const Data& data, const VecX& x, const VecX& dx, double alpha,
                             VecX& trial) {
  const RigidifyModel& rm = model.rigidify;
  const RigidifyData& w = data.rigidify;
  trial = x + alpha * dx;
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    const Vec3& c = w.centre[static_cast<std::size_t>(p)];
    Eigen::Matrix<double, 6, 6> N;
    const Eigen::Matrix<double, 6, 1> u = fit(model, part, x, c, dx, N);
    const Mat3 R = rigid::quaternion_exp(alpha * Vec3(u.tail<3>())).toRotationMatrix();
    const Vec3 c_next = c + alpha * u.head<3>();
    for (int i : part.nodes) trial.segment<3>(3 * i) = c_next + R * (x.segment<3>(3 * i) - c);
  }
}

}  // namespace softdiff::integrator
