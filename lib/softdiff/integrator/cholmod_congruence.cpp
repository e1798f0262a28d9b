// See cholmod_congruence.hpp.
#include <softdiff/integrator/cholmod_congruence.hpp>

#include <cholmod.h>

#include <algorithm>

namespace softdiff::integrator {

namespace {

void grow(std::vector<double>& v, std::ptrdiff_t n) {
  if (static_cast<std::ptrdiff_t>(v.size()) < n) v.resize(n);
}
// Dst = Src^T by 32 x 32 tiles.
void transpose_into(const Eigen::Map<MatX>& S, Eigen::Map<MatX>& D) {
  const Eigen::Index R = S.rows(), C = S.cols();
  constexpr Eigen::Index bk = 32;
  for (Eigen::Index j0 = 0; j0 < C; j0 += bk)
    for (Eigen::Index i0 = 0; i0 < R; i0 += bk) {
      const Eigen::Index j1 = std::min(C, j0 + bk), i1 = std::min(R, i0 + bk);
      for (Eigen::Index i = i0; i < i1; ++i)
        for (Eigen::Index j = j0; j < j1; ++j) D(j, i) = S(i, j);
    }
}
// G(i, j) = G(j, i) for i > j, by 32 x 32 tiles.
void mirror_upper(MatX& G) {
  const Eigen::Index m = G.rows();
  constexpr Eigen::Index bk = 32;
  for (Eigen::Index j0 = 0; j0 < m; j0 += bk)
    for (Eigen::Index i0 = j0; i0 < m; i0 += bk) {
      const Eigen::Index j1 = std::min(m, j0 + bk), i1 = std::min(m, i0 + bk);
      for (Eigen::Index i = i0; i < i1; ++i)
        for (Eigen::Index j = j0; j < std::min(j1, i); ++j) G(i, j) = G(j, i);
    }
}

}  // namespace

bool SupernodalCongruence::compute(const cholmod_factor_struct* L, const SparseMatrix& B, MatX& G) {
  if (!L || !L->is_super || !L->is_ll || L->itype != CHOLMOD_INT || L->xtype != CHOLMOD_REAL ||
      L->dtype != CHOLMOD_DOUBLE || !B.isCompressed() || static_cast<size_t>(B.rows()) != L->n)
    return false;
  if (!ready_) build_symbolic(L);
  if (!usable_) return false;
  const int m = static_cast<int>(B.cols());
  const int nsuper = static_cast<int>(L->nsuper);
  const int* super = static_cast<const int*>(L->super);
  const int* pi = static_cast<const int*>(L->pi);
  const int* px = static_cast<const int*>(L->px);
  const int* Ls = static_cast<const int*>(L->s);
  const double* Lx = static_cast<const double*>(L->x);
  const int* Bp = B.outerIndexPtr();
  const int* Bi = B.innerIndexPtr();
  const double* Bx = B.valuePtr();
  const int nnzB = Bp[m];
  G.resize(m, m);
  if (m == 0) return true;

  // ---- 1. distinct rows of B, sorted by permuted index (pos_ is all -1 between calls)
  erow_.clear();
  for (int p = 0; p < nnzB; ++p)
    if (pos_[Bi[p]] == -1) { pos_[Bi[p]] = -2; erow_.push_back(Bi[p]); }
  std::sort(erow_.begin(), erow_.end(), [&](int a, int b) { return iperm_[a] < iperm_[b]; });
  const int r = static_cast<int>(erow_.size());
  if (r > max_rows_ratio * m) {
    for (int c = 0; c < r; ++c) pos_[erow_[c]] = -1;
    return false;
  }
  for (int c = 0; c < r; ++c) pos_[erow_[c]] = c;
  Wi_.resize(nnzB);
  for (int p = 0; p < nnzB; ++p) Wi_[p] = pos_[Bi[p]];
  for (int c = 0; c < r; ++c) pos_[erow_[c]] = -1;

  // ---- column ranges per supernode: columns starting in supernodes sfirst[s] .. s
  cnt_.assign(nsuper + 1, 0);
  for (int c = 0; c < r; ++c) ++cnt_[snode_[iperm_[erow_[c]]] + 1];
  for (int s = 0; s < nsuper; ++s) cnt_[s + 1] += cnt_[s];
  clo_.resize(nsuper); chi_.resize(nsuper); off_.resize(nsuper + 1);
  off_[0] = 0;
  double flops = 0;
  int ncmax = 0;
  for (int s = 0; s < nsuper; ++s) {
    clo_[s] = cnt_[sfirst_[s]];
    chi_[s] = cnt_[s + 1];
    const double nc = chi_[s] - clo_[s], a = super[s + 1] - super[s], b = pi[s + 1] - pi[s] - a;
    off_[s + 1] = off_[s] + static_cast<std::ptrdiff_t>(a * nc);
    flops += nc * (a * a + 2 * a * b) + a * nc * nc;
    ncmax = std::max(ncmax, chi_[s] - clo_[s]);
  }
  flops += 2.0 * r * nnzB + 1.0 * m * nnzB;                 // W^T Z W (upper bound)
  if (flops > decline_ratio * 4.0 * lnz_ * m) return false; // the dense block solves are cheaper

  // ---- 2. Y = L^{-1} P E on the reach only; Z = Y^T Y (lower triangle)
  const std::ptrdiff_t ynnz = off_[nsuper];
  grow(y_, ynnz);
  std::fill(y_.begin(), y_.begin() + ynnz, 0.0);
  for (int c = 0; c < r; ++c) {
    const int k = iperm_[erow_[c]], s = snode_[k];
    y_[off_[s] + static_cast<std::ptrdiff_t>(c - clo_[s]) * (super[s + 1] - super[s]) + (k - super[s])] = 1.0;
  }
  const std::ptrdiff_t ulen = static_cast<std::ptrdiff_t>(L->maxesize) * ncmax;
  grow(u_, ulen);
  grow(zbuf_, std::ptrdiff_t(r) * r);
  Eigen::Map<MatX> Z(zbuf_.data(), r, r);
  Z.setZero();
  for (int s = 0; s < nsuper; ++s) {
    const int nc = chi_[s] - clo_[s];
    if (nc == 0) continue;
    const int k1 = super[s], nscol = super[s + 1] - k1, nsrow = pi[s + 1] - pi[s], nsrow2 = nsrow - nscol;
    const Eigen::Map<const MatX, 0, Eigen::OuterStride<>> Lsn(Lx + px[s], nsrow, nscol, Eigen::OuterStride<>(nsrow));
    Eigen::Map<MatX> Y(y_.data() + off_[s], nscol, nc);
    Lsn.topRows(nscol).triangularView<Eigen::Lower>().solveInPlace(Y);
    Z.block(clo_[s], clo_[s], nc, nc).selfadjointView<Eigen::Lower>().rankUpdate(Y.transpose());
    if (nsrow2 == 0) continue;
    Eigen::Map<MatX> U(u_.data(), nsrow2, nc);
    U.noalias() = Lsn.bottomRows(nsrow2) * Y;
    const int* rows = Ls + pi[s] + nscol;                   // sorted; ancestors of s
    for (int i = 0; i < nsrow2;) {
      const int t = snode_[rows[i]], tk1 = super[t], tk2 = super[t + 1], tncol = tk2 - tk1;
      int i2 = i + 1;
      while (i2 < nsrow2 && rows[i2] < tk2) ++i2;
      double* Yt = y_.data() + off_[t] + static_cast<std::ptrdiff_t>(clo_[s] - clo_[t]) * tncol - tk1;
      for (int q = 0; q < nc; ++q) {
        const double* uq = u_.data() + static_cast<std::ptrdiff_t>(q) * nsrow2;
        double* yq = Yt + static_cast<std::ptrdiff_t>(q) * tncol;
        for (int ii = i; ii < i2; ++ii) yq[rows[ii]] -= uq[ii];
      }
      i = i2;
    }
  }
  Z.triangularView<Eigen::StrictlyUpper>() = Z.transpose();

  // ---- 3. G = W^T Z W
  // tree range (in E positions) of each E row: Z(:, c) is zero outside it
  tlo_.resize(r); thi_.resize(r);
  for (int c = 0; c < r; ++c) {
    const int root = stree_[snode_[iperm_[erow_[c]]]];
    tlo_[c] = clo_[root]; thi_[c] = chi_[root];
  }
  grow(tbuf_, std::ptrdiff_t(r) * m);
  grow(ttbuf_, std::ptrdiff_t(r) * m);
  Eigen::Map<MatX> T(tbuf_.data(), r, m), Tt(ttbuf_.data(), m, r);
  for (int j = 0; j < m; ++j) {
    auto t = T.col(j);
    t.setZero();
    for (int p = Bp[j]; p < Bp[j + 1]; ++p) {
      const int c = Wi_[p], lo = tlo_[c], len = thi_[c] - lo;
      t.segment(lo, len).noalias() += Bx[p] * Z.col(c).segment(lo, len);
    }
  }
  // G(0..j, j) = sum_p W(k_p, j) T^T(0..j, k_p): contiguous axpys on the columns of Tt = T^T
  transpose_into(T, Tt);
  // by tiles of 64 rows of G, so that the rows of Tt in use (64 x r) stay in cache
  constexpr int tile = 64;
  for (int i0 = 0; i0 < m; i0 += tile) {
    const int i1 = std::min(m, i0 + tile);
    for (int j = i0; j < m; ++j) {
      const int len = std::min(i1, j + 1) - i0;
      auto g = G.col(j).segment(i0, len);
      g.setZero();
      for (int p = Bp[j]; p < Bp[j + 1]; ++p) g.noalias() += Bx[p] * Tt.col(Wi_[p]).segment(i0, len);
    }
  }
  mirror_upper(G);
  return true;
}

void SupernodalCongruence::build_symbolic(const cholmod_factor_struct* L) {
  ready_ = true;
  usable_ = false;
  const int n = static_cast<int>(L->n), nsuper = static_cast<int>(L->nsuper);
  const int* super = static_cast<const int*>(L->super);
  const int* pi = static_cast<const int*>(L->pi);
  const int* Ls = static_cast<const int*>(L->s);
  const int* perm = static_cast<const int*>(L->Perm);
  iperm_.resize(n); snode_.resize(n); pos_.assign(n, -1);
  for (int k = 0; k < n; ++k) iperm_[perm ? perm[k] : k] = k;
  for (int s = 0; s < nsuper; ++s)
    for (int k = super[s]; k < super[s + 1]; ++k) snode_[k] = s;
  sparent_.assign(nsuper, -1); sfirst_.resize(nsuper); stree_.resize(nsuper);
  std::vector<int> ndesc(nsuper, 1);
  lnz_ = 0;
  for (int s = 0; s < nsuper; ++s) {
    const int nscol = super[s + 1] - super[s], nsrow = pi[s + 1] - pi[s];
    lnz_ += double(nscol) * nsrow - 0.5 * double(nscol) * (nscol - 1);
    if (nsrow > nscol) sparent_[s] = snode_[Ls[pi[s] + nscol]];
    sfirst_[s] = s;
  }
  for (int s = 0; s < nsuper; ++s) {
    const int p = sparent_[s];
    if (p < 0) continue;
    if (p <= s) return;                                     // not topological: decline
    sfirst_[p] = std::min(sfirst_[p], sfirst_[s]);
    ndesc[p] += ndesc[s];
  }
  for (int s = 0; s < nsuper; ++s)
    if (ndesc[s] != s - sfirst_[s] + 1) return;             // not postordered: decline
  for (int s = nsuper - 1; s >= 0; --s) stree_[s] = sparent_[s] < 0 ? s : stree_[sparent_[s]];
  usable_ = true;
}

}  // namespace softdiff::integrator
