"""The controller: value force, second-order twist admittance, joint reference.

The per-step maths lives once, over B episodes, in ``kinadapt_nn.controller.core`` (numba
kernels); ``Controller`` here is that core at B = 1 with the public interface (``step`` ->
``JointCommand``, ``last`` -> ``StepLog``); the episode loop (``kinadapt_nn.runs.loop``) runs the same
kernels for B episodes, a single episode being a batch of one.

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
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from kinadapt_nn.controller import core
from kinadapt_nn.controller.laws import AdaptStep, LawSpec, law_of
from kinadapt_nn.controller.laws.base import LawState, law_state, state_sizes
from kinadapt_nn.errors import SensorError
from kinadapt_nn.features.base import Features, KinState
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.robot import ArmKinematics
from kinadapt_nn.sensing import channel_metric, lateral_projector, nominal_sensor_map


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

    def __init__(self, known: KnownCfg) -> None:
        c = known.control
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


def prior_cov_of(features: Features) -> np.ndarray:
    """theta's prior covariance (p, p): ``features.P0`` when the features declare one, else a
    diagonal with sd = a third of Omega's half width (finite entries; 1 where Omega is open)."""
    P0 = getattr(features, "P0", None)
    if P0 is not None:
        return np.asarray(P0, dtype=float)
    half = features.omega()[1]
    sd = np.where(np.isfinite(half), np.asarray(half, dtype=float) / 3.0, 1.0)
    return np.diag(sd**2)


def rank_margin(W: np.ndarray, J_hat: np.ndarray) -> float:
    """``lambda_min(W J_hat J_hat^T W)`` on W-scaled rows: the online proxy of the full-row-rank
    hypothesis of Theorem ft_rigid (paper: gate 1e-6). W (m,), J_hat (m, n) -> float."""
    WJ = W[:, None] * J_hat
    return float(np.linalg.eigvalsh(WJ.dot(WJ.T))[0])



#: the features computed in the kernel (``Features.kernel``) -> their kind (``CoreConsts.c[FEAT]``)
KINDS: dict[str, int] = {"adjoint": core.FEAT_ADJOINT, "neural": core.FEAT_NEURAL, "rbf": core.FEAT_RBF}
#: a kind -> its constants for the kernel (the neural body, the RBF centres; the adjoint needs none)
PACKS: dict[int, Callable[[Features], np.ndarray]] = {core.FEAT_NEURAL: core.neural_consts,
                                                      core.FEAT_RBF: core.rbf_consts}


def feature_kind(features: Features) -> int:
    """The features' kind in the kernel (:data:`KINDS`): the adjoint, the neural basis and the RBF
    are computed in it (``features.kernel``); others supply their rows from Python (``FEAT_JHAT``,
    switched to ``FEAT_TWIST`` where the features factor through the twist)."""
    return KINDS.get(features.kernel, core.FEAT_JHAT)


def feature_consts(features: Features) -> np.ndarray:
    """The in-kernel features' constants (:data:`PACKS`), else a placeholder."""
    pack = PACKS.get(feature_kind(features))
    return np.zeros(1) if pack is None else pack(features)


def run_law(known: KnownCfg, features: Features) -> str:
    """The law a controller of ``features`` runs: the features' own (``Features.fixed_law``: the
    oracle's is frozen), else the configured ``known.law``."""
    return features.fixed_law or known.law


