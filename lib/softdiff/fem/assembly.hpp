#pragma once
// Internal forces, energy and stiffness of all elements, assembled into the fixed
// pattern of FemModel::pattern. Parallel over elements (OpenMP, by color: elements of
// one color share no node, so scatters never race and the summation order, hence
// the result, does not depend on the thread count). No heap allocation in the loop.
#include <softdiff/fem/fem_model.hpp>

namespace softdiff::fem {

// The per-step record of the FEM stage (what the derivatives will need).
struct FemData {
  std::vector<Mat3> F;        // (m) deformation gradient per element; written by evaluate
  std::vector<Mat3> R;        // (m) corotational: rotation of F = R S (else unused); written by evaluate
  VecX element_energy;        // (m) V_e psi(F_e); written by evaluate when energy is requested
  double energy = 0;          // sum of element_energy
  VecX f_int;                 // (3n) f_int = -dE/dx; written by evaluate (forces)
  VecX K_values;              // (nnz) K = d^2E/dx^2 in the pattern (unprojected); written by evaluate (stiffness)
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

// Element kernel (exposed for tests): forces (12) and stiffness (12x12) of one tet.
// Returns false when the law is undefined at F.
bool element_forces_stiffness(material::Law law, const material::Lame& lame, double volume,
                              const Mat3& Dm_inv, const Eigen::Matrix<double, 3, 4>& x_e, bool psd_projection,
                              Mat3& F, Vec12& f_e, Mat12* K_e, double* energy, Mat3* R);

}  // namespace softdiff::fem
