// The Delassus operator without its dense matrix: see sparse_delassus.hpp.
#include <softdiff/contact/sparse_delassus.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/timer.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace softdiff::contact {

namespace {

// Scatter the values of X (upper, compressed) into out (nnz S) on the pattern of S,
// zeros elsewhere. False (out unspecified) if some entry of X is outside S.
bool scatter_into(const SparseMatrix& X, const SparseMatrix& S, VecX& out) {
  out.setZero(S.nonZeros());
  const int* so = S.outerIndexPtr();
  const int* si = S.innerIndexPtr();
  for (int j = 0; j < X.outerSize(); ++j) {
    int p = so[j];
    const int end = so[j + 1];
    for (SparseMatrix::InnerIterator it(X, j); it; ++it) {
      while (p < end && si[p] < it.row()) ++p;
      if (p == end || si[p] != it.row()) return false;
      out[p] += it.value();
    }
  }
  return true;
}

// The pattern of X with unit values (for unions of patterns).
SparseMatrix ones_like(const SparseMatrix& X) {
  SparseMatrix P = X;
  std::fill(P.valuePtr(), P.valuePtr() + P.nonZeros(), 1.0);
  return P;
}

// The pattern of the 3x3 node blocks that X (upper, dofs) touches, upper triangle, unit
// values: structural, so that the analyzed pattern does not depend on which entries of
// H (frame components) or of H^T H (cancellations) happen to be exactly zero.
SparseMatrix node_block_pattern(const SparseMatrix& X) {
  std::vector<Eigen::Triplet<double, int>> t;
  t.reserve(static_cast<std::size_t>(9 * X.nonZeros()));
  for (int j = 0; j < X.outerSize(); ++j)
    for (SparseMatrix::InnerIterator it(X, j); it; ++it) {
      const int bi = 3 * (static_cast<int>(it.row()) / 3), bj = 3 * (j / 3);
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
          if (bi + a <= bj + b) t.emplace_back(bi + a, bj + b, 1.0);
    }
  SparseMatrix P(X.rows(), X.cols());
  P.setFromTriplets(t.begin(), t.end(), [](double a, double) { return a; });
  return P;
}

// The columns the shifted solve and the power iteration use: H_W^T D^-1/2 when a scale
// is set (scale_sqrt_inv not empty), else H_W^T itself (no copy on the unscaled path).
const SparseMatrix& scaled_columns(const SparseMatrix& HtW, const SparseMatrix& HtWs, const VecX& scale_sqrt_inv) {
  return scale_sqrt_inv.size() > 0 ? HtWs : HtW;
}

}  // namespace

void select_contact_columns(const SparseMatrix& Ht, const std::vector<int>& ids, SparseMatrix& out) {
  const int m = static_cast<int>(ids.size());
  out.resize(Ht.rows(), 3 * m);
  Eigen::VectorXi per_column(3 * m);
  for (int b = 0; b < m; ++b)
    for (int r = 0; r < 3; ++r) {
      const int j = 3 * ids[b] + r;
      per_column[3 * b + r] = Ht.outerIndexPtr()[j + 1] - Ht.outerIndexPtr()[j];
    }
  out.reserve(per_column);
  for (int b = 0; b < m; ++b)
    for (int r = 0; r < 3; ++r)
      for (SparseMatrix::InnerIterator it(Ht, 3 * ids[b] + r); it; ++it) out.insert(it.row(), 3 * b + r) = it.value();
  out.makeCompressed();
}

void SparseDelassus::bind(integrator::LinearSolver& A_solver, const SparseMatrix& A_upper, const SparseMatrix& Ht,
                          double h, const integrator::SolverOptions& options) {
  SOFTDIFF_DEMAND(A_upper.rows() == Ht.rows() && Ht.cols() % 3 == 0, "SparseDelassus::bind: sizes");
  A_solver_ = &A_solver;
  A_ = &A_upper;
  Ht_ = &Ht;
  h_ = h;
  nc_ = static_cast<int>(Ht.cols() / 3);
  options_ = options;
  failed_ = false;
  assembly_seconds_ = factorization_seconds_ = 0;
  Kt_.resize(0, Ht.cols());
  restrict_to_all();
}

