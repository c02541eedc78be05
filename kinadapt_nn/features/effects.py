"""Library effects in the online model: ``--set model.effects=["contact_stiffness"]``.

``EffectFeatures`` wraps any ``Features`` and appends the named effects' columns
(``kinadapt_nn.features.effect_library``) to the *prediction* regressor, so the composite law adapts
their physical parameters with the same normalised prediction step as ``theta`` (eq.
ft_composite, second term). They are sensor-model terms, not kinematics: ``J_hat`` and the
drive use the base parameters only, and the tracking term does not act on the effect
parameters (``track_rows``). Per step the columns are evaluated on a one-sample ``Signals``
built from what the controller already has (encoders, the tared wrench, time); a closed-form
level column enters as its backward difference / dt (so the law's low-pass makes it the same
filtered derivative as the measured rate), a rate column as is. An effect written once in the
diagnosis's contract with ``online=True`` enters the same way (``effect_library.online_of``). The library writes the moment
channels in the tip-contact form ``Z_M = M - (R l_nom) x f_tool``; the controller's S keeps the
lever, so the columns are mapped back (``M = Z_M + (R l_nom) x f_tool``) in contact.
"""

from __future__ import annotations

import numpy as np

from typing import Sequence

from kinadapt_nn.effects.online import Signals, projector, tip_twist_map
from kinadapt_nn.features.effect_library import OnlineEffect, online_of
from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.robot import ArmKinematics

#: s rows 1..5 (F_lat x, y, M x, y, z) <- level channels (F_lat x, y, F_axial, M x, y, z)
_LEVEL_TO_S = np.array([0, 1, 3, 4, 5])


class EffectFeatures(Features):
    """``base`` + effect columns. Parameters: ``[theta_base (p0,); p_effects (k,)]``. ``effects``: names
    of the library (``effect_library.LIBRARY``), ``OnlineEffect``s, or one-file effects with an online
    side (``@effect(..., online=True)``; ``effect_library.online_of``)."""

    def __init__(self, base: Features, effects: Sequence[str | OnlineEffect | object], known: KnownCfg,
                 S: np.ndarray) -> None:
        self.base = base
        self.effects = [online_of(e) for e in effects]
        self.p0 = base.n_params
        self.k = sum(e.k for e in self.effects)
        self.n_params = self.p0 + self.k
        self.name = base.name + "+" + "+".join(e.name for e in self.effects)
        self.fixed_law = base.fixed_law  # (the oracle's frozen law holds its effect columns too)
        self.S = S
        self._P = projector(S)  # lateral projector (2, 3)
        self._n = S[0, :3]  # bore axis
        self.l_nom = np.asarray(known.sensing.nominal_offset_f_m, dtype=float)
        self.dt = known.dt_s
        self.t_tare = known.settle_s - 0.5 * known.sensing.tare_window_s
        centre, half = base.omega()
        self._omega = (np.r_[centre, np.zeros(self.k)], np.r_[half, np.full(self.k, np.inf)])
        # kalman law: the base prior, and 3x each effect's default magnitude (1 where it is 0)
        base_P0 = getattr(base, "P0", None)
        if base_P0 is not None:
            d = np.concatenate([np.abs(e.magnitude()) for e in self.effects])
            sd = np.where(d > 0, 3.0 * d, 1.0)
            self.P0 = np.zeros((self.n_params, self.n_params))
            self.P0[: self.p0, : self.p0] = base_P0
            self.P0[self.p0:, self.p0:] = np.diag(sd**2)
        self.track_rows = np.r_[np.ones(self.p0), np.zeros(self.k)]
        self._kin = ArmKinematics(known.arm_mjcf)  # its own buffers (encoder FD moves q)
        self._ctx: tuple | None = None
        self._R_tare: np.ndarray | None = None
        self._prev_level: np.ndarray | None = None

    def observe(self, t: float, s: np.ndarray, w_env_w: np.ndarray, active: bool) -> None:
        """The controller's sensor-side context of this step (called before ``regressor``)."""
        self._ctx = (float(t), s.copy(), w_env_w.copy(), bool(active))

    def jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        return self.base.jacobian(kin, theta[: self.p0])

    def twist_jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray | None:
        return self.base.twist_jacobian(kin, theta[: self.p0])

    def omega(self) -> tuple[np.ndarray, np.ndarray]:
        return self._omega

    def regressor(self, kin: KinState, qdot: np.ndarray) -> Regressor:
        reg = self.base.regressor(kin, qdot)
        Phi = np.zeros((reg.Phi.shape[0], self.n_params))
        Phi[:, : self.p0] = reg.Phi
        t, s, w, active = self._ctx if self._ctx is not None else (0.0, np.zeros(6), np.zeros(6), False)
        R = kin.R_wf.copy()
        if t <= self.t_tare or self._R_tare is None and not active:
            self._R_tare = R.copy()
        if not active:
            self._prev_level = None
            return Regressor(reg.known, Phi)
        twist = tip_twist_map(R, kin.J_arm, self.l_nom) @ qdot
        r_tared = np.r_[R.T @ w[:3], R.T @ w[3:]]
        sig = Signals(np.array([t]), self.dt, s[None], w[None], r_tared[None], R[None], twist[None],
                      np.array([1.0 if s[0] >= 0.0 else 0.0]), np.array([True]), self.t_tare, self._R_tare,
                      self.S, self.l_nom, kin.q_rad[None].copy(), qdot[None].copy(), self._kin)
        level = np.zeros((6, self.k))
        rate = np.zeros((6, self.k))
        j = 0
        for e in self.effects:
            lev, rt = e.terms(sig)
            if lev is not None:
                level[:, j:j + e.k] = lev[0]
            if rt is not None:
                rate[:, j:j + e.k] = rt[0]
            j += e.k
        if sig.gate[0] > 0:  # the library's level Z -> s: M = Z_M + (R l_nom) x f_tool (S keeps the lever)
            lever = R @ self.l_nom
            for arr in (level, rate):
                f_tool = self._P.T @ arr[:2] + np.outer(self._n, arr[2])  # (3, k)
                arr[3:] += np.cross(lever[:, None], f_tool, axis=0)
        if self._prev_level is not None:
            rate += (level - self._prev_level) / self.dt
        self._prev_level = level
        Phi[1:, self.p0:] = rate[_LEVEL_TO_S]
        return Regressor(reg.known, Phi)
