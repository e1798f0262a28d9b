#pragma once
// Hyperelastic laws for linear tetrahedra (method.md, "Internal forces and stiffness").
// For each law: the energy density psi(F), the first Piola-Kirchhoff stress
// P = dpsi/dF and its exact derivative dP/dF (a 9x9 matrix acting on vec(F),
// column-major: vec(F)[3*j + i] = F(i, j)). Kernels are templated on the scalar
// type where that is cheap (psi), so tests check them against Eigen's AutoDiff.
#include <softdiff/core/types.hpp>

#include <string>
#include <string_view>

namespace softdiff::material {

// linear: small-strain elasticity (a softdiff extension, constant stiffness).
enum class Law { corotational, stvk, neo_hookean, linear };
std::string_view law_name(Law law);

struct Lame {
  double mu = 0;
  double lambda = 0;
};
// The usual conversion: mu = E / (2 (1 + nu)), lambda = E nu / ((1 + nu)(1 - 2 nu)).
Lame lame_from_young_poisson(double young, double poisson);

// What an element evaluation may need beyond P and dP/dF (kept for derivatives).
struct PointCache {
  Mat3 R = Mat3::Identity();  // corotational: rotation of the polar decomposition F = R S
  Mat3 S = Mat3::Identity();  // corotational: symmetric stretch
  Mat3 V = Mat3::Identity();  // corotational: the signed SVD F = U diag(sigma) V^T (U = R V)
  Vec3 sigma = Vec3::Ones();  // corotational: its signed singular values
};

// The kernels of each law (templated psi, P, dP/dF, directional derivative) are
// inline in corotational.hpp, stvk.hpp and neo_hookean.hpp; these functions dispatch.

// psi(F). Returns +infinity when the energy is undefined (neo_hookean with J <= 0).
double psi(Law law, const Mat3& F, const Lame& lame);

// P(F) and, if dP_dF != nullptr, dP/dF. Returns false (and leaves the outputs
// unspecified) if the law is undefined at F (neo_hookean with J <= 0).
bool stress(Law law, const Mat3& F, const Lame& lame, Mat3& P, Mat9* dP_dF, PointCache* cache = nullptr);

// d(dP/dF)[dF]: the derivative of dP/dF in the direction dF, i.e. the third derivative
// of psi contracted with vec(dF) (a symmetric 9x9 matrix); needed for d(K v)/dx.
// Returns false (output unspecified) where the law is undefined (neo_hookean, J <= 0).
// Corotational: exact wherever dP/dF is (see corotational.hpp on sigma_i + sigma_j -> 0).
bool stress_hessian_directional(Law law, const Mat3& F, const Lame& lame, const Mat3& dF, Mat9& d_dP_dF);

// d^2P[E, W] = d(dP/dF)[E] vec(W) (3x3), the third derivative of psi contracted with E
// and W, at F with the polar decomposition `cache` of F that stress() filled (read by the
// corotational law only; the others work from F). The product the forward sensitivities
// need, without the SVD and the 9x9 of stress_hessian_directional. Returns false where
// the law is undefined.
bool stress_second_derivative(Law law, const Mat3& F, const PointCache& cache, const Lame& lame, const Mat3& E,
                              const Mat3& W, Mat3& out);

// Symmetric eigenvalue clamp of a 12x12 element Hessian: negative eigenvalues set
// to zero (the `psd_projection` option). No heap allocation.
void project_psd(Mat12& K);
void project_psd(Mat30& K);  // the 10-node element's 30x30 Hessian

}  // namespace softdiff::material
