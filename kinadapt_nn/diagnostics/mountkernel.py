"""The calibration fit's per-row kernel (numba): the normal equations of ``mount._project`` built
row by row, without the (n, 6, k) design array.

The variable-projection fit (``mount._gauss_newton``) solves for ``theta`` at every trial rotation:
a weakly turned sensor's mirror branch takes tens of thousands of such solves, and the numpy
version allocates and fills the (n, 6, 10) design each time (~4-6 ms for 2000 rows; this kernel:
~0.1 ms). The design of one row is ``mount._dense_part``'s (its docstring has the model): the
columns [m, m c] (4) and, on a moving log, the inertia nuisance ``dI`` (6), then the offset's six
identity columns. ``tests/diagnostics/test_mount_kernel.py`` checks both against the numpy design.

Inputs are already in the trial frame: ``ga``, ``om``, ``al`` (n, 3) = the declared-frame vectors
times ``D`` (rows ``D^T v``); ``I_O`` (3, 3) [kg m^2] the declared inertia; ``r`` (n, 6) [N, N m]
the measured wrench; ``w`` (6,) the channel weights [1/N, 1/(N m)]; ``rw`` (n, 6) the robust row
weights (Huber IRLS).
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
def _row(ga, om, al, I_O, moves, A, c):
    """One sample's design ``A`` (6, 10) (columns: m, m c, dI when ``moves``) and the declared
    inertia's terms ``c`` (6,)."""
    for i in range(6):
        c[i] = 0.0
        for j in range(10):
            A[i, j] = 0.0
    w2 = om[0] * om[0] + om[1] * om[1] + om[2] * om[2]
    for i in range(3):
        A[i, 0] = ga[i]
        for j in range(3):
            A[i, 1 + j] = -om[i] * om[j]
        A[i, 1 + i] += w2
    # F: - alpha x (m c)
    A[0, 2] += al[2]
    A[0, 3] -= al[1]
    A[1, 1] -= al[2]
    A[1, 3] += al[0]
    A[2, 1] += al[1]
    A[2, 2] -= al[0]
    # M: (m c) x g_a = -[g_a]x (m c)
    A[3, 2], A[3, 3], A[4, 3] = ga[2], -ga[1], ga[0]
    A[4, 1], A[5, 1], A[5, 2] = -ga[2], ga[1], -ga[0]
    # c_M = -I_O alpha - omega x (I_O omega)
    Iw0 = I_O[0, 0] * om[0] + I_O[0, 1] * om[1] + I_O[0, 2] * om[2]
    Iw1 = I_O[1, 0] * om[0] + I_O[1, 1] * om[1] + I_O[1, 2] * om[2]
    Iw2 = I_O[2, 0] * om[0] + I_O[2, 1] * om[1] + I_O[2, 2] * om[2]
    c[3] = -(I_O[0, 0] * al[0] + I_O[0, 1] * al[1] + I_O[0, 2] * al[2]) - (om[1] * Iw2 - om[2] * Iw1)
    c[4] = -(I_O[1, 0] * al[0] + I_O[1, 1] * al[1] + I_O[1, 2] * al[2]) - (om[2] * Iw0 - om[0] * Iw2)
    c[5] = -(I_O[2, 0] * al[0] + I_O[2, 1] * al[1] + I_O[2, 2] * al[2]) - (om[0] * Iw1 - om[1] * Iw0)
    if moves:
        # dI v for the symmetric basis [xx, yy, zz, xy, xz, yz]: columns of L(v)
        for col in range(6):
            a0 = a1 = a2 = 0.0  # L(al)[:, col]
            v0 = v1 = v2 = 0.0  # L(om)[:, col]
            if col == 0:
                a0, v0 = al[0], om[0]
            elif col == 1:
                a1, v1 = al[1], om[1]
            elif col == 2:
                a2, v2 = al[2], om[2]
            elif col == 3:
                a0, a1, v0, v1 = al[1], al[0], om[1], om[0]
            elif col == 4:
                a0, a2, v0, v2 = al[2], al[0], om[2], om[0]
            else:
                a1, a2, v1, v2 = al[2], al[1], om[2], om[1]
            A[3, 4 + col] = -(a0 + om[1] * v2 - om[2] * v1)
            A[4, 4 + col] = -(a1 + om[2] * v0 - om[0] * v2)
            A[5, 4 + col] = -(a2 + om[0] * v1 - om[1] * v0)


@nb.njit(cache=True)
def normal_equations(ga, om, al, I_O, r, w, rw, moves):
    """-> (H (k+6, k+6), g (k+6,)) of the weighted least squares in [m, m c, (dI), b] (k = 4, or 10
    when ``moves``): ``mount._project``'s normal equations, without its 1e-12 ridge."""
    k = 10 if moves else 4
    H = np.zeros((k + 6, k + 6))
    g = np.zeros(k + 6)
    A = np.empty((6, 10))
    c = np.empty(6)
    for n in range(ga.shape[0]):
        _row(ga[n], om[n], al[n], I_O, moves, A, c)
        for ch in range(6):
            s = w[ch] * w[ch] * rw[n, ch]
            y = r[n, ch] - c[ch]
            for a in range(k):
                sa = s * A[ch, a]
                if sa == 0.0:
                    continue
                g[a] += sa * y
                for b in range(a, k):
                    H[a, b] += sa * A[ch, b]
                H[a, k + ch] += sa
            H[k + ch, k + ch] += s
            g[k + ch] += s * y
    for a in range(k + 6):
        for b in range(a):
            H[a, b] = H[b, a]
    return H, g


@nb.njit(cache=True)
def weighted_residual(ga, om, al, I_O, r, w, sol, moves):
    """-> (n*6,) ``(r - c - A sol[:k] - sol[k:]) * w`` row-major: ``mount._project``'s residual for
    the solution ``sol`` (k+6,) of :func:`normal_equations`."""
    k = 10 if moves else 4
    n_rows = ga.shape[0]
    e = np.empty(n_rows * 6)
    A = np.empty((6, 10))
    c = np.empty(6)
    for n in range(n_rows):
        _row(ga[n], om[n], al[n], I_O, moves, A, c)
        for ch in range(6):
            p = c[ch] + sol[k + ch]
            for a in range(k):
                p += A[ch, a] * sol[a]
            e[n * 6 + ch] = (r[n, ch] - p) * w[ch]
    return e


#: the diagnosis's numba kernels (compiled once per machine, then loaded from numba's cache)
KERNELS = (normal_equations, weighted_residual)


def cached() -> bool:
    """False when a kernel still has to be compiled (the first diagnosis on a machine: ~5 s on 2
    cores), so that the command can say so; True also when numba's cache cannot be read."""
    try:
        return all(bool(f._cache._cache_file._load_index()) for f in KERNELS)
    except Exception:  # numba's cache internals moved: say nothing
        return True
