"""The oracle baseline: the adjoint at the TRUE offset, held fixed.

Not something a real cell can run -- it is the reference every adapted type is measured against
(its prediction error is the contact bias alone, ``paper/floor.py``). The truth it starts from is
the declared experiment-design input ``FeaturesContext.true_offset_f_m``; the frozen law keeps it.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.features.adjoint import nominal_adjoint
from kinadapt_nn.features.registry import Built, FeaturesContext, FeaturesSpec


def build(ctx: FeaturesContext) -> Built:
    """The adjoint (Omega about the nominal offset, no declared prior) at the true offset, under
    the frozen law whatever ``adaptation.mode`` says."""
    feats = nominal_adjoint(ctx.known, prior=False)
    feats.fixed_law = "frozen"
    return Built(feats, np.asarray(ctx.true_offset_f_m, dtype=float))


SPEC = FeaturesSpec(name="oracle", doc="the adjoint at the true offset, held (frozen law): the reference",
                    build=build, theta0_per_episode=True, baseline=True)
