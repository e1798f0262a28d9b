// Derivatives of the FEM stage: see fem_derivatives.hpp for the formulas.
#include <softdiff/core/avx512_gcc12.hpp>  // first: see there
#include <softdiff/fem/fem_derivatives.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/element_loop.hpp>
#include <softdiff/fem/element_psd.hpp>
#include <softdiff/material/psd.hpp>

namespace softdiff::fem {

namespace {

using Mat34 = Eigen::Matrix<double, 3, 4>;

Vec9 vec9(const Mat3& A) { return Eigen::Map<const Vec9>(A.data()); }
Mat3 mat3(const Vec9& v) { return Eigen::Map<const Mat3>(v.data()); }

// The element at x: F, C = dP/dF, the shape gradients; with projection, the derivative
// of the projection at K_e. Fixed size, on the stack.
struct ElementPoint {
  Mat34 G;
  double V = 0;
  Mat3 F;
  Mat9 C;
  material::Law law{};
  material::Lame lame;
  bool projected = false;  // psd_projection and K_e not PSD: dK~ = D(dK)
  Tet4PsdDerivative projection;  // D, reduced to 9 x 9 (element_psd.hpp)

  bool compute(const FemModel& model, const VecX& x, int e, bool need_projection) {
    const auto& body = model.bodies[model.tet_body[e]];
    law = body.law;
    lame = body.lame;
    V = model.rest_volume[e];
    G = shape_gradients(model.Dm_inv[e]);
    const Mat34 x_e = gather(model, x, e);
    Mat3 Ds;
    for (int k = 0; k < 3; ++k) Ds.col(k) = x_e.col(k + 1) - x_e.col(0);
    F.noalias() = Ds * model.Dm_inv[e];  // as element_forces_stiffness computes it
    if (!(F.determinant() > 0)) return false;
    Mat3 P;
    if (!material::stress(law, F, lame, P, &C)) return false;
    projected = false;
    if (need_projection && body.psd_projection) {
      projection.compute(C, G, V);
      projected = !projection.identity;
    }
    return true;
  }

  // dF for node values u_e (3 x 4).
  Mat3 dF(const Mat34& u_e) const { return u_e * G.transpose(); }
  // Node forces-like values V mat(s) G of a 9-vector s (the action of B^T, times V).
  Mat34 spread(const Vec9& s) const { return V * mat3(s) * G; }
};

// The 10-node element (tet10.hpp): the same products summed over the 4 quadrature
// points, each a "linear element" with G = dN/dX at the point and V = w_q det J_q
// (FemModel::qp_G, qp_weight). The projection (psd_projection) acts on the whole
// 30 x 30 element Hessian K_e = sum_q V_q B_q^T C_q B_q, so its derivative does too.
using Mat3x10 = Eigen::Matrix<double, 3, 10>;
using Mat9x30 = Eigen::Matrix<double, 9, 30>;

Mat3x10 gather10(const FemModel& model, const VecX& v, int e) {
  Mat3x10 v_e;
  for (int a = 0; a < 10; ++a) v_e.col(a) = v.segment<3>(3 * model.tets10(a, e));
  return v_e;
}
void scatter_add10(const FemModel& model, int e, const Mat3x10& r, VecX& out) {
  for (int a = 0; a < 10; ++a) out.segment<3>(3 * model.tets10(a, e)) += r.col(a);
}
Vec30 as30(const Mat3x10& m) { return Eigen::Map<const Vec30>(m.data()); }
Mat3x10 as3x10(const Vec30& v) { return Eigen::Map<const Mat3x10>(v.data()); }

struct QuadraticElement {
  const Eigen::Matrix<double, 3, 10>* G = nullptr;  // 4 points
  const double* V = nullptr;
  Mat3 F[4];
  Mat9 C[4];
  material::Law law{};
  material::Lame lame;
  bool projected = false;
  material::PsdProjectionDerivative<30> projection;

