"""B episodes' scenes stepped together: the simulated world of an episode loop (truth side).

``SceneBatch`` holds one ``PegInHoleSim`` per episode (its model, ids, start pose, hidden
effects, socket state) and steps them as one ``mujoco.batch.Batch`` (a batch's results are
bit-identical to ``mj_step`` on one MjData per simulation, as its documentation states); one
episode on one thread steps its own MjData with ``mj_step`` instead, which saves the batch's
per-call copies. Either way the loop sees the same (B, ...) arrays.

What it offers the loop, and nothing else:

* :meth:`sense_into` -- what a real robot's sensors hand the controller: one instant's encoders and raw
  F/T reading (for the motion each step realised: ``sim.ft_sensor``), with the hidden sensor effects (``sim.effects.SensorEffects``) and simulated
  faults (``sim.adapter.SensorFaults``) applied, (B, 2n+6) rows;
* :meth:`apply` and :meth:`step` -- the joint servo set-points, then one physics step (the socket
  contact's wrench first, where that contact model is on);
* :meth:`truth_into` -- the per-step ground truth the logger needs (true tip, contacts); for
  evaluation only, never handed to the controller (the truth firewall);
* :meth:`warned` -- which episodes MuJoCo warned about since the start (the divergence watch;
  a persistent batch or one episode).
"""

from __future__ import annotations

import types
from typing import NamedTuple

import mujoco
import mujoco.batch
import numba as nb
import numpy as np

from kinadapt_nn import compiled
from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.robot import SERVO_KP, SERVO_KV
from kinadapt_nn.sim.adapter import PegInHoleSim, SensorFaults, SensorSample, contact_sums
from kinadapt_nn.sim import ft_sensor
from kinadapt_nn.sim.ft_sensor import SOURCE_FIELDS as FT_FIELDS
from kinadapt_nn.sim.ft_sensor import RealisedSensor

#: the fields a socket contact reads and writes (``PegInHoleSim.bind_socket``)
_SOCKET_FIELDS = ("site_xpos", "xmat", "xipos", "cvel", "subtree_com", "xfrc_applied")


class StepTruth(NamedTuple):
    """One step's ground truth of B episodes (evaluation only; never given to the controller)."""

    tip_pos_w_m: np.ndarray  #: (B, 3) true tip position, world [m]
    contact: np.ndarray  #: (B, 3) [face (0/1), bore (0/1), total normal force peg <-> block [N]]


@nb.njit(cache=True)
def _gather(qpos, qvel, wrench, qadr, vadr, inp):
    """The controller's input rows [q; qdot; raw F/T] (B, 2n+6) from the (B, .) state buffers and
    the (B, 6) F/T readings."""
    n = qadr.shape[0]
    for b in range(inp.shape[0]):
        for j in range(n):
            inp[b, j] = qpos[b, qadr[j]]
            inp[b, n + j] = qvel[b, vadr[j]]
        for j in range(6):
            inp[b, 2 * n + j] = wrench[b, j]


@nb.njit(cache=True)
def _servo(u, q_ref, qdot_ref, kv_over_kp, active):
    """Servo set-points u = q_ref + kv/kp qdot_ref (B, n) of the active episodes (the single
    simulator's rounding: ``adapter._servo_setpoint``)."""
    for b in range(u.shape[0]):
        if active[b]:
            for i in range(u.shape[1]):
                u[b, i] = qdot_ref[b, i] * kv_over_kp + q_ref[b, i]


#: the scenes' numba kernels (a compile phase checks they are cached: ``controller.core.cache_probe``)
KERNELS = (_gather, _servo, contact_sums, *ft_sensor.KERNELS)


def _bound(fn, args):
    """``fn`` compiled (or loaded from numba's cache) for the types of ``args``, and its compiled
    entry: for arguments whose types never change in the loop (the dispatcher's type resolution
    skipped; ``compiled.entry_point``)."""
    compiled.compile_for(fn, args)
    return compiled.entry_point(fn, args)


