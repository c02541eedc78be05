"""``LogSignals``: one object per user log, what every effect's columns are computed from.

Built once per diagnosis from the reader's ``UserLog`` and the setup (``from_log``): the encoders
through the arm model (``physical.ArmModel``) give the sensor's pose and motion, the log's wrench
in the internal convention (the tool on the sensor), the declared tool's wrench (the nominal
model) and the contact mask. Frames: ``w`` world (z up), ``s`` the F/T sensor. Full rate, before
any filtering (the diagnosis filters the columns and the residual with the same operator).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from kinadapt_nn.effects import contact_model
from kinadapt_nn.diagnostics import physical as ph


def sample_noise(r: np.ndarray) -> np.ndarray:
    """Per-channel sample noise (6,) of a reading (n, 6) sampled in time: the robust scale (MAD) of
    its second differences (a smooth signal's cancel), no floor; zeros for fewer than 5 samples."""
    if len(r) < 5:
        return np.zeros(r.shape[1])
    out = np.empty(r.shape[1])
    for c in range(r.shape[1]):  # a channel at a time: the temporaries of one (n,) series
        x = np.asarray(r[:, c], dtype=float)
        d2 = x[2:] - 2 * x[1:-1] + x[:-2]
        out[c] = 1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0)
    return out


@dataclass(frozen=True, eq=False)
class LogSignals:
    """The signals of one log (n samples, dof joints); the ``s`` of an effect function."""

    t: np.ndarray  #: (n,) [s] from the first sample
    q: np.ndarray  #: (n, dof) [rad] encoder positions
    qdot: np.ndarray  #: (n, dof) [rad/s] (logged, or differentiated from q)
    #: (n, dof) [rad/s^2] held, or None: ``qddot`` differentiates ``qdot`` (Savitzky-Golay) when first
    #: read -- a log in time holds it per chunk only (``stream.slice_signals``), each chunk's own
    _qddot: np.ndarray | None
    R_ws: np.ndarray  #: (n, 3, 3) sensor axes in the world (columns: s's x, y, z in w)
    p_ws: np.ndarray  #: (n, 3) [m] sensor origin in the world
    g_s: np.ndarray  #: (n, 3) [m/s^2] gravity in s
    a_s: np.ndarray  #: (n, 3) [m/s^2] acceleration of the sensor origin in s
    omega_s: np.ndarray  #: (n, 3) [rad/s] angular velocity in s
    alpha_s: np.ndarray  #: (n, 3) [rad/s^2] angular acceleration in s
    wrench: np.ndarray  #: (n, 6) [N, N m] measured wrench of the tool ON the sensor, s, about its origin
    contact: np.ndarray  #: (n,) bool: contact detected
    extra: dict  #: declared extra columns ([log] extra): name -> (n,)
    setup: object  #: the validated setup (``SetupCfg``)
    w_nom: np.ndarray  #: (n, 6) [N, N m] the declared tool's wrench (+ a declared socket's: ``contact_model``)
    contact_force_s: np.ndarray  #: (n, 3) [N] force beyond the tool model in contact (s), 0 in free space
    tip_map: np.ndarray  #: (3, 6) a wrench -> its moment about the declared tip
    arm: ph.ArmModel = field(repr=False, default=None)  #: the arm model (forward kinematics)
    static: bool = False  #: a static-pose log ([log] static): rows are poses at rest, in canonical order
    has_time: bool = True  #: the log has a time column (False: ``t`` is the pose index, not a clock)
    pose_block: np.ndarray | None = None  #: (n,) static logs: the group of similar poses of each row (CV blocks)
    #: a chunk of a log (``stream.slice_signals``): the whole log's numbers that shapes need (time span,
    #: mean joint angles (dof,), extra columns' means); None for a whole log
    whole: dict | None = field(repr=False, default=None)

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def qddot(self) -> np.ndarray:
        """(n, dof) [rad/s^2] the joint accelerations: held (a static log's zeros), or the Savitzky-Golay
        derivative of ``qdot`` on ``clock``, made when first read (no built-in effect reads it; a
        user's may) and kept."""
        if self._qddot is None:
            object.__setattr__(self, "_qddot", ph.derivative(np.asarray(self.qdot, dtype=float), self.clock))
        return self._qddot

    @property
    def clock(self) -> np.ndarray:
        """(n,) the time axis derivatives are taken on: ``t``, or the pose index of a static log."""
        return np.arange(self.n, dtype=float) if self.static else self.t

    def nominal_wrench(self, q: np.ndarray) -> np.ndarray:
        """The declared tool's wrench (n, 6) had the encoders read ``q`` (n, dof) instead (same
        velocities and times): for effects that move the model's joint angles."""
        m, mc, I_O = ph.nominal_inertials(self.setup)
        kin = self.arm.series(q, self.qdot, self.clock)
        return ph.tool_wrench(kin, m, mc, I_O) + contact_model.nominal_wrench(self.setup, kin.R_ws, kin.p_ws,
                                                                               contact_model.log_times(self))

    def nominal_wrench_dq(self) -> np.ndarray:
        """(n, 6, dof) ``d w_nom / d q_j``: the declared model's wrench per unit change of each joint's
        reading (same velocities and times), analytic from the sensor's Jacobians
        (``ArmModel.sensor_jacobian``; ``physical.wrench_dq``)."""
        J_v, J_w = self.arm.sensor_jacobian(self.q)
        kin = ph.KinSeries(*(np.asarray(x, dtype=float) for x in (self.R_ws, self.g_s, self.a_s, self.omega_s,
                                                                   self.alpha_s, self.p_ws)))
        m, mc, I_O = ph.nominal_inertials(self.setup)
        C = ph.wrench_dq(kin, J_v, J_w, np.asarray(self.qdot, dtype=float), self.clock, (m, mc, I_O))
        if self.setup.contact.geometry != "none":  # a declared socket: its wrench moved with the sensor
            C += contact_model.nominal_wrench_dq(self.setup, kin.R_ws, kin.p_ws, J_v, J_w, t_s=contact_model.log_times(self))
        return C

    def with_contact(self, contact: np.ndarray, offset: np.ndarray) -> "LogSignals":
        """The same log with another contact mask; ``offset`` (6,) is the free-space offset taken
        out of the contact force."""
        f_c = np.zeros((self.n, 3), self.contact_force_s.dtype)
        f_c[contact] = self.wrench[contact, :3] - self.w_nom[contact, :3] - offset[:3]
        return replace(self, contact=contact, contact_force_s=f_c)


