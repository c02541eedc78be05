"""Panda constants: model paths, names and the nominal poses (one place for all of them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Folder holding the shipped MJCF files (``models/`` at the repository root).
MODELS_DIR: Path = Path(__file__).resolve().parent.parent / "models"
#: The Panda MJCF written from Franka's published DH and inertial parameters.
PANDA_MJCF: Path = MODELS_DIR / "panda.xml"

N_JOINTS: int = 7
JOINT_NAMES: tuple[str, ...] = tuple(f"joint{i}" for i in range(1, 8))
ACTUATOR_NAMES: tuple[str, ...] = tuple(f"servo{i}" for i in range(1, 8))
LINK_NAMES: tuple[str, ...] = tuple(f"link{i}" for i in range(0, 8))
#: Site at the flange origin O; the F/T sensor frame ``f`` coincides with it.
FLANGE_SITE: str = "flange"
#: Body that carries the flange site (the last arm link).
FLANGE_BODY: str = "link7"

#: Joint limits [rad], Franka Control Interface documentation. Shape (n, 2).
JOINT_LIMITS_RAD: np.ndarray = np.array(
    [
        [-2.8973, 2.8973],
        [-1.7628, 1.7628],
        [-2.8973, 2.8973],
        [-3.0718, -0.0698],
        [-2.8973, 2.8973],
        [-0.0175, 3.7525],
        [-2.8973, 2.8973],
    ]
)

#: A comfortable configuration with the flange pointing down (-z_w). Shape (n,).
Q_HOME_RAD: np.ndarray = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])

#: Joint servo gains of the MJCF position actuators (kp [N m/rad], kv [N m s/rad]).
SERVO_KP: float = 4500.0
SERVO_KV: float = 450.0
