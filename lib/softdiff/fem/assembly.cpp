#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/element_loop.hpp>
#include <softdiff/fem/element_psd.hpp>

#include <Eigen/LU>
#include <algorithm>
#include <limits>

namespace softdiff::fem {
namespace {

// The smallest det F over a quadratic element's quadrature points.
double min_det_F10(const FemModel& model, const VecX& x, int e) {
  Eigen::Matrix<double, 3, 10> x_e;
  for (int a = 0; a < 10; ++a) x_e.col(a) = x.segment<3>(3 * model.tets10(a, e));
  const size_t s0 = 4 * static_cast<size_t>(model.quad_slot[e]);
  double lo = std::numeric_limits<double>::infinity();
  for (int q = 0; q < 4; ++q) lo = std::min(lo, (x_e * model.qp_G[s0 + q].transpose()).determinant());
  return lo;
}

}  // namespace

void FemData::resize(const FemModel& model) {
  F.assign(model.num_tets, Mat3::Identity());
  R.assign(model.num_tets, Mat3::Identity());
  polar_V.assign(model.num_tets, Mat3::Identity());
  polar_sigma.assign(model.num_tets, Vec3::Ones());
  F_qp.assign(4 * static_cast<size_t>(model.num_quadratic), Mat3::Identity());
  R_qp.assign(4 * static_cast<size_t>(model.num_quadratic), Mat3::Identity());
  element_energy = VecX::Zero(model.num_tets);
  f_int = VecX::Zero(3 * model.num_nodes);
  K_values = VecX::Zero(model.pattern.nnz());
}

void element_stiffness_from_tangent(const Mat9& C, const Eigen::Matrix<double, 3, 4>& G, double volume, Mat12& K_e) {
  // K(3a+i, 3b+k) = V sum_{j,l} C(i+3j, k+3l) G(j,a) G(l,b)
  Eigen::Matrix<double, 9, 12> T;  // T(:, 3b+k) = sum_l C(:, k+3l) G(l,b)
  for (int b = 0; b < 4; ++b)
    for (int k = 0; k < 3; ++k)
      T.col(3 * b + k) = C.col(k) * G(0, b) + C.col(k + 3) * G(1, b) + C.col(k + 6) * G(2, b);
  for (int a = 0; a < 4; ++a)
    for (int i = 0; i < 3; ++i)
      K_e.row(3 * a + i) = volume * (G(0, a) * T.row(i) + G(1, a) * T.row(i + 3) + G(2, a) * T.row(i + 6));
}

bool element_forces_stiffness(material::Law law, const material::Lame& lame, double volume, const Mat3& Dm_inv,
                              const Eigen::Matrix<double, 3, 4>& x_e, bool psd_projection, Mat3& F, Vec12& f_e,
                              Mat12* K_e, double* energy, Mat3* R, Mat3* polar_V, Vec3* polar_sigma) {
  Mat3 Ds;
  Ds.col(0) = x_e.col(1) - x_e.col(0);
  Ds.col(1) = x_e.col(2) - x_e.col(0);
  Ds.col(2) = x_e.col(3) - x_e.col(0);
  F.noalias() = Ds * Dm_inv;
  if (!(F.determinant() > 0)) return false;
  const Eigen::Matrix<double, 3, 4> G = shape_gradients(Dm_inv);
  Mat3 P;
  Mat9 dP_dF;
  material::PointCache cache;
  if (!material::stress(law, F, lame, P, K_e ? &dP_dF : nullptr, &cache)) return false;
  if (R) *R = cache.R;
  if (polar_V) *polar_V = cache.V;
  if (polar_sigma) *polar_sigma = cache.sigma;
  if (energy) *energy = volume * material::psi(law, F, lame);
  // f_a = -V P g_a
  Eigen::Map<Eigen::Matrix<double, 3, 4>>(f_e.data()).noalias() = -volume * P * G;
  if (K_e) tet4_stiffness(dP_dF, G, volume, psd_projection, *K_e);  // element_psd.hpp
  return true;
}

bool element10_forces_stiffness(material::Law law, const material::Lame& lame,
                                const Eigen::Matrix<double, 3, 10>* G, const double* weight,
                                const Eigen::Matrix<double, 3, 10>& x_e, bool psd_projection, Mat3* F, Vec30& f_e,
                                Mat30* K_e, double* energy, Mat3* R) {
  Eigen::Map<Eigen::Matrix<double, 3, 10>> f(f_e.data());
  f.setZero();
  if (K_e) K_e->setZero();
  if (energy) *energy = 0;
  bool all_psd = true;  // every point's dP/dF PSD: K_e is too, the projection keeps it (element_psd.hpp)
  for (int q = 0; q < 4; ++q) {
    F[q].noalias() = x_e * G[q].transpose();
    if (!(F[q].determinant() > 0)) return false;
    Mat3 P;
    Mat9 dP_dF;
    material::PointCache cache;
    if (!material::stress(law, F[q], lame, P, K_e ? &dP_dF : nullptr, &cache)) return false;
    if (R) R[q] = cache.R;
    if (energy) *energy += weight[q] * material::psi(law, F[q], lame);
    f.noalias() -= weight[q] * P * G[q];
    if (K_e) add_stiffness_from_tangent<10>(dP_dF, G[q], weight[q], *K_e);
    if (K_e && psd_projection && all_psd) all_psd = tangent_is_psd(dP_dF);
  }
  if (K_e && psd_projection && !all_psd) material::project_psd(*K_e);
  return true;
}

bool evaluate(const FemModel& model, const VecX& x, const EvalRequest& request, FemData& data) {
  const auto& pattern = model.pattern;
  if (request.forces) data.f_int.setZero();
  if (request.stiffness) data.K_values.setZero();
  const int bad = for_each_element_by_color(model, [&](int e) {
    const auto& body = model.bodies[model.tet_body[e]];
    if (model.quadratic[e]) {
      const size_t s0 = 4 * static_cast<size_t>(model.quad_slot[e]);
      Eigen::Matrix<double, 3, 10> x_e;
      for (int a = 0; a < 10; ++a) x_e.col(a) = x.segment<3>(3 * model.tets10(a, e));
      Vec30 f_e;
      Mat30 K_e;
      double psi_e = 0;
      const bool ok = element10_forces_stiffness(body.law, body.lame, &model.qp_G[s0], &model.qp_weight[s0], x_e,
                                                 body.psd_projection, &data.F_qp[s0], f_e,
                                                 request.stiffness ? &K_e : nullptr, request.energy ? &psi_e : nullptr,
                                                 &data.R_qp[s0]);
      int worst = 0;  // the point with the smallest det F (for messages)
      for (int q = 1; q < 4; ++q)
        if (data.F_qp[s0 + q].determinant() < data.F_qp[s0 + worst].determinant()) worst = q;
      data.F[e] = data.F_qp[s0 + worst];
      data.R[e] = data.R_qp[s0];
      if (!ok) return false;
      if (request.energy) data.element_energy[e] = psi_e;
      if (request.forces)
        for (int a = 0; a < 10; ++a) data.f_int.segment<3>(3 * model.tets10(a, e)) += f_e.segment<3>(3 * a);
      if (request.stiffness) {
        const int* scatter = pattern.element_scatter.data() + pattern.element_scatter_begin[e];
        int s = 0;
        for (int i = 0; i < 30; ++i)
          for (int j = i; j < 30; ++j) data.K_values[scatter[s++]] += K_e(i, j);
      }
      return true;
    }
    const Eigen::Matrix<double, 3, 4> x_e = gather(model, x, e);
    Vec12 f_e;
    Mat12 K_e;
    double psi_e = 0;
    if (!element_forces_stiffness(body.law, body.lame, model.rest_volume[e], model.Dm_inv[e], x_e,
                                  body.psd_projection, data.F[e], f_e, request.stiffness ? &K_e : nullptr,
                                  request.energy ? &psi_e : nullptr, &data.R[e], &data.polar_V[e],
                                  &data.polar_sigma[e]))
      return false;
    if (request.energy) data.element_energy[e] = psi_e;
    if (request.forces)
      for (int a = 0; a < 4; ++a) data.f_int.segment<3>(3 * model.tets(a, e)) += f_e.segment<3>(3 * a);
    if (request.stiffness) {
      const int* scatter = pattern.element_scatter.data() + pattern.element_scatter_begin[e];
      int s = 0;
      for (int i = 0; i < 12; ++i)
        for (int j = i; j < 12; ++j) data.K_values[scatter[s++]] += K_e(i, j);
    }
    return true;
  });
  if (bad >= 0) {
    data.bad_element = bad;
    data.bad_det = data.F[bad].determinant();
    return false;
  }
  data.bad_element = -1;
  if (request.energy) data.energy = data.element_energy.sum();
  return true;
}

int find_inverted_element(const FemModel& model, const VecX& x, double* det_F) {
  int bad = std::numeric_limits<int>::max();
  // A determinant per element: serial below 50k elements (0.5 ms), where waking the
  // OpenMP team after the factorization costs more, and far more on a loaded machine
  // (docs/performance.md "Threads").
#pragma omp parallel for schedule(static) reduction(min : bad) if (model.num_tets > 50000)
  for (int e = 0; e < model.num_tets; ++e) {
    if (model.quadratic[e]) {
      if (!(min_det_F10(model, x, e) > 0)) bad = std::min(bad, e);
      continue;
    }
    Mat3 Ds;
    const Vec3 x0 = x.segment<3>(3 * model.tets(0, e));
    for (int k = 0; k < 3; ++k) Ds.col(k) = x.segment<3>(3 * model.tets(k + 1, e)) - x0;
    if (!(Ds.determinant() > 0)) bad = std::min(bad, e);
  }
  if (bad == std::numeric_limits<int>::max()) return -1;
  if (det_F && model.quadratic[bad]) {
    *det_F = min_det_F10(model, x, bad);
  } else if (det_F) {
    Mat3 Ds;
    const Vec3 x0 = x.segment<3>(3 * model.tets(0, bad));
    for (int k = 0; k < 3; ++k) Ds.col(k) = x.segment<3>(3 * model.tets(k + 1, bad)) - x0;
    *det_F = (Ds * model.Dm_inv[bad]).determinant();
  }
  return bad;
}

void symmetric_multiply(const FemModel& model, const VecX& values, const VecX& x, VecX& y) {
  const auto& S = model.pattern.structure;
  const int* outer = S.outerIndexPtr();
  const int* inner = S.innerIndexPtr();
  y.setZero(x.size());
  for (int col = 0; col < S.outerSize(); ++col) {
    double acc = 0;
    const double xc = x[col];
    for (int k = outer[col]; k < outer[col + 1]; ++k) {
      const int row = inner[k];
      const double s = values[k];
      y[row] += s * xc;
      if (row != col) acc += s * x[row];
    }
    y[col] += acc;
  }
}

}  // namespace softdiff::fem
