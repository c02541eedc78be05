"""The controller: value force, second-order twist admittance, joint reference.

Truth firewall: ``Controller.step(t, q, qdot, wrench)`` sees joint encoders and the raw
wrist F/T reading only. Its kinematics come from its own MuJoCo model of the *bare arm*
(``models/panda.xml``: no tool, no block); the known constants it holds (bore pose,
nominal tool offset, S, W, V's weights) are listed in docs/method.md's "known vs unknown"
table. It never receives the simulator, the true tool or the true tip.

Discrete admittance (see docs/method.md, "The admittance we implement"), per twist channel c of the
flange twist ``xi = [v_O; omega]`` (world), with ``m_c = tau_c / g_c`` and
``D_c = (1 + beta_c) / g_c``:

    m_c (xi_c[k+1] - xi_c[k]) / dt + D_c xi_c[k+1] = (rho_k J_hat_xi^T F - w_env)_c

i.e. eq. cp_admittance written on the wrist twist, ``J_hat_xi = J_hat J_arm^+`` (for the
adjoint features exactly ``S Ad(theta)``), implicit in the damping. The drive and the
contact wrench enter with the same (unit) scaling, so the power the virtual mass-damper
delivers through ``w_env`` is the power the contact stores (eq. cp_storage). The joint
reference follows ``qdot_ref = J_arm^+ xi + N (k_ns (q_0 - q))``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco
import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path
from kinadapt_nn.errors import SensorError
from kinadapt_nn.features.base import Features, KinState
from kinadapt_nn.robot import ArmKinematics
from kinadapt_nn.controller.law import AdaptStep, CompositeLaw
from kinadapt_nn.sensing import RateFilter, channel_metric, lateral_projector, nominal_sensor_map


class JointCommand(NamedTuple):
    """What the controller sends to the joint servo."""

    q_ref_rad: np.ndarray  #: (n,) joint position reference
    qdot_ref_rad_s: np.ndarray  #: (n,) joint velocity feed-forward


class StepLog(NamedTuple):
    """Controller-side quantities of one step, for the trace (all from sensors).

    ``s``, ``F`` and ``w_env_w`` are views of the controller's work buffers: valid until the next
    ``step()`` (the episode copies them into the trace at once); copy them to keep them."""

    s: np.ndarray  #: (m,) sensor vector [d, F_lat, M]
    s_dot_meas: np.ndarray  #: (m,) filtered measured rate
    s_dot_pred: np.ndarray  #: (m,) filtered predicted rate J_hat qdot
    F: np.ndarray  #: (m,) value force -grad V
    xi: np.ndarray  #: (6,) admittance twist state [v_O; omega]
    w_env_w: np.ndarray  #: (6,) wrench tool -> environment at O, world [N, N m]
    theta: np.ndarray  #: (p,) parameter estimate used this step
    drive_scale: float  #: rho in [0, 1]: 0 while taring, ramps to 1
    adapt: AdaptStep  #: what the adaptation law did this step


class ValueFunction:
    """``V(s)`` with its minimum at ``s* = [d*, 0, 0, 0, 0, 0]`` and ``F = -grad_s V`` (eq. ft_force).

    ``V = h(d - d*) + 1/2 c_F |F_lat|^2 + 1/2 c_M |M|^2`` with ``h`` the Huber function of
    slope ``k_d`` (quadratic up to the force ``depth_force_max``, linear beyond). Units: V in J,
    F in [N, m, m, rad, rad, rad] so that ``F . s_dot`` is a power.
    """

    def __init__(self, cfg: ExperimentCfg) -> None:
        c = cfg.control
        self.d_star = c.depth_target_m
        self.k_d = c.k_depth_N_per_m
        self.f_max = c.depth_force_max_N
        self.c_F = c.compliance_lat_m_per_N
        self.c_M = c.compliance_mom_rad_per_Nm
        self._e_max = self.f_max / self.k_d
        self._neg_c = np.array([0.0, -self.c_F, -self.c_F, -self.c_M, -self.c_M, -self.c_M])

    def value(self, s: np.ndarray) -> float:
        e = s[0] - self.d_star
        ae = abs(e)
        h = 0.5 * self.k_d * e * e if ae <= self._e_max else self.f_max * (ae - 0.5 * self._e_max)
        return float(h + 0.5 * self.c_F * (s[1] ** 2 + s[2] ** 2) + 0.5 * self.c_M * (s[3:] @ s[3:]))

    def value_batch(self, s: np.ndarray) -> np.ndarray:
        """``V`` for a batch of sensor vectors. (B, 6) -> (B,)."""
        e = np.abs(s[:, 0] - self.d_star)
        h = np.where(e <= self._e_max, 0.5 * self.k_d * e * e, self.f_max * (e - 0.5 * self._e_max))
        return h + 0.5 * self.c_F * (s[:, 1] ** 2 + s[:, 2] ** 2) + 0.5 * self.c_M * np.sum(s[:, 3:] ** 2, axis=1)

    def force(self, s: np.ndarray, out: np.ndarray) -> np.ndarray:
        # one multiply for the quadratic channels (-c_F s_lat, -c_M s_M), then the Huber depth slope
        np.multiply(s, self._neg_c, out=out)
        out[0] = -min(max(self.k_d * (float(s[0]) - self.d_star), -self.f_max), self.f_max)
        return out


def prior_cov_of(features: Features, adjoint_half_width: np.ndarray) -> np.ndarray:
    """theta's prior covariance (p, p): ``features.P0`` when the features declare one, else a
    diagonal with sd = a third of Omega's half width (finite entries; 1 where Omega is open)."""
    P0 = getattr(features, "P0", None)
    if P0 is not None:
        return np.asarray(P0, dtype=float)
    half = adjoint_half_width if features.name == "adjoint" else features.omega()[1]
    sd = np.where(np.isfinite(half), np.asarray(half, dtype=float) / 3.0, 1.0)
    return np.diag(sd**2)


