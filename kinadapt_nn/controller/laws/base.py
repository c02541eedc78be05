"""The contract every adaptation law fulfils, and the pieces the laws share.

A law is one module (``laws/kalman.py``, ``composite.py``, ...) that defines:

* ``step`` -- a ``numba.njit(cache=True)`` function with the signature :data:`STEP_SIG`. It is
  the law: the controller's kernels call it through its address (one compiled kernel serves every
  law), and it is callable from Python on numpy arrays (``StandaloneLaw``, tests). Per episode and
  control step *in contact* (the gate, eq. ft_pred and the Gram log are the kernel's,
  ``core._law``), with shapes for p parameters and m channels::

      n2 = step(theta (p,), H_T (p, m), G (p, p), e (m,), PhiF (p,), lo (p,), hi (p,),
                consts (nc,), x (nx,), k (nk,), unc (1,), d_track (p,), d_pred (p,))

  ``theta``: the estimate the controller used this step, overwritten with theta_{k+1};
  ``H_T = (W Phi_f)^T`` the W-scaled filtered regressor; ``G = H^T H``; ``e = W (s_dot_meas -
  known_f - Phi_f theta)`` (eq. ft_pred); ``PhiF = Phi_r^T F`` on the realised regressor (the
  features' tracking rows); ``lo, hi``: the box Omega (eq. QPaug); ``consts``: the law's own
  constants (:attr:`LawSpec.constants`); ``x, k``: the law's own float state and counters (the
  blocks it declares, :attr:`LawSpec.blocks`); ``unc[0]``: theta's remaining uncertainty as a
  fraction of the prior (the trace's ``theta_uncertainty``; NaN for a law without covariance);
  ``d_track, d_pred``: the increments for the trace (zero on entry). Returns ``||W Phi_f||^2`` as
  the law defines it (the trace's ``phi_norm2``; 0 when it has none).
* ``Params`` -- its parameters, a :class:`LawParams` subclass (unit, default and bounds per
  field; set in a config as ``[adaptation.params.<law>]``), when it has any.
* ``LAW = LawSpec(...)`` -- its name, parameters, constants, state blocks, reset and summary view.

Registering it is one line in ``laws/__init__.py`` (docs/architecture.md, "Adding a law").
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import numba as nb
import numpy as np
from numba import types
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from kinadapt_nn import compiled
from kinadapt_nn.config import AdaptationCfg
from kinadapt_nn.errors import ConfigError, did_you_mean

_F1 = types.Array(types.float64, 1, "C")
_F2 = types.Array(types.float64, 2, "C")
_I1 = types.Array(types.int64, 1, "C")
#: the signature of every law's ``step`` (module docstring)
STEP_SIG = types.float64(_F1, _F2, _F2, _F1, _F1, _F1, _F1, _F1, _F1, _I1, _F1, _F1, _F1)

#: ``law_step_fn(addr)`` inside a kernel: the law step at native address ``addr`` (int64,
#: :meth:`LawSpec.address`) as a first-class function of :data:`STEP_SIG`, called with numba's own
#: calling convention (exceptions propagate). The address is data, not code: the kernels that call
#: it compile and cache once for every law (``compiled.address_caller``).
law_step_fn = compiled.address_caller(STEP_SIG)


# ------------------------------------------------------------------------------------------------
# shared maths (numba)
@nb.njit(cache=True)
def project_omega(th, lo, hi, theta):
    """theta = Proj_Omega(th): the Euclidean projection onto the box Omega (a clip; eq. QPaug)."""
    for j in range(theta.shape[0]):
        theta[j] = min(max(th[j], lo[j]), hi[j])


@nb.njit(cache=True)
def lambda_max_sym3(G):
    """Largest eigenvalue of a symmetric 3x3 (lower triangle read), closed form: the trigonometric
    solution of the characteristic cubic (Smith 1961); relative error ~1e-15 on PSD Grams."""
    a, b, d, c, e, f = G[0, 0], G[1, 0], G[1, 1], G[2, 0], G[2, 1], G[2, 2]
    p1 = b * b + c * c + e * e
    q = (a + d + f) / 3.0
    if p1 == 0.0:
        return max(a, d, f)
    a, d, f = a - q, d - q, f - q
    p = math.sqrt((a * a + d * d + f * f + 2.0 * p1) / 6.0)
    a, b, c, d, e, f = a / p, b / p, c / p, d / p, e / p, f / p
    r = 0.5 * (a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c))
    r = -1.0 if r < -1.0 else (1.0 if r > 1.0 else r)
    return q + 2.0 * p * math.cos(math.acos(r) / 3.0)


# ------------------------------------------------------------------------------------------------
class AdaptStep(NamedTuple):
    """What one adaptation step did (for the trace)."""

    s_dot_pred: np.ndarray  #: (m,) filtered prediction known_f + Phi_f theta (before the update)
    eps_w: np.ndarray  #: (m,) W-scaled filtered prediction error before the update
    d_track: np.ndarray  #: (p,) tracking increment (before the gate)
    d_pred: np.ndarray  #: (p,) prediction increment (before the gate)
    gate: float  #: 1 in contact, 0 in free space
    phi_norm2: float  #: ||W Phi_f||^2 as the law defines it (0 when not adapting)


class LawParams(BaseModel):
    """A law's own parameters: the base every law's ``Params`` extends with its fields (SI units
    in each field's comment, a default, pydantic bounds), declared in the law's module and named
    by its ``LawSpec(params=...)``. The base holds what every law gets from the run: the control
    period and theta's prior covariance.

    Where a field's value comes from (:meth:`of`): a field declared with :func:`config_key` is a
    flat key of the config (``adaptation.<name>``: the built-in laws' knobs, several shared by
    more than one law); any other field is read from the law's own table
    ``[adaptation.params.<law>]``, else its default. A bad value is a one-line ``ConfigError``
    naming the key when the run builds the law."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False,
                              arbitrary_types_allowed=True)

    dt_s: float = Field(gt=0.0)  # [s] control period (the run's)
    prior_cov: np.ndarray  # (p, p) theta's prior covariance (the features')

    @field_validator("prior_cov", mode="before")
    @classmethod
    def _as_array(cls, v):
        return np.asarray(v, dtype=float)

    @classmethod
    def of(cls, adaptation: AdaptationCfg, dt_s: float, prior_cov: np.ndarray, law: str = "",
           **override) -> "LawParams":
        """This law's parameters (``cls``: the law's ``Params``) from the known adaptation config;
        ``law``: the law's name (its table ``adaptation.params.<law>``); ``override``: fields set
        directly, unvalidated (e.g. a negative gamma for the myopic-sign demo); a field some other
        law declares is ignored, one that no law declares is a TypeError."""
        table = dict(adaptation.params.get(law, {}))
        _check_table(cls, law, table)
        flat = {k: getattr(adaptation, k) for k in cls.model_fields if k in AdaptationCfg.model_fields}
        try:
            params = cls.model_validate({**flat, **table, "dt_s": dt_s, "prior_cov": prior_cov})
        except ValidationError as err:
            raise ConfigError(_params_error(err, law, flat)) from None
        unknown = set(override) - _declared_anywhere()
        if unknown:
            raise TypeError(f"no law declares the parameter(s) {sorted(unknown)}")
        return params.model_copy(update={k: v for k, v in override.items() if k in cls.model_fields})