class SceneBatch:
    """The scenes of ``cfgs`` (one episode each; they share the scene's structure), every arm at
    its start pose and at rest, the servos holding it. ``nthread``: the batch's threads;
    ``persistent`` (default: nthread > 1): each episode keeps its whole MjData (contacts beyond
    the contact sensor's slots, for :meth:`truth_into`). Arrays are (B, ...), B = len(cfgs)."""

    def __init__(self, cfgs: list[ExperimentCfg], nthread: int = 1, persistent: bool | None = None) -> None:
        self.sims = [PegInHoleSim(c) for c in cfgs]
        s0 = self.sims[0]
        self.ids = ids = s0.ids
        self.B, self.n = len(cfgs), len(ids.qpos_adr)
        if self.B == 1 and nthread <= 1:  # one episode: its own MjData, mj_step
            self.physics = None
            d = s0.data
            src = types.SimpleNamespace(**{f: getattr(d, f)[None] for f in ("qpos", "qvel", "ctrl", "sensordata",
                                                                            *_SOCKET_FIELDS)})
            self._data_of = [lambda: d]
            self.ft = s0.ft  # the F/T reading for the realised motion (``sim.ft_sensor``)
        else:
            self.physics = self._batch(nthread, nthread > 1 if persistent is None else persistent)
            src = types.SimpleNamespace(**{f: self.physics.bind(f) for f in ("qpos", "qvel", "ctrl", "sensordata",
                                                                            *_SOCKET_FIELDS, "ncon", "time")})
            dbuf = mujoco.MjData(s0.model)  # one episode's whole MjData, copied out when needed
            self._data_of = [lambda b=b: self.physics.get_data(b, dbuf) for b in range(self.B)]
            self.ft = RealisedSensor(types.SimpleNamespace(**{f: self.physics.bind(f) for f in FT_FIELDS}),
                                     s0.ft_chain, s0.model.opt.timestep)
        self.qpos, self.qvel, self.ctrl, self.sensordata = src.qpos, src.qvel, src.ctrl, src.sensordata
        self._src = src
        #: (B, 3) the true tips, world [m]: a live view (truth side: evaluation only, never the controller's)
        self.tip_w_m = src.site_xpos[:, ids.tip_site]
        self._sens_rows = list(self.sensordata)  # each episode's sensordata row (a view)
        rows = [types.SimpleNamespace(**{k: getattr(src, k)[b] for k in _SOCKET_FIELDS}) for b in range(self.B)]
        self._sockets = [(b, s.bind_socket(rows[b])) for b, s in enumerate(self.sims) if s.has_socket]
        self._has_socket = [s.has_socket for s in self.sims]
        self._sensor_side = self._sensor_side_of(cfgs)
        self._timed = [(b, s.timed) for b, s in enumerate(self.sims) if s.timed is not None]
        if self.physics is not None and any(fx.payload is not None or fx.slip is not None for _b, fx in self._timed):
            raise ConfigError("a payload picked up mid-run (effects.tool_gravity.onset_s > 0) or a grasp slip changes "
                              "the scene's model during the run: run it as one episode (kinadapt online), not in a "
                              "batch")
        self._warn0 = self._warnings(range(self.B)) if self.physics is None or self.physics.persistent else None
        self._init_kernels()

    def _batch(self, nthread: int, persistent: bool) -> mujoco.batch.Batch:
        """The ``mujoco.batch.Batch`` of the episodes' models at their start poses, at rest."""
        physics = mujoco.batch.Batch(self.sims[0].model, self.B, nthread, persistent)
        try:
            physics.set_models([s.model for s in self.sims])
        except mujoco.FatalError as exc:
            raise ConfigError("a batch shares the scene's structure (contact model, chamfer, the friction reference "
                              "scene.contact_friction_timeconst_s on or off, hidden effects); these configs differ in "
                              f"it -- run them as separate batches ({exc})") from None
        q0 = np.array([s.q_start for s in self.sims])
        physics.bind("qpos")[:, self.ids.qpos_adr] = q0
        physics.bind("qvel")[:] = 0.0
        physics.bind("ctrl")[:] = q0
        physics.forward()
        return physics

    def _sensor_side_of(self, cfgs: list[ExperimentCfg]) -> list[tuple[int, object, object]]:
        """(episode, hidden sensor effects or None, simulated faults or None) of the episodes
        with either."""
        rows = []
        for b, (s, c) in enumerate(zip(self.sims, cfgs)):
            fx = s.sensor_effects if s.sensor_effects.active else None
            faults = SensorFaults(c.faults, c.run.seed, c.start.settle_s) if SensorFaults.active(c.faults) else None
            if fx is not None or faults is not None:
                rows.append((b, fx, faults))
        return rows

    def _init_kernels(self) -> None:
        ids = self.ids
        self._qadr, self._vadr = np.ascontiguousarray(ids.qpos_adr), np.ascontiguousarray(ids.dof_adr)
        self._all = np.arange(self.B, dtype=np.int64)
        self._kv_over_kp = SERVO_KV / SERVO_KP
        self._gather = None  # bound to the caller's input rows at the first sense_into
        self._servo = None

    # -- what the sensors give ----------------------------------------------------------------
    def sense_into(self, t: float, inp: np.ndarray, active: np.ndarray) -> None:
        """Every episode's sample [q [rad]; qdot [rad/s]; raw F/T reading in f [N, N m]] into
        ``inp`` (B, 2n+6), as a real robot gives it: the hidden sensor effects and the simulated
        faults applied to the ``active`` (B,) bool episodes' samples at time ``t`` [s]."""
        if self._gather is None:
            self._gather = _bound(_gather, (self.ft.qpos0, self.ft.qvel0, self.ft.wrench, self._qadr, self._vadr, inp))
        self._gather(self.ft.qpos0, self.ft.qvel0, self.ft.wrench, self._qadr, self._vadr, inp)
        n = self.n
        for b, fx, faults in self._sensor_side:
            if active[b]:
                row = inp[b]
                w = row[2 * n:]
                if fx is not None:
                    fx(t, w)
                if faults is not None:
                    o = faults(t, SensorSample(row[:n].copy(), row[n:2 * n].copy(), w.copy()))
                    row[:n], row[n:2 * n], row[2 * n:] = o.q_rad, o.qdot_rad_s, o.wrench_raw_f

    # -- what the robot is given --------------------------------------------------------------
    def apply(self, q_ref: np.ndarray, qdot_ref: np.ndarray, active: np.ndarray) -> None:
        """Joint servo set-points with velocity feed-forward, q_ref + kv/kp qdot_ref (B, n) [rad],
        for the ``active`` (B,) bool episodes."""
        if self._servo is None:
            self._servo = _bound(_servo, (self.ctrl, q_ref, qdot_ref, self._kv_over_kp, active))
        self._servo(self.ctrl, q_ref, qdot_ref, self._kv_over_kp, active)

    def step(self, t: float, active: np.ndarray, every_one: bool) -> None:
        """One physics step of the ``active`` (B,) bool episodes (``every_one``: all of them), the
        socket contact's wrench at time ``t`` [s] applied first where it is on: for the state the
        step starts from (its positions and velocities computed first: ``mj_step1``, then the
        socket, then ``mj_step2``; a batch computes those stages with ``forward(stage=VEL)`` and
        then steps), so the fixture's spring acts on the pose the reading belongs to."""
        for b, fx in self._timed:  # hidden effects with an onset (``sim.effects.TimedEffects``)
            if active[b]:
                fx(t, self.sims[b].model if self.physics is None else None, self._src.xfrc_applied[b])
        if self.physics is None:
            if every_one or active[0]:
                s = self.sims[0]
                mujoco.mj_step1(s.model, s.data)
                for _b, socket in self._sockets:
                    socket(t)
                s.ft.before_step()
                mujoco.mj_step2(s.model, s.data)
                s.ft.after_step(self._all)
            return
        rows = None if every_one else np.flatnonzero(active)
        if self._sockets:
            self.physics.forward(rows, stage=mujoco.mjtStage.mjSTAGE_VEL.value)
            for b, socket in self._sockets:
                if active[b]:
                    socket(t)
        self.ft.before_step()
        self.physics.step(rows)
        self.ft.after_step(self._all if rows is None else rows.astype(np.int64))

    # -- ground truth (evaluation only) -------------------------------------------------------
    def truth_into(self, rows, truth: StepTruth) -> None:
        """This step's ground truth of episodes ``rows`` (a slice or a (B,) bool mask) into the rows
        of ``truth`` (:class:`StepTruth`, (B, ...) arrays): the true tip; [face, bore, normal force]
        where an episode has a contact (its row is left as it is otherwise: zeros in a new log).
        MuJoCo's contact sensor on the peg <-> block contacts (``PegInHoleSim.contacts_of``)."""
        truth.tip_pos_w_m[rows] = self.tip_w_m[rows]
        self.contacts_into(rows, truth.contact)

    def contacts_into(self, rows, contact: np.ndarray) -> None:
        """The contact part of :meth:`truth_into`: [face, bore, normal force [N]] into the rows of
        ``contact`` (B, 3) of episodes ``rows`` that have a contact (the others left as they are)."""
        if self.physics is None:  # one episode: its own MjData
            s = self.sims[0]
            if s.has_socket or s.data.ncon:
                contact[0] = s.contacts_of(self._sens_rows[0], self._data_of[0])
            return
        ncon = self._src.ncon.tolist()
        for b in (range(self.B) if isinstance(rows, slice) else np.flatnonzero(rows)):
            if self._has_socket[b] or ncon[b]:
                contact[b] = self.sims[b].contacts_of(self._sens_rows[b], self._data_of[b])

    def tip_depths(self, b: int, tip_w_m: np.ndarray) -> np.ndarray:
        """Episode ``b``'s true tip depths below its true bore entrance for tips (N, 3) [m] -> (N,)."""
        return self.sims[b].tip_depths(tip_w_m)

    @property
    def time_s(self) -> np.ndarray:
        """(B,) each episode's simulated time [s]."""
        if self.physics is None:
            return np.array([self.sims[0].data.time])
        return self._src.time.copy()

    def _warnings(self, rows) -> np.ndarray:
        """Warning counts (summed over MuJoCo's kinds) of episodes ``rows`` (indices)."""
        if self.physics is None:
            return np.array([int(self.sims[0].data.warning.number.sum())])
        return np.array([int(self._data_of[b]().warning.number.sum()) for b in rows], dtype=np.int64)

    def warned(self, active: np.ndarray) -> np.ndarray:
        """(B,) bool: MuJoCo warned about the episode (a warning counter rose) since the start, of
        the ``active`` (B,) bool episodes. A batch that is not persistent keeps no MjData per
        episode, hence no warnings of its own: nothing is reported then."""
        out = np.zeros(self.B, bool)
        if self.physics is not None and not self.physics.persistent:
            return out
        rows = np.flatnonzero(active)
        out[rows] = self._warnings(rows) > self._warn0[rows]
        return out