void SparseDelassus::set_rigid(const MatX& Kt, const MatX* Kt_more) {
  const Eigen::Index bound = Ht_->cols();
  const Eigen::Index cols = std::max({Kt.rows() > 0 ? Kt.cols() : 0, Kt_more && Kt_more->rows() > 0 ? Kt_more->cols() : 0, bound});
  auto check = [&](const MatX& K) {
    SOFTDIFF_DEMAND(K.rows() == 0 || (K.cols() >= bound && K.cols() % 3 == 0),
                    "SparseDelassus::set_rigid: expected at least " + std::to_string(bound) +
                        " columns (a multiple of 3), got " + std::to_string(K.cols()));
  };
  check(Kt);
  if (Kt_more) check(*Kt_more);
  if (cols > bound) {  // rows without soft dofs after the contacts: Ht with zero columns
    Ht_padded_ = *Ht_;
    Ht_padded_.conservativeResize(Ht_padded_.rows(), cols);
    Ht_padded_.makeCompressed();
    Ht_ = &Ht_padded_;
    nc_ = static_cast<int>(cols / 3);
    restrict_to_all();
  }
  Eigen::Index k = 0;
  for (Eigen::Index r = 0; r < Kt.rows(); ++r) k += Kt.row(r).squaredNorm() > 0;
  if (Kt_more)
    for (Eigen::Index r = 0; r < Kt_more->rows(); ++r) k += Kt_more->row(r).squaredNorm() > 0;
  Kt_.setZero(k, cols);
  k = 0;
  for (Eigen::Index r = 0; r < Kt.rows(); ++r)
    if (Kt.row(r).squaredNorm() > 0) Kt_.row(k++).head(Kt.cols()) = Kt.row(r);
  if (Kt_more)
    for (Eigen::Index r = 0; r < Kt_more->rows(); ++r)
      if (Kt_more->row(r).squaredNorm() > 0) Kt_.row(k++).head(Kt_more->cols()) = Kt_more->row(r);
  select_rigid_columns();
  scale_sqrt_inv_.resize(0);
  pattern_ready_ = false;
  c_ = 0;
}

void SparseDelassus::select_rigid_columns() {
  const Eigen::Index m = static_cast<Eigen::Index>(W_.size());
  KtW_.resize(Kt_.rows(), 3 * m);
  if (Kt_.rows() > 0)
    for (Eigen::Index b = 0; b < m; ++b) KtW_.middleCols<3>(3 * b) = Kt_.middleCols<3>(3 * W_[b]);
  soft_empty_ = HtW_.nonZeros() == 0;
}

void SparseDelassus::restrict_to_all() {
  W_.resize(static_cast<std::size_t>(nc_));
  for (int i = 0; i < nc_; ++i) W_[i] = i;
  HtW_ = *Ht_;
  select_rigid_columns();
  scale_sqrt_inv_.resize(0);  // unscaled: HtWs_ is not used
  pattern_ready_ = false;
  c_ = 0;
}

void SparseDelassus::restrict_to(const std::vector<int>& W) {
  const auto t0 = Clock::now();
  W_ = W;
  select_contact_columns(*Ht_, W, HtW_);
  select_rigid_columns();
  assembly_seconds_ += seconds_since(t0);
  scale_sqrt_inv_.resize(0);  // unscaled: HtWs_ is not used
  pattern_ready_ = false;
  c_ = 0;
}

