"""A kinadapt effect file (Python code that runs, like a test file): a hose's weight on the tool.

A hose clamped on the tool at ``CLAMP_S_M`` (sensor frame) hangs part of its weight there: a force
``m g`` straight down in the world at the clamp, the one parameter ``m`` [kg] (the hanging part's
mass). The columns read only ``s.g_s`` (gravity in the sensor frame), which the controller has from
its encoders, so ``online=True`` makes this one file both model sides: ``kinadapt diagnose LOG
--effects examples/effects/hose_weight.py`` judges it in a log, and the controller adapts ``m``
online (``model.effects``, ``PATH.py:NAME``; ``kinadapt_nn.effects.online.from_wrench``).
tests/features/test_effect_one_file.py checks both against the simulator's ``effects.world_force``.
"""
import numpy as np

from kinadapt_nn.diagnostics import effect

CLAMP_S_M = np.array([0.0, 0.035, 0.10])  # [m] the clamp point in the sensor frame s


@effect(params={"hose_mass": "kg"}, relevant=[0.02],
        doc="a hose clamped 35 mm off the tool axis hangs part of its weight on the tool",
        excite="reorient the tool in free space (the weight turns in the sensor frame, unlike an offset)",
        online=True)
def hose_weight(s):
    """(n, 6, 1): the change of s.wrench per kg of the hanging hose (its weight at the clamp)."""
    f = s.g_s  # (n, 3) [N/kg] the weight per kg, sensor frame
    return np.concatenate([f, np.cross(CLAMP_S_M, f)], axis=1)[:, :, None]  # force; its moment about s