def rank_margin(W: np.ndarray, J_hat: np.ndarray) -> float:
    """``lambda_min(W J_hat J_hat^T W)`` on W-scaled rows: the online proxy of the full-row-rank
    hypothesis of Theorem ft_rigid (paper: gate 1e-6). W (m,), J_hat (m, n) -> float."""
    WJ = W[:, None] * J_hat
    return float(np.linalg.eigvalsh(WJ.dot(WJ.T))[0])


class Controller:
    """F/T + encoder admittance controller. ``step(t, q, qdot, wrench) -> JointCommand``.

    Parameters are known constants only (config sections ``sensing``, ``control`` and the
    bore pose); ``features`` and ``theta0`` define ``J_hat``; ``theta`` is adapted by the
    composite law (``adaptation.mode``; ``features=oracle`` holds the true offset frozen as a
    declared baseline).
    """

    def __init__(
        self,
        cfg: ExperimentCfg,
        features: Features,
        theta0: np.ndarray,
        bore_axis_w: np.ndarray,
        mode: str | None = None,
    ) -> None:
        self.cfg = cfg
        c, sc = cfg.control, cfg.sensing
        self.dt = cfg.run.dt_s
        self.features = features
        self.theta = np.asarray(theta0, dtype=float).copy()
        self.kin = ArmKinematics(arm_mjcf_path(cfg.scene))
        self.kin_n = self.kin.model.nq
        #: longest run of non-finite samples bridged by holding the last valid one [steps]
        self.max_hold_steps = max(0, int(round(cfg.sensing.max_dropout_s / cfg.run.dt_s)))
        self.n_axis = np.asarray(bore_axis_w, dtype=float)
        self.entry_w = np.asarray(cfg.scene.bore_entry_w_m, dtype=float)  # known bore pose
        self.l_nom_f = np.asarray(sc.nominal_offset_f_m, dtype=float)
        self.S = nominal_sensor_map(sc, self.n_axis)
        self.P = lateral_projector(self.S, sc.stiffness_lat_N_per_m)  # (2, 3)
        self.W = channel_metric(sc)
        self._n_entry = float(self.n_axis @ self.entry_w)
        self._G = np.zeros((5, 6))  # s[1:] = G w_env: F_lat = -P f_env, M = -m_env
        self._G[0:2, 0:3] = -self.P
        self._G[2:5, 3:6] = -np.eye(3)
        self._zero6 = np.zeros(6)
        self.value_fn = ValueFunction(cfg)
        tau = np.array([c.tau_trans_s] * 3 + [c.tau_ang_s] * 3)
        gain = np.array([c.gain_trans] * 3 + [c.gain_ang] * 3)
        beta = np.array([c.beta_trans] * 3 + [c.beta_ang] * 3)
        self.M_virt = tau / gain  # [kg | kg m^2] virtual inertia per twist channel
        self.D_virt = (1.0 + beta) / gain  # [N s/m | N m s/rad] damping (I + beta) / g
        self._inv_den = 1.0 / (self.M_virt + self.dt * self.D_virt)
        self._rigid = c.loop == "rigid"
        self._gain_t = tuple((gain / (1.0 + beta)).tolist())  # rigid: xi = g/(1+beta) (S Ad)^T F, the admittance's DC gain
        self.v_max, self.w_max = c.v_max_m_per_s, c.w_max_rad_per_s
        self.k_ns = c.nullspace_gain
        self._dither = np.asarray(c.dither_rad_s, dtype=float)
        self._dither_on = bool(np.any(self._dither))
        self._two_pi_f = 2.0 * math.pi * c.dither_hz
        self._damp = 1e-6  # Tikhonov term of J_arm^+ = J^T (J J^T + 1e-6 I)^-1
        # scripted excitation (control.program = "excite"): a commanded nominal-tip twist per segment
        self._excite = c.program == "excite"
        segs = np.asarray(cfg.excite.segments, dtype=float).reshape(-1, 7)
        self._seg_end = np.cumsum(segs[:, 0])
        self._seg_twist = segs[:, 1:]
        self._blend = cfg.excite.blend_s
        self.t_settle = cfg.start.settle_s
        self.t_tare0 = max(0.0, self.t_settle - sc.tare_window_s)
        self.ramp_s = c.ramp_s
        # -- work buffers of step() (allocated once; step() fills them in place)
        p, m = features.n_params, self.S.shape[0]
        # One filter pass for every filtered channel (README: the prediction goes through the
        # *same* filter as the measured rate): rows [s; known; Phi^T] -> states
        # [y (rate filter of s); known_f; Phi_f^T] (the law's LowPass states are views of rows 1:).
        self._U = np.zeros((2 + p, m))  # filter inputs this step
        self._Z = np.zeros((2 + p, m))  # filter states
        self._D = np.zeros((2 + p, m))  # scratch: U - Z
        self._s, self._s_tail, self._known, self._Phi_T = self._U[0], self._U[0, 1:], self._U[1], self._U[2:]
        self._D0 = self._D[0]
        self.rate_meas = RateFilter(sc.filter_tau_s, self.dt, m, y=self._Z[0])
        self._alpha, self._inv_tau = self.rate_meas.alpha, self.rate_meas.inv
        self._dw = np.zeros(6)  # wrench - tare
        self._dw23 = self._dw.reshape(2, 3)
        self._w_env = np.zeros(6)  # tool -> environment wrench, world
        self._w_env23 = self._w_env.reshape(2, 3)
        self._L = np.zeros((6, 6))  # J J^T + 1e-6 I, then its Cholesky factor
        self._L_diag = self._L.reshape(-1)[::7]
        # adjoint features: fused kernels (no J_hat_xi formed); other features: generic path
        self._fused = bool(getattr(features, "has_fused_kernels", lambda: False)())
        self._observe = getattr(features, "observe", None)
        track_rows = getattr(features, "track_rows", None)  # rows of Phi the tracking term uses
        self._track_mask = None if track_rows is None else np.asarray(track_rows, dtype=float)[:, None]
        self._n_t = tuple(self.n_axis.tolist())
        self._M_t = tuple(self.M_virt.tolist())
        self._inv_den_t = tuple(self._inv_den.tolist())
        ad = cfg.adaptation
        self.theta0 = self.theta.copy()
        half = np.array([ad.omega_lateral_m, ad.omega_lateral_m, ad.omega_axial_m])
        self.law_args = dict(
            features=features,
            mode=mode or ad.mode,
            gamma=ad.gamma,
            gamma_d=ad.gamma_d,
            eta=ad.eta,
            eps_norm=ad.eps_norm,
            W=self.W,
            filter_tau_s=sc.filter_tau_s,
            dt_s=self.dt,
            # Omega: the adjoint's box about the nominal offset; learned features give their own
            theta_nominal=self.l_nom_f if features.name == "adjoint" else features.omega()[0],
            omega_half_width=half if features.name == "adjoint" else features.omega()[1],
            contact_force_N=ad.contact_force_N,
            contact_moment_Nm=ad.contact_moment_Nm,
            # kalman law: the features' prior covariance (declared by make_features), else Omega/3
            prior_cov=prior_cov_of(features, half),
            corr_s=ad.corr_s,
            resid_tau_s=ad.resid_tau_s,
            resid_floor_w=ad.resid_floor_w,
            persist_tau_s=ad.persist_tau_s,
            act_sd_ratio=ad.act_sd_ratio,
        )
        self.reset()

    def reset(self, carry_estimate: bool = False) -> None:
        """Back to the start of an insertion. ``carry_estimate``: keep theta and what the law
        learned about it (covariance, residual level) -- the next insertion of the same tool."""
        carried = (self.theta.copy(), self.law) if carry_estimate else None
        self.dropouts = 0
        self._bad_run = 0
        self._held = (np.zeros(self.kin_n), np.zeros(self.kin_n), np.zeros(6))
        self._have_held = False
        p = self.features.n_params
        self._hold_step = AdaptStep(np.zeros(6), np.zeros(6), np.zeros(p), np.zeros(p), 0.0, 0.0)
        self.xi = np.zeros(6)
        self.q_ref: np.ndarray | None = None
        self.q_posture: np.ndarray | None = None
        self.tare_sum = np.zeros(6)
        self.tare_n = 0
        self.tare = np.zeros(6)
        self.F = np.zeros(6)
        self.tared = False
        self._tmp6 = np.zeros(6)
        self._xi_t = (0.0,) * 6
        self._Z[...] = 0.0
        self.rate_meas.primed = False
        self.theta = self.theta0.copy()
        self.law = CompositeLaw(**self.law_args, filter_state=self._Z[1:])
        if carried is not None:
            self.theta = carried[0]
            self.law.carry_from(carried[1])
        self.last: StepLog | None = None

    # ------------------------------------------------------------------------------------
    def rank_margin_now(self) -> float:
        """``lambda_min(W J_hat J_hat^T W)`` of the Jacobian the controller will use next (the
        current theta) at this step's configuration (the kinematics' buffers of the last step, no
        new forward kinematics). The rank gate, every step (~10 us; benchmarks/bench_episode.py)."""
        k = self.kin
        kin = KinState(k._qpos[: self.kin_n].copy(), k._p, k._R, k._jac)
        return rank_margin(self.W, self.features.jacobian(kin, self.theta))

    def sensor_vector(self, kin: KinState, w_env_w: np.ndarray) -> np.ndarray:
        """s = [d, F_lat, M] (see kinadapt_nn.sensing). -> (6,)."""
        s = np.empty(6)
        s[0] = self.n_axis @ (kin.p_w_O + kin.R_wf @ self.l_nom_f) - self._n_entry
        s[1:] = self._G @ w_env_w  # F_lat = P f_on_tool = -P w_env_f ; M = -w_env_m
        return s

    def excite_twist(self, t_rel: float) -> np.ndarray:
        """The excitation program's commanded nominal-tip twist [v_tip; omega] (world) at time
        ``t_rel`` after the settle, blended linearly from the previous segment's over
        ``excite.blend_s``. -> (6,); zero before the program, ramping to zero after it."""
        if t_rel < 0.0 or not len(self._seg_end):
            return np.zeros(6)
        k = int(np.searchsorted(self._seg_end, t_rel, side="right"))
        cur = self._seg_twist[k] if k < len(self._seg_end) else np.zeros(6)
        start = self._seg_end[k - 1] if k > 0 else 0.0
        prev = self._seg_twist[k - 1] if k > 0 else np.zeros(6)
        if self._blend > 0.0 and t_rel - start < self._blend:  # linear blend: bounded acceleration
            a = (t_rel - start) / self._blend
            return prev + a * (cur - prev)
        return cur.copy()

    def _excite_drive(self, t_rel: float, lever_w: list[float]) -> list[float]:
        """``D xi_ref`` for the admittance: in free space the wrist twist follows ``xi_ref``
        (time constant M/D), in contact the contact wrench balances it (compliant). The tip
        twist is moved to O: ``v_O = v_tip - omega x (R l_nom)``."""
        x = self.excite_twist(t_rel)
        x[:3] -= np.cross(x[3:], lever_w)
        return (self.D_virt * x).tolist()

    def step(self, t: float, q: np.ndarray, qdot: np.ndarray, wrench: np.ndarray) -> JointCommand:
        """One control period. Inputs: time [s], encoders (n,), raw F/T reading (6,) in f.

        Hot path (1 kHz): numpy calls cost ~0.3-1 us each whatever the size here, so small
        vectors are handled as Python floats and the rest is fused into few calls on
        preallocated buffers; the comments name what each fused line implements."""
        if math.isfinite(q.dot(q) + qdot.dot(qdot) + wrench.dot(wrench)):
            holding = False
            self._bad_run = 0
            self._held[0][:] = q
            self._held[1][:] = qdot
            self._held[2][:] = wrench
            self._have_held = True
        else:  # a dropout: hold the last valid sample (no adaptation on it); never let NaN in
            self.dropouts += 1
            self._bad_run += 1
            enc_ok = math.isfinite(q.dot(q) + qdot.dot(qdot))
            if self._bad_run > self.max_hold_steps or not (self._have_held or enc_ok):
                raise SensorError(
                    f"non-finite sensor sample at t={t:.3f} s ({self._bad_run} in a row; check the encoders and "
                    "the F/T sensor for NaN/inf)"
                )
            holding = True
            if self._have_held:
                q, qdot, wrench = self._held
            else:  # the very first samples: valid encoders, no valid wrench yet -> zero wrench, no tare
                wrench = self._zero6
        kin = self.kin.update(q)  # views, valid for this step
        R, J = kin.R_wf, kin.J_arm
        if self.q_ref is None:
            self.q_ref = q.copy()
            self.q_posture = q.copy()
        # -- tare: average the free-space reading (tool weight) while holding still
        if t < self.t_settle:
            if t >= self.t_tare0 and not holding:
                self.tare_sum += wrench
                self.tare_n += 1
            rho = 0.0
            w_env = self._zero6
        else:
            if not self.tared:
                self.tare = self.tare_sum / max(self.tare_n, 1)
                self.tared = True
            rho = min(1.0, (t - self.t_settle) / self.ramp_s) if self.ramp_s > 0 else 1.0
            # tool -> environment, world axes, about O: [R (r_f - r0_f); R (r_m - r0_m)]
            np.subtract(wrench, self.tare, out=self._dw)
            np.dot(self._dw23, R.T, out=self._w_env23)
            w_env = self._w_env
        # -- s = [d, F_lat, M] (kinadapt_nn.sensing), written into row 0 of the filter input
        s = self._s
        np.dot(self._G, w_env, out=self._s_tail)  # F_lat = P f_on_tool = -P w_env_f ; M = -w_env_m
        p0, p1, p2 = kin.p_w_O.tolist()
        lw = R.dot(self.l_nom_f).tolist()  # nominal lever R l_nom, shared with the fused kernels
        l0, l1, l2 = lw
        n0, n1, n2 = self._n_t
        s[0] = n0 * (p0 + l0) + n1 * (p1 + l1) + n2 * (p2 + l2) - self._n_entry  # n . (p_O + R l_nom) - n . p_entry
        # -- regressor on the realised velocity (rows 1: of the filter input)
        if self._fused:
            self.features.regressor_rows(kin, qdot, self._known, self._Phi_T, lw)
        else:
            if self._observe is not None:  # effect columns need the sensor-side context
                self._observe(t, s, w_env, rho > 0.0)
            reg = self.features.regressor(kin, qdot)
            self._known[:] = reg.known
            self._Phi_T[:] = reg.Phi.T
        # -- one pass of the shared first-order filter (sensing.RateFilter / LowPass):
        #    s_dot_meas = (s - y) / (tau + dt);  y, known_f, Phi_f += alpha (input - state)
        U, Z, D = self._U, self._Z, self._D
        if not self.rate_meas.primed:
            Z[0] = s
            self.rate_meas.primed = True
        np.subtract(U, Z, out=D)
        s_dot_meas = self._D0 * self._inv_tau
        D *= self._alpha
        Z += D
        # -- value force and the twist admittance (eq. ft_force, eq. cp_admittance)
        F = self.value_fn.force(s, self.F)
        L = self._L
        mujoco.mju_mulMatMatT(L, J, J)
        self._L_diag += self._damp
        mujoco.mju_cholFactor(L, 0.0)
        if self._excite:  # the scripted program replaces V's drive (control.program = "excite")
            drive = self._excite_drive(t - self.t_settle, lw)
        elif self._fused:
            drive = self.features.twist_drive(kin, self.theta, F, lw)  # (S Ad)^T F: wrench at O
        else:
            J_xi = self.features.twist_jacobian(kin, self.theta)  # (m, 6) or None
            if J_xi is not None:
                drive = J_xi.T.dot(F).tolist()
            else:  # J_hat_xi^T F = J_arm^{+T} J_hat^T F
                dr = np.empty(6)
                mujoco.mju_cholSolve(dr, L, J.dot(self.features.jacobian(kin, self.theta).T.dot(F)))
                drive = dr.tolist()
        # M (xi+ - xi)/dt + D xi+ = rho drive - w_env   (implicit in the damping), per channel,
        # unrolled on Python floats (same operations, in the same order, as the vector form)
        dt = self.dt
        m0, m1, m2, m3, m4, m5 = self._M_t
        i0, i1, i2, i3, i4, i5 = self._inv_den_t
        x0, x1, x2, x3, x4, x5 = self._xi_t
        d0, d1, d2, d3, d4, d5 = drive
        w0, w1, w2, w3, w4, w5 = w_env.tolist()
        if self._rigid:  # eq. ft_control: the commanded twist is realised, no contact feedback
            g0, g1, g2, g3, g4, g5 = self._gain_t
            x0, x1, x2, x3, x4, x5 = g0 * rho * d0, g1 * rho * d1, g2 * rho * d2, g3 * rho * d3, g4 * rho * d4, g5 * rho * d5
        else:
            x0 = (m0 * x0 + dt * (rho * d0 - w0)) * i0
            x1 = (m1 * x1 + dt * (rho * d1 - w1)) * i1
            x2 = (m2 * x2 + dt * (rho * d2 - w2)) * i2
            x3 = (m3 * x3 + dt * (rho * d3 - w3)) * i3
            x4 = (m4 * x4 + dt * (rho * d4 - w4)) * i4
            x5 = (m5 * x5 + dt * (rho * d5 - w5)) * i5
        vn = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        if vn > self.v_max:
            c = self.v_max / vn
            x0, x1, x2 = x0 * c, x1 * c, x2 * c
        wn = math.sqrt(x3 * x3 + x4 * x4 + x5 * x5)
        if wn > self.w_max:
            c = self.w_max / wn
            x3, x4, x5 = x3 * c, x4 * c, x5 * c
        self._xi_t = (x0, x1, x2, x3, x4, x5)
        self.xi = xi = np.array(self._xi_t)
        if self._dither_on and rho > 0.0:  # commanded excitation (Remark ft_excitation), not stored
            ph = self._two_pi_f * (t - self.t_settle)
            xi = xi.copy()
            xi[3] += rho * self._dither[0] * math.sin(ph)
            xi[4] += rho * self._dither[1] * math.cos(ph)
            xi[5] += rho * self._dither[2] * math.sin(1.7 * ph)
        # -- joint reference: qdot = J^+ xi + (I - J^+ J) k_ns (q_0 - q)
        z = self.q_posture - q
        z *= self.k_ns
        y = self._tmp6
        mujoco.mju_cholSolve(y, L, xi - J.dot(z))
        qdot_ref = y.dot(J)  # J^T y
        qdot_ref += z
        self.q_ref = self.q_ref + dt * qdot_ref
        # -- adaptation (eq. ft_composite) on the realised velocity; theta_{k+1} is used next step
        theta = self.theta
        if holding:  # a held sample carries no new information: theta stays
            a = self._hold_step._replace(s_dot_pred=s_dot_meas.copy())
        else:
            Phi_r = self._Phi_T if self._track_mask is None else self._Phi_T * self._track_mask
            self.theta, a = self.law.step_filtered(theta, Phi_r, s_dot_meas, F, w_env)
        # -- diagnostics for the trace (V and lambda_min are evaluated off the hot path)
        self.last = StepLog(s, s_dot_meas, a.s_dot_pred, F, xi, w_env, theta, rho, a)
        return JointCommand(self.q_ref, qdot_ref)
