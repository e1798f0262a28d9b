#pragma once
// Internal forces, energy and stiffness of all elements, assembled into the fixed
// pattern of FemModel::pattern. Parallel over elements (OpenMP, by color: elements of
// one color share no node, so scatters never race and the summation order, hence
// the result, does not depend on the thread count). No heap allocation in the loop.
#include <softdiff/fem/fem_model.hpp>

namespace softdiff::fem {

// The per-step record of the FEM stage (what the derivatives will need).
struct FemData {
  std::vector<Mat3> F;        // (m) deformation gradient per element (quadratic: at the quadrature point
                              // with the smallest det F); written by evaluate
  std::vector<Mat3> R;        // (m) corotational: rotation of F = R S (else unused); written by evaluate
  std::vector<Mat3> polar_V;  // (m) corotational, linear tets: V of the signed SVD F = U diag(sigma) V^T
                              // (U = R V); written by evaluate (read by add_stiffness_product)
  std::vector<Vec3> polar_sigma;  // (m) corotational, linear tets: its signed singular values; written by evaluate
  std::vector<Mat3> F_qp;     // (4 per quadratic element, FemModel::quad_slot) F at each quadrature point
  std::vector<Mat3> R_qp;     // (4 per quadratic element) corotational: its rotation
  VecX element_energy;        // (m) V_e psi(F_e); written by evaluate when energy is requested
  double energy = 0;          // sum of element_energy
  VecX f_int;                 // (3n) f_int = -dE/dx; written by evaluate (forces)
  VecX K_values;              // (nnz) K~ in the pattern: K = d^2E/dx^2, per element projected for a body with
                              // psd_projection; written by evaluate (stiffness)
  int bad_element = -1;       // first element where the law is undefined or det F <= 0, or -1
  double bad_det = 0;         // det F of that element

  void resize(const FemModel& model);
};

struct EvalRequest {
  bool energy = false;
  bool forces = true;
  bool stiffness = true;
};

// Evaluates at positions x (3n). Returns false if an element is inverted (det F <= 0)
// or its law is undefined; then data.bad_element/bad_det name the first one (by index)
// and the outputs are unspecified.
bool evaluate(const FemModel& model, const VecX& x, const EvalRequest& request, FemData& data);

// First inverted element (det F <= 0) at positions x, or -1. Cheap (no stress).
int find_inverted_element(const FemModel& model, const VecX& x, double* det_F = nullptr);

// y = S x for a symmetric matrix S stored as upper-triangle values in the pattern.
void symmetric_multiply(const FemModel& model, const VecX& values, const VecX& x, VecX& y);

// K_e = V B^T C B for a 9x9 tangent C (dP/dF, or its directional derivative for dK_e),
// with vec(F) = B x_e: K(3a+i, 3b+k) = V sum_{j,l} C(i+3j, k+3l) G(j,a) G(l,b),
// G = shape_gradients(Dm_inv).
void element_stiffness_from_tangent(const Mat9& C, const Eigen::Matrix<double, 3, 4>& G, double volume, Mat12& K_e);

// The same for N nodes, added to K_e (3N x 3N): K_e += V B^T C B with G (3 x N) = dN/dX.
template <int N>
void add_stiffness_from_tangent(const Mat9& C, const Eigen::Matrix<double, 3, N>& G, double volume,
                                Eigen::Matrix<double, 3 * N, 3 * N>& K_e) {
  Eigen::Matrix<double, 9, 3 * N> T;  // T(:, 3b+k) = sum_l C(:, k+3l) G(l,b)
  for (int b = 0; b < N; ++b)
    for (int k = 0; k < 3; ++k)
      T.col(3 * b + k) = C.col(k) * G(0, b) + C.col(k + 3) * G(1, b) + C.col(k + 6) * G(2, b);
  for (int a = 0; a < N; ++a)
    for (int i = 0; i < 3; ++i)
      K_e.row(3 * a + i) += volume * (G(0, a) * T.row(i) + G(1, a) * T.row(i + 3) + G(2, a) * T.row(i + 6));
}

// Element kernel (exposed for tests): forces (12) and stiffness (12x12) of one tet.
// R, polar_V, polar_sigma (if not null): the corotational polar decomposition of F.
// Returns false when the law is undefined at F.
bool element_forces_stiffness(material::Law law, const material::Lame& lame, double volume,
                              const Mat3& Dm_inv, const Eigen::Matrix<double, 3, 4>& x_e, bool psd_projection,
                              Mat3& F, Vec12& f_e, Mat12* K_e, double* energy, Mat3* R,
                              Mat3* polar_V = nullptr, Vec3* polar_sigma = nullptr);

// The 10-node element (fem/tet10.hpp): G[q] = dN/dX and weight[q] = w_q det J_q at the
// stiffness rule's 4 points (FemModel::qp_G, qp_weight). F[q] = x_e G[q]^T,
// f_e = -sum_q weight_q P(F_q) G_q, K_e = sum_q weight_q B_q^T dP/dF(F_q) B_q, energy
// sum_q weight_q psi(F_q); R[q] (if R != nullptr) the corotational rotation at q. The
// polar decomposition is taken at each point. psd_projection clamps the 30x30 K_e.
// Returns false when the law is undefined or det F <= 0 at a point.
bool element10_forces_stiffness(material::Law law, const material::Lame& lame,
                                const Eigen::Matrix<double, 3, 10>* G, const double* weight,
                                const Eigen::Matrix<double, 3, 10>& x_e, bool psd_projection, Mat3* F, Vec30& f_e,
                                Mat30* K_e, double* energy, Mat3* R);

}  // namespace softdiff::fem