def core_consts(known: KnownCfg, features: Features,
                law_address: bool = True) -> tuple[core.CoreConsts, LawSpec, np.ndarray]:
    """The kernels' constants from the known config and the features, for the law :func:`run_law`
    (a registered law, ``controller.laws.LAWS``). ``law_address``: False leaves ``law_fn`` at 0
    for the caller to set (``spec.address()``) before the first kernel call. -> (CoreConsts, the
    law's LawSpec, the in-kernel features' constants ``fx``)."""
    c, sc, ad, dt = known.control, known.sensing, known.adaptation, known.dt_s
    # what the features give, asked once each: the law they run, theta's prior covariance (theirs, else
    # Omega/3), Omega (their own box: the adjoint's about l_nom), their kind and constants in the kernel
    name, P0 = run_law(known, features), prior_cov_of(features)
    theta_nominal, half = features.omega()
    fx, kind = feature_consts(features), feature_kind(features)
    spec, params = law_of(ad, name, dt, P0)
    n_axis = known.n_axis
    S = nominal_sensor_map(sc, n_axis)
    P = lateral_projector(S, sc.stiffness_lat_N_per_m)
    W = channel_metric(sc)
    l_nom = np.asarray(sc.nominal_offset_f_m, dtype=float)
    tau = np.array([c.tau_trans_s] * 3 + [c.tau_ang_s] * 3)
    gain = np.array([c.gain_trans] * 3 + [c.gain_ang] * 3)
    beta = np.array([c.beta_trans] * 3 + [c.beta_ang] * 3)
    M_virt = tau / gain  # [kg | kg m^2] virtual inertia per twist channel
    D_virt = (1.0 + beta) / gain  # [N s/m | N m s/rad] damping (I + beta) / g
    p = features.n_params
    lc = spec.constants(params, S.shape[0], p)  # the law's constants
    alpha, inv_tau = dt / (sc.filter_tau_s + dt), 1.0 / (sc.filter_tau_s + dt)
    dither = np.asarray(c.dither_rad_s, dtype=float)
    v = core.pack_c({  # by the names declared in controller/layout.py (C_FIELDS): every one, at its size
        "DT": dt, "T_SETTLE": known.settle_s, "T_TARE0": max(0.0, known.settle_s - sc.tare_window_s),
        "RAMP": c.ramp_s, "D_STAR": c.depth_target_m, "K_D": c.k_depth_N_per_m, "F_MAX": c.depth_force_max_N,
        "C_F": c.compliance_lat_m_per_N, "C_M": c.compliance_mom_rad_per_Nm, "V_MAX": c.v_max_m_per_s,
        "W_MAX": c.w_max_rad_per_s, "K_NS": c.nullspace_gain, "DAMP": 1e-6, "ALPHA": alpha, "INV_TAU": inv_tau,
        "N_ENTRY": float(n_axis @ np.asarray(known.bore_entry_w_m, dtype=float)), "RIGID": float(c.loop == "rigid"),
        "DITHER_ON": float(np.any(dither)), "TWO_PI_F": 2.0 * math.pi * c.dither_hz,
        "EXCITE": float(c.program == "excite"), "BLEND": known.excite.blend_s, "F_GATE": ad.contact_force_N,
        "M_GATE": ad.contact_moment_Nm, "MAX_HOLD": max(0, int(round(sc.max_dropout_s / dt))),
        "FEAT": kind,
        "RANK_ON": 1.0, "RANK_GATE_V": core.RANK_GATE,  # 1: lambda_min every step; 2: the gate only
        "V_N": n_axis, "V_LNOM": l_nom, "V_M": M_virt, "V_INVDEN": 1.0 / (M_virt + dt * D_virt),
        "V_GRIGID": gain / (1.0 + beta),  # rigid: the admittance's DC gain
        "V_W": W, "V_D": D_virt, "V_DITHER": dither,
    })
    G = np.zeros((6, 6))  # s[1:] = G[1:] w_env: F_lat = -P f_env, M = -m_env
    G[1:3, 0:3] = -P
    G[3:6, 3:6] = -np.eye(3)
    lo = np.asarray(theta_nominal, dtype=float) - half
    hi = np.asarray(theta_nominal, dtype=float) + half
    track_rows = getattr(features, "track_rows", None)  # rows of Phi the tracking term uses
    mask = np.ones(p) if track_rows is None else np.asarray(track_rows, dtype=float)
    segs = np.asarray(known.excite.segments, dtype=float).reshape(-1, 7)
    seg = np.column_stack([np.cumsum(segs[:, 0]), segs[:, 1:]]) if len(segs) else np.zeros((0, 7))
    return core.CoreConsts(
        c=v, mats=np.stack([S, G]), pv=np.ascontiguousarray(np.stack([lo, hi, mask])),
        lc=np.ascontiguousarray(lc, dtype=float),
        law_fn=np.array([spec.address() if law_address else 0], dtype=np.int64),
        seg=np.ascontiguousarray(seg),
    ), spec, fx


