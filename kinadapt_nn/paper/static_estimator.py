"""The static wrench-balance offset estimator of Remark ft_static (a foil for the law).

An ideal point contact at the tip gives ``M = r x F``; the "obvious" estimator solves this
balance for ``r`` by least squares over the contact samples, in the flange frame:
``-[F_w]x R_wf r_f = M_w``. Any contact *couple* (friction, a patch, constraint reactions --
the socket's angular spring here) is not a lever moment, so the balance's zero is not at the
true offset. Offline, from a trace's ``w_env_w`` (wrench tool -> environment about O; the
moment obeys the same balance) and ``q_rad`` (for ``R_wf``).
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.geometry import skew


def static_offset_estimate(trace, kin_fn, min_force_N: float = 1.0) -> np.ndarray | None:
    """LS offset (3,) in f from all samples with |F| >= min_force_N; None if too few."""
    w = trace["w_env_w"]
    fmag = np.linalg.norm(w[:, :3], axis=1)
    idx = np.flatnonzero(fmag >= min_force_N)
    if len(idx) < 10:
        return None
    A, b = [], []
    for i in idx[:: max(1, len(idx) // 2000)]:
        R = kin_fn(trace["q_rad"][i]).R_wf
        A.append(-skew(w[i, :3]) @ R)
        b.append(w[i, 3:])
    x, *_ = np.linalg.lstsq(np.vstack(A), np.concatenate(b), rcond=None)
    return x
