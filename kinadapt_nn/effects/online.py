"""The controller's level domain: what an effect's online columns are computed on (``Signals``), what
they are (``Terms``), the generic maps into it, and ``from_wrench``, which derives an effect's online
columns from its diagnosis columns.

Everything here is computed from what a real robot logs (encoders, the raw F/T reading, time)
and the known model (nominal tool offset ``l_nom``, the nominal map ``S``, the bore pose, the
arm's nominal kinematics); nothing reads the simulator or the truth.

Level domain. The nominal model is S's contact at the nominal tip (eq. ft_pred, ``s_dot = S
[v_tip; omega]``, ``[v_tip; omega] = Ad(R l_nom) J_arm qdot``) without S's linearised lever: the
measured force acts at the nominal tip ``R l_nom`` (so the measured level of the moment channels
is ``Z_M = M - (R l_nom) x f_tool``), the lateral force follows ``-k_t P v_tip`` and the couple
``-k_r omega``. It applies only where the nominal tip is at or below the bore entrance (``d >=
0``, proprioceptive); above it the model predicts a zero tared wrench. The residual level ``L(t) = s(t) - s(t0) - int s_dot``
is compared with each effect's level signature ``C_e(t) p_e`` (channels ``LEVEL_CHANNELS``: F_lat
x/y, the axial force outside contact, M x/y/z; ``d`` is a kinematic identity of the encoders). Effects that act on the
wrench directly give ``C_e`` in closed form (``Terms.level``); effects that change the contact
kinematics give ``C_e`` as the integral of their rate signature, gated like ``S`` (``Terms.rate``).

One definition, both sides. Every effect -- a built-in (``kinadapt_nn/effects/builtin/``) or a user's
-- is one function in the contract (``kinadapt_nn.effects.contract``). ``online=True``: its diagnosis
columns read only what the controller has (``WrenchView``) and ``from_wrench`` maps them into the level
channels, tared at the controller's tare (the payload, the sensor rotation, the drift, a user's hose
weight). ``online=fn``: ``fn(Signals) -> Terms`` in the same module, for an effect whose online form
is the contact's kinematics rather than a wrench (stiffness, tool tilt, grasp, encoder offset) or needs
the contact force the declared socket gives offline (the friction couple). The controller adapts them
through ``kinadapt_nn.features.effect_library`` (``LIBRARY``, ``online_of``).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.errors import KinadaptError
from kinadapt_nn.geometry import adjoint_offset
from kinadapt_nn.sensing import lateral_projector

#: the level channels the library fits: s's wrench rows plus the axial force (d is an encoder
#: identity). The nominal model predicts the axial force only outside contact (zero), so F_axial
#: rows are used only where the contact gate is off.
LEVEL_CHANNELS: tuple[str, ...] = ("F_lat_x", "F_lat_y", "F_axial", "M_x", "M_y", "M_z")
LEVEL_UNITS: tuple[str, ...] = ("N", "N", "N", "N m", "N m", "N m")
AXIAL = 2
G_W = np.array([0.0, 0.0, -9.81])  # [m/s^2] gravity, world


class Signals(NamedTuple):
    """Per-sample quantities of a replayed log that the columns need (N samples)."""

    t_s: np.ndarray  #: (N,) time from the start of the log [s]
    dt_s: float  #: sample time [s]
    s: np.ndarray  #: (N, 6) sensor vector
    w_env_w: np.ndarray  #: (N, 6) tared wrench tool -> environment, world, about O [N, N m]
    r_tared_f: np.ndarray  #: (N, 6) tared raw reading in f (flange on tool) [N, N m]
    R_wf: np.ndarray  #: (N, 3, 3) flange orientation (encoders)
    twist_tip_w: np.ndarray  #: (N, 6) nominal-tip twist [v_tip; omega] (world)
    gate: np.ndarray  #: (N,) float: 1 where S's contact rows apply (d >= 0 and active)
    active: np.ndarray  #: (N,) bool: drive on (after the tare)
    t_tare_s: float  #: middle of the tare window [s]
    R_tare: np.ndarray  #: (3, 3) flange orientation during the tare
    S: np.ndarray  #: (6, 6) nominal map
    l_nom_f: np.ndarray  #: (3,) nominal offset
    q_rad: np.ndarray  #: (N, 7)
    qdot_rad_s: np.ndarray  #: (N, 7)
    kin: object  #: the controller's ArmKinematics (bare arm, nominal)


class Terms(NamedTuple):
    """An effect's signature on a ``Signals`` (N samples, k parameters), in LEVEL_CHANNELS."""

    level: np.ndarray | None  #: (N, 6, k) closed-form change of the tared levels, or None
    rate: np.ndarray | None  #: (N, 6, k) gated rate signature (integrated by ``OnlineEffect.columns``), or None


