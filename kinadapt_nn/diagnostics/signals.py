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

from kinadapt_nn.diagnostics import physical as ph


@dataclass(frozen=True, eq=False)
class LogSignals:
    """The signals of one log (n samples, dof joints); the ``s`` of an effect function."""

    t: np.ndarray  #: (n,) [s] from the first sample
    q: np.ndarray  #: (n, dof) [rad] encoder positions
    qdot: np.ndarray  #: (n, dof) [rad/s] (logged, or differentiated from q)
    qddot: np.ndarray  #: (n, dof) [rad/s^2] (differentiated, Savitzky-Golay)
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
    w_nom: np.ndarray  #: (n, 6) [N, N m] the declared tool's wrench (the nominal model)
    contact_force_s: np.ndarray  #: (n, 3) [N] force beyond the tool model in contact (s), 0 in free space
    tip_map: np.ndarray  #: (3, 6) a wrench -> its moment about the declared tip
    arm: ph.ArmModel = field(repr=False, default=None)  #: the arm model (forward kinematics)

    @property
    def n(self) -> int:
        return len(self.t)

    def nominal_wrench(self, q: np.ndarray) -> np.ndarray:
        """The declared tool's wrench (n, 6) had the encoders read ``q`` (n, dof) instead (same
        velocities and times): for effects that move the model's joint angles."""
        m, mc, I_O = ph.nominal_inertials(self.setup)
        return ph.tool_wrench(self.arm.series(q, self.qdot, self.t), m, mc, I_O)

    def with_contact(self, contact: np.ndarray, offset: np.ndarray) -> "LogSignals":
        """The same log with another contact mask; ``offset`` (6,) is the free-space offset taken
        out of the contact force."""
        e = self.wrench - self.w_nom - offset
        return replace(self, contact=contact, contact_force_s=np.where(contact[:, None], e[:, :3], 0.0))


def from_log(log, setup, progress=lambda msg: None) -> LogSignals:
    """A reader's ``UserLog`` + setup -> ``LogSignals`` (contact: none yet; ``with_contact``)."""
    arm = ph.ArmModel(setup)
    t = np.asarray(log.t_s, dtype=float)
    q = np.asarray(log.q_rad, dtype=float)
    qdot = np.asarray(log.qdot_rad_s, dtype=float) if log.qdot_rad_s is not None else ph.derivative(q, t)
    progress(f"kinematics of {len(t)} samples")
    kin = arm.series(q, qdot, t)
    m, mc, I_O = ph.nominal_inertials(setup)
    r = setup.log.sign * np.asarray(log.wrench_log, dtype=float)
    n = len(t)
    return LogSignals(t - t[0], q, qdot, ph.derivative(qdot, t), kin.R_ws, kin.p_ws, kin.g_s, kin.a_s, kin.omega_s,
                      kin.alpha_s, r, np.zeros(n, bool), dict(getattr(log, "extra", None) or {}), setup,
                      ph.tool_wrench(kin, m, mc, I_O), np.zeros((n, 3)), ph.tip_moment_map(setup.tool.tip_sensor_m),
                      arm)
