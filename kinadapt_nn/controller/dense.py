"""Small dense linear algebra for the per-step kernels (numba; p, m, n are small): no allocation
beyond scratch, loops where a BLAS call would cost more than the product. Used by the kernels
(``controller.core``) and by the laws (``controller.laws``)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


#: sizes up to which the small products sum in scalars (``v += a * b``; the adjoint's p = 3, the
#: 6 x 6 and 6 x n products) instead of sweeping rows, which vectorises long rows (the RBF's p in
#: the hundreds) but on short ones costs several times the arithmetic (a vectorised loop's set-up
#: per row); the same sums in the same order either way
SMALL = 8


@nb.njit(cache=True)
def chol(A, k):
    """In-place lower Cholesky of A[:k, :k]; False if not positive definite."""
    for j in range(k):
        d = A[j, j]
        for i in range(j):
            d -= A[j, i] * A[j, i]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        A[j, j] = d
        for i in range(j + 1, k):
            v = A[i, j]
            for r in range(j):
                v -= A[i, r] * A[j, r]
            A[i, j] = v / d
    return True


@nb.njit(cache=True)
def chol_solve(L, k, x):
    """Solve (L L^T) x = b in place (b given in x)."""
    for i in range(k):
        v = x[i]
        for r in range(i):
            v -= L[i, r] * x[r]
        x[i] = v / L[i, i]
    for i in range(k - 1, -1, -1):
        v = x[i]
        for r in range(i + 1, k):
            v -= L[r, i] * x[r]
        x[i] = v / L[i, i]


@nb.njit(cache=True)
def chol_solve_cols(L, k, X):
    """Solve (L L^T) X = B in place (B given in X (k, p)) for all p columns at once: per column
    the arithmetic of :func:`chol_solve`, swept along rows (contiguous, vectorised); up to
    :data:`SMALL` columns, column by column in scalars (the same arithmetic)."""
    p = X.shape[1]
    if p <= SMALL:
        for j in range(p):
            for i in range(k):
                v = X[i, j]
                for r in range(i):
                    v -= L[i, r] * X[r, j]
                X[i, j] = v / L[i, i]
            for i in range(k - 1, -1, -1):
                v = X[i, j]
                for r in range(i + 1, k):
                    v -= L[r, i] * X[r, j]
                X[i, j] = v / L[i, i]
        return
    for i in range(k):
        for r in range(i):
            Lir = L[i, r]
            for j in range(p):
                X[i, j] -= Lir * X[r, j]
        d = L[i, i]
        for j in range(p):
            X[i, j] /= d
    for i in range(k - 1, -1, -1):
        for r in range(i + 1, k):
            Lri = L[r, i]
            for j in range(p):
                X[i, j] -= Lri * X[r, j]
        d = L[i, i]
        for j in range(p):
            X[i, j] /= d


@nb.njit(cache=True)
def mm(A, B):
    """A @ B: by loops for the small products of the per-step maths (a BLAS call costs more than
    the product), by BLAS for large ones (p in the hundreds: the RBF features). Each loop entry is
    summed from 0.0 in r's order: in scalars for an inner dimension up to :data:`SMALL`, else by row
    sweeps (the same sums)."""
    if A.shape[0] * B.shape[1] > 400:
        return np.ascontiguousarray(A) @ np.ascontiguousarray(B)
    if A.shape[1] <= SMALL:
        out = np.empty((A.shape[0], B.shape[1]))
        for i in range(A.shape[0]):
            for j in range(B.shape[1]):
                v = 0.0
                for r in range(A.shape[1]):
                    v += A[i, r] * B[r, j]
                out[i, j] = v
        return out
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for r in range(A.shape[1]):
            a = A[i, r]
            for j in range(B.shape[1]):
                out[i, j] += a * B[r, j]
    return out


@nb.njit(cache=True)
def mm_nt(A, B):
    """A @ B.T: ``mm(A, B.T)`` (the same sums)."""
    return mm(A, B.T)


@nb.njit(cache=True)
def gram_lower(A, G):
    """The lower triangle of A @ A.T into G (k, k) (A (k, r)), each entry summed as ``mm_nt``'s loops
    sum it; the upper triangle is left as it is (a Cholesky reads the lower only; a product
    commutes exactly, so :func:`mirror_lower` then gives ``mm_nt(A, A)`` to the bit)."""
    k, r = A.shape
    for i in range(k):
        for j in range(i + 1):
            v = 0.0
            for c in range(r):
                v += A[i, c] * A[j, c]
            G[i, j] = v


@nb.njit(cache=True)
def mirror_lower(G):
    """G's upper triangle = its lower (k, k), in place."""
    for i in range(G.shape[0]):
        for j in range(i):
            G[j, i] = G[i, j]


