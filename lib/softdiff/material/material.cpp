// Dispatch from Law to the inline kernels (corotational.hpp, stvk.hpp, neo_hookean.hpp).
#include <softdiff/core/avx512_gcc12.hpp>  // first: see there
#include <softdiff/material/corotational.hpp>
#include <softdiff/material/material.hpp>
#include <softdiff/material/neo_hookean.hpp>
#include <softdiff/material/psd.hpp>
#include <softdiff/material/linear.hpp>
#include <softdiff/material/stvk.hpp>

#include <limits>

namespace softdiff::material {

double psi(Law law, const Mat3& F, const Lame& lame) {
  switch (law) {
    case Law::corotational: return corotational::psi(F, lame.mu, lame.lambda);
    case Law::stvk: return stvk::psi(F, lame.mu, lame.lambda);
    case Law::neo_hookean: return neo_hookean::psi(F, lame.mu, lame.lambda);
    case Law::linear: return linear::psi(F, lame.mu, lame.lambda);
  }
  return std::numeric_limits<double>::quiet_NaN();
}

bool stress(Law law, const Mat3& F, const Lame& lame, Mat3& P, Mat9* dP_dF, PointCache* cache) {
  switch (law) {
    case Law::corotational: {
      corotational::Polar polar;
      corotational::polar_svd(F, polar);
      corotational::stress(F, polar, lame.mu, lame.lambda, P, dP_dF);
      if (cache != nullptr) {
        cache->R = polar.R;
        cache->S = polar.stretch();
        cache->V = polar.V;
        cache->sigma = polar.sigma;
      }
      return true;
    }
    case Law::stvk: stvk::stress(F, lame.mu, lame.lambda, P, dP_dF); return true;
    case Law::neo_hookean: return neo_hookean::stress(F, lame.mu, lame.lambda, P, dP_dF);
    case Law::linear: linear::stress(F, lame.mu, lame.lambda, P, dP_dF); return true;
  }
  return false;
}

bool stress_hessian_directional(Law law, const Mat3& F, const Lame& lame, const Mat3& dF, Mat9& d_dP_dF) {
  switch (law) {
    case Law::corotational:
      corotational::stress_hessian_directional(F, lame.mu, lame.lambda, dF, d_dP_dF);
      return true;
    case Law::stvk: stvk::stress_hessian_directional(F, lame.mu, lame.lambda, dF, d_dP_dF); return true;
    case Law::neo_hookean: return neo_hookean::stress_hessian_directional(F, lame.mu, lame.lambda, dF, d_dP_dF);
    case Law::linear: d_dP_dF.setZero(); return true;  // constant dP/dF
  }
  return false;
}

bool stress_second_derivative(Law law, const Mat3& F, const PointCache& cache, const Lame& lame, const Mat3& E,
                              const Mat3& W, Mat3& out) {
  if (law == Law::corotational) {
    corotational::stress_second_derivative(cache.R, cache.V, cache.sigma, lame.mu, lame.lambda, E, W, out);
    return true;
  }
  if (law == Law::linear) {  // constant dP/dF
    out.setZero();
    return true;
  }
  Mat9 T;
  if (!stress_hessian_directional(law, F, lame, E, T)) return false;
  Eigen::Map<Vec9>(out.data()).noalias() = T * detail::vec(W);
  return true;
}

void project_psd(Mat12& K) { clamp_negative_eigenvalues(K); }
void project_psd(Mat30& K) { clamp_negative_eigenvalues(K); }

}  // namespace softdiff::material
