"""Model vs measurement: where the nominal model's prediction misses the sensor (``kinadapt diagnose``).

``residual.py`` recomputes, from raw logged channels only (time, joint positions and velocities,
the raw wrist wrench — a kinadapt trace or a CSV from a real robot), the sensor vector, its
measured rate and the model's predicted rate through the same filter, and analyses the residual
(the paper's bias ``b``) by channel, by contact phase and in time; ``importers.py`` reads the
documented CSV format.

The public effect contract (``kinadapt_nn.diagnostics.contract``): ``from kinadapt_nn.diagnostics
import effect`` and decorate a function of the log's signals (docs/missing_physics.md).
"""

from kinadapt_nn.diagnostics.contract import Effect, effect

__all__ = ["Effect", "effect"]
