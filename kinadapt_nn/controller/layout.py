"""The kernels' constants and state, declared once: what lies where in ``CoreConsts.c``, in a
``ControllerState`` row, in its counters and in a step's ``out`` row.

Each layout is a declaration of names and sizes (:data:`C_FIELDS`, :data:`K_FIELDS`,
:data:`X_BLOCKS`, :data:`OUT_BLOCKS`); the integer constants the numba kernels index with (``DT``,
``V_N``, ``K_TARED``, ``X_TH``, ``O_F``, ...; numba freezes a module-level int into the compiled
code) are generated from it when this module is imported, so nothing is numbered by hand.
``controller.core_consts`` fills ``c`` by these names (:func:`pack_c`: every field, each at its
declared size, or a ValueError); ``Layout`` lays out the blocks of a state row for n joints, m
channels, p parameters and the law's own block.

Shapes: B episodes, n joints, m = 6 sensor channels, p parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

#: the paper's kinematic gate on lambda_min(W J_hat J_hat^T W) (Results, "A separate kinematic gate")
RANK_GATE = 1e-6
#: features kinds (``c[FEAT]``): in the kernel (adjoint, neural, RBF) or from Python (twist, J_hat)
FEAT_ADJOINT, FEAT_TWIST, FEAT_JHAT, FEAT_NEURAL, FEAT_RBF = 0, 1, 2, 3, 4

#: ``CoreConsts.c``: (kernel name, size, [unit] meaning), in order; the scalars, then small vectors
C_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("DT", 1, "[s] control period"),
    ("T_SETTLE", 1, "[s] end of the settle: the tare is taken, the drive starts"),
    ("T_TARE0", 1, "[s] start of the tare window"),
    ("RAMP", 1, "[s] the drive's ramp rho"),
    ("D_STAR", 1, "[m] depth target d*"),
    ("K_D", 1, "[N/m] depth gain"),
    ("F_MAX", 1, "[N] saturation of the depth force"),
    ("C_F", 1, "[m/N] lateral compliance"),
    ("C_M", 1, "[rad/(N m)] moment compliance"),
    ("V_MAX", 1, "[m/s] translational speed limit"),
    ("W_MAX", 1, "[rad/s] angular speed limit"),
    ("K_NS", 1, "[1/s] null-space gain toward the posture"),
    ("DAMP", 1, "[-] damping of J J^T in J^+"),
    ("ALPHA", 1, "[-] the rate filter's dt / (tau + dt)"),
    ("INV_TAU", 1, "[1/s] 1 / (tau + dt)"),
    ("N_ENTRY", 1, "[m] n . p_entry, the bore entrance along its axis"),
    ("RIGID", 1, "[-] 1: the rigid loop (eq. ft_control)"),
    ("DITHER_ON", 1, "[-] 1: the dither is on"),
    ("TWO_PI_F", 1, "[rad/s] 2 pi x the dither frequency"),
    ("EXCITE", 1, "[-] 1: the excitation program drives"),
    ("BLEND", 1, "[s] the excitation program's blend"),
    ("F_GATE", 1, "[N] contact gate: |f_env| at or above this adapts"),
    ("M_GATE", 1, "[N m] contact gate: ... or |m_env| at or above this"),
    ("MAX_HOLD", 1, "[steps] the longest dropout held"),
    ("FEAT", 1, "[-] the features kind (FEAT_*)"),
    ("RANK_ON", 1, "[-] the rank gate: 0 off, 1 lambda_min every step, 2 the gate only"),
    ("RANK_GATE_V", 1, "[-] the rank gate's threshold"),
    ("V_N", 3, "[-] bore axis n, world"),
    ("V_LNOM", 3, "[m] nominal offset l_nom, f"),
    ("V_M", 6, "[kg | kg m^2] virtual inertia M per twist channel"),
    ("V_INVDEN", 6, "[1/(kg) | 1/(kg m^2)] 1 / (M + dt D)"),
    ("V_GRIGID", 6, "[m/(N s) | rad/(N m s)] the rigid loop's DC gain g / (1 + beta)"),
    ("V_W", 6, "[-] channel metric W"),
    ("V_D", 6, "[N s/m | N m s/rad] damping D"),
    ("V_DITHER", 3, "[rad/s] dither amplitudes"),
)

#: the controller's counters, columns of ``ControllerState.k`` (the law's own follow, from N_K); K_DONE and
#: K_PAUSED are set from outside the kernels: a batch episode that has stopped, and the law paused this step
#: (``monitor.pause_law``: a live monitor's event open, ``runs.loop.run``)
K_FIELDS: tuple[str, ...] = ("K_TARE_N", "K_TARED", "K_PRIMED", "K_STARTED", "K_HAVE_HELD", "K_BAD_RUN",
                             "K_DROPOUTS", "K_HOLDING", "K_ERROR", "K_GRAM_N", "K_DONE", "K_PAUSED")

Size = Callable[[int, int, int, int], int]  #: (n, m, p, law nx) -> a block's size

#: the blocks of a ``ControllerState.x`` row: (name, kernel offset name, size), in order
X_BLOCKS: tuple[tuple[str, str, Size], ...] = (
    ("xi", "X_XI", lambda n, m, p, lx: 6),  # the admittance's twist
    ("q_ref", "X_QREF", lambda n, m, p, lx: n),  # the joint reference
    ("q_post", "X_QPOST", lambda n, m, p, lx: n),  # the posture (null space)
    ("tare_sum", "X_TSUM", lambda n, m, p, lx: 6),
    ("tare", "X_TARE", lambda n, m, p, lx: 6),
    ("filt", "X_FILT", lambda n, m, p, lx: (2 + p) * m),  # y, known_f, Phi_f^T
    ("theta", "X_TH", lambda n, m, p, lx: p),
    ("gram_sum", "X_GRAM", lambda n, m, p, lx: p * p),
    ("unc", "X_UNC", lambda n, m, p, lx: 1),
    ("law", "X_LAW", lambda n, m, p, lx: lx),  # the law's own state (LawSpec.blocks)
    ("held", "X_HELD", lambda n, m, p, lx: 2 * n + 6),  # the last valid sample
)
#: the blocks of a step's ``out`` row: (name, kernel offset name, size), in order
OUT_BLOCKS: tuple[tuple[str, str, Size], ...] = (
    ("s", "O_S", lambda n, m, p, lx: m), ("s_dot_meas", "O_SDM", lambda n, m, p, lx: m),
    ("s_dot_pred", "O_SDP", lambda n, m, p, lx: m), ("F", "O_F", lambda n, m, p, lx: m),
    ("xi_cmd", "O_XI", lambda n, m, p, lx: 6), ("w_env", "O_WENV", lambda n, m, p, lx: 6),
    ("theta_used", "O_TH", lambda n, m, p, lx: p), ("rho", "O_RHO", lambda n, m, p, lx: 1),
    ("eps_w", "O_EPS", lambda n, m, p, lx: m), ("d_track", "O_DTR", lambda n, m, p, lx: p),
    ("d_pred", "O_DPR", lambda n, m, p, lx: p), ("gate", "O_GATE", lambda n, m, p, lx: 1),
    ("phi_norm2", "O_N2", lambda n, m, p, lx: 1), ("qdot_ref", "O_QDR", lambda n, m, p, lx: n),
    ("lam_min", "O_LAM", lambda n, m, p, lx: 1), ("uncertainty", "O_UNC", lambda n, m, p, lx: 1),
)
#: the head of ``Layout.arr``: [n, m, p, law nx, law nk], then the offsets of the x blocks, then of the out blocks
LAY_HEAD: tuple[str, ...] = ("L_N", "L_M", "L_P", "L_LNX", "L_LNK")


def _running(sizes: list[tuple[str, int]]) -> dict[str, int]:
    """name -> offset, the names laid out one after another."""
    out, o = {}, 0
    for name, size in sizes:
        out[name] = o
        o += size
    return out


#: name -> index in c (a vector's first entry)
C_INDEX: dict[str, int] = _running([(name, size) for name, size, _ in C_FIELDS])
C_SIZE: dict[str, int] = {name: size for name, size, _ in C_FIELDS}
N_C = sum(C_SIZE.values())
N_K = len(K_FIELDS)
#: every generated kernel constant: c indices, counters, Layout.arr positions
GENERATED: dict[str, int] = {**C_INDEX, **{k: i for i, k in enumerate(K_FIELDS)},
                             **{k: i for i, k in enumerate(LAY_HEAD + tuple(c for _, c, _ in X_BLOCKS + OUT_BLOCKS))}}
if len(GENERATED) != len(C_FIELDS) + N_K + len(LAY_HEAD) + len(X_BLOCKS) + len(OUT_BLOCKS):
    raise ValueError("two kernel constants share a name in the layouts of controller/layout.py")
globals().update(GENERATED)  # DT = 0, ..., V_DITHER = 63, K_TARE_N = 0, ..., L_N = 0, X_XI = 5, ...


def pack_c(values: dict[str, float | np.ndarray], complete: bool = True) -> np.ndarray:
    """``CoreConsts.c`` (N_C,) from ``values``: declared name -> a number or an array of the
    declared size. ``complete``: every declared field must be given (else the rest stay 0)."""
    unknown = sorted(set(values) - set(C_INDEX))
    missing = sorted(set(C_INDEX) - set(values)) if complete else []
    if unknown or missing:
        raise ValueError(f"CoreConsts.c: unknown field(s) {unknown}, missing {missing} (controller/layout.py, C_FIELDS)")
    c = np.zeros(N_C)
    for name, v in values.items():
        a = np.asarray(v, dtype=float).ravel()
        if a.size != C_SIZE[name]:
            raise ValueError(f"CoreConsts.c: {name} has {a.size} entries, declared {C_SIZE[name]}")
        c[C_INDEX[name]:C_INDEX[name] + a.size] = a
    return c


class Layout:
    """Offsets of the named state blocks in a ``ControllerState.x`` row (:data:`X_BLOCKS`) and of
    the per-step outputs in an ``out`` row (:data:`OUT_BLOCKS`) for n joints, m channels, p
    parameters; ``law_sizes`` (nx, nk): the law's own float block ``law`` and its counters
    (``LawSpec.sizes``)."""

    def __init__(self, n: int, m: int, p: int, law_sizes: tuple[int, int] = (0, 0)) -> None:
        self.n, self.m, self.p = n, m, p
        self.law_nx, self.law_nk = law_sizes
        sizes = [(name, size(n, m, p, self.law_nx)) for name, _, size in X_BLOCKS]
        self.x_blocks = {name: (o, dict(sizes)[name]) for name, o in _running(sizes).items()}
        self.nx = sum(s for _, s in sizes)
        sizes = [(name, size(n, m, p, self.law_nx)) for name, _, size in OUT_BLOCKS]
        self.out_blocks = {name: (o, dict(sizes)[name]) for name, o in _running(sizes).items()}
        self.nout = sum(s for _, s in sizes)
        # the kernels' view: [n, m, p, law nx, law nk, offsets of x blocks..., offsets of out blocks...]
        self.arr = np.array([n, m, p, self.law_nx, self.law_nk] + [o for o, _ in self.x_blocks.values()]
                            + [o for o, _ in self.out_blocks.values()], dtype=np.int64)


class ControllerState:
    """All filter and law state of B controllers, one owner: ``x`` (B, NX) float rows and ``k``
    (B, N_K + law nk) counters; the named blocks are views into them (shapes with a leading B).
    The law's own state: ``law_x`` (B, nx), ``law_k`` (B, nk), ``unc`` (B,) (``laws.base.law_state``
    names its blocks)."""

    def __init__(self, layout: Layout, B: int) -> None:
        self.layout = layout
        self.x = np.zeros((B, layout.nx))
        self.k = np.zeros((B, N_K + layout.law_nk), dtype=np.int64)
        m, p = layout.m, layout.p
        shapes = {"filt": (2 + p, m), "gram_sum": (p, p)}
        for name, (o, size) in layout.x_blocks.items():
            setattr(self, name, self.x[:, o:o + size].reshape((B, *shapes.get(name, (size,)))))
        # the filter rows: y (rate filter of s), known_f, Phi_f^T
        self.y, self.known_f, self.Phi_fT = self.filt[:, 0], self.filt[:, 1], self.filt[:, 2:]
        self.law_x, self.law_k, self.unc = self.law, self.k[:, N_K:], self.unc[:, 0]


@dataclass(frozen=True)
class CoreConsts:
    """The known constants the kernels read (built once by the wrappers)."""

    c: np.ndarray  #: (N_C,) scalars and small vectors (:data:`C_FIELDS`, :func:`pack_c`)
    mats: np.ndarray  #: (2, 6, 6): S; G (row 0 zero, s[1:] = G[1:] w_env)
    pv: np.ndarray  #: (3, p): Omega's lo, hi; the tracking term's row mask
    lc: np.ndarray  #: (nc,) the law's own constants (``LawSpec.constants``)
    #: (1,) int64: the law step's native address (``LawSpec.address``), valid only in the process
    #: that built it (and its forks): never save it or send it to another process
    law_fn: np.ndarray
    seg: np.ndarray  #: (nseg, 7): excite program [end time s, twist (6)]


__all__ = ["C_FIELDS", "C_INDEX", "C_SIZE", "FEAT_ADJOINT", "FEAT_JHAT", "FEAT_NEURAL", "FEAT_RBF", "FEAT_TWIST",
           "GENERATED", "K_FIELDS", "LAY_HEAD", "N_C", "N_K", "OUT_BLOCKS", "RANK_GATE", "X_BLOCKS", "ControllerState",
           "CoreConsts", "Layout", "pack_c", *GENERATED]
