// Per-quadrature-point cost of the constitutive kernels (one linear tet = one point):
// P alone, P + dP/dF, the directional derivative of dP/dF, and the 12x12 PSD projection.
// GCC 12 + AVX-512 false positives in the intrinsics headers: see material/material.cpp.
#include <softdiff/core/avx512_gcc12.hpp>  // first: see there

#include <softdiff/material/material.hpp>

#include <benchmark/benchmark.h>

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

}  // namespace

