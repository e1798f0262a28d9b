// Rigidified parts of soft bodies: see rigidify.hpp and docs/method.md "Rigidified parts".
#include <softdiff/integrator/rigidify.hpp>
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

StepStatus prepare_rigidified(const Model& model, Data& data, const VecX& x, double h, long step_index,
                              const VecX* K_damping) {
  SOFTDIFF_DEMAND(!model.solver.factor_reuse, "rigidified parts: without factor reuse (issue 21)");
  // The static solver (integrator/static_rigid.hpp): A = K, called with h = 1.
  const bool is_static = model.step.integrator == IntegratorKind::static_equilibrium;
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
  }
  w.x = x;
  for (std::size_t p = 0; p < rm.parts.size(); ++p) w.centre[p] = part_centre(model, rm.parts[p], x);

  // A's coupling values: A = (1 + h alpha) M + h beta K_d + h^2 K (the linearized step:
  // K_d = K), with the part's body coefficients (the pattern couples no two bodies).
  const double* M = fem.mass_values.data();
  const double* K = data.fem.K_values.data();
  const double* Kd = K_damping ? K_damping->data() : K;
  auto value = [&](int k, int part) {
    if (is_static) return K[k];
    const auto& b = fem.bodies[static_cast<std::size_t>(rm.parts[static_cast<std::size_t>(part)].body)];
    return (1 + h * b.rayleigh_mass) * M[k] + h * b.rayleigh_stiffness * Kd[k] + h * h * K[k];
  };
  auto row_of = [&](int dof, int part) {
    return rigid_row(x.segment<3>(3 * (dof / 3)) - w.centre[static_cast<std::size_t>(part)], dof % 3);
  };
  w.C.setZero();
  w.S.setZero();
  for (const auto& e : rm.rigid_free) {
    const int p = rm.dof_part[static_cast<std::size_t>(e.rigid)];
    w.C.block<1, 6>(e.other, 6 * p).noalias() += value(e.value, p) * row_of(e.rigid, p);
  }
  for (const auto& e : rm.rigid_rigid) {
    const int p = rm.dof_part[static_cast<std::size_t>(e.rigid)], q = rm.dof_part[static_cast<std::size_t>(e.other)];
    const double a = value(e.value, p);
    const Eigen::Matrix<double, 1, 6> tp = row_of(e.rigid, p), tq = row_of(e.other, q);
    w.S.block<6, 6>(6 * p, 6 * q).noalias() += a * tp.transpose() * tq;
    if (e.rigid != e.other) w.S.block<6, 6>(6 * q, 6 * p).noalias() += a * tq.transpose() * tp;
  }
  StepStatus status;
  // Y = A_ff^{-1} C: one solve with 6m right-hand sides on the step's factor.
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

bool solve_rigidified(const Model& model, Data& data, const VecX& b, VecX& v) {
  const RigidifyModel& rm = model.rigidify;
  RigidifyData& w = data.rigidify;
  w.b_soft = b;
  for (const auto& part : rm.parts)
    for (int i : part.nodes) w.b_soft.segment<3>(3 * i).setZero();
  if (!data.solver->solve(w.b_soft, w.y)) return false;
  w.g.noalias() = -w.C.transpose() * w.y;
  for (int p = 0; p < rm.size(); ++p) {
    const auto& part = rm.parts[static_cast<std::size_t>(p)];
    for (int i : part.nodes) {
      const Vec3 r = w.x.segment<3>(3 * i) - w.centre[static_cast<std::size_t>(p)];
      const Vec3 bi = b.segment<3>(3 * i);  // T_i^T b_i = (b_i, r x b_i)
      w.g.segment<3>(6 * p) += bi;
      w.g.segment<3>(6 * p + 3) += r.cross(bi);
    }
  }
  w.u = w.g;
  w.S_factor.solveInPlace(w.u);
  v = w.y;
  v.noalias() -= w.Y * w.u;
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