def config_key(name: str) -> Any:
    """A law's field that *is* the flat config key ``adaptation.<name>`` (declared there, with its
    unit, default and bounds; read by the runs and the paper off the controller side): in a law's
    ``Params``, ``corr_s: float = config_key("corr_s")``."""
    return copy.copy(AdaptationCfg.model_fields[name])


def _declared_anywhere() -> set[str]:
    """Every field any law's ``Params`` declares (the subclasses of LawParams defined so far)."""
    names, todo = set(LawParams.model_fields), [LawParams]
    while todo:
        for sub in todo.pop().__subclasses__():
            names |= set(sub.model_fields)
            todo.append(sub)
    return names


def _check_table(cls: type[LawParams], law: str, table: dict) -> None:
    """Every key of ``[adaptation.params.<law>]`` is one of the law's own (not flat) fields."""
    own = [k for k in cls.model_fields if k not in LawParams.model_fields and k not in AdaptationCfg.model_fields]
    for key in table:
        if key in AdaptationCfg.model_fields:
            raise ConfigError(f"config key 'adaptation.params.{law}.{key}': the {law} law reads the flat key "
                              f"'adaptation.{key}'; set that instead")
        if key not in own:
            hint = did_you_mean(key, own)
            has = f"it has: {', '.join(own)}" if own else "it has none"
            raise ConfigError(f"config key 'adaptation.params.{law}.{key}' is not a parameter of the {law} law "
                              f"({hint + '; ' if hint else ''}{has})")


def _params_error(err: ValidationError, law: str, flat: dict) -> str:
    """One line for a law's parameter out of its bounds: the config key, what is wrong, the value."""
    first = err.errors()[0]
    name = ".".join(str(x) for x in first["loc"])
    key = f"adaptation.{name}" if name in flat else f"adaptation.params.{law}.{name}"
    msg = " ".join(str(first["msg"]).split()).removeprefix("Value error, ")
    return f"config key '{key}': {msg} (got {first.get('input')!r}; a parameter of the {law} law)"


class LawState(NamedTuple):
    """A law's state in one or more episodes: named views of its own blocks (leading B axis)."""

    x: np.ndarray  #: (B, nx) the law's float state (its blocks, in declaration order)
    k: np.ndarray  #: (B, nk) the law's counters
    unc: np.ndarray  #: (B,) theta's remaining uncertainty, fraction of the prior (NaN: no covariance)
    blocks: dict[str, np.ndarray]  #: name -> (B, *shape) view into ``x``
    counters: dict[str, np.ndarray]  #: name -> (B,) view into ``k``