class KernelParts(NamedTuple):
    """What the compiled step of B episodes of one features type is built from, on the controller
    side alone (:func:`kernel_parts`)."""

    chain: np.ndarray  #: the bare arm's kinematic chain (``core.arm_chain``)
    consts: core.CoreConsts  #: the kernels' constants (:func:`core_consts`)
    law: LawSpec  #: the law :func:`run_law`
    layout: core.Layout  #: n, m, p and the state/out layout
    state: core.ControllerState  #: (B, ...) filter and law state, zero
    fx: np.ndarray  #: the in-kernel features' constants (:func:`feature_consts`)
    law_state: LawState  #: the law's named views of ``state`` (``laws.base.law_state``)


def kernel_parts(known: KnownCfg, features: Features, arm_model, site: int, B: int,
                 law_address: bool = True) -> KernelParts:
    """The kernels' parts for B episodes of ``features`` on the bare arm ``arm_model`` (a
    ``mujoco.MjModel``) whose flange is site ``site``: the one construction that the single
    controller (B = 1) and the batched loop share."""
    consts, spec, fx = core_consts(known, features, law_address)
    m, p = consts.mats.shape[1], features.n_params
    blocks = spec.blocks(m, p)  # the law's state, declared for m and p (asked once)
    layout = core.Layout(arm_model.nq, m, p, state_sizes(blocks, spec.counters))
    state = core.ControllerState(layout, B)
    return KernelParts(core.arm_chain(arm_model, site), consts, spec, layout, state, fx,
                       law_state(blocks, spec.counters, state.law_x, state.law_k, state.unc))


class StepBuffers(NamedTuple):
    """The kernels' per-step buffers of B episodes, allocated once (:meth:`zeros`): the one set a
    ``Controller`` (B = 1) and the batched loop (``runs.loop.Kernels``) each hold."""

    inp: np.ndarray  #: (B, 2n+6) the samples [q; qdot; raw F/T] (after the intake: as the controller used them)
    p_O: np.ndarray  #: (B, 3) [m] the flange O, world (the controller's own kinematics)
    R: np.ndarray  #: (B, 3, 3) R_wf, the flange's orientation
    J: np.ndarray  #: (B, 6, n) the bare arm's geometric Jacobian at O
    reg: np.ndarray  #: (B, 1+p, m) the regressor rows [known; Phi^T]
    ext_J: np.ndarray  #: (B, m, max(n, 6)) J_hat_xi (m, 6) or J_hat (m, n) of features computed in Python
    out: np.ndarray  #: (B, nout) this step's out rows (``core.Layout.out_blocks``)

    @classmethod
    def zeros(cls, layout: core.Layout, B: int) -> StepBuffers:
        n, m, p = layout.n, layout.m, layout.p
        return cls(np.zeros((B, 2 * n + 6)), np.zeros((B, 3)), np.zeros((B, 3, 3)), np.zeros((B, 6, n)),
                   np.zeros((B, 1 + p, m)), np.zeros((B, m, max(n, 6))), np.zeros((B, layout.nout)))

    def kin(self, b: int, copy_q: bool = False) -> KinState:
        """Episode ``b``'s kinematic state (views; ``copy_q``: q copied)."""
        q = self.inp[b, :self.J.shape[2]]
        return KinState(q.copy() if copy_q else q, self.p_O[b], self.R[b], self.J[b])

    def rank_margin(self, b: int, W: np.ndarray, features: Features, theta: np.ndarray) -> float:
        """:func:`rank_margin` of episode ``b``'s J_hat from ``features`` in Python (features not fused)."""
        return rank_margin(W, features.jacobian(self.kin(b, copy_q=True), theta))


