"""Parameterisations ``J_hat = Y(q) theta`` of the sensor Jacobian: one module per type, one registry.

Every type fulfils the contract of ``features/registry.py`` (a ``Features`` subclass, a ``build``
and a ``FeaturesSpec``). The run side builds the type a config names (``run.features``) through
:func:`features_spec`. Adding a type: one new module and one line in ``FEATURES`` below
(docs/architecture.md, "Adding a features type").
"""

from kinadapt_nn.features import adjoint, neural, oracle, rbf
from kinadapt_nn.features.adjoint import AdjointFeatures
from kinadapt_nn.features.base import Features, KinState
from kinadapt_nn.errors import registered
from kinadapt_nn.features.registry import Built, FeaturesContext, FeaturesSpec, Workspace, registry

#: every features type by name, the default first (the config's ``run.features``)
FEATURES: dict[str, FeaturesSpec] = registry(
    adjoint.SPEC,
    rbf.SPEC,
    neural.SPEC,
    oracle.SPEC,
)


def features_spec(name: str, key: str = "run.features") -> FeaturesSpec:
    """The registered features type ``name`` (a one-line ConfigError on config key ``key``
    listing the choices and the closest otherwise)."""
    return registered(FEATURES, name, f"config key '{key}': ", "features type")


def compared_types() -> list[str]:
    """The types compared by default (``kinadapt compare``, ``kinadapt reproduce``): every
    registered one but the baselines (the oracle), in registry order."""
    return [name for name, spec in FEATURES.items() if not spec.baseline]


__all__ = ["FEATURES", "AdjointFeatures", "Built", "Features", "FeaturesContext", "FeaturesSpec", "KinState",
           "Workspace", "compared_types", "features_spec"]
