"""The online model's effects (``model.effects``, adapted by ``kinadapt_nn.features.effects``):
each named physical effect as regressor columns linear in physical parameters, per control step
(the simulator side is ``kinadapt_nn.sim.effects``; the diagnosis judges the same names with its
own registry, ``kinadapt_nn.effects.builtin``, on every log alike).

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
wrench directly (gravity, drift, sensor rotation, friction couple) give ``C_e`` in closed form;
effects that change the contact kinematics (stiffness, tool tilt, grasp yield, encoder offset)
give ``C_e`` as the integral of their rate signature, gated like ``S``.

=========================  ==========================================  ========================
effect                     parameters (units)                          level signature
=========================  ==========================================  ========================
tool_gravity               m [kg], m c_f x/y/z [kg m]                  w += R (G(q) - G(q_tare)):
                                                                       payload weight at c_f
ft_bias_drift              rate_f: 3 [N/s] + 3 [N m/s]                 w += R rate (t - t_tare)
ft_frame_rotation          rotation vector in f, 3 [rad]               r -> r x delta (tared r)
tool_tilt                  tilt about f x, f y, 2 [rad]                lever R (delta x l_nom):
                                                                       tip velocity + F x lever
contact_stiffness          factor - 1 [-]                              int S_c v (gated)
contact_friction_couple    radius [m]                                  M -= radius |f| w/(|w|+e)
grasp_compliance           compliance [rad/(N m)]                      S_c [M_perp x R l; M_perp]
encoder_offset             joint 1..6 zero offsets, 6 [rad]            d/dq_j of the model
=========================  ==========================================  ========================

A joint-7 zero offset is not in the library: it turns the reading about the flange axis exactly
like a sensor rotation about z_f (the nominal tip is on that axis), so no force/encoder
experiment can tell them apart; it shows up as ``ft_frame_rotation``.

One definition, both sides. An effect written in the diagnosis's contract
(``kinadapt_nn.diagnostics.effect``) with ``online=True`` is an online effect too (``online_of``; in
``model.effects`` as ``PATH.py:NAME``): ``from_wrench`` evaluates its function on what the controller
has (``WrenchView``) and maps the change of the tool's wrench on the sensor into the level channels,
tared at the controller's tare. ``online=fn`` gives the controller's own ``Terms`` in the same module.
The built-ins above are still written here as well as in ``effects/builtin/``: this module is on
the controller side, which may not import the diagnosis (``tests/test_layout.py``), and four of their
diagnosis functions need the declared socket's model (``effects/contact_model``). For three
(gravity, sensor rotation, drift) ``from_wrench`` of the diagnosis function equals the columns here to
rounding (``tests/features/test_effect_one_file.py``).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.config import EffectsCfg
from kinadapt_nn.errors import ConfigError, KinadaptError, did_you_mean
from kinadapt_nn.geometry import adjoint_offset
from kinadapt_nn.sensing import lateral_projector

#: smoothing of sign(omega) in the friction-couple columns [rad/s] (a model constant)
OMEGA_EPS_RAD_S = 0.005
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
    rate: np.ndarray | None  #: (N, 6, k) gated rate signature (integrated by ``Effect.columns``), or None


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


def _lever_w(sig: Signals) -> np.ndarray:
    """The nominal lever ``R_wf l_nom`` (N, 3), world."""
    return _rot(sig.R_wf, np.broadcast_to(sig.l_nom_f, (len(sig.t_s), 3)))


def to_level(sig: Signals, w_w: np.ndarray) -> np.ndarray:
    """The measured level ``Z`` of a world wrench tool -> env (N, 6): ``_wrench_to_s`` with, in
    contact, the moment of the force at the nominal tip taken out, ``M - gate (R l_nom) x f_tool``
    (the tip-contact model: the force acts at the tip, the rest is a couple)."""
    out = _wrench_to_s(w_w, sig.S)
    f_tool = -w_w[:, :3]
    out[:, 3:] -= sig.gate[:, None] * np.cross(_lever_w(sig), f_tool)
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


def _rot(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R_n v_n for (N, 3, 3), (N, 3) -> (N, 3)."""
    return np.einsum("nij,nj->ni", R, v)


