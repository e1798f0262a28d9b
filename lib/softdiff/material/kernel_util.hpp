#pragma once
// Small helpers shared by the constitutive kernels (corotational.hpp, stvk.hpp,
// neo_hookean.hpp). Everything here is header-only, fixed-size and allocation-free,
// and the templated helpers work for double and for Eigen::AutoDiffScalar (nested too).
#include <softdiff/core/types.hpp>

#include <type_traits>

namespace softdiff::material::detail {

// The plain double value of a scalar: x for arithmetic types, x.value() recursively
// for AutoDiff-like scalars (used for branches and iteration control, never for maths
// that must be differentiated).
template <class T>
double value_of(const T& x) {
  if constexpr (std::is_arithmetic_v<T>)
    return static_cast<double>(x);
  else
    return value_of(x.value());
}

template <class T>
Mat3 value_of_matrix(const Eigen::Matrix<T, 3, 3>& A) {
  Mat3 out;
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 3; ++i) out(i, j) = value_of(A(i, j));
  return out;
}

// Cofactor matrix cof(A) = det(A) A^{-T} = d det(A) / dA, written out so that it
// works for any scalar type: column j is the cross product of the other two columns.
template <class T>
Eigen::Matrix<T, 3, 3> cofactor(const Eigen::Matrix<T, 3, 3>& A) {
  Eigen::Matrix<T, 3, 3> C;
  for (int j = 0; j < 3; ++j) {
    const int a = (j + 1) % 3, b = (j + 2) % 3;
    C(0, j) = A(1, a) * A(2, b) - A(2, a) * A(1, b);
    C(1, j) = A(2, a) * A(0, b) - A(0, a) * A(2, b);
    C(2, j) = A(0, a) * A(1, b) - A(1, a) * A(0, b);
  }
  return C;
}

// det(A) from its cofactor matrix (first-column expansion). Used wherever J is needed so
// that every kernel of a law computes J by the same expression.
template <class T>
T det_from_cofactor(const Eigen::Matrix<T, 3, 3>& A, const Eigen::Matrix<T, 3, 3>& C) {
  return A(0, 0) * C(0, 0) + A(1, 0) * C(1, 0) + A(2, 0) * C(2, 0);
}

// [w]_x, the cross-product matrix: [w]_x v = w x v.
inline Mat3 skew(const Vec3& w) {
  Mat3 W;
  W << 0.0, -w(2), w(1),  //
      w(2), 0.0, -w(0),   //
      -w(1), w(0), 0.0;
  return W;
}

// vec(A) for a 3x3 matrix, column-major: vec(A)[3 j + i] = A(i, j).
inline Eigen::Map<const Vec9> vec(const Mat3& A) { return Eigen::Map<const Vec9>(A.data()); }

}  // namespace softdiff::material::detail
