"""Any registered law on its own, outside the controller: demos, offline replays, tests.

``StandaloneLaw`` is not a second implementation: it holds a B = 1 ``ControllerState`` with the
law's own blocks and runs ``core.law_kernel`` -- the regressor filter, the law-independent part of
the step (``core._law``: eq. ft_pred, the contact gate, the Gram log) and the law's numba step
through the same address the controller's kernels use.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kinadapt_nn.controller import core
from kinadapt_nn.controller.controller import core_consts
from kinadapt_nn.controller.laws import AdaptStep, LawParams, LawSpec, LawView, law_spec
from kinadapt_nn.controller.laws.base import law_state, state_sizes
from kinadapt_nn.features.base import Features
from kinadapt_nn.known import KnownCfg


class StandaloneLaw:
    """The law ``name`` for one episode of p parameters on m channels (B = 1).

    ``params``: the law's own parameters (an instance of its ``Params``: ``LawSpec.params_of``); ``W`` (m,) the channel metric; ``lo``, ``hi``
    (p,) the box Omega (``-inf``/``inf`` for none); ``filter_tau_s`` the rate filter's time
    constant (the regressor rows go through the same filter); ``contact_gate`` the free-space
    rule, (force [N], moment [N m]) (default (0, 0): always in contact); ``track_mask`` (p,) the
    rows of the tracking term (default all).
    """

    def __init__(self, name: str, params: LawParams, W: np.ndarray, lo: np.ndarray, hi: np.ndarray, *,
                 filter_tau_s: float, contact_gate: tuple[float, float] = (0.0, 0.0),
                 track_mask: np.ndarray | None = None) -> None:
        spec = law_spec(name)
        if not isinstance(params, spec.params):
            raise TypeError(f"the {name} law takes its own parameters ({spec.params.__module__}.{spec.params.__qualname__}"
                            f", from law_spec({name!r}).params_of(...)), not {type(params).__qualname__}")
        W = np.asarray(W, dtype=float)
        lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        m, p = W.size, lo.size
        dt = float(params.dt_s)
        if m > core.C_SIZE["V_W"]:
            raise ValueError(f"W has {m} channels; the kernels take at most {core.C_SIZE['V_W']}")
        c = core.pack_c({"ALPHA": dt / (filter_tau_s + dt),  # the rate filter's (sensing.LowPass)
                         "F_GATE": contact_gate[0], "M_GATE": contact_gate[1],
                         "V_W": np.pad(W, (0, core.C_SIZE["V_W"] - m))}, complete=False)
        mask = np.ones(p) if track_mask is None else np.asarray(track_mask, dtype=float)
        consts = core.CoreConsts(
            c=c, mats=np.zeros((2, 6, 6)), pv=np.ascontiguousarray(np.stack([lo, hi, mask])),
            lc=np.ascontiguousarray(spec.constants(params, m, p), dtype=float),
            law_fn=np.array([spec.address()], dtype=np.int64), seg=np.zeros((0, 7)))
        self._bind(spec, consts, m, p)

    @classmethod
    def of(cls, known: KnownCfg, features: Features, name: str | None = None) -> "StandaloneLaw":
        """The law a ``Controller(known, features, ...)`` runs (or the registered law ``name`` with
        the same constants): W, Omega, the filter, the gate and the law's constants as the
        controller builds them."""
        consts, spec, _fx = core_consts(known if name is None else replace(known, law=name), features)
        law = cls.__new__(cls)
        law._bind(spec, consts, consts.mats.shape[1], features.n_params)  # m: the rows of S (m, 6)
        return law

    def _bind(self, spec: LawSpec, consts: core.CoreConsts, m: int, p: int) -> None:
        """A B = 1 state with the law's blocks, for ``spec`` with kernel constants ``consts``."""
        self.spec, self.name, self.consts, self.m, self.p = spec, spec.name, consts, m, p
        blocks = spec.blocks(m, p)
        self.layout = core.Layout(0, m, p, state_sizes(blocks, spec.counters))
        self.state = core.ControllerState(self.layout, 1)
        st = self.state
        self._law_state = law_state(blocks, spec.counters, st.law_x, st.law_k, st.unc)
        self.view: LawView = self.spec.view(self.spec, self.consts.lc, self._law_state, 0)
        self._reg = np.zeros((1, 1 + p, m))
        self.out = np.zeros((1, self.layout.nout))
        self._o = {k: self.out[0, o:o + size] for k, (o, size) in self.layout.out_blocks.items()}
        self.reset()

    def reset(self) -> None:
        """Filters and the law's state back to the start (theta is the caller's)."""
        self.state.x[...] = 0.0
        self.state.k[...] = 0
        self.spec.reset(self.consts.lc, self._law_state, False)

    @property
    def known_f(self) -> np.ndarray:
        """(m,) the filtered known rate."""
        return self.state.known_f[0]

    @property
    def Phi_f(self) -> np.ndarray:
        """(m, p) the filtered regressor."""
        return self.state.Phi_fT[0].T

    @property
    def gram_sum(self) -> np.ndarray:
        """(p, p) sum over contact steps of (W Phi_f)^T (W Phi_f)."""
        return self.state.gram_sum[0]

    def update(self, known: np.ndarray, Phi: np.ndarray, theta: np.ndarray, s_dot_meas: np.ndarray, F: np.ndarray,
               w_env: np.ndarray) -> tuple[np.ndarray, AdaptStep]:
        """One control step: filter the regressor rows ``known`` (m,) and ``Phi`` (m, p) (on the
        realised velocity), then the law on ``theta`` (p,) with the filtered measured rate
        ``s_dot_meas`` (m,), the value force ``F`` (m,) and the tared contact wrench ``w_env`` (6,)
        (the gate). -> (theta_next (p,), AdaptStep)."""
        self._reg[0, 0] = known
        self._reg[0, 1:] = np.asarray(Phi).T
        o = self._o
        o["s_dot_meas"][:] = s_dot_meas
        o["F"][:] = F
        o["w_env"][:] = w_env
        self.state.theta[0] = theta
        cs = self.consts
        core.law_kernel(self._reg, self.state.x, self.state.k, self.layout.arr, cs.c, cs.pv, cs.lc, cs.law_fn,
                        self.out)
        a = AdaptStep(o["s_dot_pred"].copy(), o["eps_w"].copy(), o["d_track"].copy(), o["d_pred"].copy(),
                      float(o["gate"][0]), float(o["phi_norm2"][0]))
        return self.state.theta[0].copy(), a