# ---------------------------------------------------------------------------------------- library
@dataclass(frozen=True)
class OnlineEffect:
    """An effect as the online model adapts it (``model.effects``): columns, parameter names/units, the
    default magnitude, and what motion excites it. A built-in is an entry of ``LIBRARY``; a user's
    one-file effect (``kinadapt_nn.diagnostics.effect(..., online=...)``) becomes one through
    ``online_of``."""

    name: str
    params: tuple[str, ...]
    units: tuple[str, ...]
    #: Signals -> Terms(level, rate); the rate part is integrated by ``columns`` and used as is by
    #: the online regressor (``kinadapt_nn.features.effects``)
    terms: Callable[[Signals], "Terms"]
    #: the simulator config's magnitude as model parameters (k,) (the prior's scale, validation), or None
    default: Callable[[EffectsCfg], np.ndarray] | None
    excite_hint: str
    doc: str
    #: True: the effect is "one of" its columns (e.g. one joint's offset): one column at a time
    one_of: bool = False

    @property
    def k(self) -> int:
        return len(self.params)

    def columns(self, sig: Signals, **kw) -> Terms:
        """Level columns: (closed-form level, integral of the rate), (N, 6, k) each or None
        (``kw``: passed to ``terms``, e.g. the encoder derivatives already computed)."""
        lev, rate = self.terms(sig, **kw)
        return Terms(lev, None if rate is None else cumulative(rate, sig.dt_s))

    def magnitude(self) -> np.ndarray:
        """(k,) the default config's magnitude in these parameters, zeros without ``default``."""
        return np.zeros(self.k) if self.default is None else np.asarray(self.default(EffectsCfg()), dtype=float)


# ------------------------------------------------------------------- one definition, both sides
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
                            "(kinadapt_nn.features.effect_library) for the controller's own columns")


def wrench_view(sig: Signals) -> tuple[WrenchView, WrenchView]:
    """(now, at the tare): the controller's signals as an effect function reads them (``WrenchView``).
    The package's reading is the sensor's wrench on the tool, so the tool's on the sensor is its
    negative; at the tare the tared reading is zero and the arm at rest."""
    n = len(sig.t_s)
    w = sig.twist_tip_w[:, 3:]
    v_O = sig.twist_tip_w[:, :3] - np.cross(w, _lever_w(sig))  # the flange origin's velocity
    a_O = smooth_derivative(v_O, sig.dt_s) * sig.active[:, None]
    alpha = smooth_derivative(w, sig.dt_s) * sig.active[:, None]
    R_T = np.swapaxes(sig.R_wf, 1, 2)
    now = WrenchView(sig.t_s, -sig.r_tared_f, sig.R_wf, _rot(R_T, w), _rot(R_T, np.broadcast_to(G_W, (n, 3))),
                     _rot(R_T, a_O), _rot(R_T, alpha))
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

    def terms(sig: Signals) -> Terms:
        now, tare = wrench_view(sig)
        C, C0 = evaluate(now), evaluate(tare)
        if C.ndim == 2:
            C, C0 = C[:, :, None], C0[:, :, None]
        dC = C - C0  # (N, 6, k): the tared reading's change (tool on sensor)
        level = np.empty_like(dC)
        for j in range(dC.shape[2]):
            w_env_w = -np.concatenate([_rot(sig.R_wf, dC[:, :3, j]), _rot(sig.R_wf, dC[:, 3:, j])], axis=1)
            level[:, :, j] = to_level(sig, w_env_w)
        return Terms(level, None)
    return terms


def online_of(eff) -> OnlineEffect:
    """An ``OnlineEffect`` from a library name, ``"PATH.py:NAME"`` (a user's effects file), an
    ``OnlineEffect``, or a diagnosis ``Effect`` with an online side (``@effect(..., online=True | fn)``:
    derived by ``from_wrench``, or ``fn`` Signals -> Terms in the same parameters). A one-line
    ``ConfigError`` otherwise, with the closest name."""
    if isinstance(eff, OnlineEffect):
        return eff
    if isinstance(eff, str) and ".py:" in eff:
        eff = _from_file(*eff.rsplit(":", 1))
    elif isinstance(eff, str):
        if eff not in LIBRARY:
            hint = did_you_mean(eff, LIBRARY)
            raise ConfigError(f"model.effects: unknown effect '{eff}'{' (' + hint + ')' if hint else ''}; the online "
                              f"library has {', '.join(LIBRARY)}, or give PATH.py:NAME of an effect with online=True")
        return LIBRARY[eff]
    online = getattr(eff, "online", None)
    name = getattr(eff, "name", repr(eff))
    if online is None or online is False:
        raise ConfigError(f"model.effects: effect '{name}' has no online side; declare @effect(..., online=True) "
                          f"when its columns read only s.{', s.'.join(WrenchView._fields)} (or online=<Signals -> Terms>)")
    terms = from_wrench(eff.columns, name) if online is True else online
    return OnlineEffect(name, tuple(eff.params), tuple(eff.units), terms, None, getattr(eff, "excite", ""),
                        getattr(eff, "doc", ""), bool(getattr(eff, "one_of", False)))