void SparseDelassus::contact_compliance(Eigen::Ref<VecX> d) const {
  const int m = static_cast<int>(W_.size());
  SOFTDIFF_DEMAND(d.size() == m, "SparseDelassus::contact_compliance: expected " + std::to_string(m) +
                                     " contacts, got " + std::to_string(d.size()));
  if (!mass_ || mass_->size() != HtW_.rows()) {
    d.setOnes();
    return;
  }
  d.setZero();
  const VecX& mass = *mass_;
  for (int b = 0; b < m; ++b) {
    double t = 0;
    for (int r = 0; r < 3; ++r)
      for (SparseMatrix::InnerIterator it(HtW_, 3 * b + r); it; ++it) t += it.value() * it.value() / mass[it.row()];
    d[b] = h_ * t / 3;
  }
  // The rigid part of G_ii exactly: h |K_i|^2 (unit mass).
  if (KtW_.rows() > 0)
    for (int b = 0; b < m; ++b) d[b] += h_ * KtW_.middleCols<3>(3 * b).squaredNorm() / 3;
}

void SparseDelassus::set_scale(const Eigen::Ref<const VecX>& d) {
  const Eigen::Index m = static_cast<Eigen::Index>(W_.size());
  SOFTDIFF_DEMAND(d.size() == m && (m == 0 || d.minCoeff() > 0),
                  "SparseDelassus::set_scale: expected " + std::to_string(m) + " positive values");
  const auto t0 = Clock::now();
  scale_sqrt_inv_.resize(3 * m);
  for (Eigen::Index b = 0; b < m; ++b) scale_sqrt_inv_.segment<3>(3 * b).setConstant(1 / std::sqrt(d[b]));
  HtWs_ = HtW_ * scale_sqrt_inv_.asDiagonal();
  KtWs_ = KtW_ * scale_sqrt_inv_.asDiagonal();
  assembly_seconds_ += seconds_since(t0);
  pattern_ready_ = false;  // H~^T H~ changes (the pattern does not)
  c_ = 0;
}

void SparseDelassus::set_frames(const std::vector<Mat3>& frames, const Eigen::Ref<const VecX>& s) {
  const Eigen::Index m = static_cast<Eigen::Index>(W_.size());
  SOFTDIFF_DEMAND(static_cast<Eigen::Index>(frames.size()) == m && s.size() == 3 * m && (m == 0 || s.minCoeff() >= 0),
                  "SparseDelassus::set_frames: expected " + std::to_string(m) + " frames and " +
                      std::to_string(3 * m) + " non-negative weights");
  // Z = blockdiag(frames[b]^T) diag(s): the columns of H_W^T R^T diag(s) = HtW_ Z.
  std::vector<Eigen::Triplet<double, int>> t;
  t.reserve(static_cast<std::size_t>(9 * m));
  for (Eigen::Index b = 0; b < m; ++b)
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        if (s[3 * b + j] != 0 && frames[b](j, i) != 0)
          t.emplace_back(static_cast<int>(3 * b + i), static_cast<int>(3 * b + j), frames[b](j, i) * s[3 * b + j]);
  SparseMatrix Z(3 * m, 3 * m);
  Z.setFromTriplets(t.begin(), t.end());
  HtWs_ = HtW_ * Z;
  KtWs_ = KtW_ * Z;
  scale_sqrt_inv_ = s;
  pattern_ready_ = false;
  c_ = 0;
}

bool SparseDelassus::product(const Eigen::Ref<const VecX>& y, const SparseMatrix& soft_rows, const MatX& rigid_rows,
                             Eigen::Ref<VecX> out) {
  if (soft_empty_) {
    out.setZero();
  } else {
    u_.noalias() = HtW_ * y;
    if (!A_solver_->solve(u_, w_)) {  // w_ is not defined then: out is NaN, not stale
      failed_ = true;
      out.setConstant(std::numeric_limits<double>::quiet_NaN());
      return false;
    }
    out.noalias() = h_ * (soft_rows.transpose() * w_);
  }
  if (KtW_.rows() > 0) {  // + h K_rows K_W^T y
    kr_.noalias() = KtW_ * y;
    out.noalias() += h_ * (rigid_rows.transpose() * kr_);
  }
  return true;
}

