"""The simulated wrist F/T sensor: the interaction wrench for the motion the integrator realises.

MuJoCo evaluates its ``force``/``torque`` sensors inside ``mj_forward``, with the acceleration
``qacc = M^-1 (qfrc_smooth + qfrc_constraint)`` of the explicit dynamics. The ``implicitfast``
integrator then advances the velocity with ``(M - dt D)^-1 (qfrc_smooth + qfrc_constraint)``
(D: the derivative of the smooth forces in the velocity, here the stiff servos' ``-kv``), so the
motion the encoders show is not the one the sensor was evaluated for: on the Panda's wrist joints
``qacc`` is 4.7-5.3x the realised acceleration (``benchmarks/sim_sensor_acceleration.py``), and
the tool's inertial load in the simulated reading was up to -6x the one its motion implies. A real
sensor measures the wrench that produced the real motion.

The reading here is the interaction wrench between the sensor site's body and its parent (what
MuJoCo's sensors define), with the acceleration the step realised,
``a = (qvel_{k+1} - qvel_k) / dt`` (exactly what the encoders' velocities show), and that step's
contact forces and applied forces (``cfrc_ext``, unchanged). The sensor's composite-rigid-body
wrench is linear in ``qacc``, so the reading is MuJoCo's plus the change that the acceleration's
difference makes (Featherstone, *Rigid Body Dynamics Algorithms*, 2008, sec. 5.3: the recursive
Newton-Euler force of a subtree)::

    d cfrc_int(s) = sum_{b in subtree(s)} I_b  sum_{j in chain(b)} cdof_j (a_j - qacc_j)

``I_b``: body b's spatial inertia about the subtree root's centre of mass (MuJoCo's ``cinert``),
``cdof_j``: dof j's motion axis in the same frame; the force then moved to the site and rotated into
its frame as MuJoCo's ``mj_sensorAcc`` does. The reading belongs to the state the step started from
(positions, velocities, contacts of step k) with the acceleration over [k, k+1], and it is handed
out with the encoders of that same state (:attr:`RealisedSensor.qpos0`, ``qvel0``): one instant's
encoders and wrench, as a real robot samples them together. The sample reaches the controller one
physics step after that instant (a transport delay, as on a real robot's bus); before, the encoders
of k+1 were paired with the reading of k, a 1 ms offset between the two that no model of the
diagnosis has (it turned the socket's angular spring by omega dt between them:
``benchmarks/excite_table.py --shift-wrench``).

Checked against MuJoCo's own recursive Newton-Euler with ``qacc`` set to the realised acceleration
(``mj_rnePostConstraint`` + ``mj_sensorAcc``, to rounding) and against an independent Newton-Euler
computation of the rigid tool from a logged trajectory (tests/sim/test_ft_sensor.py).
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numba as nb
import numpy as np


class SensorChain(NamedTuple):
    """What the reading needs of a model, looked up once."""

    site: int  #: the sensor site's id
    root: int  #: the root body of the site's body (its subtree_com is the c-frame origin)
    bodies: np.ndarray  #: (k,) int64 ids of the bodies in the subtree of the site's body
    chain: np.ndarray  #: (k, nv) float64: 1 where dof j moves body ``bodies[i]`` (its ancestors' and own dofs)
    force_adr: int  #: sensordata address of the 3 force values (site frame) [N]
    torque_adr: int  #: sensordata address of the 3 torque values (about the site, site frame) [N m]


def sensor_chain(model: mujoco.MjModel, force_sensor: str, torque_sensor: str) -> SensorChain:
    """The :class:`SensorChain` of the force/torque sensor pair named ``force_sensor``,
    ``torque_sensor`` (both on one site)."""
    fi = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, force_sensor)
    ti = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, torque_sensor)
    site = int(model.sensor_objid[fi])
    body = int(model.site_bodyid[site])
    bodies = [b for b in range(model.nbody) if _descends(model, b, body)]
    chain = np.zeros((len(bodies), model.nv))
    for i, b in enumerate(bodies):
        a = b
        while a > 0:
            for j in range(int(model.body_dofadr[a]), int(model.body_dofadr[a]) + int(model.body_dofnum[a])):
                chain[i, j] = 1.0
            a = int(model.body_parentid[a])
    return SensorChain(site, int(model.body_rootid[body]), np.array(bodies, dtype=np.int64), chain,
                       int(model.sensor_adr[fi]), int(model.sensor_adr[ti]))


def _descends(model: mujoco.MjModel, b: int, ancestor: int) -> bool:
    while b > 0:
        if b == ancestor:
            return True
        b = int(model.body_parentid[b])
    return b == ancestor


@nb.njit(cache=True)
def realised_wrench(out, state, qvel0, inv_dt, model, rows):
    """The sensor's reading [force (3) N, torque (3) N m], site frame, with the realised
    acceleration, into ``out`` (B, 6) for the episodes in ``rows`` (int64 indices).

    ``state``: the fields of :data:`FIELDS` in that order, each (B, ...), one MjData's each after
    the step: ``sensordata`` (nsensordata,) MuJoCo's reading; ``qacc`` (nv,) the acceleration it
    used; ``qvel`` (nv,) the velocity after the step; ``cinert`` (nbody, 10), ``cdof`` (nv, 6),
    ``site_xpos`` (nsite, 3), ``site_xmat`` (nsite, 9), ``subtree_com`` (nbody, 3): the step's
    start state. ``qvel0`` (B, nv) the velocity before the step; ``inv_dt`` 1/timestep [1/s];
    ``model``: (bodies, chain, [site, root, force_adr, torque_adr]) of :class:`SensorChain`."""
    sens, qacc, qvel1, cinert, cdof, site_xpos, site_xmat, subtree_com = state
    bodies, chain, idx = model
    site, root, force_adr, torque_adr = idx[0], idx[1], idx[2], idx[3]
    nv = qacc.shape[1]
    da = np.empty(nv)
    cacc = np.empty(6)
    df = np.empty(6)
    for r in range(rows.shape[0]):
        b = rows[r]
        for j in range(nv):
            da[j] = (qvel1[b, j] - qvel0[b, j]) * inv_dt - qacc[b, j]
        for k in range(6):
            df[k] = 0.0
        for i in range(bodies.shape[0]):
            for k in range(6):
                cacc[k] = 0.0
            for j in range(nv):
                if chain[i, j] != 0.0:
                    for k in range(6):
                        cacc[k] += cdof[b, j, k] * da[j]
            c = cinert[b, bodies[i]]  # mju_mulInertVec: [rotational; translational] spatial force
            df[0] += c[0] * cacc[0] + c[3] * cacc[1] + c[4] * cacc[2] - c[8] * cacc[4] + c[7] * cacc[5]
            df[1] += c[3] * cacc[0] + c[1] * cacc[1] + c[5] * cacc[2] + c[8] * cacc[3] - c[6] * cacc[5]
            df[2] += c[4] * cacc[0] + c[5] * cacc[1] + c[2] * cacc[2] - c[7] * cacc[3] + c[6] * cacc[4]
            df[3] += c[8] * cacc[1] - c[7] * cacc[2] + c[9] * cacc[3]
            df[4] += c[6] * cacc[2] - c[8] * cacc[0] + c[9] * cacc[4]
            df[5] += c[7] * cacc[0] - c[6] * cacc[1] + c[9] * cacc[5]
        # the torque about the site: t - (p_site - p_com) x f; then both into the site frame (R^T)
        px = site_xpos[b, site, 0] - subtree_com[b, root, 0]
        py = site_xpos[b, site, 1] - subtree_com[b, root, 1]
        pz = site_xpos[b, site, 2] - subtree_com[b, root, 2]
        tx = df[0] - (py * df[5] - pz * df[4])
        ty = df[1] - (pz * df[3] - px * df[5])
        tz = df[2] - (px * df[4] - py * df[3])
        R = site_xmat[b, site]
        for k in range(3):
            out[b, k] = sens[b, force_adr + k] + R[k] * df[3] + R[3 + k] * df[4] + R[6 + k] * df[5]
            out[b, 3 + k] = sens[b, torque_adr + k] + R[k] * tx + R[3 + k] * ty + R[6 + k] * tz


#: the fields of a step's start state the reading reads (all MjData fields; a batch binds them)
FIELDS = ("sensordata", "qacc", "qvel", "cinert", "cdof", "site_xpos", "site_xmat", "subtree_com")
#: the fields a :class:`RealisedSensor` is built on: :data:`FIELDS` and the positions (its encoders)
SOURCE_FIELDS = (*FIELDS, "qpos")


class RealisedSensor:
    """The F/T reading of B episodes' scenes for the motion each step realised.

    ``src``: an object with the (B, ...) arrays of :data:`SOURCE_FIELDS` (one MjData's fields with
    a leading axis of 1, or a ``mujoco.batch.Batch``'s bound fields); ``chain``: the model's
    :class:`SensorChain`; ``dt_s``: the timestep [s]. Call :meth:`before_step` with the episodes
    about to step, then :meth:`after_step`; :attr:`wrench` (B, 6) [N, N m] holds each episode's
    latest reading (MuJoCo's own until its first step: at rest there is no realised motion yet),
    and :attr:`qpos0` (B, nq) [rad], :attr:`qvel0` (B, nv) [rad/s] the encoders of the same instant
    (the state that reading's step started from; the current state before the first step)."""

    def __init__(self, src, chain: SensorChain, dt_s: float) -> None:
        self._src, self._c, self._inv_dt = src, chain, 1.0 / dt_s
        self._state = tuple(getattr(src, f) for f in FIELDS)
        self._model = (chain.bodies, chain.chain,
                       np.array([chain.site, chain.root, chain.force_adr, chain.torque_adr], dtype=np.int64))
        B = src.qvel.shape[0]
        self.qvel0 = np.zeros((B, src.qvel.shape[1]))
        self.qpos0 = np.zeros((B, src.qpos.shape[1]))
        self.wrench = np.zeros((B, 6))
        self.reset()

    def reset(self) -> None:
        """Every episode's reading back to MuJoCo's own and its encoders to the current state (after
        a reset or a forward)."""
        self.qpos0[:] = self._src.qpos
        self.qvel0[:] = self._src.qvel
        c, s = self._c, self._src.sensordata
        self.wrench[:, :3] = s[:, c.force_adr:c.force_adr + 3]
        self.wrench[:, 3:] = s[:, c.torque_adr:c.torque_adr + 3]

    def before_step(self) -> None:
        """Keep the positions and velocities the step starts from (the reading's instant)."""
        self.qpos0[:] = self._src.qpos
        self.qvel0[:] = self._src.qvel

    def after_step(self, rows: np.ndarray) -> None:
        """The readings of the episodes ``rows`` ((k,) int64) that stepped."""
        realised_wrench(self.wrench, self._state, self.qvel0, self._inv_dt, self._model, rows)


#: the reading's numba kernel (a compile phase checks it is cached: ``controller.core.cache_probe``)
KERNELS = (realised_wrench,)