  bool compute(const FemModel& model, const VecX& x, int e, bool need_projection) {
    const auto& body = model.bodies[model.tet_body[e]];
    law = body.law;
    lame = body.lame;
    const size_t s0 = 4 * static_cast<size_t>(model.quad_slot[e]);
    G = &model.qp_G[s0];
    V = &model.qp_weight[s0];
    const Mat3x10 x_e = gather10(model, x, e);
    for (int q = 0; q < 4; ++q) {
      F[q].noalias() = x_e * G[q].transpose();  // as element10_forces_stiffness computes it
      if (!(F[q].determinant() > 0)) return false;
      Mat3 P;
      if (!material::stress(law, F[q], lame, P, &C[q])) return false;
    }
    projected = false;
    if (need_projection && body.psd_projection) {
      // As element10_forces_stiffness: kept when every point's dP/dF is PSD.
      bool all_psd = true;
      for (int q = 0; q < 4 && all_psd; ++q) all_psd = tangent_is_psd(C[q]);
      if (!all_psd) {
        Mat30 K = Mat30::Zero();
        for (int q = 0; q < 4; ++q) add_stiffness_from_tangent<10>(C[q], G[q], V[q], K);
        projection.compute(K);
        projected = !projection.identity;
      }
    }
    return true;
  }
  Mat3 dF(int q, const Mat3x10& u_e) const { return u_e * G[q].transpose(); }
  Mat3x10 spread(int q, const Vec9& s) const { return V[q] * mat3(s) * G[q]; }
  Mat9x30 B(int q) const {
    Mat9x30 b = Mat9x30::Zero();
    for (int a = 0; a < 10; ++a)
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) b(3 * j + i, 3 * a + i) = G[q](j, a);
    return b;
  }
};

bool quadratic_jvp(const FemModel& model, const VecX& x, const VecX& u, const VecX& w, double ab, double cb, int e,
                   VecX& out) {
  QuadraticElement p;
  if (!p.compute(model, x, e, cb != 0)) return false;
  const Mat3x10 u_e = gather10(model, u, e), w_e = gather10(model, w, e);
  Mat3x10 r = Mat3x10::Zero();
  Mat30 dK = Mat30::Zero();
  for (int q = 0; q < 4; ++q) {
    const Mat3 dF_u = p.dF(q, u_e);
    if (ab != 0) r += ab * p.spread(q, p.C[q] * vec9(dF_u));
    if (cb != 0) {
      Mat9 dC;
      if (!material::stress_hessian_directional(p.law, p.F[q], p.lame, dF_u, dC)) return false;
      if (!p.projected) r += cb * p.spread(q, dC * vec9(p.dF(q, w_e)));
      else add_stiffness_from_tangent<10>(dC, p.G[q], p.V[q], dK);
    }
  }
  if (cb != 0 && p.projected) r += cb * as3x10(p.projection.apply(dK) * as30(w_e));
  scatter_add10(model, e, r, out);
  return true;
}

bool quadratic_vjp(const FemModel& model, const VecX& x, const VecX& y, const VecX& w, double ab, double cb, int e,
                   VecX& out) {
  QuadraticElement p;
  if (!p.compute(model, x, e, cb != 0)) return false;
  const Mat3x10 y_e = gather10(model, y, e), w_e = gather10(model, w, e);
  Mat3x10 r = Mat3x10::Zero();
  Mat30 S;
  if (cb != 0 && p.projected) {
    const Vec30 yv = as30(y_e), wv = as30(w_e);
    const Mat30 Y = 0.5 * (yv * wv.transpose() + wv * yv.transpose());
    S = p.projection.apply(Y);
  }
  for (int q = 0; q < 4; ++q) {
    const Mat3 dF_y = p.dF(q, y_e);
    if (ab != 0) r += ab * p.spread(q, p.C[q] * vec9(dF_y));
    if (cb == 0) continue;
    if (!p.projected) {
      Mat9 dC;
      if (!material::stress_hessian_directional(p.law, p.F[q], p.lame, dF_y, dC)) return false;
      r += cb * p.spread(q, dC * vec9(p.dF(q, w_e)));
    } else {
      const Mat9x30 B = p.B(q);
      const Mat9 S_hat = B * S * B.transpose();
      Vec9 g;
      for (int m = 0; m < 9; ++m) {
        Mat3 E = Mat3::Zero();
        E(m % 3, m / 3) = 1;
        Mat9 dC;
        if (!material::stress_hessian_directional(p.law, p.F[q], p.lame, E, dC)) return false;
        g[m] = S_hat.cwiseProduct(dC).sum();
      }
      r += cb * p.spread(q, g);
    }
  }
  scatter_add10(model, e, r, out);
  return true;
}

bool quadratic_parameter_derivative(const FemModel& model, const VecX& x, const material::Lame& dlame,
                                    const VecX& w, int e, VecX& df, VecX& dKw) {
  QuadraticElement p;
  if (!p.compute(model, x, e, true)) return false;
  const Mat3x10 w_e = gather10(model, w, e);
  Mat3x10 f = Mat3x10::Zero(), r = Mat3x10::Zero();
  Mat30 dK = Mat30::Zero();
  for (int q = 0; q < 4; ++q) {
    Mat3 P_d;
    Mat9 C_d;
    if (!material::stress(p.law, p.F[q], dlame, P_d, &C_d)) return false;
    f -= p.V[q] * P_d * p.G[q];
    if (!p.projected) r += p.spread(q, C_d * vec9(p.dF(q, w_e)));
    else add_stiffness_from_tangent<10>(C_d, p.G[q], p.V[q], dK);
  }
  if (p.projected) r = as3x10(p.projection.apply(dK) * as30(w_e));
  scatter_add10(model, e, f, df);
  scatter_add10(model, e, r, dKw);
  return true;
}

Vec12 as12(const Mat34& m) { return Eigen::Map<const Vec12>(m.data()); }
Mat34 as34(const Vec12& v) { return Eigen::Map<const Mat34>(v.data()); }

void check_sizes(const FemModel& model, const VecX& v, const char* name) {
  SOFTDIFF_DEMAND(v.size() == 3L * model.num_nodes, std::string(name) + ": expected size 3n = " +
                                                          std::to_string(3L * model.num_nodes) + ", got " +
                                                          std::to_string(v.size()));
}

void check_body_scalars(const FemModel& model, const VecX& s, const char* name) {
  SOFTDIFF_DEMAND(s.size() == static_cast<Eigen::Index>(model.bodies.size()),
                  std::string(name) + ": expected one value per body (" + std::to_string(model.bodies.size()) +
                      "), got " + std::to_string(s.size()));
}

// The sizes of a product's arguments: x, the direction (or cotangent) u, w, out (3n);
// the per-body scalars a, c.
void check_product_sizes(const FemModel& model, const VecX& x, const VecX& u, const VecX& w, const VecX& a,
                         const VecX& c, const VecX& out) {
  check_sizes(model, x, "x");
  check_sizes(model, u, "u (or y)");
  check_sizes(model, w, "w");
  check_sizes(model, out, "out");
  check_body_scalars(model, a, "a");
  check_body_scalars(model, c, "c");
}

// One linear element's share of add_stiffness_jvp (ab, cb: its body's scalars).
bool linear_jvp(const FemModel& model, const VecX& x, const VecX& u, const VecX& w, double ab, double cb, int e,
                VecX& out) {
  ElementPoint p;
  if (!p.compute(model, x, e, cb != 0)) return false;
  const Mat3 dF_u = p.dF(gather(model, u, e));
  Mat34 r = Mat34::Zero();
  if (ab != 0) r += ab * p.spread(p.C * vec9(dF_u));
  if (cb != 0) {
    Mat9 dC;
    if (!material::stress_hessian_directional(p.law, p.F, p.lame, dF_u, dC)) return false;
    const Mat34 w_e = gather(model, w, e);
    if (!p.projected) {
      r += cb * p.spread(dC * vec9(p.dF(w_e)));
    } else {
      r += cb * as34(p.projection.apply_tangent(dC, p.V, as12(w_e)));
    }
  }
  scatter_add(model, e, r, out);
  return true;
}

// One linear element's share of add_stiffness_vjp.
bool linear_vjp(const FemModel& model, const VecX& x, const VecX& y, const VecX& w, double ab, double cb, int e,
                VecX& out) {
  ElementPoint p;
  if (!p.compute(model, x, e, cb != 0)) return false;
  const Mat34 y_e = gather(model, y, e);
  const Mat3 dF_y = p.dF(y_e);
  Mat34 r = Mat34::Zero();
  if (ab != 0) r += ab * p.spread(p.C * vec9(dF_y));
  if (cb != 0) {
    const Mat34 w_e = gather(model, w, e);
    if (!p.projected) {
      Mat9 dC;
      if (!material::stress_hessian_directional(p.law, p.F, p.lame, dF_y, dC)) return false;
      r += cb * p.spread(dC * vec9(p.dF(w_e)));
    } else {
      const Mat9 S_hat = p.projection.reverse(as12(y_e), as12(w_e));
      Vec9 g;
      for (int m = 0; m < 9; ++m) {
        Mat3 E = Mat3::Zero();
        E(m % 3, m / 3) = 1;
        Mat9 dC;
        if (!material::stress_hessian_directional(p.law, p.F, p.lame, E, dC)) return false;
        g[m] = S_hat.cwiseProduct(dC).sum();
      }
      r += cb * p.spread(g);
    }
  }
  scatter_add(model, e, r, out);
  return true;
}

}  // namespace