bool SparseDelassus::apply(const Eigen::Ref<const VecX>& y, Eigen::Ref<VecX> out) {
  return product(y, HtW_, KtW_, out);
}

bool SparseDelassus::apply_full(const Eigen::Ref<const VecX>& y, Eigen::Ref<VecX> out) {
  return product(y, *Ht_, Kt_, out);
}

bool SparseDelassus::dense(MatX& G) {
  const auto t0 = Clock::now();
  bool ok = true;
  if (soft_empty_) {
    G.setZero(HtW_.cols(), HtW_.cols());
  } else {
    ok = A_solver_->inverse_congruence(HtW_, G);
    failed_ = failed_ || !ok;
    G *= h_;
  }
  if (KtW_.rows() > 0) G.noalias() += h_ * (KtW_.transpose() * KtW_);
  assembly_seconds_ += seconds_since(t0);
  return ok;
}

void SparseDelassus::build_pattern() {
  const auto t0 = Clock::now();
  // P = H~_W^T H~_W, upper triangle (H~ = D^-1/2 H: the same pattern as H's).
  const SparseMatrix& Hs = scaled_columns(HtW_, HtWs_, scale_sqrt_inv_);
  const SparseMatrix full = Hs * Hs.transpose();
  const SparseMatrix P = full.triangularView<Eigen::Upper>();
  const SparseMatrix blocks = node_block_pattern(P);
  ShiftedStorage& st = *storage_;
  bool contained = st.analyzed && st.S.rows() == A_->rows() && scatter_into(blocks, st.S, st.p_values);  // (a test)
  if (!contained) {
    // S = S (or A's pattern, the first time) + P's node blocks; analyzed once.
    SparseMatrix base = st.analyzed && st.S.rows() == A_->rows() ? ones_like(st.S) : ones_like(*A_);
    st.S = base + blocks;
    st.S.makeCompressed();
    if (!st.solver) st.solver = integrator::make_linear_solver(options_);
    st.solver->analyze(st.S);
    st.analyzed = true;
    ++analyses_;
  }
  SOFTDIFF_DEMAND(scatter_into(P, st.S, st.p_values), "SparseDelassus: H^T H outside the analyzed pattern");
  SOFTDIFF_DEMAND(scatter_into(*A_, st.S, st.a_values), "SparseDelassus: A outside the analyzed pattern");
  generation_ = ++st.generation;  // the storage's values are this operator's B
  pattern_ready_ = true;
  assembly_seconds_ += seconds_since(t0);
}

bool SparseDelassus::factorize_shifted(double c) {
  SOFTDIFF_DEMAND(c > 0, "SparseDelassus::factorize_shifted: the shift must be positive");
  c_ = 0;
  if (!soft_empty_) {
    // (another operator sharing the storage may have written its B since: its values again)
    if (!pattern_ready_ || !owns_storage()) build_pattern();
    ShiftedStorage& st = *storage_;
    const auto t0 = Clock::now();
    Eigen::Map<VecX>(st.S.valuePtr(), st.S.nonZeros()) = st.a_values + (h_ / c) * st.p_values;
    ++factorizations_;
    const bool ok = st.solver->factorize(st.S).ok;
    factorization_seconds_ += seconds_since(t0);
    if (!ok) return false;
  }
  c_ = c;
  const MatX& Ks = scaled_rigid();
  if (Ks.rows() == 0) return true;
  // The rigid rows' Woodbury terms: Z = M K~ (k soft shifted solves), C = I / h + K~^T Z
  // (k x k, symmetric positive definite: M is, and C >= I / h).
  const auto t0 = Clock::now();
  Z_ = Ks.transpose();
  bool ok = true;
  for (Eigen::Index j = 0; j < Z_.cols(); ++j) ok = shifted_soft(Z_.col(j)) && ok;
  MatX C = Ks * Z_;
  C.diagonal().array() += 1 / h_;
  capacitance_.compute(C);
  factorization_seconds_ += seconds_since(t0);
  if (!ok || capacitance_.info() != Eigen::Success) {
    c_ = 0;
    return false;
  }
  return true;
}

