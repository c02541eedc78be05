"""A law with a parameter of its own, in one file: sign-LMS (docs/architecture.md, "Adding a law").

Per control step in contact, with ``H = W Phi_f`` (m, p) and ``e = W (s_dot_meas - known_f -
Phi_f theta)`` (eq. ft_pred; the kernel's)::

    d_pred      = mu sign(H^T e)
    theta_{k+1} = Proj_Omega(theta_k + d_pred)

``mu`` is declared below (unit, default, bounds) and set in a config as::

    [adaptation]
    mode = "sign_lms"
    [adaptation.params.sign_lms]
    mu = 2e-5

Registering it is the second file's one line: ``LAWS[LAW.name] = LAW`` (or ``LAW`` in the
``registry(...)`` of ``kinadapt_nn/controller/laws/__init__.py``). The law keeps its last increment
(state block ``last``) and counts its steps (counter ``steps``) to show a law's own state.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from pydantic import Field

from kinadapt_nn.controller.laws.base import LawParams, LawSpec, project_omega


class Params(LawParams):
    """sign-LMS's own parameter."""

    mu: float = Field(1e-5, gt=0.0, le=1e-3)  # [theta's unit: m for the adjoint] step per sample in contact


def constants(params: Params, m: int, p: int) -> np.ndarray:
    """[mu] (1,)."""
    return np.array([params.mu])


def blocks(m: int, p: int) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """The law's state: its last increment (p,)."""
    return (("last", (p,)),)


@nb.njit(cache=True)
def step(theta, H_T, G, e, PhiF, lo, hi, consts, x, k, unc, d_track, d_pred):
    """theta = Proj_Omega(theta + mu sign(H^T e)) (laws.base: the step contract); x = d_pred,
    k[0] += 1. Returns 0 (no normalised step)."""
    p, m = H_T.shape
    th = theta.copy()
    for j in range(p):
        v = 0.0
        for i in range(m):
            v += H_T[j, i] * e[i]
        d_pred[j] = consts[0] * np.sign(v)
        th[j] += d_pred[j]
        x[j] = d_pred[j]
    k[0] += 1
    project_omega(th, lo, hi, theta)
    return 0.0


LAW = LawSpec(name="sign_lms", doc="sign-LMS with its own step mu (an example law)", step=step, params=Params,
              constants=constants, blocks=blocks, counters=("steps",))