int add_stiffness_jvp(const FemModel& model, const VecX& x, const VecX& u, const VecX& w, const VecX& a,
                      const VecX& c, VecX& out) {
  check_product_sizes(model, x, u, w, a, c, out);
  return for_each_element_by_color(model, [&](int e) {
    const int b = model.tet_body[e];
    const double ab = a[b], cb = c[b];
    if (ab == 0 && cb == 0) return true;
    if (model.quadratic[e]) return quadratic_jvp(model, x, u, w, ab, cb, e, out);
    return linear_jvp(model, x, u, w, ab, cb, e, out);
  });
}

int add_stiffness_vjp(const FemModel& model, const VecX& x, const VecX& y, const VecX& w, const VecX& a,
                      const VecX& c, VecX& out) {
  check_product_sizes(model, x, y, w, a, c, out);
  return for_each_element_by_color(model, [&](int e) {
    const int b = model.tet_body[e];
    const double ab = a[b], cb = c[b];
    if (ab == 0 && cb == 0) return true;
    if (model.quadratic[e]) return quadratic_vjp(model, x, y, w, ab, cb, e, out);
    return linear_vjp(model, x, y, w, ab, cb, e, out);
  });
}

int add_stiffness_product(const FemModel& model, const FemData& record, const VecX& x, StiffnessProduct kind,
                          const VecX& u, const VecX& w, const VecX& a, const VecX& c, VecX& out, VecX& work) {
  check_product_sizes(model, x, u, w, a, c, out);
  const auto nb = static_cast<Eigen::Index>(model.bodies.size());
  SOFTDIFF_DEMAND(record.K_values.size() == model.pattern.nnz() &&
                      record.F.size() == static_cast<std::size_t>(model.num_tets) &&
                      record.polar_V.size() == record.F.size() && record.polar_sigma.size() == record.F.size(),
                  "add_stiffness_product: the record is not sized for this model (FemData::resize)");
  // a_b K u from the record's K (bodies without projection: K~ = K there).
  bool any_plain = false;
  for (Eigen::Index b = 0; b < nb; ++b) any_plain = any_plain || (a[b] != 0 && !model.bodies[b].psd_projection);
  if (any_plain) {
    symmetric_multiply(model, record.K_values, u, work);  // bodies share no node: K is block diagonal per body
    for (Eigen::Index b = 0; b < nb; ++b) {
      const auto& body = model.bodies[static_cast<std::size_t>(b)];
      if (a[b] == 0 || body.psd_projection) continue;
      out.segment(3L * body.node_begin, 3L * body.num_nodes) += a[b] * work.segment(3L * body.node_begin, 3L * body.num_nodes);
    }
  }
  bool any_element = false;  // an element pass is needed: a dK term, or a projected body
  for (Eigen::Index b = 0; b < nb; ++b) {
    const auto& body = model.bodies[static_cast<std::size_t>(b)];
    any_element = any_element || (body.psd_projection && a[b] != 0) ||
                  (c[b] != 0 && body.law != material::Law::linear);
  }
  if (!any_element) return -1;
  return for_each_element_by_color(model, [&](int e) {
    const int b = model.tet_body[e];
    const auto& body = model.bodies[b];
    const double ab = a[b], cb = c[b];
    if (body.psd_projection) {  // K~ != K, dK~ needs the projection's derivative: the element pass
      if (ab == 0 && cb == 0) return true;
      if (kind == StiffnessProduct::jvp)
        return model.quadratic[e] ? quadratic_jvp(model, x, u, w, ab, cb, e, out) : linear_jvp(model, x, u, w, ab, cb, e, out);
      return model.quadratic[e] ? quadratic_vjp(model, x, u, w, ab, cb, e, out) : linear_vjp(model, x, u, w, ab, cb, e, out);
    }
    // Without projection dK[u] w = dK[w] u = grad_x(u^T K w): the jvp and vjp agree.
    if (cb == 0 || body.law == material::Law::linear) return true;
    if (model.quadratic[e]) return quadratic_jvp(model, x, u, w, 0.0, cb, e, out);
    const Mat3& F = record.F[e];
    SOFTDIFF_ASSERT((gather(model, x, e) * shape_gradients(model.Dm_inv[e]).transpose() - F).norm() <=
                    1e-12 * (1 + F.norm()));  // the record is at x
    if (!(F.determinant() > 0)) return false;
    const Eigen::Matrix<double, 3, 4> G = shape_gradients(model.Dm_inv[e]);
    material::PointCache polar;
    polar.R = record.R[e];
    polar.V = record.polar_V[e];
    polar.sigma = record.polar_sigma[e];
    const Mat3 dF_u = gather(model, u, e) * G.transpose();
    const Mat3 dF_w = gather(model, w, e) * G.transpose();
    Mat3 d2P;
    if (!material::stress_second_derivative(body.law, F, polar, body.lame, dF_u, dF_w, d2P)) return false;
    scatter_add(model, e, (cb * model.rest_volume[e]) * d2P * G, out);
    return true;
  });
}

