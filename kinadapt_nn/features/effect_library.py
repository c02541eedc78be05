"""The online model's effects (``model.effects``, adapted by ``kinadapt_nn.features.effects``): every
effect with an online side, as the controller adapts it (``OnlineEffect``: its columns in the level
domain, its parameters, the simulator config's magnitude in them).

Nothing here is an effect's physics. Each built-in is one module, ``kinadapt_nn/effects/builtin/<name>.py``,
written in the public contract (``kinadapt_nn.effects.contract``): its diagnosis columns, and its online
side, ``online=True`` (those columns, mapped into the level domain by ``effects.online.from_wrench``) or
``online=fn`` (its own level-domain columns, in the same module). ``LIBRARY`` is derived from the one
registry (``effects.builtin.BUILTINS``); a user's effect file enters the same way (``online_of``,
``model.effects = ["PATH.py:NAME"]``). The level domain itself (``Signals``, ``Terms``, the maps) is
``kinadapt_nn.effects.online``. The simulator side of the same names is ``kinadapt_nn.sim.effects``.

A joint-7 zero offset has no column (``encoder_offset``'s flange joint): it turns the reading about the
flange axis exactly like a sensor rotation about z_f (the nominal tip is on that axis), so no
force/encoder experiment can tell them apart; it shows up as ``ft_frame_rotation``.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from kinadapt_nn.config import EffectsCfg
from kinadapt_nn.effects.builtin import BUILTINS
from kinadapt_nn.effects.online import Signals, Terms, WrenchView, cumulative, from_wrench
from kinadapt_nn.errors import ConfigError, did_you_mean


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
    return _online_effect(eff)


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


#: the simulator config's magnitude of each built-in in its parameters (``OnlineEffect.default``: the
#: Kalman prior's scale, the benchmarks' truth): the one place the truth side's config meets the model
#: side's parameters
DEFAULTS: dict[str, Callable[[EffectsCfg], np.ndarray]] = {
    "tool_gravity": lambda e: np.array([e.tool_gravity.mass_kg, *(e.tool_gravity.mass_kg * np.asarray(e.tool_gravity.com_f_m))]),
    # the simulator drifts the package's reading (the sensor's wrench on the tool); the parameter is the
    # change of the tool's wrench on the sensor (the contract's convention): the opposite sign
    "ft_bias_drift": lambda e: -np.asarray(e.ft_bias_drift.rate_f, dtype=float),
    "ft_frame_rotation": lambda e: np.deg2rad(np.asarray(e.ft_frame_rotation.rotvec_deg, dtype=float)),
    "tool_tilt": lambda e: np.deg2rad(np.asarray(e.tool_tilt.tilt_deg, dtype=float)),
    "contact_stiffness": lambda e: np.array([e.contact_stiffness.factor - 1.0]),
    "contact_friction_couple": lambda e: np.array([e.contact_friction_couple.radius_m]),
    "grasp_compliance": lambda e: np.array([1.0 / e.grasp_compliance.stiffness_Nm_per_rad]),
    "encoder_offset": lambda e: _joint_offset(e, len(BUILTINS["encoder_offset"].params)),
}


def _joint_offset(e: EffectsCfg, dof: int) -> np.ndarray:
    """(dof,) [rad]: the simulated joint's offset; the flange joint's is the sensor rotation's (no column)."""
    p = np.zeros(dof)
    if e.encoder_offset.joint < dof:
        p[e.encoder_offset.joint - 1] = np.deg2rad(e.encoder_offset.offset_deg)
    return p


def _online_effect(eff, default: Callable[[EffectsCfg], np.ndarray] | None = None) -> OnlineEffect:
    """The ``OnlineEffect`` of a contract ``Effect`` with an online side (``online=True``: ``from_wrench`` of
    its columns; ``online=fn``: ``fn``), in the effect's own parameters."""
    terms = from_wrench(eff.columns, eff.name) if eff.online is True else eff.online
    return OnlineEffect(eff.name, tuple(eff.params), tuple(eff.units), terms, default, eff.excite, eff.doc,
                        bool(eff.one_of))


#: every built-in with an online side, by name (the order of ``BUILTINS``)
LIBRARY: dict[str, OnlineEffect] = {n: _online_effect(e, DEFAULTS.get(n)) for n, e in BUILTINS.items()
                                    if e.online is not False}
