"""Model vs measurement: where the nominal model's prediction misses the sensor (``kinadapt diagnose``).

``residual.py`` recomputes, from raw logged channels only (time, joint positions and velocities,
the raw wrist wrench — a kinadapt trace or a CSV from a real robot), the sensor vector, its
measured rate and the model's predicted rate through the same filter, and analyses the residual
(the paper's bias ``b``) by channel, by contact phase and in time; ``importers.py`` reads the
documented CSV format.

The public effect contract (``kinadapt_nn.effects.contract``, a layer the controller's online columns
may import too): ``from kinadapt_nn.diagnostics import effect`` and decorate a function of the log's
signals (docs/missing_physics.md).
"""

from __future__ import annotations

from typing import Callable

from kinadapt_nn.diagnostics.setup import SetupCfg
from kinadapt_nn.effects import contract
from kinadapt_nn.effects.contract import Effect


def effect(*args, **kwargs) -> Callable[[Callable], Effect]:
    """The public ``@effect`` decorator (``kinadapt_nn.effects.contract.effect``, same arguments): an
    effect with ``params_for`` and no ``params`` shows the parameters of the diagnosis's default set-up
    (``SetupCfg()``) until ``Effect.for_setup`` fixes them for a log's."""
    kwargs.setdefault("default_setup", SetupCfg)
    return contract.effect(*args, **kwargs)


__all__ = ["Effect", "effect"]
