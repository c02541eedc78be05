"""Segmentation: where a log is surely in free space, decided from the data, not from a model
fitted to contact.

A contact adds a wrench that is not a function of the sensor's orientation and motion; in free
space the wrench is one. Whatever the sensor's mount, the tool's free-space wrench is affine in the
specific gravity ``u = g_s - a_s`` [m/s^2] (sensor frame, declared mount; ``mount`` module)::

    F = K_F u + b_F,    M = K_M u + b_M        (K_F = m D^T, K_M = [m c]x D^T; inertial terms neglected)

so free space can be found before any calibration:

1. **seed**: a quiet window (0.1 s) whose force is what the tool alone gives -- a tared log reads
   ~0 at its tare pose (the window of smallest force); an untared one reads the tool's weight
   (the window whose |F| is nearest the declared ``m g``).
2. **grown** in time from the seed, one window at a time, the affine model refitted on what is free
   so far (normal equations; a ridge keeps the orientation directions the span has not moved in
   at zero). Growth stops where the smoothed force leaves the model by more than
   ``[contact] detect_force_N``: that sample is a **contact onset**.
3. **turned**: the declared weight is one of the things under test (a hidden payload changes it),
   and a steady axial push along gravity can read as the declared weight. So seeds are tried in
   the order of step 1, each outside the spans already grown (at most ``MAX_SEEDS``), and the first
   span in which the sensor turns against gravity (``u`` spreads by ``TURN_MPS2``) wins -- a free
   span the calibration can use; a contact span rarely turns the tool that far. When no span
   turns, the first one stands.

The calibration (``mount.fit``) then runs on this free span alone; contact everywhere else is
decided against the calibrated model (``userlog.detect_contact``) with the free span's offset --
never the median of a log that may be mostly contact. Memory and work are linear in the log's
length (the normal equations are accumulated window by window).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinadapt_nn.diagnostics.stream import smooth

WINDOW_S = 0.1  #: [s] seed / growth window
MIN_WINDOW = 5  #: samples in a window at least
SMOOTH_S = 0.02  #: [s] centred moving average on the wrench before the test (the row filter's width)
RIDGE_MPS2 = 0.1  #: [m/s^2] orientation spread below which a direction of u is not fitted (ridge scale)
MIN_FREE = 20  #: fewer free samples than this: the seed is not trusted, every sample is a candidate
MAX_SEEDS = 6  #: seeds tried at most (step 3 of the module docstring)
TURN_MPS2 = 1.0  #: [m/s^2] a span turns against gravity when |u - mean u| reaches this (~6 deg)


@dataclass(frozen=True)
class Segmentation:
    """Which samples are surely free space (the calibration's samples)."""

    free: np.ndarray  #: (n,) bool: the free-space span grown from the seed
    seed_s: tuple[float, float]  #: [s] the seed window, from the first sample
    span_s: tuple[float, float]  #: [s] the grown span, from the first sample
    onsets_s: tuple[float, ...]  #: [s] where the force first leaves the free-space model (ends of the span inside the log)
    method: str  #: how the free span was found (one sentence)
    turn_mps2: float | None = None  #: [m/s^2] how far u moves in the span (``_turns``)
    passed_over: tuple = ()  #: ((start s, end s, turn m/s^2), ...) spans grown first that did not turn

    def to_json(self) -> dict:
        return {"free_span_s": list(self.span_s), "seed_window_s": list(self.seed_s),
                "free_samples": int(self.free.sum()), "contact_onsets_s": list(self.onsets_s), "method": self.method,
                "turn_mps2": self.turn_mps2, "passed_over": [list(p) for p in self.passed_over]}


def everything(n: int, t_s: np.ndarray, why: str) -> Segmentation:
    """Every sample a calibration candidate (static logs, ``[contact] mode = "none"``, no seed)."""
    span = (0.0, float(t_s[-1] - t_s[0])) if n else (0.0, 0.0)
    return Segmentation(np.ones(n, bool), span, span, (), why)


def _seed_cost(F: np.ndarray, ok: np.ndarray, L: int, tared: bool, weight_N: float) -> np.ndarray:
    """(n // L,) the seed cost of each window (lower: quieter and nearer the tool's own free-space
    force level); inf where a window holds an excluded sample."""
    nw = len(F) // L
    Fw = F[: nw * L].reshape(nw, L, 3)
    mean, sd = Fw.mean(1), np.linalg.norm(Fw.std(1), axis=1)
    level = np.linalg.norm(mean, axis=1)
    cost = (level if tared else np.abs(level - weight_N)) + 3.0 * sd
    cost[~ok[: nw * L].reshape(nw, L).all(1)] = np.inf
    return cost


def _turns(u: np.ndarray) -> float:
    """[m/s^2] how far the specific gravity ``u`` (n, 3) moves from its mean over a span."""
    return float(np.linalg.norm(u - u.mean(0), axis=1).max()) if len(u) else 0.0


def _grown_spans(F: np.ndarray, u: np.ndarray, ok: np.ndarray, L: int, cost: np.ndarray, thr: float):
    """Step 3 of the module docstring: spans grown from the seeds in the order of ``cost``, each
    seed outside the spans so far. -> ((seed sample, lo, hi, onsets) of the first span that turns
    by ``TURN_MPS2``, else of the first span; [(lo, hi)] of the spans passed over)."""
    cost = cost.copy()
    first, passed = None, []
    for _ in range(MAX_SEEDS):
        w = int(np.argmin(cost))
        if not np.isfinite(cost[w]):
            break
        start = w * L
        lo, hi, onsets = _grow(F, u, ok, start, L, thr)
        first = first or (start, lo, hi, onsets)
        if hi - lo >= MIN_FREE and _turns(u[lo:hi]) >= TURN_MPS2:
            return (start, lo, hi, onsets), passed
        passed.append((lo, hi))
        cost[lo // L:(hi + L - 1) // L] = np.inf
        cost[w] = np.inf
    return first, []


class _Affine:
    """Running normal equations of ``F = K u + b`` over the free span (force channels)."""

    def __init__(self, u0: np.ndarray) -> None:
        self.u0 = u0
        self.A = np.zeros((4, 4))
        self.B = np.zeros((4, 3))
        self.n = 0

    def add(self, u: np.ndarray, F: np.ndarray) -> None:
        X = np.c_[u - self.u0, np.ones(len(u))]
        self.A += X.T @ X
        self.B += X.T @ F
        self.n += len(u)

    def predict(self, u: np.ndarray) -> np.ndarray:
        ridge = np.diag([self.n * RIDGE_MPS2**2] * 3 + [0.0])
        beta = np.linalg.solve(self.A + ridge + 1e-12 * np.eye(4), self.B)
        return np.c_[u - self.u0, np.ones(len(u))] @ beta


def _leaves(F: np.ndarray, u: np.ndarray, model: _Affine, lo: int, hi: int) -> int:
    """Where the force first leaves the model before the threshold crossing at ``hi``: back from
    ``hi`` to the last sample within 4 sd of the span's own residual (robust)."""
    r = np.linalg.norm(F[lo:hi] - model.predict(u[lo:hi]), axis=1)
    tol = 4.0 * 1.4826 * float(np.median(r)) + 1e-9
    a = max(lo, hi - 4 * MIN_WINDOW * 10)
    tail = np.linalg.norm(F[a:hi] - model.predict(u[a:hi]), axis=1) <= tol
    return a + int(np.flatnonzero(tail)[-1]) + 1 if tail.any() else hi


def _grow(F: np.ndarray, u: np.ndarray, ok: np.ndarray, start: int, L: int, thr: float) -> tuple[int, int, list[int]]:
    """Grow [lo, hi) from the seed window both ways while the force stays within ``thr`` of the
    affine model fitted so far. -> (lo, hi, onset samples)."""
    n = len(F)
    lo, hi = start, min(start + L, n)
    model = _Affine(u[lo:hi].mean(0))
    model.add(u[lo:hi], F[lo:hi])
    onsets: list[int] = []
    fwd, bwd = hi < n, lo > 0
    while fwd or bwd:
        if fwd:
            b = min(hi + L, n)
            bad = (np.linalg.norm(F[hi:b] - model.predict(u[hi:b]), axis=1) > thr) | ~ok[hi:b]
            stop = int(np.argmax(bad)) if bad.any() else b - hi
            if stop:
                model.add(u[hi:hi + stop], F[hi:hi + stop])
            hi += stop
            fwd = not bad.any() and hi < n
            if bad.any() and ok[hi]:
                onsets.append(_leaves(F, u, model, lo, hi))
                hi = max(onsets[-1], lo + 1)  # the samples past where the force left the model are not free
        if bwd:
            a = max(lo - L, 0)
            bad = (np.linalg.norm(F[a:lo] - model.predict(u[a:lo]), axis=1) > thr) | ~ok[a:lo]
            keep = (lo - a) - (int(np.flatnonzero(bad)[-1]) + 1) if bad.any() else lo - a
            if keep:
                model.add(u[lo - keep:lo], F[lo - keep:lo])
            lo -= keep
            bwd = not bad.any() and lo > 0
    return lo, hi, onsets


def free_space(s, excluded: np.ndarray | None = None) -> Segmentation:
    """The free-space span of ``LogSignals`` s found from the data (module docstring).
    ``excluded`` (n,) bool: samples the user left out (``[analysis] exclude_s``), never free.
    -> ``Segmentation``."""
    setup, n = s.setup, s.n
    ok = np.ones(n, bool) if excluded is None else ~excluded
    if setup.contact.mode == "none":
        return everything(n, s.t, "[contact] mode = \"none\": every sample is free space")
    if s.static:
        return everything(n, s.t, "static poses: every pose is a candidate; contact from the robust calibration fit")
    dt = float(np.median(np.diff(s.t)))
    L = max(MIN_WINDOW, int(round(WINDOW_S / dt)))
    if n < 3 * L:
        return everything(n, s.t, "too short to segment: every sample is a candidate")
    F = smooth(s.wrench[:, :3], max(1, int(round(SMOOTH_S / dt))))  # in chunks
    u = s.g_s - s.a_s
    weight = setup.tool.mass_kg * setup.world.gravity_mps2
    cost = _seed_cost(F, ok, L, setup.log.tared, weight)
    if not np.isfinite(cost).any():
        return everything(n, s.t, "no seed window outside [analysis] exclude_s: every sample is a candidate")
    (start, lo, hi, onsets), passed = _grown_spans(F, u, ok, L, cost, setup.contact.detect_force_N)
    t = s.t - s.t[0]
    if hi - lo < MIN_FREE:
        return everything(n, s.t, "no free-space span found from the data: every sample is a candidate")
    free = np.zeros(n, bool)
    free[lo:hi] = True
    how = ("grown from the tare pose (the quietest window of least force)" if setup.log.tared else
           "grown from the quietest window whose force is nearest the declared tool's weight")
    if passed:
        how += " among those whose span turns the sensor against gravity (the nearest grew in a span that does not)"
    return Segmentation(free, (float(t[start]), float(t[min(start + L, n) - 1])), (float(t[lo]), float(t[hi - 1])),
                        tuple(float(t[i]) for i in sorted(onsets)),
                        how + f"; a sample is free while the force stays within {setup.contact.detect_force_N:g} N of "
                        "the free-space wrench (affine in the sensor's gravity direction)", _turns(u[lo:hi]),
                        tuple((float(t[a]), float(t[b - 1]), _turns(u[a:b])) for a, b in passed))


__all__ = ["Segmentation", "everything", "free_space"]
