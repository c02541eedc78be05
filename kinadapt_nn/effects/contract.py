"""The public effect contract: one physical effect = one function over a log's signals.

A user's effect and a built-in one are written the same way (``kinadapt_nn/effects/builtin/``
holds the built-ins, one module each)::

    import numpy as np
    from kinadapt_nn.diagnostics import effect

    @effect(params={"fx_w": "N", "fy_w": "N", "fz_w": "N"}, relevant=[0.2, 0.2, 0.2],
            doc="a hose pulling with a constant world-frame force, clamped 35 mm off the tool axis")
    def cable_pull(s):
        '''(n, 6, 3): the change of s.wrench per unit of each parameter.'''
        ...

* The effect's name is the function's name; ``params`` maps each parameter to its unit (in order),
  ``relevant`` gives the smallest size worth reporting per parameter (in those units), ``doc`` one
  line; ``excite`` says which motion shows it; ``one_of=True``: the parameters are alternatives
  and one of them at a time is fitted (as the built-in joint encoder offset).
* ``s`` is a ``kinadapt_nn.diagnostics.signals.LogSignals`` (full rate, before any filtering).
* The function returns (n, 6, k) columns: the change of the measured wrench the tool exerts on the
  sensor (sensor frame, about its origin; [N, N m]) per unit of each parameter. The change is
  linear in the parameters. The diagnosis filters, weights, ranks, re-estimates and ``--add``s the
  effect exactly like a built-in one.
* Built-ins may also give ``report`` (the estimate in the user's units), ``plausible`` (why an
  estimate is physically impossible) and ``applies`` (whether it is judged for a set-up); a user's
  effect may too.
* ``online=True``: the same effect is also usable by the controller online (``model.effects``): its
  columns, evaluated on what the controller has (``s.t``, ``s.wrench``, ``s.R_ws``, ``s.omega_s``, ``s.g_s``,
  ``s.a_s``, ``s.alpha_s``),
  are mapped into the controller's level channels by one generic map
  (``kinadapt_nn.effects.online.from_wrench``). An effect that needs more (the contact
  kinematics, a declared set-up) gives ``online=fn`` instead, ``fn(sig) -> Terms`` in the same
  parameters, in the same module (``docs/effect_library.md``).
* ``depth=fn``, ``fn(s, idx) -> (e, k)`` [m per unit parameter]: an effect that moves the tool's tip
  says how it moves the tip's depth along a declared socket's axis at the samples ``idx``; the
  socket's releases that the data show are rows of the fit (``kinadapt_nn.diagnostics.release``).
  Built-ins that give it: ``encoder_offset``, ``tool_tilt``.
* Parameters that depend on the set-up (one per arm joint, say): give
  ``params_for=lambda setup: (params, relevant)`` instead of (or besides) ``params``/``relevant``.
  The diagnosis calls ``Effect.for_setup(setup)``, which fixes the parameters for that set-up;
  without ``params`` the public decorator (``kinadapt_nn.diagnostics.effect``) takes those of the
  diagnosis's default set-up (``SetupCfg()``)::

      @effect(params_for=lambda setup: ({f"drag_joint{j + 1}": "N m s/rad" for j in range(len(setup.log.q))},
                                        [0.1] * len(setup.log.q)),
              doc="viscous drag of a hose, per joint")
      def hose_drag(s):
          ...  # (n, 6, dof) with dof = s.q.shape[1]

An effects file is Python code that runs (like a test file): ``load_effect_files`` executes it.
Every ``Effect`` defined at the module level of the file is taken.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from kinadapt_nn.errors import KinadaptError

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Effect:
    """One effect of the library: its columns and what the report needs (module docstring)."""

    name: str
    params: tuple[str, ...]  #: parameter names, in column order
    units: tuple[str, ...]  #: their units
    relevant: tuple[float, ...]  #: (k,) smallest size worth reporting per parameter (> 0)
    doc: str  #: one line: the physical reading
    columns: Callable  #: LogSignals -> (n, 6, k)
    excite: str = ""  #: the motion that shows it
    one_of: bool = False  #: one column at a time
    source: str = "built-in"  #: where it was defined (a file path for a user's effect)
    report: Callable | None = None  #: (p (k,), sd (k,), setup) -> {param: {value, sd, unit, ...}}
    plausible: Callable | None = None  #: (p (k,), setup) -> why it is impossible, or None
    applies: Callable | None = None  #: setup -> bool: judged for this set-up
    uses_contact: bool = True  #: the columns depend on the contact mask (recomputed when it changes)
    params_for: Callable | None = None  #: setup -> (params {name: unit}, relevant (k,)); ``for_setup``
    exact: Callable | None = None  #: (s, p (k,)) -> (n, 6) the exact change where the columns are first order
    #: the controller's online columns (``model.effects``): True derives them from ``columns`` (which then
    #: reads only what ``effects.online.WrenchView`` has: ``from_wrench``); a function
    #: ``effects.online.Signals -> Terms`` gives them in the controller's level domain; False: none
    online: bool | Callable = False
    #: (s, idx (e,)) -> (e, k) [m per unit parameter]: how the parameters move the declared tip's depth along
    #: a declared socket's axis at the samples idx (``diagnostics.release``: the socket's releases are rows
    #: of the fit); None: the effect does not move the tip
    depth: Callable | None = None

    @property
    def k(self) -> int:
        return len(self.params)

    def for_setup(self, setup) -> "Effect":
        """This effect with the parameters of ``setup`` (``params_for``); itself without one."""
        if self.params_for is None:
            return self
        where = f"effect '{self.name}' ({self.source})"
        try:
            params, relevant = self.params_for(setup)
        except KinadaptError:
            raise
        except Exception as exc:  # a user's code (or not a pair): one line
            msg = str(exc).splitlines()[0] if str(exc) else ""
            raise KinadaptError(f"{where}: params_for raised {type(exc).__name__}: {msg}"[:300]) from None
        names, units, rel = _checked_params(where, params, relevant)
        return replace(self, params=names, units=units, relevant=rel)

    def __call__(self, s) -> np.ndarray:
        return self.columns(s)

    def evaluate(self, s) -> np.ndarray:
        """The columns, checked: (n, 6, k) finite floats, or a one-line ``KinadaptError`` naming
        the effect, its file and the problem."""
        where = f"effect '{self.name}' ({self.source})"
        try:
            C = self.columns(s)
        except KinadaptError:
            raise
        except Exception as exc:  # a user's code: any exception is their bug, reported in one line
            msg = str(exc).splitlines()[0] if str(exc) else ""
            raise KinadaptError(f"{where} raised {type(exc).__name__}: {msg}"[:300]) from None
        try:
            C = np.asarray(C, dtype=float)
        except (TypeError, ValueError):
            raise KinadaptError(f"{where} returned {type(C).__name__}, not an array of numbers "
                                f"(return the (n, 6, {self.k}) columns)") from None
        n = len(s.t)
        if C.ndim == 2 and self.k == 1 and C.shape == (n, 6):
            C = C[:, :, None]
        if C.shape != (n, 6, self.k):
            raise KinadaptError(f"{where} returned shape {C.shape}; expected (n, 6, k) = ({n}, 6, {self.k}) "
                                f"for its {self.k} parameter(s) {', '.join(self.params)}")
        bad = ~np.isfinite(C)
        if bad.any():
            i, _, j = np.argwhere(bad)[0]
            raise KinadaptError(f"{where} returned non-finite columns (first at sample {i}, parameter "
                                f"'{self.params[j]}'); return finite numbers")
        return C

    def user_report(self, p: np.ndarray, sd: np.ndarray, setup) -> dict:
        """The estimate ``{param: {value, sd, unit}}`` in the effect's declared units (or its own
        ``report``)."""
        if self.report is not None:
            return self.report(np.asarray(p, float), np.asarray(sd, float), setup)
        return {pn: {"value": float(v), "sd": float(s), "unit": u}
                for pn, v, s, u in zip(self.params, p, sd, self.units)}

    def why_impossible(self, p: np.ndarray, setup) -> str | None:
        if not np.all(np.isfinite(p)):
            return "the estimate is not finite"
        return self.plausible(np.asarray(p, float), setup) if self.plausible is not None else None


def effect(params: dict[str, str] | None = None, relevant=None, doc: str = "", excite: str = "",  # noqa: PLR0913
           # (the public decorator's options, every one but the first five keyword-only)
           one_of: bool = False, *, report: Callable | None = None, plausible: Callable | None = None,
           applies: Callable | None = None, uses_contact: bool = True,
           params_for: Callable | None = None, exact: Callable | None = None,
           online: bool | Callable = False, default_setup: Callable | None = None,
           depth: Callable | None = None) -> Callable[[Callable], Effect]:
    """Decorator: a function ``f(s) -> (n, 6, k)`` becomes an ``Effect`` named ``f.__name__``
    (module docstring). ``params_for(setup) -> (params, relevant)``: parameters that depend on the
    set-up (``Effect.for_setup``). ``exact(s, p) -> (n, 6)``: the exact change where the columns are a
    first-order model (``diagnostics.nonlinear``). ``online``: the controller's columns of the same effect
    (``Effect.online``; ``model.effects``). ``depth(s, idx) -> (e, k)``: how the parameters move the
    declared tip's depth along a declared socket's axis (``Effect.depth``). ``default_setup() -> setup``: the set-up whose parameters an
    effect with ``params_for`` and no ``params`` takes until ``for_setup`` (the public
    ``kinadapt_nn.diagnostics.effect`` gives the diagnosis's default set-up; this layer knows no set-up
    type). Bad arguments raise a one-line ``KinadaptError``."""
    def wrap(fn: Callable) -> Effect:
        name = getattr(fn, "__name__", "")
        src = _source_of(fn)
        where = f"effect '{name}' ({src})"
        if not callable(fn) or not _NAME.match(name or ""):
            raise KinadaptError(f"@effect must decorate a named function ({src})")
        if params_for is not None and not callable(params_for):
            raise KinadaptError(f"{where}: params_for must be a function setup -> (params, relevant)")
        if depth is not None and not callable(depth):
            raise KinadaptError(f"{where}: depth must be a function (s, idx) -> (e, k) or None")
        if not (isinstance(online, bool) or callable(online)):
            raise KinadaptError(f"{where}: online must be True (derived from the columns), a function "
                                "Signals -> Terms, or False")
        proto = Effect(name, (), (), (), "", fn, source=src, params_for=params_for)
        if params is None and relevant is None and params_for is not None and default_setup is not None:
            default = proto.for_setup(default_setup())
            names, units, rel = default.params, default.units, default.relevant
        elif params is None and params_for is not None:
            raise KinadaptError(f"{where}: give params={{name: unit, ...}} and relevant=[...] besides params_for "
                                "(the parameters until a set-up fixes them), or decorate with "
                                "kinadapt_nn.diagnostics.effect (the diagnosis's default set-up)")
        elif params is None:
            raise KinadaptError(f"{where}: give params={{name: unit, ...}} and relevant=[...] "
                                "(or params_for=setup -> (params, relevant))")
        else:
            names, units, rel = _checked_params(where, params, relevant)
        if not isinstance(doc, str) or not doc.strip():
            raise KinadaptError(f"{where}: doc must be a one-line description")
        return Effect(name, names, units, rel, doc.strip().splitlines()[0], fn, str(excite), bool(one_of), src,
                      report, plausible, applies, bool(uses_contact), params_for, exact, online, depth)
    return wrap


def _checked_params(where: str, params, relevant) -> tuple[tuple[str, ...], tuple[str, ...], tuple[float, ...]]:
    """(names, units, relevant) of a ``params`` dict and its ``relevant`` sizes, or a one-line error."""
    if not isinstance(params, dict) or not params or not all(isinstance(k, str) and isinstance(v, str)
                                                              for k, v in params.items()):
        raise KinadaptError(f"{where}: params must be a non-empty dict of parameter name -> unit (strings)")
    try:
        rel = tuple(float(x) for x in np.atleast_1d(np.asarray(relevant, dtype=float)))
    except (TypeError, ValueError):
        raise KinadaptError(f"{where}: relevant must be numbers, one per parameter") from None
    if len(rel) != len(params):
        raise KinadaptError(f"{where}: {len(rel)} relevant size(s) for {len(params)} parameter(s) "
                            f"({', '.join(params)}); give one per parameter")
    if not all(np.isfinite(r) and r > 0 for r in rel):
        raise KinadaptError(f"{where}: every relevant size must be finite and > 0 (got {list(rel)})")
    return tuple(params), tuple(params.values()), rel


def _source_of(fn) -> str:
    mod = sys.modules.get(getattr(fn, "__module__", "") or "")
    f = getattr(mod, "__file__", None) if mod is not None else None
    if f and Path(f).resolve().is_relative_to(Path(__file__).resolve().parent / "builtin"):
        return "built-in"
    return str(f) if f else "built-in"


def effects_of_module(mod) -> dict[str, Effect]:
    """Every ``Effect`` at the module level of ``mod``, by name (definition order)."""
    return {v.name: v for v in vars(mod).values() if isinstance(v, Effect)}


def load_effect_file(path: str | Path) -> dict[str, Effect]:
    """Execute one effects file and return its effects; one-line ``KinadaptError`` otherwise."""
    p = Path(path)
    if not p.is_file():
        raise KinadaptError(f"effects file '{p}' not found (give the path of a .py file)")
    if p.suffix != ".py":
        raise KinadaptError(f"effects file '{p}' is not a .py file (an effects file is Python code)")
    mod_name = f"kinadapt_user_effects_{abs(hash(str(p.resolve())))}"
    spec = importlib.util.spec_from_file_location(mod_name, p)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = mod
    try:
        spec.loader.exec_module(mod)
    except KinadaptError as exc:
        sys.modules.pop(mod_name, None)
        raise KinadaptError(str(exc)) from None
    except SyntaxError as exc:
        sys.modules.pop(mod_name, None)
        raise KinadaptError(f"effects file '{p}' line {exc.lineno}: syntax error: {exc.msg}") from None
    except Exception as exc:
        sys.modules.pop(mod_name, None)
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise KinadaptError(f"effects file '{p}' raised {type(exc).__name__} while loading: {msg}"[:300]) from None
    found = effects_of_module(mod)
    if not found:
        raise KinadaptError(f"effects file '{p}' defines no effect (decorate a function with "
                            "@effect(params=..., relevant=..., doc=...) from kinadapt_nn.diagnostics)")
    return found


def load_effect_files(paths, builtins: dict[str, Effect]) -> dict[str, Effect]:
    """The user's effects of every file, by name; a name that clashes with a built-in or with
    another file's effect is a one-line error."""
    out: dict[str, Effect] = {}
    for path in paths:
        for name, eff in load_effect_file(path).items():
            if name in builtins:
                raise KinadaptError(f"effects file '{path}': effect '{name}' has the name of a built-in effect "
                                    f"(rename the function; built-ins: {', '.join(builtins)})")
            if name in out:
                raise KinadaptError(f"effects file '{path}': effect '{name}' is also defined in {out[name].source} "
                                    "(rename one of them)")
            out[name] = eff
    return out


__all__ = ["Effect", "effect", "load_effect_file", "load_effect_files", "effects_of_module"]