bool SparseDelassus::shifted_soft(Eigen::Ref<VecX> r) {
  if (soft_empty_) {
    r /= c_;
    return true;
  }
  const SparseMatrix& Hs = scaled_columns(HtW_, HtWs_, scale_sqrt_inv_);
  u_.noalias() = Hs * r;
  const bool ok = storage_->solver->solve(u_, w_);
  failed_ = failed_ || !ok;
  r.noalias() -= (h_ / c_) * (Hs.transpose() * w_);
  r /= c_;
  return ok;
}

void SparseDelassus::share_shifted_storage(const SparseDelassus& other) {
  if (storage_ != other.storage_) storage_ = other.storage_;
  generation_ = 0;
  pattern_ready_ = false;
  c_ = 0;
}

bool SparseDelassus::solve_shifted(Eigen::Ref<VecX> r) {
  SOFTDIFF_DEMAND(c_ > 0, "SparseDelassus::solve_shifted without factorize_shifted");
  // The shared storage holds another operator's B since factorize_shifted(c_): this one's
  // again (the same B, the same factorization; docs/method.md "The derivative's memory").
  if (!soft_empty_ && !owns_storage() && !factorize_shifted(c_)) {
    failed_ = true;
    r.setConstant(std::numeric_limits<double>::quiet_NaN());
    return false;
  }
  const bool scaled = scale_sqrt_inv_.size() == r.size();
  if (scaled) r.array() *= scale_sqrt_inv_.array();
  const bool ok = shifted_soft(r);
  const MatX& Ks = scaled_rigid();
  if (Ks.rows() > 0) {  // r <- M r - Z C^{-1} K~^T (M r)
    kr_.noalias() = Ks * r;
    capacitance_.solveInPlace(kr_);
    r.noalias() -= Z_ * kr_;
  }
  if (scaled) r.array() *= scale_sqrt_inv_.array();
  return ok;
}

double SparseDelassus::largest_eigenvalue(int iterations) {
  const Eigen::Index m = 3 * static_cast<Eigen::Index>(W_.size());
  if (m == 0) return 0;
  if (power_.size() != m || !(power_.norm() > 0)) {
    power_.resize(m);
    for (Eigen::Index k = 0; k < m; ++k) power_[k] = 1.0 + 0.01 * static_cast<double>(k % 7);
  }
  power_ /= power_.norm();
  power_next_.resize(m);
  double L = 0;
  for (int it = 0; it < iterations; ++it) {
    // power_next = D^-1/2 G_WW D^-1/2 power_ = h H~ A^{-1} H~^T power_.
    // (+ h K~ K~^T power_ for the rigid rows)
    if (soft_empty_) {
      power_next_.setZero();
    } else {
      const SparseMatrix& Hs = scaled_columns(HtW_, HtWs_, scale_sqrt_inv_);
      u_.noalias() = Hs * power_;
      const bool ok = A_solver_->solve(u_, w_);
      failed_ = failed_ || !ok;
      if (!ok) break;
      power_next_.noalias() = h_ * (Hs.transpose() * w_);
    }
    const MatX& Ks = scaled_rigid();
    if (Ks.rows() > 0) {
      kr_.noalias() = Ks * power_;
      power_next_.noalias() += h_ * (Ks.transpose() * kr_);
    }
    const double n = power_next_.norm();
    if (!(n > 0) || !std::isfinite(n)) break;
    L = n;
    power_ = power_next_ / n;
  }
  last_eigenvalue_ = L;
  return L;
}

}  // namespace softdiff::contact