def cumulative(rate: np.ndarray, dt: float) -> np.ndarray:
    """Rectangle-rule integral along axis 0, starting at 0 (same rule as the nominal level)."""
    out = np.cumsum(rate, axis=0) * dt
    out -= out[0]
    return out


def tip_twist_map(R_wf: np.ndarray, J_arm: np.ndarray, l_nom_f: np.ndarray) -> np.ndarray:
    """``Ad(R l_nom) J_arm``: joint velocities -> nominal-tip twist [v_tip; omega] (world),
    eq. ft_factor's middle factor with the nominal offset. (3, 3), (6, n), (3,) -> (6, n)."""
    return adjoint_offset(R_wf @ l_nom_f) @ J_arm


def projector(S: np.ndarray) -> np.ndarray:
    """S's lateral projector P (2, 3) (``sensing.lateral_projector`` with k_t = |row|)."""
    return lateral_projector(S, float(np.linalg.norm(S[1, :3])))


def moving_average(x: np.ndarray, k: int) -> np.ndarray:
    """Centred moving average over ``k`` samples along axis 0 (edges: shorter windows)."""
    if k <= 1 or len(x) < 2:
        return x
    c = np.cumsum(np.concatenate([np.zeros((1, *x.shape[1:])), x]), axis=0)
    i = np.arange(len(x))
    lo = np.clip(i - k // 2, 0, len(x))
    hi = np.clip(i + (k - k // 2), 0, len(x))
    return (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))


def smooth_derivative(x: np.ndarray, dt: float, width_s: float = 0.002) -> np.ndarray:
    """d/dt of a (N, 3) series, central differences then a ``width_s`` moving average (zeros for
    fewer than 3 samples: the controller's one-sample step has no history)."""
    if len(x) < 3:
        return np.zeros_like(x)
    return moving_average(np.gradient(x, dt, axis=0), max(1, int(round(width_s / dt))))


def contact_rate(sig: Signals, tip_twist_w: np.ndarray) -> np.ndarray:
    """Rate of the tip-contact model for a tip twist (N, 6) -> (N, 6) level-channel rates,
    gated: lateral force ``-k_t P v_tip`` and the couple ``-k_r omega`` (S's rows without the
    lever term, which the level ``Z`` takes from the measured force; no axial row)."""
    out = np.zeros((len(tip_twist_w), 6))
    out[:, :2] = sig.gate[:, None] * (tip_twist_w[:, :3] @ sig.S[1:3, :3].T)
    out[:, 3:] = sig.gate[:, None] * (tip_twist_w[:, 3:] @ sig.S[3:6, 3:].T)
    return out


def lever_w(sig: Signals) -> np.ndarray:
    """The nominal lever ``R_wf l_nom`` (N, 3), world."""
    return rot(sig.R_wf, np.broadcast_to(sig.l_nom_f, (len(sig.t_s), 3)))


def to_level(sig: Signals, w_w: np.ndarray) -> np.ndarray:
    """The measured level ``Z`` of a world wrench tool -> env (N, 6): ``_wrench_to_s`` with, in
    contact, the moment of the force at the nominal tip taken out, ``M - gate (R l_nom) x f_tool``
    (the tip-contact model: the force acts at the tip, the rest is a couple)."""
    out = _wrench_to_s(w_w, sig.S)
    f_tool = -w_w[:, :3]
    out[:, 3:] -= sig.gate[:, None] * np.cross(lever_w(sig), f_tool)
    return out


def _wrench_to_s(w_w: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Level channels from a world wrench tool -> env: F_lat = -P f, F_axial = -n.f (the force
    on the tool along the bore axis), M = -m. (N, 6) -> (N, 6)."""
    P = projector(S)
    n = S[0, :3]
    out = np.empty((len(w_w), 6))
    out[:, :2] = -w_w[:, :3] @ P.T
    out[:, 2] = -w_w[:, :3] @ n
    out[:, 3:] = -w_w[:, 3:]
    return out


def rot(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R_n v_n for (N, 3, 3), (N, 3) -> (N, 3)."""
    return np.einsum("nij,nj->ni", R, v)


class WrenchView(NamedTuple):
    """What an effect's diagnosis columns may read when the controller evaluates them online
    (``from_wrench``): the attributes of ``diagnostics.signals.LogSignals`` the controller has, in its
    convention (sensor frame = the flange frame f). Reading another one (``s.setup``, ``s.contact``...)
    is a one-line ``KinadaptError`` naming it."""

    t: np.ndarray  #: (N,) [s] from the start of the log
    wrench: np.ndarray  #: (N, 6) [N, N m] the tared reading as the tool's wrench ON the sensor, f
    R_ws: np.ndarray  #: (N, 3, 3) sensor (flange) axes in the world (encoders)
    omega_s: np.ndarray  #: (N, 3) [rad/s] angular velocity in the sensor frame (encoders)
    g_s: np.ndarray  #: (N, 3) [m/s^2] gravity in the sensor frame
    a_s: np.ndarray  #: (N, 3) [m/s^2] acceleration of the sensor origin, s (encoders, ``smooth_derivative``; 0 off drive)
    alpha_s: np.ndarray  #: (N, 3) [rad/s^2] angular acceleration, s (likewise)

    @property
    def n(self) -> int:
        return len(self.t)

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        raise KinadaptError(f"s.{name} is not known online: an effect derived with online=True reads only "
                            f"s.{', s.'.join((*self._fields, 'n'))}; give online=<function Signals -> Terms> "
                            "(kinadapt_nn.effects.online) for the controller's own columns")


def wrench_view(sig: Signals) -> tuple[WrenchView, WrenchView]:
    """(now, at the tare): the controller's signals as an effect function reads them (``WrenchView``).
    The package's reading is the sensor's wrench on the tool, so the tool's on the sensor is its
    negative; at the tare the tared reading is zero and the arm at rest."""
    n = len(sig.t_s)
    w = sig.twist_tip_w[:, 3:]
    v_O = sig.twist_tip_w[:, :3] - np.cross(w, lever_w(sig))  # the flange origin's velocity
    a_O = smooth_derivative(v_O, sig.dt_s) * sig.active[:, None]
    alpha = smooth_derivative(w, sig.dt_s) * sig.active[:, None]
    R_T = np.swapaxes(sig.R_wf, 1, 2)
    now = WrenchView(sig.t_s, -sig.r_tared_f, sig.R_wf, rot(R_T, w), rot(R_T, np.broadcast_to(G_W, (n, 3))),
                     rot(R_T, a_O), rot(R_T, alpha))
    zero = np.zeros((1, 3))
    tare = WrenchView(np.full(1, sig.t_tare_s), np.zeros((1, 6)), sig.R_tare[None], zero, (sig.R_tare.T @ G_W)[None],
                      zero, zero)
    return now, tare


def from_wrench(columns: Callable, name: str = "effect") -> Callable[[Signals], Terms]:
    """The controller's online columns derived from an effect's diagnosis columns, one generic map:
    ``columns(s) -> (N, 6, k)`` is the change of the tool's wrench on the sensor (sensor frame, the
    diagnosis's contract); the controller's reading is tared, so its change is ``C(now) - C(tare)``;
    that reading change, as the world wrench ``w_env = R_wf r`` with ``r = -wrench``, goes into the
    level channels by ``to_level`` (the lever of the nominal tip taken out in contact). A closed-form
    level: ``Terms(level, None)``. Valid where the columns read only ``WrenchView``'s attributes and are
    linear in ``s.wrench`` or independent of it (the controller has the tared reading, a log the raw
    one); an error in them is one line naming the effect ``name``."""
    def evaluate(s: WrenchView) -> np.ndarray:
        try:
            C = np.asarray(columns(s), dtype=float)
        except KinadaptError as exc:
            raise KinadaptError(f"effect '{name}' online: {exc}") from None
        except Exception as exc:  # a user's code: one line
            msg = str(exc).splitlines()[0] if str(exc) else ""
            raise KinadaptError(f"effect '{name}' online raised {type(exc).__name__}: {msg}"[:300]) from None
        if C.ndim not in (2, 3) or C.shape[:2] != (s.n, 6):
            raise KinadaptError(f"effect '{name}' online returned shape {C.shape}; expected (n, 6, k) with n = {s.n}")
        return C

    at_tare: dict[tuple, np.ndarray] = {}  # the columns at the tare (t_tare, R_tare): one per episode, not per step

    def terms(sig: Signals) -> Terms:
        now, tare = wrench_view(sig)
        key = (sig.t_tare_s, sig.R_tare.tobytes())
        if key not in at_tare:
            at_tare.clear()
            at_tare[key] = evaluate(tare)
        C, C0 = evaluate(now), at_tare[key]
        if C.ndim == 2:
            C, C0 = C[:, :, None], C0[:, :, None]
        dC = C - C0  # (N, 6, k): the tared reading's change (tool on sensor)
        n, _, k = dC.shape
        # the k columns as n k samples (row i k + j: sample i, column j), mapped in one call
        rep = sig._replace(t_s=np.repeat(sig.t_s, k), R_wf=np.repeat(sig.R_wf, k, axis=0), gate=np.repeat(sig.gate, k))
        d = dC.transpose(0, 2, 1).reshape(n * k, 6)
        w_env_w = -np.concatenate([rot(rep.R_wf, d[:, :3]), rot(rep.R_wf, d[:, 3:])], axis=1)
        return Terms(to_level(rep, w_env_w).reshape(n, k, 6).transpose(0, 2, 1), None)
    return terms
