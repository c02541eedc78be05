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
from kinadapt_nn.errors import ConfigError, did_you_mean

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
    spec = LAWS.get(name)
    if spec is None:
        hint = did_you_mean(name, LAWS)
        raise ConfigError(f"adaptation mode {name!r} is not a registered law (choose from {', '.join(LAWS)})"
                          f"{'; ' + hint if hint else ''}")
    return spec


def law_of(adaptation: AdaptationCfg, name: str, dt_s: float, prior_cov: np.ndarray) -> tuple[LawSpec, LawParams]:
    """The registered law ``name`` and its parameters (its ``Params``, ``LawSpec.params_of``), after
    checking every table ``[adaptation.params.<law>]`` of the config: each names a registered law
    and holds valid values for it (a one-line ConfigError otherwise)."""
    for other in adaptation.params:
        if other not in LAWS:
            raise ConfigError(f"config key 'adaptation.params.{other}': {other!r} is not a registered law "
                              f"(choose from {', '.join(LAWS)})")
        if other != name:
            LAWS[other].params_of(adaptation, dt_s, prior_cov)
    spec = law_spec(name)
    return spec, spec.params_of(adaptation, dt_s, prior_cov)


__all__ = ["LAWS", "AdaptStep", "LawParams", "LawSpec", "LawState", "LawView", "law_of", "law_spec"]
