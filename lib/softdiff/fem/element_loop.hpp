#pragma once
// The parallel loop over elements shared by assembly and its derivatives: by color
// (elements of one color share no node, so per-node scatters never race and the
// summation order, hence the result, does not depend on the thread count); the last
// color is run serially when the coloring overflowed (its elements may share nodes).
#include <softdiff/fem/fem_model.hpp>

#include <algorithm>
#include <limits>

namespace softdiff::fem {

// Calls fn(e) for every element e; fn returns false where the law is undefined.
// Returns the smallest such element, or -1.
template <class Fn>
int for_each_element_by_color(const FemModel& model, Fn&& fn) {
  const auto& pattern = model.pattern;
  int bad = std::numeric_limits<int>::max();
  const int num_colors = static_cast<int>(pattern.color_begin.size()) - 1;
  for (int c = 0; c < num_colors; ++c) {
    const int begin = pattern.color_begin[c], end = pattern.color_begin[c + 1];
    const bool serial = (c == num_colors - 1) && pattern.last_color_shares_nodes;
#pragma omp parallel for schedule(static) reduction(min : bad) if (!serial && end - begin > 256)
    for (int k = begin; k < end; ++k) {
      const int e = pattern.color_elements[k];
      if (!fn(e)) bad = std::min(bad, e);
    }
  }
  return bad == std::numeric_limits<int>::max() ? -1 : bad;
}

// The element's node positions (3 x 4) gathered from a global vector (3n).
inline Eigen::Matrix<double, 3, 4> gather(const FemModel& model, const VecX& x, int e) {
  Eigen::Matrix<double, 3, 4> x_e;
  for (int a = 0; a < 4; ++a) x_e.col(a) = x.segment<3>(3 * model.tets(a, e));
  return x_e;
}

// out (3n) += the element's 3 x 4 node values.
inline void scatter_add(const FemModel& model, int e, const Eigen::Matrix<double, 3, 4>& v, VecX& out) {
  for (int a = 0; a < 4; ++a) out.segment<3>(3 * model.tets(a, e)) += v.col(a);
}

}  // namespace softdiff::fem