class LawView:
    """What a law learned in one episode, read from *its own* state only: the summary's door into
    a law (``Controller.law``). Laws without a covariance keep these defaults."""

    has_covariance = False

    def __init__(self, spec: "LawSpec", consts: np.ndarray, state: LawState, b: int = 0) -> None:
        self.spec, self.name, self.consts, self.b = spec, spec.name, consts, b
        self.blocks = {k: v[b] for k, v in state.blocks.items()}
        self.counters = {k: v[b:b + 1] for k, v in state.counters.items()}
        self._unc = state.unc[b:b + 1]

    def identified_directions(self) -> int | None:
        """How many directions of theta the controller acts on as identified; None: the law has no
        notion of it (no covariance)."""
        return None

    def uncertainty_ratio(self) -> float:
        """``sqrt(tr P / tr P0)``: theta's remaining uncertainty as a fraction of the prior (NaN
        without a covariance)."""
        return float(self._unc[0])

    def information_sd(self) -> np.ndarray | None:
        """Posterior standard deviation of each parameter (None without a covariance)."""
        return None

    def residual_rms(self) -> float:
        """RMS of the W-scaled residual level the law measured in contact (NaN if it keeps none)."""
        return math.nan

    def identified_criterion(self) -> str:
        """What "identified" means for this law, in words ('' without a covariance)."""
        return ""


def _no_blocks(m: int, p: int) -> tuple[tuple[str, tuple[int, ...]], ...]:
    return ()


def _no_consts(params: LawParams, m: int, p: int) -> np.ndarray:
    return np.zeros(0)


def reset_plain(consts: np.ndarray, state: LawState, carried: bool) -> None:
    """The reset of a law without covariance: no uncertainty (NaN); state and counters zero
    unless ``carried`` (the next insertion keeps what the law learned)."""
    if not carried:
        state.x[...] = 0.0
        state.k[...] = 0
    state.unc[...] = math.nan


@dataclass(frozen=True)
class LawSpec:
    """One adaptation law: its name, its step and what the controller needs around it."""

    name: str  #: the config's ``adaptation.mode`` value
    doc: str  #: one line for help texts and docs tables
    step: Callable  #: the numba step (module docstring, :data:`STEP_SIG`)
    #: the law's own parameters (a :class:`LawParams` subclass in the law's module; the base: none)
    params: type[LawParams] = LawParams
    #: (params, m, p) -> the law's constants (nc,), passed to every step; ``params``: an instance of
    #: :attr:`params`
    constants: Callable[[Any, int, int], np.ndarray] = _no_consts
    #: (m, p) -> ((name, shape), ...): the law's float state blocks, in the order ``step`` reads them
    blocks: Callable[[int, int], tuple[tuple[str, tuple[int, ...]], ...]] = _no_blocks
    counters: tuple[str, ...] = ()  #: names of the law's integer counters
    #: (consts, state, carried) -> None: the start of an insertion (``carried``: the law's state of
    #: the previous insertion of the same tool is in place; keep what it learned)
    reset: Callable[[np.ndarray, LawState, bool], None] = reset_plain
    view: type[LawView] = LawView  #: the summary's view of the law's state
    _address: list = field(default_factory=list, repr=False, compare=False)

    def params_of(self, adaptation: AdaptationCfg, dt_s: float, prior_cov: np.ndarray, **override) -> LawParams:
        """The law's parameters from the known adaptation config (:meth:`LawParams.of`)."""
        return self.params.of(adaptation, dt_s, prior_cov, law=self.name, **override)

    def address(self) -> int:
        """The native address of ``step`` compiled for :data:`STEP_SIG` in this process (compiled,
        or loaded from numba's cache, on first use)."""
        if not self._address:
            self._address.append(compiled.jit_address(self.step, STEP_SIG))
        return self._address[0]


def state_sizes(blocks: tuple[tuple[str, tuple[int, ...]], ...], counters: tuple[str, ...]) -> tuple[int, int]:
    """(nx, nk): the float state and counter sizes of a law's ``blocks`` (``LawSpec.blocks(m, p)``,
    asked once by the caller) and ``counters``."""
    return sum(int(np.prod(s)) for _, s in blocks), len(counters)


def law_state(blocks: tuple[tuple[str, tuple[int, ...]], ...], counters: tuple[str, ...], x: np.ndarray,
              k: np.ndarray, unc: np.ndarray) -> LawState:
    """Named views of a law's ``blocks`` (``LawSpec.blocks(m, p)``) in ``x`` (B, nx) and of its
    ``counters`` in ``k`` (B, nk)."""
    B = x.shape[0]
    views, o = {}, 0
    for name, shape in blocks:
        size = int(np.prod(shape))
        views[name] = x[:, o:o + size].reshape((B, *shape))
        o += size
    return LawState(x, k, unc, views, {name: k[:, i] for i, name in enumerate(counters)})


def registry(*specs: LawSpec) -> dict[str, LawSpec]:
    """name -> LawSpec, refusing duplicate names."""
    laws: dict[str, LawSpec] = {}
    for s in specs:
        if s.name in laws:
            raise ValueError(f"two laws named {s.name!r}")
        laws[s.name] = s
    return laws