@nb.njit(cache=True)
def dot(a, b):
    """sum_j a[j] b[j] (1-D) with four partial sums: a strict-IEEE reduction is one serial chain
    of adds (~4 cycles each); four chains run ~4x faster on the p ~ 200 rows of the RBF's law."""
    n = a.shape[0]
    v0 = v1 = v2 = v3 = 0.0
    j = 0
    while j + 4 <= n:
        v0 += a[j] * b[j]
        v1 += a[j + 1] * b[j + 1]
        v2 += a[j + 2] * b[j + 2]
        v3 += a[j + 3] * b[j + 3]
        j += 4
    while j < n:
        v0 += a[j] * b[j]
        j += 1
    return (v0 + v1) + (v2 + v3)


@nb.njit(cache=True)
def gram_sparse(A):
    """A @ A.T for A (p, m) with many zeros (the RBF's regressor: each parameter in one channel),
    from the non-zero entries of each column only; summed over the columns in order, as ``mm_nt``'s
    loops do. -> (p, p)."""
    return gram_sparse_log(A, np.empty((0, 0)))


@nb.njit(cache=True)
def gram_sparse_log(A, log):
    """:func:`gram_sparse`, and ``log += A @ A.T`` (``log`` (p, p); (0, 0): none) with the same
    roundings as adding the whole Gram: where the columns' non-zero rows are disjoint (the RBF:
    each parameter in one channel) only each column's block is added -- the Gram is exactly zero
    elsewhere --, else every (i, j) of the rows that have a non-zero. Each column's products go
    through a contiguous copy of its non-zeros, so a contiguous block's row update vectorises.
    -> the Gram (p, p)."""
    p, m = A.shape
    G = np.zeros((p, p))
    if p <= SMALL:
        return _gram_small(A, G, log)
    idx = np.empty((m, p), dtype=np.int64)  # per column: its non-zero rows, and how many
    cnt = np.zeros(m, dtype=np.int64)
    owner = np.full(p, -1, dtype=np.int64)
    disjoint = _gram_columns(A, G, idx, cnt, owner)
    if log.shape[0] == 0:
        return G
    if disjoint:
        _log_blocks(log, G, idx, cnt)
    else:
        _log_rows(log, G, owner)
    return G


@nb.njit(cache=True)
def _gram_small(A, G, log):
    """:func:`gram_sparse_log` for few rows: ``G += A @ A.T`` column by column, the products of two
    non-zeros only (the same sums, in the same order, as :func:`_gram_columns`), then ``log += G``
    everywhere -- G is +0.0 exactly where the listing adds nothing, and adding +0.0 changes no
    entry of the log (which never holds -0.0: it starts at +0.0 and adds such sums). -> G."""
    p, m = A.shape
    for r in range(m):
        for i in range(p):
            a = A[i, r]
            if a != 0.0:
                for j in range(p):
                    v = A[j, r]
                    if v != 0.0:
                        G[i, j] += a * v
    if log.shape[0] != 0:
        for i in range(p):
            for j in range(p):
                log[i, j] += G[i, j]
    return G


@nb.njit(cache=True)
def _gram_columns(A, G, idx, cnt, owner):
    """``G += A @ A.T`` column by column from each column's non-zeros (:func:`gram_sparse_log`);
    fills ``idx[r, :cnt[r]]`` (column r's non-zero rows) and ``owner`` (a row's last column).
    -> whether the columns' non-zero rows are disjoint."""
    p, m = A.shape
    disjoint = True
    col = np.empty(p)
    for r in range(m):
        nz = 0
        for i in range(p):
            if A[i, r] != 0.0:
                idx[r, nz] = i
                col[nz] = A[i, r]
                nz += 1
                if owner[i] >= 0:
                    disjoint = False
                owner[i] = r
        cnt[r] = nz
        if nz > 0:
            _add_outer(G, idx[r], nz, col)
    return disjoint


