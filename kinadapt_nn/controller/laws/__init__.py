"""The adaptation laws: one module per law, one registry.

Every law fulfils the contract of ``laws/base.py`` (a numba ``step`` and a ``LawSpec``). The
controller's kernels call the step of the law a config names (``adaptation.mode``) through its
address, so one compiled kernel serves every law; ``controller.standalone.StandaloneLaw`` runs the
same step outside the controller. Adding a law: one new module and one line in ``LAWS`` below
(docs/architecture.md, "Adding a law").
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.config import AdaptationCfg
from kinadapt_nn.controller.laws import composite, frozen, kalman, prediction, tracking
from kinadapt_nn.controller.laws.base import AdaptStep, LawParams, LawSpec, LawState, LawView, registry
from kinadapt_nn.errors import registered

#: every law by name, the default first (the config's ``adaptation.mode``)
LAWS: dict[str, LawSpec] = registry(
    kalman.LAW,
    composite.LAW,
    prediction.LAW,
    tracking.LAW,
    frozen.LAW,
)


def law_spec(name: str) -> LawSpec:
    """The registered law ``name`` (a one-line ConfigError listing the choices and the closest otherwise)."""
    return registered(LAWS, name, "adaptation mode ", "law")


def law_of(adaptation: AdaptationCfg, name: str, dt_s: float, prior_cov: np.ndarray) -> tuple[LawSpec, LawParams]:
    """The registered law ``name`` and its parameters (its ``Params``, ``LawSpec.params_of``), after
    checking every table ``[adaptation.params.<law>]`` of the config: each names a registered law
    and holds valid values for it (a one-line ConfigError otherwise)."""
    for other in adaptation.params:
        spec = registered(LAWS, other, f"config key 'adaptation.params.{other}': ", "law")
        if other != name:
            spec.params_of(adaptation, dt_s, prior_cov)
    spec = law_spec(name)
    return spec, spec.params_of(adaptation, dt_s, prior_cov)


__all__ = ["LAWS", "AdaptStep", "LawParams", "LawSpec", "LawState", "LawView", "law_of", "law_spec"]