def generic_step(t: float, chain: np.ndarray, cs: core.CoreConsts, layout: core.Layout, st: core.ControllerState,
                 bufs: StepBuffers, feats_b: list[Features], active: np.ndarray) -> None:
    """One step of features that are not fused, after the intake (``core.intake_kernel``), for B
    episodes: kinematics and sense in the kernels; for each ``active`` (B,) episode without a
    sensor error its features' (``feats_b`` (B,)) sensor-side context (effect columns'
    ``observe``), regressor rows and J_hat (or J_hat_xi) from Python; then the rest of the step in
    the kernel (``core.act_kernel``). ``chain``, ``cs``, ``layout``, ``st``: the kernels' (``KernelParts``)."""
    lay, n, inp, out = layout.arr, layout.n, bufs.inp, bufs.out
    core.fk_batch(chain, inp, bufs.p_O, bufs.R, bufs.J)
    core.sense_kernel(t, inp, bufs.p_O, bufs.R, st.x, st.k, lay, cs.c, cs.mats, out)
    (i_s, n_s), (i_w, n_w), (i_rho, _) = (layout.out_blocks[k] for k in ("s", "w_env", "rho"))
    for b in np.flatnonzero(active & (st.k[:, core.K_ERROR] == 0)):
        fb = feats_b[b]
        kin = bufs.kin(b)
        observe = getattr(fb, "observe", None)
        if observe is not None:  # effect columns: the sensor-side context of this step
            observe(t, out[b, i_s:i_s + n_s], out[b, i_w:i_w + n_w], out[b, i_rho] > 0.0)
        rg = fb.regressor(kin, inp[b, n:2 * n])
        bufs.reg[b, 0], bufs.reg[b, 1:] = rg.known, rg.Phi.T
        if cs.c[core.EXCITE]:
            continue
        J_xi = fb.twist_jacobian(kin, st.theta[b])  # (m, 6) or None
        if J_xi is not None:
            cs.c[core.FEAT] = core.FEAT_TWIST
            bufs.ext_J[b, :, :6] = J_xi
        else:
            cs.c[core.FEAT] = core.FEAT_JHAT
            bufs.ext_J[b, :, :n] = fb.jacobian(kin, st.theta[b])
    core.act_kernel(t, inp, bufs.p_O, bufs.R, bufs.J, bufs.reg, bufs.ext_J, st.x, st.k, lay, cs.c, cs.mats, cs.pv,
                    cs.lc, cs.law_fn, cs.seg, out)


def sensor_error_message(t: float, bad_run: int) -> str:
    """What a controller says of a dropout longer than ``sensing.max_dropout_s`` at ``t`` [s]:
    ``bad_run`` non-finite samples in a row (``SensorError``; the batched runs report the same)."""
    return (f"non-finite sensor sample at t={t:.3f} s ({bad_run} in a row; check the encoders and the F/T sensor "
            "for NaN/inf)")


_ONE = np.ones(1, dtype=bool)  #: the one episode of a Controller, active


