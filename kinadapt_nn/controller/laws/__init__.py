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
from kinadapt_nn.controller.laws.base import AdaptStep, LawParams, LawSpec, LawState, LawView, lookup, registry
from kinadapt_nn.errors import ConfigError

#: every law by name, the default first (the config's ``adaptation.mode``)
LAWS: dict[str, LawSpec] = registry(
    kalman.LAW,
    composite.LAW,
    prediction.LAW,
    tracking.LAW,
    frozen.LAW,
)


def law_spec(name: str) -> LawSpec:
    """The registered law ``name`` (a ConfigError listing the choices otherwise)."""
    return lookup(LAWS, name)


def law_params(adaptation: AdaptationCfg, name: str, dt_s: float, prior_cov: np.ndarray) -> LawParams:
    """The parameters of the registered law ``name`` (its ``Params``, ``LawSpec.params_of``), after
    checking every table ``[adaptation.params.<law>]`` of the config: each names a registered law
    and holds valid values for it (a one-line ConfigError otherwise)."""
    for other in adaptation.params:
        if other not in LAWS:
            raise ConfigError(f"config key 'adaptation.params.{other}': {other!r} is not a registered law "
                              f"(choose from {', '.join(LAWS)})")
        if other != name:
            LAWS[other].params_of(adaptation, dt_s, prior_cov)
    return law_spec(name).params_of(adaptation, dt_s, prior_cov)


__all__ = ["LAWS", "AdaptStep", "LawParams", "LawSpec", "LawState", "LawView", "law_params", "law_spec"]
