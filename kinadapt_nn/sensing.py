"""Sensing: the sensor vector ``s = [d, F_lat, M]`` from encoders + wrist F/T only.

Channels (m = 6), all in the bore frame ``b`` (axes of the world frame here: x, y lateral,
the bore axis ``n = -z_w`` pointing into the hole):

=====  ========  ======  ==================================================================
index  symbol    unit    definition (every input is an encoder or the F/T reading)
=====  ========  ======  ==================================================================
0      d         m       depth of the *nominal* tip: n . (p_O + R_wf l_nom - p_entry)
1, 2   F_lat     N       lateral contact force on the tool, bore x / y
3..5   M         N m     contact moment on the tool about O (world axes)
=====  ========  ======  ==================================================================

``p_O`` and ``R_wf`` come from forward kinematics of the encoders, ``p_entry`` (bore entrance)
and ``l_nom`` (the nominal, CAD tool offset) are known constants; the offset *estimate* never
enters ``d``, so a drifting estimate cannot "seat" the peg without moving it.

Contact wrench: the F/T reading ``r_f`` is the wrench the flange exerts on the tool (MuJoCo
force/torque sensor convention, about O, in ``f``). After a free-space tare ``r0_f`` (tool
weight), the wrench the tool exerts on the environment is ``w_env = R_wf (r_f - r0_f)``
(paper's ``w`` in eq. cp_admittance) and the contact wrench on the tool is ``-w_env``.

Nominal sensor map ``S`` (6 x 6, on the tip twist ``[v_tip; omega]``, constant): a point
contact at the nominal tip with lateral stiffness ``k_t`` and a contact couple ``k_r``:

    d_dot     = n^T v_tip
    F_lat_dot = -k_t P v_tip                         (P: 2 x 3 lateral projector)
    M_dot     = -k_t L [n]x P^T P v_tip - k_r omega  (L = |l_nom|, lever along n)

Whatever this misses (contact away from the tip, stiffness mismatch, axial force, the
F-dependent terms of the moment) is the paper's bias ``b`` (eq. ft_pred).
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.config import SensingCfg
from kinadapt_nn.geometry import skew

M_CHANNELS = 6
CHANNEL_NAMES: tuple[str, ...] = ("d", "F_lat_x", "F_lat_y", "M_x", "M_y", "M_z")
CHANNEL_UNITS: tuple[str, ...] = ("m", "N", "N", "N m", "N m", "N m")


def nominal_sensor_map(cfg: SensingCfg, bore_axis_w: np.ndarray) -> np.ndarray:
    """The constant nominal map S (module docstring). -> (6, 6) on ``[v_tip; omega]``."""
    n = np.asarray(bore_axis_w, dtype=float)
    n = n / np.linalg.norm(n)
    # lateral axes: any orthonormal pair perpendicular to n (world x, y for a vertical bore)
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    ex = ref - (ref @ n) * n
    ex /= np.linalg.norm(ex)
    ey = np.cross(n, ex)
    if ey @ np.array([0.0, 1.0, 0.0]) < 0:  # lateral axes = world x, y when n = -z (left-handed with n)
        ey = -ey
    P = np.vstack([ex, ey])  # (2, 3)
    L = float(np.linalg.norm(cfg.nominal_offset_f_m))
    k_t, k_r = cfg.stiffness_lat_N_per_m, cfg.stiffness_rot_Nm_per_rad
    S = np.zeros((6, 6))
    S[0, :3] = n
    S[1:3, :3] = -k_t * P
    S[3:6, :3] = -k_t * L * skew(n) @ P.T @ P
    S[3:6, 3:] = -k_r * np.eye(3)
    return S


def lateral_projector(S: np.ndarray, k_t: float) -> np.ndarray:
    """Recover P (2, 3) from S's force rows."""
    return -S[1:3, :3] / k_t


def channel_metric(cfg: SensingCfg) -> np.ndarray:
    """W = diag(1 / channel_scale): makes m, N and N m commensurate. -> (6,) diagonal."""
    return 1.0 / np.asarray(cfg.channel_scale, dtype=float)


class RateFilter:
    """First-order low-pass ``1/(tau s + 1)``, backward Euler, applied per channel.

    ``rate(s_k)`` returns the filtered derivative ``(s_k - y_{k-1}) / (tau + dt)`` where ``y``
    is the low-passed signal; this equals low-passing the backward difference of ``s`` with
    the same filter (``lowpass``), which is how the prediction side is filtered so filter
    lag does not enter the residual. Shapes: (k,) channels.
    """

    def __init__(self, tau_s: float, dt_s: float, n_channels: int, y: np.ndarray | None = None) -> None:
        self.alpha = dt_s / (tau_s + dt_s)
        self.inv = 1.0 / (tau_s + dt_s)
        #: filter state; ``y`` may be a view into a caller's stacked buffer (Controller.step
        #: updates it there together with the law's filters, in one pass)
        self.y = np.zeros(n_channels) if y is None else y
        self.z = np.zeros(n_channels)
        self.primed = False

    def reset(self, s0: np.ndarray) -> None:
        self.y[:] = s0
        self.z[:] = 0.0
        self.primed = True

    def rate(self, s: np.ndarray) -> np.ndarray:
        """Filtered derivative of the measured signal. (k,) -> (k,)."""
        if not self.primed:
            self.reset(s)
        r = (s - self.y) * self.inv
        self.y += self.alpha * (s - self.y)
        return r


class LowPass:
    """The same first-order filter applied to an already-differentiated signal. (k,) or (k, p)."""

    def __init__(self, tau_s: float, dt_s: float, shape: tuple[int, ...], z: np.ndarray | None = None) -> None:
        self.alpha = dt_s / (tau_s + dt_s)
        #: filter state; may be a view into a caller's stacked buffer
        self.z = np.zeros(shape) if z is None else z
        if self.z.shape != tuple(shape):
            raise ValueError(f"LowPass state shape {self.z.shape} != {tuple(shape)}")

    def reset(self) -> None:
        self.z[...] = 0.0

    def __call__(self, u: np.ndarray) -> np.ndarray:
        self.z += self.alpha * (u - self.z)
        return self.z
