"""The frozen law: theta stays where it started (the oracle baseline and the compliant study
hold the Jacobian fixed). The kernel still computes the prediction error and logs the Gram."""

from __future__ import annotations

import numba as nb

from kinadapt_nn.controller.laws.base import LawSpec


@nb.njit(cache=True)
def step(theta, H_T, G, e, PhiF, lo, hi, consts, x, k, unc, d_track, d_pred):
    """theta unchanged (laws.base: the step contract). Returns 0."""
    return 0.0


LAW = LawSpec(name="frozen", doc="theta held fixed", step=step)
