"""Analytic adjoint features: ``J_hat = S Ad(R_wf theta) J_arm`` (eq. ft_factor).

``theta`` (p = 3) is the estimated offset O -> tip in the flange frame ``f`` [m]. The depth
row is built on the *known* nominal offset (the depth channel is defined on it, see
``kinadapt_nn.sensing``) and so is a known constant part that is never adapted.

With the flange twist ``xi = J_arm qdot = [v; omega]`` (world):
``Ad(l_w) xi = [v + omega x l_w; omega]`` and ``l_w = R_wf theta``, hence

    J_hat qdot = S xi + S_v [omega]x R_wf theta      (rows F_lat, M)
    Phi        = S_v [omega]x R_wf                   (m, 3); depth row 0

which is affine in ``theta`` as the paper requires.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.features.registry import Built, FeaturesContext, FeaturesSpec
from kinadapt_nn.geometry import skew
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.sensing import nominal_sensor_map


class AdjointFeatures(Features):
    """Analytic adjoint of the wrist-to-tip offset (p = 3).

    Besides the ``Features`` interface it offers two hot-path kernels for ``Controller.step``
    (same math, no (m, 6) ``J_hat_xi`` formed, few numpy calls): :meth:`regressor_rows` and
    :meth:`twist_drive`.
    """

    n_params = 3
    name = "adjoint"
    theta_is_offset = True  # theta is the wrist-to-tip offset in f [m]: comparable with the true tool

    def __init__(self, S: np.ndarray, nominal_offset_f_m: np.ndarray,
                 omega_half_width_m: np.ndarray | None = None) -> None:
        """S (m, 6) the nominal map; the nominal (CAD) offset (3,) in f [m]; Omega's half widths
        (3,) [m] about it (the law's projection box; ``None``: unbounded)."""
        self.S = np.asarray(S, dtype=float)  # (m, 6)
        self.S_v = self.S[:, :3].copy()
        self.S_v[0] = 0.0  # the depth row does not see theta
        self.l_nom_f = np.asarray(nominal_offset_f_m, dtype=float)
        self._half = (np.full(3, np.inf) if omega_half_width_m is None
                      else np.asarray(omega_half_width_m, dtype=float).copy())
        # -- constants of the hot-path kernels
        self._n = tuple(self.S[0, :3].tolist())  # depth row, linear part (the bore axis)
        self._K = np.vstack([self.S.T, self.S_v.T])  # (9, m): K F = [S^T F; S_v^T F]
        # Phi^T = (S_v [w]x R)^T = R^T sum_k w_k T_k with T_k = -[e_k]x S_v^T  (3, m) each
        self._T = np.stack([-skew(e) @ self.S_v.T for e in np.eye(3)]).reshape(3, -1)
        self._xi = np.zeros(6)  # scratch: realised flange twist J_arm qdot
        self._w = self._xi[3:]
        self._B = np.zeros(self._T.shape[1])
        self._B3m = self._B.reshape(3, -1)

    def omega(self) -> tuple[np.ndarray, np.ndarray]:
        """Omega: the box of half widths ``omega_half_width_m`` about the nominal offset."""
        return self.l_nom_f.copy(), self._half.copy()

    def twist_jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        """``S Ad(R_wf theta)`` with the depth row on the nominal offset. -> (m, 6)."""
        R = kin.R_wf
        # S Ad(l) = [S_v, S_w - S_v [l]x]  (geometry.adjoint_offset), with S_v [a]x = (sum_k a_k T_k)^T
        J_xi = self.S.copy()
        J_xi[:, 3:] -= R.dot(theta).dot(self._T).reshape(3, -1).T
        # depth row on the nominal offset: S_0v^T [lw]x = (n x lw)^T
        l0, l1, l2 = R.dot(self.l_nom_f).tolist()
        n0, n1, n2 = self._n
        J_xi[0, 3:] -= (n1 * l2 - n2 * l1, n2 * l0 - n0 * l2, n0 * l1 - n1 * l0)
        return J_xi

    def jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        return self.twist_jacobian(kin, theta).dot(kin.J_arm)

    def regressor(self, kin: KinState, qdot: np.ndarray) -> Regressor:
        # known = S xi + e_0 n . (w x R l_nom),  Phi = S_v [w]x R  (xi = J_arm qdot = [v; w])
        known, Phi_T = np.empty(self.S.shape[0]), np.empty((3, self.S.shape[0]))
        self.regressor_rows(kin, qdot, known, Phi_T)
        return Regressor(known=known, Phi=Phi_T.T)

    @property
    def kernel(self) -> str | None:
        """"adjoint" unless a subclass changed the maths the kernel implements."""
        return "adjoint" if self.has_fused_kernels() else None

    # -- hot-path kernels ------------------------------------------------------------------
    def has_fused_kernels(self) -> bool:
        """True when the kernels below compute what ``regressor``/``twist_jacobian`` do (a
        subclass that overrides either must not be served by them)."""
        cls = type(self)
        return cls.regressor is AdjointFeatures.regressor and cls.twist_jacobian is AdjointFeatures.twist_jacobian

    def regressor_rows(
        self, kin: KinState, qdot: np.ndarray, known_out: np.ndarray, Phi_T_out: np.ndarray, lw: list | None = None
    ) -> None:
        """``regressor(kin, qdot)`` written in place: ``known_out`` (m,) and ``Phi_T_out`` (3, m)
        = Phi^T, both C-contiguous (rows of the controller's filter buffer). ``lw``: ``R_wf l_nom``
        (3 floats) if the caller has it."""
        xi = np.dot(kin.J_arm, qdot, out=self._xi)  # realised twist [v; w]
        np.dot(self.S, xi, out=known_out)
        np.dot(self._w, self._T, out=self._B)  # [w]x S_v^T, negated, flattened
        np.dot(kin.R_wf.T, self._B3m, out=Phi_T_out)  # Phi^T = -R^T [w]x S_v^T
        # depth row on the nominal offset: S_0 Ad(R l_nom) xi = S_0 xi + n . (w x R l_nom)
        w0, w1, w2 = self._w.tolist()
        l0, l1, l2 = kin.R_wf.dot(self.l_nom_f).tolist() if lw is None else lw
        n0, n1, n2 = self._n
        known_out[0] += n0 * (w1 * l2 - w2 * l1) + n1 * (w2 * l0 - w0 * l2) + n2 * (w0 * l1 - w1 * l0)

    def twist_drive(self, kin: KinState, theta: np.ndarray, F: np.ndarray, lw: list | None = None) -> list[float]:
        """``twist_jacobian(kin, theta)^T F`` (6 floats) without forming it: with ``a = R theta``,
        ``lw = R l_nom`` (3 floats, if the caller has it), ``u = S_v^T F`` and ``f0 = F_0 n`` (the
        depth row), ``[S_v^T F + f0; S_w^T F + a x u + lw x f0]`` since ``(S_v [a]x)^T F = -[a]x u``."""
        g = self._K.dot(F).tolist()  # [S^T F (6); u (3)]
        R = kin.R_wf
        a0, a1, a2 = R.dot(theta).tolist()
        l0, l1, l2 = R.dot(self.l_nom_f).tolist() if lw is None else lw
        u0, u1, u2 = g[6], g[7], g[8]
        f0 = float(F[0])
        m0, m1, m2 = f0 * self._n[0], f0 * self._n[1], f0 * self._n[2]
        return [
            g[0],
            g[1],
            g[2],
            g[3] + (a1 * u2 - a2 * u1) + (l1 * m2 - l2 * m1),
            g[4] + (a2 * u0 - a0 * u2) + (l2 * m0 - l0 * m2),
            g[5] + (a0 * u1 - a1 * u0) + (l0 * m1 - l1 * m0),
        ]


def nominal_adjoint(known: KnownCfg, prior: bool = True) -> AdjointFeatures:
    """The adjoint on the known nominal map S and the nominal (CAD) offset, with the law's box
    Omega (``adaptation.omega_*``); ``prior``: with the declared tool tolerance as theta's prior
    ``P0`` (``adaptation.prior_sd_*``). The learned types build on it as their known part."""
    ad = known.adaptation
    S = nominal_sensor_map(known.sensing, known.n_axis)
    l_nom = np.asarray(known.sensing.nominal_offset_f_m, dtype=float)
    adjoint = AdjointFeatures(S, l_nom, np.array([ad.omega_lateral_m, ad.omega_lateral_m, ad.omega_axial_m]))
    if prior:
        adjoint.P0 = np.diag([ad.prior_sd_lateral_m**2, ad.prior_sd_lateral_m**2, ad.prior_sd_axial_m**2])
    return adjoint


def build(ctx: FeaturesContext) -> Built:
    """The adjoint from the initial offset estimate (experiment design: the true offset + the
    configured error)."""
    return Built(nominal_adjoint(ctx.known), np.asarray(ctx.offset_estimate_f_m, dtype=float))


SPEC = FeaturesSpec(name="adjoint", doc="analytic adjoint of the wrist-to-tip offset (p = 3, theta in m)",
                    build=build, theta0_per_episode=True, cost=1.0)