def _from_file(path: str, name: str):
    """The effect ``name`` defined at the module level of the effects file ``path`` (Python code that
    runs, like the diagnosis's ``--effects`` files); a one-line ``ConfigError`` otherwise."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"model.effects: effects file '{p}' not found (give PATH.py:NAME of an existing file)")
    spec = importlib.util.spec_from_file_location(f"kinadapt_online_effects_{abs(hash(str(p.resolve())))}", p)
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    except Exception as exc:  # a user's file: one line
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise ConfigError(f"model.effects: effects file '{p}' raised {type(exc).__name__} while loading: {msg}"[:300]) \
            from None
    found = {getattr(v, "name", None): v for v in vars(mod).values() if hasattr(v, "online") and hasattr(v, "columns")}
    if name not in found:
        hint = did_you_mean(name, [n for n in found if n])
        raise ConfigError(f"model.effects: effects file '{p}' defines no effect '{name}'"
                          f"{' (' + hint + ')' if hint else ''}; it has {', '.join(n for n in found if n) or 'none'}")
    return found[name]


# ------------------------------------------------- the built-ins' online columns (LIBRARY)
# (their diagnosis side is effects/builtin/<name>.py; the controller side may not import it)
def _cols_tool_gravity(sig: Signals) -> Terms:
    """Payload (m, m c_f) on the tool: the flange holds ``m (a_com - g)`` with
    ``a_com = a_O + alpha x (R c) + w x (w x (R c))`` (encoder accelerations), tared at the still
    tare pose: linear in m and m c (the payload's own rotational inertia, quadratic in c, is
    left out)."""
    n = len(sig.t_s)
    w = sig.twist_tip_w[:, 3:]
    v_O = sig.twist_tip_w[:, :3] - np.cross(w, _lever_w(sig))
    a_O = smooth_derivative(v_O, sig.dt_s) * sig.active[:, None]
    alpha = smooth_derivative(w, sig.dt_s) * sig.active[:, None]
    # force per unit mass, tared: (a_O - g) - R R0^T (-g)
    df_w = a_O - G_W[None, :] + _rot(sig.R_wf, np.broadcast_to(sig.R_tare.T @ G_W, (n, 3)))
    cols = np.zeros((n, 6, 4))
    wr = np.zeros((n, 6))
    wr[:, :3] = df_w  # w_env = R (r - r0) is the flange's force ON the tool: same sign
    cols[:, :, 0] = to_level(sig, wr)
    for j in range(3):
        e_w = sig.R_wf[:, :, j]  # R e_j
        wr = np.zeros((n, 6))
        wr[:, :3] = np.cross(alpha, e_w) + np.cross(w, np.cross(w, e_w))
        wr[:, 3:] = np.cross(e_w, df_w)  # moment of (m c) about O: (R m c) x (a_O - g ...)
        cols[:, :, 1 + j] = to_level(sig, wr)
    return Terms(cols, None)


def _cols_ft_bias_drift(sig: Signals) -> Terms:
    cols = np.zeros((len(sig.t_s), 6, 6))
    dtau = (sig.t_s - sig.t_tare_s)[:, None]
    for j in range(6):
        w = np.zeros((len(sig.t_s), 6))
        part = slice(0, 3) if j < 3 else slice(3, 6)
        w[:, part] = sig.R_wf[:, :, j % 3] * dtau
        cols[:, :, j] = to_level(sig, w)
    return Terms(cols, None)


def _cols_ft_frame_rotation(sig: Signals) -> Terms:
    cols = np.zeros((len(sig.t_s), 6, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        w = np.zeros((len(sig.t_s), 6))
        w[:, :3] = _rot(sig.R_wf, np.cross(sig.r_tared_f[:, :3], e))  # measured = true x delta
        w[:, 3:] = _rot(sig.R_wf, np.cross(sig.r_tared_f[:, 3:], e))
        cols[:, :, j] = to_level(sig, w)
    return Terms(cols, None)


def _cols_tool_tilt(sig: Signals) -> Terms:
    lev = np.zeros((len(sig.t_s), 6, 2))
    integ = np.zeros((len(sig.t_s), 6, 2))  # rates
    f_tool = -sig.w_env_w[:, :3]
    for j in range(2):
        e = np.zeros(3)
        e[j] = 1.0
        dl_w = _rot(sig.R_wf, np.broadcast_to(np.cross(e, sig.l_nom_f), (len(sig.t_s), 3)))
        tw = np.zeros((len(sig.t_s), 6))
        tw[:, :3] = np.cross(sig.twist_tip_w[:, 3:], dl_w)  # the true tip's extra velocity
        integ[:, :, j] = contact_rate(sig, tw)
        lev[:, 3:, j] = sig.gate[:, None] * np.cross(dl_w, f_tool)  # moment of the contact force about O
    return Terms(lev, integ)


def _cols_contact_stiffness(sig: Signals) -> Terms:
    return Terms(None, contact_rate(sig, sig.twist_tip_w)[:, :, None])


def _cols_contact_friction_couple(sig: Signals) -> Terms:
    w = sig.twist_tip_w[:, 3:]
    fn = np.linalg.norm(sig.w_env_w[:, :3], axis=1)
    cols = np.zeros((len(sig.t_s), 6, 1))
    cols[:, 3:, 0] = -(sig.gate * fn)[:, None] * w / (np.linalg.norm(w, axis=1) + OMEGA_EPS_RAD_S)[:, None]
    return Terms(cols, None)


def _cols_grasp_compliance(sig: Signals) -> Terms:
    M = sig.s[:, 3:]  # contact moment on the tool about O (world)
    z = sig.R_wf[:, :, 2]
    M_perp = M - np.sum(M * z, axis=1)[:, None] * z  # the hinges yield about f x, f y only
    lever = _rot(sig.R_wf, np.broadcast_to(sig.l_nom_f, (len(sig.t_s), 3)))
    disp = np.concatenate([np.cross(M_perp, lever), M_perp], axis=1)  # tip displacement + rotation per unit compliance
    return Terms(contact_rate(sig, disp)[:, :, None], None)  # the map is linear: displacement -> level change


def encoder_derivatives(sig: Signals, eps: float = 1e-6, grid_s: float = 0.005) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per joint ``j`` = 0..5, the derivatives of the encoder-dependent signals in that joint's
    zero (``q -> q + eps e_j``, forward differences): ``(dR (N, 3, 3), dtwist (N, 6))`` of
    ``R_wf`` and of the nominal-tip twist ``Ad(R l_nom) J_arm qdot``. The derivatives of the
    tip-twist map and of ``R_wf`` depend on ``q`` only, so they are evaluated on a ``grid_s``
    grid and interpolated, then applied to the full-rate ``qdot``. -> 6 pairs."""
    n = len(sig.t_s)
    step = max(1, int(round(grid_s / sig.dt_s)))
    grid = np.r_[np.arange(0, n, step), n - 1] if n > 1 else np.zeros(1, int)
    grid = np.unique(grid)

    def tip_map(k) -> np.ndarray:  # (6, 7): [v_tip; omega] = A qdot
        return tip_twist_map(k.R_wf, k.J_arm, sig.l_nom_f)

    base_A = np.empty((len(grid), 6, 7))
    base_R = np.empty((len(grid), 3, 3))
    for gi, i in enumerate(grid):
        k = sig.kin.update(sig.q_rad[i])
        base_A[gi], base_R[gi] = tip_map(k), k.R_wf
    t = sig.t_s
    out = []
    for j in range(6):
        dA = np.empty((len(grid), 6, 7))
        dR = np.empty((len(grid), 3, 3))
        for gi, i in enumerate(grid):
            q = sig.q_rad[i].copy()
            q[j] += eps
            k = sig.kin.update(q)
            dA[gi] = (tip_map(k) - base_A[gi]) / eps
            dR[gi] = (k.R_wf - base_R[gi]) / eps
        dA_f = np.stack([np.interp(t, t[grid], dA[:, a, b]) for a in range(6) for b in range(7)], axis=1).reshape(n, 6, 7)
        dR_f = np.stack([np.interp(t, t[grid], dR[:, a, b]) for a in range(3) for b in range(3)], axis=1).reshape(n, 3, 3)
        out.append((dR_f, np.einsum("nij,nj->ni", dA_f, sig.qdot_rad_s)))
    return out


