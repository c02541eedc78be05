"""The adaptation laws: one module per law, one registry.

Every law fulfils the contract of ``laws/base.py`` (a numba ``step`` and a ``LawSpec``). The
controller's kernels call the step of the law a config names (``adaptation.mode``) through its
address, so one compiled kernel serves every law; ``controller.standalone.StandaloneLaw`` runs the
same step outside the controller. Adding a law: one new module and one line in ``LAWS`` below
(docs/architecture.md, "Adding a law").
"""

from __future__ import annotations

from kinadapt_nn.controller.laws import composite, frozen, kalman, prediction, tracking
from kinadapt_nn.controller.laws.base import AdaptStep, LawParams, LawSpec, LawState, LawView, lookup, registry

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


__all__ = ["LAWS", "AdaptStep", "LawParams", "LawSpec", "LawState", "LawView", "law_spec"]