material::Lame lame_derivative(const BodyModel& body, ElasticParameter p) {
  const double E = body.young, nu = body.poisson;
  material::Lame d;
  if (p == ElasticParameter::young) {
    // mu and lambda are proportional to E.
    d.mu = body.lame.mu / E;
    d.lambda = body.lame.lambda / E;
  } else {
    // mu = E / (2 (1 + nu)), lambda = E nu / ((1 + nu)(1 - 2 nu)) = E nu / D, D' = -1 - 4 nu.
    const double D = (1 + nu) * (1 - 2 * nu);
    d.mu = -E / (2 * (1 + nu) * (1 + nu));
    d.lambda = E * (1 + 2 * nu * nu) / (D * D);
  }
  return d;
}

int add_elastic_parameter_derivative(const FemModel& model, const VecX& x, int body, ElasticParameter param,
                                     const VecX& w, VecX& df, VecX& dKw) {
  check_sizes(model, x, "x");
  check_sizes(model, w, "w");
  check_sizes(model, df, "df");
  check_sizes(model, dKw, "dKw");
  SOFTDIFF_DEMAND(body >= 0 && body < static_cast<int>(model.bodies.size()), "body index out of range");
  const material::Lame dlame = lame_derivative(model.bodies[body], param);
  return for_each_element_by_color(model, [&](int e) {
    if (model.tet_body[e] != body) return true;
    if (model.quadratic[e]) return quadratic_parameter_derivative(model, x, dlame, w, e, df, dKw);
    ElementPoint p;
    if (!p.compute(model, x, e, true)) return false;
    Mat3 P_d;
    Mat9 C_d;
    if (!material::stress(p.law, p.F, dlame, P_d, &C_d)) return false;
    scatter_add(model, e, -p.V * P_d * p.G, df);
    const Mat34 w_e = gather(model, w, e);
    if (!p.projected) {
      scatter_add(model, e, p.spread(C_d * vec9(p.dF(w_e))), dKw);
    } else {
      scatter_add(model, e, as34(p.projection.apply_tangent(C_d, p.V, as12(w_e))), dKw);
    }
    return true;
  });
}

}  // namespace softdiff::fem
