"""Small dense linear algebra for the per-step kernels (numba; p, m, n are small): no allocation
beyond scratch, loops where a BLAS call would cost more than the product. Used by the kernels
(``controller.core``) and by the laws (``controller.laws``)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


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
def mm(A, B):
    """A @ B: by loops for the small products of the per-step maths (a BLAS call costs more than
    the product), by BLAS for large ones (p in the hundreds: the RBF features)."""
    if A.shape[0] * B.shape[1] > 400:
        return np.ascontiguousarray(A) @ np.ascontiguousarray(B)
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for r in range(A.shape[1]):
            a = A[i, r]
            for j in range(B.shape[1]):
                out[i, j] += a * B[r, j]
    return out


@nb.njit(cache=True)
def mm_nt(A, B):
    """A @ B.T (loops when small, as ``mm``)."""
    if A.shape[0] * B.shape[0] > 400:
        return np.ascontiguousarray(A) @ np.ascontiguousarray(B.T)
    out = np.empty((A.shape[0], B.shape[0]))
    for i in range(A.shape[0]):
        for j in range(B.shape[0]):
            v = 0.0
            for r in range(A.shape[1]):
                v += A[i, r] * B[j, r]
            out[i, j] = v
    return out
