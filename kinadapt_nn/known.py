"""What a real robot knows: the controller's and the features' whole view of an experiment.

``KnownCfg`` is the truth firewall written as a type. The controller and the features are
built from it and from nothing else: it holds the nominal (CAD) tool, the nominal sensor map's
constants, the law's constants, the arm model file, the *known* bore pose and the timing --
never the true tool, the arm's kinematic errors, the hidden effects, the bore pose error or
the simulator. ``KnownCfg.of(cfg)`` is the one place where an experiment config is cut down to
it (the run side calls it; the controller side never sees an ``ExperimentCfg``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kinadapt_nn.config import (
    AdaptationCfg,
    ControlCfg,
    ExciteCfg,
    ExperimentCfg,
    FeaturesCfg,
    SensingCfg,
    SuccessCfg,
    arm_mjcf_path,
)

#: Bore axis (unit, world frame): the bore points down, -z_w. A known constant of the cell.
BORE_AXIS_W: np.ndarray = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class KnownCfg:
    """The known constants of one experiment (SI units; frames in the names).

    Every field is something the integrator of a real cell writes down before the first run:
    the sections are the validated config sections of the same name (all of them known).
    """

    sensing: SensingCfg  #: nominal tool offset, nominal contact stiffness, W, filter, tare window
    control: ControlCfg  #: V, the admittance, limits, dither, program
    adaptation: AdaptationCfg  #: the law's constants (mode, gains, Omega, prior sds)
    features: FeaturesCfg  #: Y(q)'s settings (RBF centres, neural checkpoint)
    excite: ExciteCfg  #: the scripted excitation program
    success: SuccessCfg  #: the sensor-side seat check
    model_effects: tuple[str, ...]  #: library effects whose columns are adapted online
    features_kind: str  #: the features type, a name in ``kinadapt_nn.features.FEATURES``
    law: str  #: the configured law (features may fix their own: the oracle's is frozen, ``Features.fixed_law``)
    dt_s: float  #: control period [s]
    settle_s: float  #: hold still this long at the start (tare at its end) [s]
    arm_mjcf: Path  #: the bare arm's model (no tool): the controller's kinematics
    bore_entry_w_m: tuple[float, float, float]  #: the KNOWN bore entrance, world [m]
    bore_axis_w: tuple[float, float, float]  #: the known bore axis (unit), world

    @classmethod
    def of(cls, cfg: ExperimentCfg) -> "KnownCfg":
        """Cut an experiment config down to what the robot knows (nothing hidden survives)."""
        return cls(
            sensing=cfg.sensing,
            control=cfg.control,
            adaptation=cfg.adaptation,
            features=cfg.features,
            excite=cfg.excite,
            success=cfg.success,
            model_effects=tuple(cfg.model.effects),
            features_kind=cfg.run.features,
            law=cfg.adaptation.mode,
            dt_s=cfg.run.dt_s,
            settle_s=cfg.start.settle_s,
            arm_mjcf=arm_mjcf_path(cfg.scene),
            bore_entry_w_m=tuple(cfg.scene.bore_entry_w_m),
            bore_axis_w=tuple(BORE_AXIS_W.tolist()),
        )

    @property
    def n_axis(self) -> np.ndarray:
        """The bore axis (3,), world, unit."""
        return np.asarray(self.bore_axis_w, dtype=float)
