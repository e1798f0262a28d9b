#pragma once
// GCC 12 reports false -W(maybe-)uninitialized warnings inside its own AVX-512
// intrinsics (avx512fintrin.h, _mm512_extractf64x4_pd / _mm512_insertf64x4; GCC PR
// 105593, fixed in GCC 13) whenever Eigen uses 8-wide double packets under
// -march=native. Including <immintrin.h> first, with those warnings off, silences them
// for the intrinsics' own lines only; code that includes this keeps the warnings.
// Include it before any Eigen header in files that use 8-wide Eigen operations.
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ == 12 && defined(__AVX512F__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#include <immintrin.h>
#pragma GCC diagnostic pop
#endif
