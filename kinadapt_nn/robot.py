"""The arm the robot knows: Panda constants (model paths, names, nominal poses) and the bare
arm's forward kinematics and Jacobian from encoder readings (MuJoCo, no tool, no truth)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import mujoco
import numpy as np

from kinadapt_nn.errors import ModelFileError

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


class KinState(NamedTuple):
    """Arm kinematics from the joint encoders (controller side; no truth)."""

    q_rad: np.ndarray  #: (n,) joint positions
    p_w_O: np.ndarray  #: (3,) flange origin O in the world
    R_wf: np.ndarray  #: (3, 3) flange orientation: f -> w
    J_arm: np.ndarray  #: (6, n) world-frame geometric Jacobian of O, rows [v_O; omega]


class ArmKinematics:
    """Forward kinematics and ``J_arm`` of the bare arm from encoder readings (MuJoCo).

    ``update(q)`` is the hot-path form: it returns a ``KinState`` of *views* into this object's
    buffers (``p_w_O``, ``R_wf``, ``J_arm``), valid until the next ``update``/call; ``kin(q)``
    returns copies that may be kept.
    """

    def __init__(self, mjcf_path: Path = PANDA_MJCF) -> None:
        mjcf_path = Path(mjcf_path)
        if not mjcf_path.is_file():
            raise ModelFileError(f"arm model file '{mjcf_path}' not found (fix scene.arm_mjcf or reinstall)")
        try:
            self.model = mujoco.MjModel.from_xml_path(str(mjcf_path))
        except Exception as exc:
            raise ModelFileError(f"arm model '{mjcf_path}' could not be loaded: {str(exc).splitlines()[0]}") from None
        self.data = mujoco.MjData(self.model)
        self.site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
        self._jac = np.zeros((6, self.model.nv))
        # views into MjData, fetched once (each attribute access builds a new array object)
        self._qpos = self.data.qpos
        self._p = self.data.site_xpos[self.site]
        self._R = self.data.site_xmat[self.site].reshape(3, 3)
        self._jacp, self._jacr = self._jac[:3], self._jac[3:]

    def update(self, q: np.ndarray) -> KinState:
        """FK + ``J_arm`` at ``q``; the returned arrays are views, overwritten by the next call."""
        m, d = self.model, self.data
        self._qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacSite(m, d, self._jacp, self._jacr, self.site)
        return KinState(q, self._p, self._R, self._jac)

    def __call__(self, q: np.ndarray) -> KinState:
        self.update(q)
        return KinState(q_rad=q, p_w_O=self._p.copy(), R_wf=self._R.copy(), J_arm=self._jac.copy())
