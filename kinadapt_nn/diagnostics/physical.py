"""The physical nominal model of a user's set-up, and the effect library in the sensor frame.

Everything here comes from the setup file (``kinadapt_nn.diagnostics.setup``) and what the robot
logged (encoders, the F/T reading, time). Nothing needs a tare window, a contact stiffness or
this package's simulator (docs/diagnose.md).

Convention inside this module: ``r`` (N, 6) is the wrench the tool exerts ON the sensor, in the
sensor frame s, about the sensor origin [N; N m] (``setup.log.sign`` converts the log). Frames:
``w`` world = the arm's base (z up, gravity ``-g z`` with ``g = [world] gravity_mps2``), ``f`` the arm
model's flange (an MJCF site, a URDF link or a DH table: ``kinadapt_nn.diagnostics.arms``), ``s``
the sensor.

Nominal model (free space). The declared tool (mass m, COM c, inertia I_c, all in s) is a rigid
body on the sensor. With ``g_s`` gravity, ``a_s`` the acceleration of the sensor origin, ``omega``
and ``alpha`` the angular velocity and acceleration (all in s, from the encoders)::

    F = m (g_s - a_s) - alpha x (m c) - omega x (omega x (m c))
    M = (m c) x (g_s - a_s) - I_O alpha - omega x (I_O omega),   I_O = I_c + m (|c|^2 1 - c c^T)

(Newton-Euler about the sensor origin; linear in the ten inertial parameters.)

Contact. Any contact acts through the declared tip ``p`` (in s): the contact wrench at the sensor
is ``[F_c; p x F_c]``, whatever the surface. The force is unknown, so in contact only the moment
about the tip is a model prediction: ``L r = M - p x F`` equals ``L w_nominal``. Contact samples are
those whose force departs from the tool model by more than ``contact.detect_force_N`` (widened by
``contact.margin_s``); the ``L`` rows hold anywhere, so calling a free sample "contact" only loses
information, never biases.

Effects: the built-in effects are columns over ``LogSignals`` in the public form a user writes
(``kinadapt_nn.effects.contract``), one module each in ``kinadapt_nn/effects/builtin/``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from kinadapt_nn.diagnostics.setup import SetupCfg
from kinadapt_nn.errors import KinadaptError

#: [s] Savitzky-Golay window of the velocity derivative (accelerations)
ACC_WINDOW_S = 0.1
#: configurations per call of MuJoCo's batched kinematics (``ArmModel._frames``; about half the CPU
#: time of a per-sample loop from Python: ``python benchmarks/arm_kinematics.py``)
FRAMES_BATCH = 4096


class KinSeries(NamedTuple):
    """Sensor-frame kinematics of every sample (N samples), from the encoders."""

    R_ws: np.ndarray  #: (N, 3, 3) sensor axes in the world
    g_s: np.ndarray  #: (N, 3) gravity in s [m/s^2]
    a_s: np.ndarray  #: (N, 3) acceleration of the sensor origin in s [m/s^2]
    omega_s: np.ndarray  #: (N, 3) angular velocity in s [rad/s]
    alpha_s: np.ndarray  #: (N, 3) angular acceleration in s [rad/s^2]
    p_ws: np.ndarray | None = None  #: (N, 3) sensor origin in the world [m]


class ArmModel:
    """The arm of ``[arm]`` (MJCF, URDF or DH; ``arms.load_arm``) for forward kinematics and site
    Jacobians of its ``dof`` joints (looked up once)."""

    def __init__(self, setup: SetupCfg) -> None:
        import mujoco

        from kinadapt_nn.diagnostics.arms import load_arm

        arm = load_arm(setup.arm)
        self.model, self.site, self.dof, self.source = arm.model, arm.site, arm.dof, arm.source
        self._qpos, self._cols = _as_slice(arm.qpos_adr), _as_slice(arm.dof_adr)  # qpos / Jacobian columns
        self._jnt = np.asarray(arm.joint_ids, dtype=int)  # (dof,) joint ids, base to flange
        self._hinge = self.model.jnt_type[self._jnt] == int(mujoco.mjtJoint.mjJNT_HINGE)  # else a slide
        self._batch = self._batch_qpos = None  #: ``_mj_batch`` and its bound ``qpos``, made on first use
        self.R_fs = setup.sensor.R_fs()
        self.p_fs = np.asarray(setup.sensor.position_flange_m, dtype=float)
        self.g_w = setup.world.g_w()  #: (3,) [m/s^2] gravity in the world
        self._mj = mujoco

    def check_joints(self, q: np.ndarray, what: str = "the log") -> None:
        """A one-line error unless ``q`` is (N, dof)."""
        q = np.asarray(q)
        if q.ndim == 2 and q.shape[1] == self.dof:
            return
        got = f"{q.shape[1]} joint(s) per sample" if q.ndim == 2 else f"shape {q.shape}, not (samples, joints),"
        raise KinadaptError(f"{what} has {got} but {self.source} has {self.dof} joints between its base and the "
                            "flange; give one [log] q column per arm joint (base to flange) or fix [arm]")

    def _frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """MuJoCo's forward kinematics of joint positions (N, dof), ``FRAMES_BATCH`` configurations at
        a time (``mujoco.batch.Batch``, one thread, contacts and constraints off: position stage
        only): (R_wf (N, 3, 3), flange origin x_w (N, 3), site Jacobians Jp, Jr (N, 3, dof)). The
        Jacobian of the site from the joints' world axes and anchors, as ``mj_jacSite`` forms it
        (a hinge: ``Jr = axis``, ``Jp = axis x (site - anchor)``; a slide: ``Jp = axis``, ``Jr = 0``)."""
        n = len(q)
        if self._batch is None:
            self._batch, self._batch_qpos = self._mj_batch()
        b, qpos = self._batch, self._batch_qpos
        R_wf = np.empty((n, 3, 3))
        x_w = np.empty((n, 3))
        Jp = np.empty((n, 3, self.dof))
        Jr = np.empty((n, 3, self.dof))
        for a in range(0, n, FRAMES_BATCH):
            m = min(FRAMES_BATCH, n - a)
            qpos[:m, self._qpos] = q[a:a + m]
            b.forward(stage=int(self._mj.mjtStage.mjSTAGE_POS))
            site = b.bind("site_xpos")[:m, self.site]
            R_wf[a:a + m] = b.bind("site_xmat")[:m, self.site].reshape(m, 3, 3)
            x_w[a:a + m] = site
            axis = b.bind("xaxis")[:m][:, self._jnt].transpose(0, 2, 1)  # (m, 3, dof)
            arm = site[:, :, None] - b.bind("xanchor")[:m][:, self._jnt].transpose(0, 2, 1)
            hinge = self._hinge[None, None, :]
            Jr[a:a + m] = np.where(hinge, axis, 0.0)
            Jp[a:a + m] = np.where(hinge, _x(axis, arm), axis)
        return R_wf, x_w, Jp, Jr

    def _mj_batch(self):
        """A one-thread ``mujoco.batch.Batch`` of ``FRAMES_BATCH`` copies of the arm with contacts and
        constraints off (only the kinematics is read), and its bound ``qpos`` (FRAMES_BATCH, nq)."""
        import copy

        import mujoco.batch

        mj = self._mj
        m = copy.copy(self.model)
        m.opt.disableflags |= int(mj.mjtDisableBit.mjDSBL_CONTACT) | int(mj.mjtDisableBit.mjDSBL_CONSTRAINT)
        b = mujoco.batch.Batch(m, FRAMES_BATCH, 1, False)
        qpos = b.bind("qpos")
        qpos[:] = self.model.qpos0[None, :]
        for name in ("site_xpos", "site_xmat", "xaxis", "xanchor"):  # outputs: registered before the first call
            b.bind(name)
        return b, qpos

    def series(self, q: np.ndarray, qdot: np.ndarray, t_s: np.ndarray, dt_s: float | None = None) -> KinSeries:
        """Sensor kinematics for (N, dof) joint positions/velocities at times (N,) -> ``KinSeries``.

        Velocities from the site Jacobian, accelerations by a Savitzky-Golay derivative of the
        world-frame sensor twist (window ``ACC_WINDOW_S``; ``dt_s`` as ``derivative``'s)."""
        self.check_joints(q)
        self.check_joints(qdot, "the joint velocity")
        n = len(q)
        R_wf, x_w, Jp, Jr = self._frames(q)
        R_ws = R_wf @ self.R_fs
        lever_w = R_wf @ self.p_fs  # (n, 3) flange origin -> sensor origin, world
        p_ws = x_w + lever_w
        w_w = np.einsum("nij,nj->ni", Jr, qdot)
        v_w = np.einsum("nij,nj->ni", Jp, qdot) + np.cross(w_w, lever_w)
        dv = derivative(v_w, t_s, dt_s=dt_s)
        dw = derivative(w_w, t_s, dt_s=dt_s)
        rot = lambda x: np.einsum("nji,nj->ni", R_ws, x)  # noqa: E731  (world -> s)
        return KinSeries(R_ws, rot(np.broadcast_to(self.g_w, (n, 3))), rot(dv), rot(w_w), rot(dw), p_ws)

    def sensor_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The sensor origin's Jacobians, world frame: (J_v, J_w), each (N, 3, dof): the velocity of
        the sensor origin and the angular velocity per unit rate of each joint (a hinge's J_w column
        is its axis, J_v = axis x (sensor origin - a point on the axis); a slide's J_w is 0, J_v its
        axis)."""
        self.check_joints(q)
        R_wf, _, Jp, Jr = self._frames(q)
        lever_w = R_wf @ self.p_fs  # (n, 3)
        return Jp + _x(Jr, lever_w[:, :, None]), Jr


def _as_slice(idx: np.ndarray) -> slice | np.ndarray:
    """Consecutive addresses as a slice (a view, no copy per sample); any others as they are."""
    if len(idx) and np.array_equal(idx, idx[0] + np.arange(len(idx))):
        return slice(int(idx[0]), int(idx[0]) + len(idx))
    return idx


def derivative(x: np.ndarray, t_s: np.ndarray, window_s: float = ACC_WINDOW_S, dt_s: float | None = None
               ) -> np.ndarray:
    """Smoothed time derivative of (N, k) samples: Savitzky-Golay (cubic) over ``window_s`` on
    the median step (the readers refuse gaps; ``dt_s``: that step, when ``x`` is a chunk of a
    longer log), ``np.gradient`` for very short logs."""
    from scipy.signal import savgol_filter

    n = len(x)
    dt = float(dt_s) if dt_s is not None else float(np.median(np.diff(t_s))) if n > 1 else 1.0
    k = int(round(window_s / dt)) | 1
    if n < max(k, 7):
        return np.gradient(x, t_s, axis=0) if n > 1 else np.zeros_like(x)
    return savgol_filter(x, max(k, 5), 3, deriv=1, delta=dt, axis=0, mode="interp")


def _x(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products along axis 1 of (n, 3[, k]) arrays (broadcast; written out: ``np.cross``
    with axis arguments copies its operands)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def twist_dq(J_v: np.ndarray, J_w: np.ndarray, qdot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dv, dw), each (n, 3, dof): the world-frame velocity of the sensor origin and angular velocity
    per unit change of each joint's position at fixed joint rates. Moving joint j turns (or shifts)
    everything distal to it: the columns i > j turn about joint j's axis ``z_j`` (their derivative
    ``z_j x col_i``) and the sensor origin moves by ``J_v[:, j]``, which the proximal rates i <= j see::

        dw_j = z_j x sum_{i>j} J_w,i qd_i
        dv_j = z_j x sum_{i>j} J_v,i qd_i + (sum_{i<=j} J_w,i qd_i) x J_v,j

    (a serial chain, joints base first; a slide joint has z_j = 0)."""
    wq = J_w * qdot[:, None, :]  # (n, 3, dof)
    vq = J_v * qdot[:, None, :]
    w_le, v_le = np.cumsum(wq, axis=2), np.cumsum(vq, axis=2)
    w_gt, v_gt = w_le[:, :, -1:] - w_le, v_le[:, :, -1:] - v_le
    return _x(J_w, v_gt) + _x(w_le, J_v), _x(J_w, w_gt)


def wrench_dq(kin: KinSeries, J_v: np.ndarray, J_w: np.ndarray, qdot: np.ndarray, t_s: np.ndarray,
              inertials: tuple[float, np.ndarray, np.ndarray]) -> np.ndarray:
    """(n, 6, dof): ``d tool_wrench / d q_j`` (joint rates and times fixed), analytic. The sensor
    frame turns by ``z_j`` (world) per unit ``q_j``, so a world vector seen in s changes by
    ``-zs x x_s`` (``zs = R_ws^T z_j``) plus its own change; the accelerations are the same
    Savitzky-Golay derivative (``derivative``) of the twist's change (``twist_dq``). ``inertials``
    = (m, m c, I_O) of ``nominal_inertials``."""
    m, mc, I_O = inertials
    n, dof = qdot.shape
    dv, dw = twist_dq(J_v, J_w, qdot)
    ddv = derivative(dv.reshape(n, 3 * dof), t_s).reshape(n, 3, dof)
    ddw = derivative(dw.reshape(n, 3 * dof), t_s).reshape(n, 3, dof)
    R = kin.R_ws
    Rt = R.transpose(0, 2, 1)
    to_s = lambda x: np.matmul(Rt, x)  # noqa: E731  (world -> s, (n, 3, dof))
    zs = to_s(J_w)
    om, al = kin.omega_s[:, :, None], kin.alpha_s[:, :, None]
    d_om = to_s(dw) - _x(zs, om)
    d_al = to_s(ddw) - _x(zs, al)
    d_ga = _x(zs, (kin.a_s - kin.g_s)[:, :, None]) - to_s(ddv)  # d(g_s - a_s)
    mcv = np.broadcast_to(mc[None, :, None], zs.shape)
    C = np.empty((n, 6, dof))
    C[:, :3] = m * d_ga - _x(d_al, mcv) - _x(d_om, _x(om, mcv)) - _x(om, _x(d_om, mcv))
    I_om = np.einsum("ij,nj->ni", I_O, kin.omega_s)[:, :, None]
    C[:, 3:] = _x(mcv, d_ga) - I_O @ d_al - _x(d_om, I_om) - _x(om, I_O @ d_om)
    return C


def tool_wrench(kin: KinSeries, mass: float, mc_s: np.ndarray, I_O: np.ndarray) -> np.ndarray:
    """Rigid-body wrench a tool exerts on the sensor (s, about its origin), Newton-Euler
    (module docstring). mass [kg], first moment ``m c`` (3,) [kg m], inertia about the sensor
    origin (3, 3) [kg m^2] -> (N, 6)."""
    ga = kin.g_s - kin.a_s
    F = mass * ga - np.cross(kin.alpha_s, mc_s) - np.cross(kin.omega_s, np.cross(kin.omega_s, mc_s))
    Iw = kin.omega_s @ I_O.T
    M = np.cross(mc_s, ga) - kin.alpha_s @ I_O.T - np.cross(kin.omega_s, Iw)
    return np.concatenate([F, M], axis=1)


def nominal_inertials(setup: SetupCfg) -> tuple[float, np.ndarray, np.ndarray]:
    """(m [kg], m c (3,) [kg m], I_O (3, 3) [kg m^2] about the sensor origin) of the declared tool
    (``setup.ToolDeclCfg.inertials``)."""
    return setup.tool.inertials()


def tip_moment_map(tip_s: np.ndarray) -> np.ndarray:
    """``L = [-[p]x, 1]`` (3, 6): a sensor wrench -> its moment about the tip ``p`` (s)."""
    p = np.asarray(tip_s, dtype=float)
    px = np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])
    return np.concatenate([-px, np.eye(3)], axis=1)