def _cols_encoder_offset(sig: Signals, eps: float = 1e-6, grid_s: float = 0.005,
                         derivs: list[tuple[np.ndarray, np.ndarray]] | None = None) -> Terms:
    """Finite differences of the nominal model in each joint's zero (``encoder_derivatives``):
    the measured level ``Z = to_level(R r)`` with the lever ``R l_nom`` and the tip-contact rate
    of the twist. A joint that sits at reading + offset leaves ``-dZ/dq_j`` in the level and
    ``+d(rate)/dq_j`` in the prediction's integral (the residual is measured minus predicted).
    ``derivs``: ``encoder_derivatives`` when already computed."""
    n = len(sig.t_s)
    lev = np.zeros((n, 6, 6))
    integ = np.zeros((n, 6, 6))
    for j, (dR_f, dtw) in enumerate(derivs if derivs is not None else encoder_derivatives(sig, eps, grid_s)):
        dRr = np.concatenate([_rot(dR_f, sig.r_tared_f[:, :3]), _rot(dR_f, sig.r_tared_f[:, 3:])], axis=1)
        integ[:, :, j] = contact_rate(sig, dtw)
        dZ = to_level(sig, dRr)  # d/dq_j of Z = to_level(R r) with the lever R l_nom:
        dZ[:, 3:] -= sig.gate[:, None] * np.cross(_rot(dR_f, np.broadcast_to(sig.l_nom_f, (n, 3))), -sig.w_env_w[:, :3])
        lev[:, :, j] = -dZ
    return Terms(lev, integ)