@nb.njit(cache=True)
def _add_outer(G, rows, nz, col):
    """``G[rows[a], rows[b]] += col[a] col[b]`` for a, b < nz; a contiguous block of rows by
    slices (the loops vectorise)."""
    j0 = rows[0]
    if rows[nz - 1] - j0 == nz - 1:
        for a in range(nz):
            Gi = G[j0 + a, j0:j0 + nz]
            v = col[a]
            for b in range(nz):
                Gi[b] += v * col[b]
    else:
        for a in range(nz):
            Gi = G[rows[a]]
            v = col[a]
            for b in range(nz):
                Gi[rows[b]] += v * col[b]


@nb.njit(cache=True)
def _log_blocks(log, G, idx, cnt):
    """``log += G`` on each column's block only (disjoint columns: G is exactly zero elsewhere)."""
    for r in range(idx.shape[0]):
        nz = cnt[r]
        if nz == 0:
            continue
        j0 = idx[r, 0]
        if idx[r, nz - 1] - j0 == nz - 1:
            for a in range(nz):
                Li, Gi = log[j0 + a, j0:j0 + nz], G[j0 + a, j0:j0 + nz]
                for b in range(nz):
                    Li[b] += Gi[b]
            continue
        for a in range(nz):
            i = idx[r, a]
            Li, Gi = log[i], G[i]
            for b in range(nz):
                j = idx[r, b]
                Li[j] += Gi[j]


@nb.njit(cache=True)
def _log_rows(log, G, owner):
    """``log += G`` on every (i, j) of the rows that have a non-zero (``owner >= 0``)."""
    p = owner.shape[0]
    rows = np.empty(p, dtype=np.int64)
    n_rows = 0
    for i in range(p):
        if owner[i] >= 0:
            rows[n_rows] = i
            n_rows += 1
    for a in range(n_rows):
        i = rows[a]
        Li, Gi = log[i], G[i]
        for b in range(n_rows):
            j = rows[b]
            Li[j] += Gi[j]


# slice assignment and array arithmetic compile to numba's broadcasting machinery (seconds of
# compile per layout); the kernels copy and fill by these loops instead
@nb.njit(cache=True)
def vcopy(dst, src):
    """dst[i] = src[i] (1-D, same length)."""
    for i in range(dst.shape[0]):
        dst[i] = src[i]


@nb.njit(cache=True)
def vfill(dst, v):
    """dst[i] = v (1-D)."""
    for i in range(dst.shape[0]):
        dst[i] = v


@nb.njit(cache=True)
def sym_eigmin(G):
    """The smallest eigenvalue of the symmetric G (k, k) by cyclic Jacobi rotations on a copy
    (small k: the 6x6 rank-gate Gram; converged to ~1e-15 relative to ||G||, at most 50 sweeps)."""
    k = G.shape[0]
    A = np.empty((k, k))
    for i in range(k):
        for j in range(k):
            A[i, j] = G[i, j]
    for _sweep in range(50):
        off, scale = 0.0, 0.0
        for i in range(k):
            scale += A[i, i] * A[i, i]
            for j in range(i + 1, k):
                off += A[i, j] * A[i, j]
        if off <= 1e-32 * scale or off == 0.0:
            break
        for pp in range(k - 1):
            for q in range(pp + 1, k):
                apq = A[pp, q]
                if apq == 0.0:
                    continue
                tau = (A[q, q] - A[pp, pp]) / (2.0 * apq)  # the rotation that zeroes A[p, q]
                t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + math.sqrt(1.0 + tau * tau))
                cs = 1.0 / math.sqrt(1.0 + t * t)
                sn = t * cs
                for r in range(k):  # A <- A J (columns p, q)
                    arp, arq = A[r, pp], A[r, q]
                    A[r, pp] = cs * arp - sn * arq
                    A[r, q] = sn * arp + cs * arq
                for r in range(k):  # A <- J^T A (rows p, q)
                    apr, aqr = A[pp, r], A[q, r]
                    A[pp, r] = cs * apr - sn * aqr
                    A[q, r] = sn * apr + cs * aqr
    lam = A[0, 0]
    for i in range(1, k):
        lam = min(lam, A[i, i])
    return lam