class Controller:
    """F/T + encoder admittance controller at B = 1. ``step(t, q, qdot, wrench) -> JointCommand``.

    Built from the known constants only (``KnownCfg``: sensing, control, adaptation, the bore
    pose, the arm model); ``features`` and ``theta0`` define ``J_hat``; ``theta`` is adapted by
    the registered law :func:`run_law` (``known.law`` unless the features fix their own;
    ``controller.laws``). All filter and law state is one
    ``controller/core.py: ControllerState``; :attr:`law` is the law's own view of its state.
    """

    def __init__(self, known: KnownCfg, features: Features, theta0: np.ndarray) -> None:
        self.known = known
        sc = known.sensing
        self.dt = known.dt_s
        self.features = features
        self.mode = run_law(known, features)  # the law's name
        self.kin = ArmKinematics(known.arm_mjcf)
        self.kin_n = n = self.kin.model.nq
        #: longest run of non-finite samples bridged by holding the last valid one [steps]
        self.max_hold_steps = max(0, int(round(sc.max_dropout_s / self.dt)))
        self.n_axis = known.n_axis
        self.entry_w = np.asarray(known.bore_entry_w_m, dtype=float)  # known bore pose
        self.l_nom_f = np.asarray(sc.nominal_offset_f_m, dtype=float)
        self.value_fn = ValueFunction(known)
        parts = kernel_parts(known, features, self.kin.model, self.kin.site, 1, law_address=False)  # (compile_kernels)
        self.consts, self.law_spec, self.chain = parts.consts, parts.law, parts.chain
        self.layout, self.state, self._law_state = parts.layout, parts.state, parts.law_state
        # the known constants as the kernels hold them (core_consts: computed there once)
        self.S = self.consts.mats[0].copy()  #: (m, 6) the nominal sensor map S
        self.W = self.consts.c[core.V_W:core.V_W + self.S.shape[0]].copy()  #: (m,) the channel metric W
        self.M_virt = self.consts.c[core.V_M:core.V_M + 6].copy()
        self.D_virt = self.consts.c[core.V_D:core.V_D + 6].copy()
        self.theta0 = np.asarray(theta0, dtype=float).copy()
        #: what the law learned, read from its own state (the summary's view; LawView)
        self.law = self.law_spec.view(self.law_spec, self.consts.lc, self._law_state, 0)
        #: the fused step kernel (features computed in the kernel: one call per step), else None
        self._fused = core.FUSED.get(int(self.consts.c[core.FEAT]))
        self._kernels_ready = False  # compile_kernels done
        self._fused_call, self._fused_args = self._fused, ()  # (compile_kernels binds them)
        self._fx = parts.fx
        self._feats_b = [features]  # (generic_step: the features of each of the B = 1 episodes)
        # -- kernel buffers (B = 1), allocated once
        self._bufs = StepBuffers.zeros(self.layout, 1)
        self._inp, self._p_O, self._R, self._J, self._reg, self._ext_J, self.out = self._bufs
        self._q, self._qdot, self._wrench = self._inp[0, :n], self._inp[0, n:2 * n], self._inp[0, 2 * n:]
        ob = {k: self.out[0, o:o + size] for k, (o, size) in self.layout.out_blocks.items()}
        self._o = ob
        self._i_rho, self._i_gate = self.layout.out_blocks["rho"][0], self.layout.out_blocks["gate"][0]
        self._i_n2, self._i_lam = self.layout.out_blocks["phi_norm2"][0], self.layout.out_blocks["lam_min"][0]
        self.reset()

    # -- state views -----------------------------------------------------------------------
    @property
    def theta(self) -> np.ndarray:
        """(p,) the estimate the next step uses."""
        return self.state.theta[0]

    @theta.setter
    def theta(self, value: np.ndarray) -> None:
        self.state.theta[0] = value

    @property
    def xi(self) -> np.ndarray:
        return self.state.xi[0]

    @property
    def q_ref(self) -> np.ndarray | None:
        return self.state.q_ref[0] if self.state.k[0, core.K_STARTED] else None

    @property
    def tare(self) -> np.ndarray:
        return self.state.tare[0]

    @property
    def tared(self) -> bool:
        return bool(self.state.k[0, core.K_TARED])

    @property
    def dropouts(self) -> int:
        return int(self.state.k[0, core.K_DROPOUTS])

    @property
    def F(self) -> np.ndarray:
        return self._o["F"]

    @property
    def regressor_rows(self) -> np.ndarray:
        """(1 + p, m) this step's regressor on the realised velocity, [known; Phi^T] (before the
        filter): what the law's tracking term and filters took (``StandaloneLaw.update`` takes it)."""
        return self._reg[0]

    @property
    def contact_steps(self) -> int:
        """Steps of this insertion with the contact gate open (the law adapted, or could have)."""
        return int(self.state.k[0, core.K_GRAM_N])

    @property
    def gram_sum(self) -> np.ndarray:
        """(p, p) sum over those steps of (W Phi_f)^T (W Phi_f): the regressor Gram (observability)."""
        return self.state.gram_sum[0]

    def reset(self, carry_estimate: bool = False) -> None:
        """Back to the start of an insertion. ``carry_estimate``: keep theta and what the law
        learned about it (its ``reset(carried=True)`` says what: the kalman law's covariance and
        residual level) -- the next insertion of the same tool."""
        st = self.state
        keep = (st.theta[0].copy(), st.law_x[0].copy(), st.law_k[0].copy()) if carry_estimate else None
        st.x[...] = 0.0
        st.k[...] = 0
        st.theta[0] = self.theta0
        if keep is not None:
            st.theta[0], st.law_x[0], st.law_k[0] = keep
        self.law_spec.reset(self.consts.lc, self._law_state, keep is not None)
        self.theta_start = st.theta[0].copy()  #: (p,) theta at the start of this insertion
        self.out[...] = 0.0
        self._stepped = False

    def set_state(self, x: np.ndarray, k: np.ndarray, out: np.ndarray) -> None:
        """Take the state a batched loop stepped this controller in (``runs.loop``: its row of a
        B-episode ``ControllerState``): ``x`` (NX,) float state, ``k`` (N_K + law nk,) counters
        (the error, done and paused flags cleared) and ``out`` (nout,) the last step's out row."""
        st = self.state
        st.x[0], st.k[0] = x, k
        st.k[0, core.K_ERROR] = st.k[0, core.K_DONE] = st.k[0, core.K_PAUSED] = 0
        self.out[0] = out
        self._stepped = True

    # ------------------------------------------------------------------------------------
    def rank_margin_now(self) -> float:
        """``lambda_min(W J_hat J_hat^T W)`` of the Jacobian the controller will use next (the
        current theta) at this step's configuration (the rank gate, every step). The adjoint's is
        computed in the kernel; other features evaluate ``features.jacobian`` here."""
        if self._fused is not None:
            return float(self.out[0, self._i_lam])
        return self._bufs.rank_margin(0, self.W, self.features, self.theta)

    def sensor_vector(self, kin: KinState, w_env_w: np.ndarray) -> np.ndarray:
        """s = [d, F_lat, M] (see kinadapt_nn.sensing). -> (6,)."""
        s = np.empty(6)
        s[0] = self.n_axis @ (kin.p_w_O + kin.R_wf @ self.l_nom_f) - self.consts.c[core.N_ENTRY]
        s[1:] = self.consts.mats[1, 1:] @ w_env_w  # F_lat = P f_on_tool = -P w_env_f ; M = -w_env_m
        return s

    def excite_twist(self, t_rel: float) -> np.ndarray:
        """The excitation program's commanded nominal-tip twist [v_tip; omega] (world) at time
        ``t_rel`` after the settle, blended linearly from the previous segment's over
        ``excite.blend_s``. -> (6,); zero before the program, ramping to zero after it."""
        seg, blend = self.consts.seg, self.known.excite.blend_s
        if t_rel < 0.0 or not len(seg):
            return np.zeros(6)
        k = int(np.searchsorted(seg[:, 0], t_rel, side="right"))
        cur = seg[k, 1:] if k < len(seg) else np.zeros(6)
        start = seg[k - 1, 0] if k > 0 else 0.0
        prev = seg[k - 1, 1:] if k > 0 else np.zeros(6)
        if blend > 0.0 and t_rel - start < blend:
            return prev + (t_rel - start) / blend * (cur - prev)
        return cur.copy()

    def step(self, t: float, q: np.ndarray, qdot: np.ndarray, wrench: np.ndarray) -> JointCommand:
        """One control period. Inputs: time [s], encoders (n,), raw F/T reading (6,) in f.
        The maths is ``controller.core`` at B = 1 (see its module docstring). -> copies."""
        self.advance(t, q, qdot, wrench)
        return JointCommand(self.state.q_ref[0].copy(), self._o["qdot_ref"].copy())

    @property
    def last(self) -> StepLog | None:
        """This step's controller-side quantities (views of ``out``, valid until the next step)."""
        if not self._stepped:
            return None
        o = self._o
        out = self.out[0]
        a = AdaptStep(o["s_dot_pred"], o["eps_w"], o["d_track"], o["d_pred"], float(out[self._i_gate]),
                      float(out[self._i_n2]))
        return StepLog(o["s"], o["s_dot_meas"], o["s_dot_pred"], o["F"], o["xi_cmd"], o["w_env"],
                       o["theta_used"], float(out[self._i_rho]), a)

    def advance(self, t: float, q: np.ndarray, qdot: np.ndarray, wrench: np.ndarray) -> None:
        """``step`` without building the command (the command: ``state.q_ref[0]`` and ``out``'s
        ``qdot_ref`` block)."""
        self._q[:] = q
        self._qdot[:] = qdot
        self._wrench[:] = wrench
        self.advance_input(t)

    @property
    def input_row(self) -> np.ndarray:
        """(2n + 6,) the next step's input [q; qdot; wrench]: a caller may write the sample here
        and call :meth:`advance_input` (no copies on the hot path)."""
        return self._inp[0]

    def kernel_calls(self) -> list[tuple[str, object, tuple]]:
        """The numba kernels one step of this controller calls: (name, dispatcher, arguments) each,
        the arguments being this controller's own buffers (what :meth:`advance_input` passes)."""
        st, cs, lay = self.state, self.consts, self.layout.arr
        if self._fused is not None:
            return [("step", self._fused, (0.0, self._inp, self.chain, self._p_O, self._R, self._J, self._reg, st.x,
                                            st.k, lay, cs.c, cs.mats, cs.pv, cs.lc, cs.law_fn, cs.seg, self._fx,
                                            self.out))]
        return [("intake", core.intake_kernel, (self._inp, st.x, st.k, lay, cs.c)),
                ("kinematics", core.fk_batch, (self.chain, self._inp, self._p_O, self._R, self._J)),
                ("sense", core.sense_kernel, (0.0, self._inp, self._p_O, self._R, st.x, st.k, lay, cs.c, cs.mats,
                                              self.out)),
                ("act", core.act_kernel, (0.0, self._inp, self._p_O, self._R, self._J, self._reg, self._ext_J, st.x,
                                          st.k, lay, cs.c, cs.mats, cs.pv, cs.lc, cs.law_fn, cs.seg, self.out))]

    def compile_kernels(self, progress: bool = False) -> float:
        """Compile (or load from numba's on-disk cache) every kernel :meth:`advance_input` will call,
        so that the episode's first step does not carry the one-time compile. ``progress``: when the
        cache is cold, show it as its own bar (``core.compiling``). Once per controller (a work
        cell's later insertions skip it). -> wall seconds spent (0 when done before)."""
        if self._kernels_ready:
            return 0.0
        calls = self.kernel_calls()
        wall = core.compile_calls(calls, progress, law=self.law_spec)
        self.consts.law_fn[0] = self.law_spec.address()
        if self._fused is not None:  # the step's one dispatch, its arguments (this controller's buffers) bound once
            (_name, fn, args), = calls
            self._fused_call, self._fused_args = core.entry_point(fn, args), args[1:]
        self._kernels_ready = True
        return wall

    def advance_input(self, t: float) -> None:
        """``advance`` on the sample already in :attr:`input_row`."""
        if not self._kernels_ready:  # the kernels and the law's address, once
            self.compile_kernels()
        st, cs = self.state, self.consts
        if self._fused is not None:  # intake, kinematics, sense, regressor, drive, admittance, law: one dispatch
            self._fused_call(t, *self._fused_args)
        else:
            core.intake_kernel(self._inp, st.x, st.k, self.layout.arr, cs.c)
            if not st.k[0, core.K_ERROR]:
                generic_step(t, self.chain, cs, self.layout, st, self._bufs, self._feats_b, _ONE)
        if st.k[0, core.K_ERROR]:
            st.k[0, core.K_ERROR] = 0
            raise SensorError(sensor_error_message(t, int(st.k[0, core.K_BAD_RUN])))
        self._stepped = True

    def set_bore(self, bore_entry_w_m) -> None:
        """Aim at another KNOWN bore entrance (world, (3,) [m]): the next insertion of a work cell.
        Only the depth channel's reference changes; theta, the law's state and the filters are
        the caller's to keep (``reset(carry_estimate=True)``)."""
        import dataclasses

        entry = tuple(float(x) for x in bore_entry_w_m)
        self.known = dataclasses.replace(self.known, bore_entry_w_m=entry)
        self.entry_w = np.asarray(entry, dtype=float)
        self.consts.c[core.N_ENTRY] = float(self.n_axis @ self.entry_w)
