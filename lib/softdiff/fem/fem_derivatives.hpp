#pragma once
// Derivatives of the FEM stage (method.md "Derivatives"; sibling of assembly.hpp):
// products with the derivatives of f_int(x) and of the stiffness the step uses,
// element by element, never a third-order tensor.
//
// Notation: E(x) the elastic energy, K = d^2E/dx^2 = -df_int/dx (the true Hessian),
// K~ the stiffness the step uses: K, or for a body with psd_projection the
// per-element projection K~_e = (K_e)+ (material::clamp_negative_eigenvalues).
// Per element, with vec(F) = B x_e, C = dP/dF and dC[dF] its directional derivative
// (material::stress_hessian_directional):
//   K_e u_e      = V B^T C vec(dF_u)                       (dF_u = u_e G^T)
//   dK_e[u] w_e  = V B^T dC[dF_u] vec(dF_w)
//   dK~_e[u]     = D(dK_e[u])   with D the derivative of the projection (psd.hpp)
// and for the reverse mode grad_x (y^T K~(x) w):
//   without projection: V B^T dC[dF_y] vec(dF_w) (= dK[y] w: the third derivative of
//   E is symmetric in its three arguments);
//   with projection: S = D(sym(y_e w_e^T)) (D is self-adjoint), S^ = B S B^T, and the
//   gradient V B^T g with g_m = <S^, dC[E_m]> over the 9 unit directions E_m of F.
// Parameters (young, poisson) enter through the Lame constants, in which P and C are
// linear for every law: df_int/dp = f_int at the Lame derivative (dmu/dp, dlambda/dp),
// dK/dp likewise, and dK~/dp = D(dK/dp).
//
// Per-body scalars (a_b, c_b below) are VecX of size bodies.size(); elements of a body
// whose scalar is 0 are skipped. Every function returns the first element where the
// law is undefined (det F <= 0), or -1; outputs are then unspecified. Parallel over
// elements by color (element_loop.hpp); no heap allocation in the element loop.
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/fem_model.hpp>

namespace softdiff::fem {

// out += a_b K(x) u + c_b dK~(x)[u] w   (per body b)
int add_stiffness_jvp(const FemModel& model, const VecX& x, const VecX& u, const VecX& w, const VecX& a,
                      const VecX& c, VecX& out);

// out += a_b K(x) y + c_b grad_x (y^T K~(x) w)   (per body b): the transpose of
// u -> add_stiffness_jvp(x, u, w), applied to y.
int add_stiffness_vjp(const FemModel& model, const VecX& x, const VecX& y, const VecX& w, const VecX& a,
                      const VecX& c, VecX& out);

// The same products from the record of an evaluation at x (`record`: fem::evaluate(model,
// x, stiffness) wrote it; the step's data.fem of a linearized step), for the forward
// sensitivities (docs/method.md "Derivatives", "The cost of a JVP column"):
//   - a_b K u from the record's assembled K (one sparse product for all bodies; K~ = K
//     for a body without psd_projection), not an element pass;
//   - c_b dK[u] w per element from the record's F and polar decomposition (R,
//     polar_V, polar_sigma) and material::stress_second_derivative: no SVD, no 9x9;
//     no element pass at all when every such c_b is 0 or the law is linear;
//   - bodies with psd_projection (dK~ is the projection's derivative) and quadratic
//     elements' dK term: the element pass of add_stiffness_jvp / _vjp as above.
// kind: jvp gives add_stiffness_jvp(x, u, w), vjp gives add_stiffness_vjp(x, y = u, w);
// without projection they are the same product (dK[u] w = grad_x(u^T K w)). The same
// values as those functions up to rounding. work: (3n) scratch. Returns as those do.
enum class StiffnessProduct { jvp, vjp };
int add_stiffness_product(const FemModel& model, const FemData& record, const VecX& x, StiffnessProduct kind,
                          const VecX& u, const VecX& w, const VecX& a, const VecX& c, VecX& out, VecX& work);

enum class ElasticParameter { young, poisson };

// (dmu/dp, dlambda/dp) of a body.
material::Lame lame_derivative(const BodyModel& body, ElasticParameter p);

// Body b's elements only: df += df_int/dp, dKw += (dK~/dp) w.
int add_elastic_parameter_derivative(const FemModel& model, const VecX& x, int body, ElasticParameter p,
                                     const VecX& w, VecX& df, VecX& dKw);

}  // namespace softdiff::fem