def _p_gravity(e: EffectsCfg) -> np.ndarray:
    g = e.tool_gravity
    return np.array([g.mass_kg, *(g.mass_kg * np.asarray(g.com_f_m))])


def _p_tilt(e: EffectsCfg) -> np.ndarray:
    return np.deg2rad(np.asarray(e.tool_tilt.tilt_deg, dtype=float))


def _p_encoder(e: EffectsCfg) -> np.ndarray:
    p = np.zeros(6)
    if e.encoder_offset.joint <= 6:
        p[e.encoder_offset.joint - 1] = np.deg2rad(e.encoder_offset.offset_deg)
    return p


LIBRARY: dict[str, OnlineEffect] = {
    e.name: e
    for e in (
        OnlineEffect("tool_gravity", ("mass", "mass*com_x_f", "mass*com_y_f", "mass*com_z_f"), ("kg", "kg m", "kg m", "kg m"),
               _cols_tool_gravity, _p_gravity,
               "reorient the tool in free space through several poses (tilts of 20-30 deg about two axes)",
               "tool mass and centre of mass loading the wrist sensor"),
        OnlineEffect("ft_bias_drift", ("rate_fx", "rate_fy", "rate_fz", "rate_tx", "rate_ty", "rate_tz"),
               ("N/s", "N/s", "N/s", "N m/s", "N m/s", "N m/s"), _cols_ft_bias_drift,
               lambda e: np.asarray(e.ft_bias_drift.rate_f, dtype=float),
               "hold still in free space for several seconds, at more than one orientation",
               "the F/T offset drifts linearly in time"),
        OnlineEffect("ft_frame_rotation", ("rot_x_f", "rot_y_f", "rot_z_f"), ("rad", "rad", "rad"), _cols_ft_frame_rotation,
               lambda e: np.deg2rad(np.asarray(e.ft_frame_rotation.rotvec_deg, dtype=float)),
               "press axially and push laterally in both directions (large forces along several axes)",
               "the sensor is mounted slightly rotated"),
        OnlineEffect("tool_tilt", ("tilt_x_f", "tilt_y_f"), ("rad", "rad"), _cols_tool_tilt, _p_tilt,
               "rotate about the tip in contact and push laterally (the tip lever shows in the moment)",
               "the tool sits rotated in the grasp"),
        OnlineEffect("contact_stiffness", ("stiffness_factor_minus_1",), ("-",), _cols_contact_stiffness,
               lambda e: np.array([e.contact_stiffness.factor - 1.0]),
               "push laterally into the contact and rotate about the tip in contact",
               "the contact stiffness differs from the model's S"),
        OnlineEffect("contact_friction_couple", ("radius",), ("m",), _cols_contact_friction_couple,
               lambda e: np.array([e.contact_friction_couple.radius_m]),
               "rotate back and forth in contact under a steady normal force (a couple that flips with omega)",
               "a torsional friction couple opposing rotation in contact"),
        OnlineEffect("grasp_compliance", ("compliance",), ("rad/(N m)",), _cols_grasp_compliance,
               lambda e: np.array([1.0 / e.grasp_compliance.stiffness_Nm_per_rad]),
               "load the tool with a moment in contact (lateral pushes at the tip)",
               "the tool yields in the grasp under moment"),
        OnlineEffect("encoder_offset", tuple(f"offset_joint{j}" for j in range(1, 7)), ("rad",) * 6, _cols_encoder_offset,
               _p_encoder,
               "push in contact at two tool-axis angles (turn the tool between contacts) and move the arm",
               "a joint encoder zero offset (one of joints 1-6)", one_of=True),
    )
}
