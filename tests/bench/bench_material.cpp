// Per-quadrature-point cost of the constitutive kernels (one linear tet = one point):
// P alone, P + dP/dF, the directional derivative of dP/dF, and the 12x12 PSD projection;
// and the element stiffness with psd_projection (BM_element_psd): the 12x12 projection
// of main before 2026-12-02 (old) against fem/element_psd.hpp (new: the skip and the
// 9x9 reduction), per element, on compressed elements (all indefinite), stretched ones
// (all PSD) and a mix.
// GCC 12 + AVX-512 false positives in the intrinsics headers: see material/material.cpp.
#include <softdiff/core/avx512_gcc12.hpp>  // first: see there

#include <softdiff/fem/element_psd.hpp>
#include <softdiff/material/material.hpp>

#include <benchmark/benchmark.h>

#include <Eigen/LU>
#include <Eigen/QR>
#include <cstdlib>
#include <vector>

namespace {

using namespace softdiff;
using namespace softdiff::material;

std::vector<Mat3> deformations(int n) {
  std::vector<Mat3> Fs(n);
  for (int k = 0; k < n; ++k) Fs[k] = Mat3::Identity() + 0.2 * Mat3::Random();
  return Fs;
}

void BM_stress(benchmark::State& state, Law law, bool with_derivative) {
  const auto Fs = deformations(1024);
  const Lame lame = lame_from_young_poisson(1e5, 0.4);
  Mat3 P;
  Mat9 H;
  std::size_t k = 0;
  for (auto _ : state) {
    stress(law, Fs[k++ & 1023], lame, P, with_derivative ? &H : nullptr);
    benchmark::DoNotOptimize(P);
    benchmark::DoNotOptimize(H);
  }
}

void BM_directional(benchmark::State& state, Law law) {
  const auto Fs = deformations(1024);
  const Lame lame = lame_from_young_poisson(1e5, 0.4);
  const Mat3 dF = Mat3::Random();
  Mat9 T;
  std::size_t k = 0;
  for (auto _ : state) {
    stress_hessian_directional(law, Fs[k++ & 1023], lame, dF, T);
    benchmark::DoNotOptimize(T);
  }
}

void BM_project_psd(benchmark::State& state) {
  std::vector<Mat12> Ks(64);
  for (auto& K : Ks) {
    K = Mat12::Random();
    K = (K + K.transpose()).eval();
  }
  std::size_t k = 0;
  for (auto _ : state) {
    Mat12 K = Ks[k++ & 63];
    project_psd(K);
    benchmark::DoNotOptimize(K);
  }
}

// Elements: a random rest tet (edges ~ 1 cm) and C = dP/dF at F = R diag(s) R2 with
// stretches s in [lo, hi]; the benchmark times K_e from C, projected (without
// computing C, which BM_stress times).
struct PsdElement {
  Mat9 C;
  Eigen::Matrix<double, 3, 4> G;
  double V;
};

std::vector<PsdElement> psd_elements(Law law, double lo, double hi, int n) {
  std::vector<PsdElement> out(n);
  std::srand(7);
  for (auto& el : out) {
    Mat3 Dm = 0.01 * (Mat3::Identity() + 0.2 * Mat3::Random());
    el.G = fem::shape_gradients(Dm.inverse());
    el.V = Dm.determinant() / 6;
    const auto R = [] {
      Eigen::HouseholderQR<Mat3> qr(Mat3::Random());
      return Mat3(qr.householderQ());
    };
    const Vec3 s = lo + (hi - lo) * 0.5 * (Vec3::Random().array() + 1);
    const Mat3 F = R() * s.asDiagonal() * R();
    Mat3 P;
    stress(law, F.determinant() > 0 ? F : Mat3(-F), lame_from_young_poisson(1e5, 0.4), P, &el.C);
  }
  return out;
}

void BM_element_psd(benchmark::State& state, Law law, double lo, double hi, bool reduced) {
  const auto els = psd_elements(law, lo, hi, 256);
  int indefinite = 0;
  for (const auto& el : els) indefinite += !fem::tangent_is_psd(el.C);
  std::size_t k = 0;
  for (auto _ : state) {
    const auto& el = els[k++ & 255];
    Mat12 K;
    if (reduced) {
      fem::tet4_stiffness(el.C, el.G, el.V, true, K);
    } else {
      fem::element_stiffness_from_tangent(el.C, el.G, el.V, K);
      project_psd(K);
    }
    benchmark::DoNotOptimize(K);
  }
  state.counters["indefinite"] = indefinite / 256.0;
}

BENCHMARK_CAPTURE(BM_stress, corotational_P, Law::corotational, false);
BENCHMARK_CAPTURE(BM_stress, corotational_P_dPdF, Law::corotational, true);
BENCHMARK_CAPTURE(BM_stress, stvk_P, Law::stvk, false);
BENCHMARK_CAPTURE(BM_stress, stvk_P_dPdF, Law::stvk, true);
BENCHMARK_CAPTURE(BM_stress, neo_hookean_P, Law::neo_hookean, false);
BENCHMARK_CAPTURE(BM_stress, neo_hookean_P_dPdF, Law::neo_hookean, true);
BENCHMARK_CAPTURE(BM_directional, corotational, Law::corotational);
BENCHMARK_CAPTURE(BM_directional, stvk, Law::stvk);
BENCHMARK_CAPTURE(BM_directional, neo_hookean, Law::neo_hookean);
BENCHMARK(BM_project_psd);
BENCHMARK_CAPTURE(BM_element_psd, corotational_compressed_old, Law::corotational, 0.6, 0.95, false);
BENCHMARK_CAPTURE(BM_element_psd, corotational_compressed_new, Law::corotational, 0.6, 0.95, true);
BENCHMARK_CAPTURE(BM_element_psd, corotational_mixed_old, Law::corotational, 0.8, 1.2, false);
BENCHMARK_CAPTURE(BM_element_psd, corotational_mixed_new, Law::corotational, 0.8, 1.2, true);
BENCHMARK_CAPTURE(BM_element_psd, corotational_stretched_old, Law::corotational, 1.05, 1.3, false);
BENCHMARK_CAPTURE(BM_element_psd, corotational_stretched_new, Law::corotational, 1.05, 1.3, true);
BENCHMARK_CAPTURE(BM_element_psd, neo_hookean_compressed_old, Law::neo_hookean, 0.6, 0.95, false);
BENCHMARK_CAPTURE(BM_element_psd, neo_hookean_compressed_new, Law::neo_hookean, 0.6, 0.95, true);
BENCHMARK_CAPTURE(BM_element_psd, stvk_compressed_old, Law::stvk, 0.6, 0.95, false);
BENCHMARK_CAPTURE(BM_element_psd, stvk_compressed_new, Law::stvk, 0.6, 0.95, true);
BENCHMARK_CAPTURE(BM_element_psd, linear_old, Law::linear, 0.9, 1.1, false);
BENCHMARK_CAPTURE(BM_element_psd, linear_new, Law::linear, 0.9, 1.1, true);

}  // namespace