#: static logs: poses per cross-validation block (groups of similar gravity directions)
POSES_PER_BLOCK = 8
MAX_STATIC_BLOCKS = 30


#: samples per chunk of the kinematics (its work arrays are ~1 kB per sample)
KIN_CHUNK = 50_000
#: storage of the whole log's derived series (kinematics, the nominal wrench): single precision
#: (relative rounding 6e-8, far below any sensor's noise); a chunk (``stream.slice_signals``) is
#: handed to the effects in double precision. The encoders, the time and the wrench stay double.
STORE = np.float32


def from_log(log, setup, progress=lambda msg: None) -> LogSignals:
    """A reader's ``UserLog`` + setup -> ``LogSignals`` (contact: none yet; ``with_contact``).

    A static-pose log (``[log] static``): no derivatives are taken (velocities and accelerations
    are zero), and the rows are put in a canonical order that does not depend on the file's row
    order (sorted by the poses' values, then grouped by the direction of gravity in the sensor:
    ``pose_block``), so that no verdict depends on the order the poses were logged in. A log in
    time: the kinematics in chunks of ``KIN_CHUNK`` samples (each widened by the derivatives'
    windows, so every sample sees the same neighbours), stored as ``STORE``."""
    arm = ph.ArmModel(setup)
    static = bool(setup.log.static)
    q = np.asarray(log.q_rad, dtype=float)
    n = len(q)
    has_time = log.t_s is not None
    t = np.asarray(log.t_s, dtype=float) if has_time else np.arange(n, dtype=float)
    r = np.asarray(log.wrench_log, dtype=float)
    r = r if setup.log.sign == 1 else setup.log.sign * r  # no copy of a log in the internal convention
    extra = {k: np.asarray(v, dtype=float) for k, v in (getattr(log, "extra", None) or {}).items()}
    progress(f"kinematics of {n} {'poses' if static else 'samples'}")
    if not static:
        return _timed(arm, setup, (t, q, r, extra), log.qdot_rad_s, has_time)
    order = np.lexsort(np.concatenate([q, r], axis=1).T[::-1])  # canonical: by the values, not the file
    q, r, t = q[order], r[order], t[order]
    extra = {k: v[order] for k, v in extra.items()}
    qdot = np.zeros_like(q)
    kin = arm.series(q, qdot, np.arange(n, dtype=float))
    block = gravity_groups(kin.g_s, max(2, min(MAX_STATIC_BLOCKS, n // POSES_PER_BLOCK)))
    order = np.argsort(block, kind="stable")
    q, r, t, qdot, block = q[order], r[order], t[order], qdot[order], block[order]
    extra = {k: v[order] for k, v in extra.items()}
    kin = ph.KinSeries(*(None if x is None else x[order] for x in kin))
    m, mc, I_O = ph.nominal_inertials(setup)
    return LogSignals(t, q, qdot, np.zeros_like(q), kin.R_ws, kin.p_ws, kin.g_s, kin.a_s, kin.omega_s,
                      kin.alpha_s, r, np.zeros(n, bool), extra, setup,
                      ph.tool_wrench(kin, m, mc, I_O) + contact_model.nominal_wrench(setup, kin.R_ws, kin.p_ws),
                      np.zeros((n, 3)), ph.tip_moment_map(setup.tool.tip_sensor_m), arm, True, has_time, block)


def _timed(arm: ph.ArmModel, setup, data: tuple, qdot_log, has_time: bool) -> LogSignals:
    """``from_log`` of a log in time: ``data`` = (t, q, r, extra); the kinematics chunk by chunk."""
    from kinadapt_nn.diagnostics import stream

    t, q, r, extra = data
    n, dof = q.shape
    arm.check_joints(q)
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    halo = 2 * max(int(round(ph.ACC_WINDOW_S / dt)) | 1, 7) + 2  # two derivatives deep (q -> qdot -> acceleration)
    qdot = np.asarray(qdot_log, dtype=float) if qdot_log is not None else np.empty((n, dof), STORE)
    out = {k: np.empty(shape, STORE) for k, shape in (("R_ws", (n, 3, 3)), ("p_ws", (n, 3)),
                                                    ("g_s", (n, 3)), ("a_s", (n, 3)), ("omega_s", (n, 3)),
                                                    ("alpha_s", (n, 3)), ("w_nom", (n, 6)))}
    m, mc, I_O = ph.nominal_inertials(setup)
    socket = setup.contact.geometry != "none"  # its anchors are where its gate opens: the whole log at once,
    pose64 = (np.empty((n, 3, 3)), np.empty((n, 3))) if socket else None  # from the pose in double precision
    for a, b in stream.chunks(n, KIN_CHUNK):
        lo, hi = max(0, a - halo), min(n, b + halo)
        tc = t[lo:hi]
        qd = qdot[lo:hi] if qdot_log is not None else ph.derivative(q[lo:hi], tc, dt_s=dt)
        kin = arm.series(q[lo:hi], np.asarray(qd, dtype=float), tc, dt_s=dt)
        keep = slice(a - lo, b - lo)
        if qdot_log is None:
            qdot[a:b] = qd[keep]
        for k in ("R_ws", "p_ws", "g_s", "a_s", "omega_s", "alpha_s"):
            out[k][a:b] = getattr(kin, k)[keep]
        out["w_nom"][a:b] = ph.tool_wrench(kin, m, mc, I_O)[keep]
        if socket:
            pose64[0][a:b], pose64[1][a:b] = kin.R_ws[keep], kin.p_ws[keep]
    if socket:
        out["w_nom"] += contact_model.nominal_wrench(setup, *pose64, t)
    t0 = t[0] if has_time else 0.0
    return LogSignals(t - t0 if t0 != 0.0 else t, q, qdot, None, out["R_ws"], out["p_ws"], out["g_s"],
                      out["a_s"], out["omega_s"], out["alpha_s"], r, np.zeros(n, bool), extra, setup, out["w_nom"],
                      np.zeros((n, 3), STORE), ph.tip_moment_map(setup.tool.tip_sensor_m), arm, False, has_time, None)


def can_turn(s: LogSignals, setup) -> bool:
    """Whether ``in_mount(s, setup)`` applies: a log in time, ``setup`` differs from ``s.setup`` only in
    the sensor's orientation on the flange, and no contact geometry is declared (its wrench is
    computed from the pose in double precision: ``from_log``)."""
    if s.static or setup.contact.geometry != "none":
        return False
    a, b = s.setup.sensor, setup.sensor
    return a.model_copy(update={"rpy_flange_deg": b.rpy_flange_deg}) == b and \
        s.setup.model_copy(update={"sensor": b}) == setup


def in_mount(s: LogSignals, setup) -> LogSignals:
    """``from_log`` of the same log with the sensor turned on the flange to ``setup.sensor.rpy_flange_deg``
    (``can_turn``): the sensor-frame series turned by ``D = R_fs_old^T R_fs_new`` (``R_ws D``; a vector in s
    ``D^T v``; the sensor origin does not move), the declared tool's wrench computed again in the new
    axes -- chunk by chunk, without a second pass of the arm's kinematics. Equal to ``from_log`` to the
    rounding of the stored series (``STORE``)."""
    from kinadapt_nn.diagnostics import stream

    D = s.setup.sensor.R_fs().T @ setup.sensor.R_fs()
    names = ("R_ws", "g_s", "a_s", "omega_s", "alpha_s")
    out = {k: np.empty_like(getattr(s, k)) for k in (*names, "w_nom")}
    m, mc, I_O = ph.nominal_inertials(setup)
    for a, b in stream.chunks(s.n, KIN_CHUNK):
        turned = [np.asarray(getattr(s, k)[a:b], dtype=float) @ D for k in names]
        for k, v in zip(names, turned):
            out[k][a:b] = v
        out["w_nom"][a:b] = ph.tool_wrench(ph.KinSeries(*turned), m, mc, I_O)
    return replace(s, setup=setup, arm=ph.ArmModel(setup), **out)


def gravity_groups(g_s: np.ndarray, k: int, iters: int = 30) -> np.ndarray:
    """(n,) group of each pose: k-means on the direction of gravity in the sensor (n, 3), started
    from the farthest-point sequence of the rows' canonical order (deterministic). Groups are
    numbered by their smallest row."""
    u = g_s / np.maximum(np.linalg.norm(g_s, axis=1, keepdims=True), 1e-12)
    n = len(u)
    k = min(k, n)
    centres = [0]
    dmin = np.linalg.norm(u - u[0], axis=1)
    for _ in range(1, k):
        j = int(np.argmax(dmin))
        centres.append(j)
        dmin = np.minimum(dmin, np.linalg.norm(u - u[j], axis=1))
    C = u[centres].copy()
    lab = np.zeros(n, int)
    for _ in range(iters):
        lab_new = np.argmin(((u[:, None, :] - C[None]) ** 2).sum(-1), axis=1)
        if np.array_equal(lab_new, lab) and _ > 0:
            break
        lab = lab_new
        for j in range(k):
            if np.any(lab == j):
                C[j] = u[lab == j].mean(0)
    first = {j: int(np.flatnonzero(lab == j)[0]) for j in np.unique(lab)}
    rank = {j: i for i, j in enumerate(sorted(first, key=first.get))}
    return np.array([rank[j] for j in lab])
