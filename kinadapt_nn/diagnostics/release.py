"""A declared socket's releases, decided from the data: rows of the regression beside the wrench rows.

A declared socket (``[contact] geometry = "socket"``, ``effects.contact_model``) holds the tip until the
tip is ``RELEASE_M`` back above the entrance plane; then its springs let go and the sensor's contact
force falls to nothing from one sample to the next. The declared model computes that depth from the
encoders and the declared tip; the data show *when* it happened. So each release the sensor shows is a
measurement of the tool tip's depth along the socket's axis at that instant::

    depth(q_true, tip) = (p_ws + R_ws tip - entry) . n = -RELEASE_M

A joint whose encoder reads ``q - offset`` moves the declared tip (a 1 deg offset of the Panda's elbow:
8 mm along the axis in the excitation run) and the declared socket releases at another time: a
misfit of up to ~10 N for 0.4 s that no first-order wrench column describes (the anchors and the gate
are not differentiable; those rows are left out of the wrench rows, ``tip._without_disputed``). The
release's depth is linear in the offsets instead, so the releases enter the regression as rows of
their own (``stream.ExtraRows``): residual ``-RELEASE_M - depth_declared`` at the release, columns
``d depth / d p`` of every effect that moves the tip (the contract's ``Effect.depth``: the encoder
offsets, the tool's tilt) and of the tip nuisance, weighted by the depth's sd.

The depth's sd: the release lies between the last sample with force and the first without, and the
sensor's sample and the encoders' may be one period apart: ``SD_SAMPLES`` samples' axial travel of the
declared tip (at least ``MIN_SD_M``).

A release the data show: a sample ``k`` after which the force beyond the declared tool steps by at least
``min_force`` (``MIN_FORCE_NOISE`` times the force noise and ``MIN_FORCE_FRAC`` of ``[contact]
detect_force_N``) to a steady level, the step complete at the next sample (``_drops``). Each declared engagement takes the last such
drop from its start until the next engagement (at most ``SEARCH_S`` after its declared release): the
socket releases once per engagement, wherever the data put it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from kinadapt_nn.effects import contact_model

#: a release's force: at least this times the force's noise (|f| of three channels)
MIN_FORCE_NOISE = 10.0
#: and at least this fraction of ``[contact] detect_force_N``
MIN_FORCE_FRAC = 0.25
#: after the release the force is below this fraction of the force before
FALLEN = 0.2
#: samples before (steady) and after (fallen) a release
STEADY = 5
#: [s] the data's release is searched at most this long after the declared release
SEARCH_S = 2.0
#: a release's depth sd in samples of the tip's axial travel: the release lies between two samples, and
#: the sensor's reading and the encoders' may be a sample apart
SD_SAMPLES = 2.0
#: [m] the smallest sd of a release's depth (a tip that leaves the socket sideways, barely moving axially)
MIN_SD_M = 1e-5


class Releases(NamedTuple):
    """The releases the data show, matched to the declared socket's engagements (m of them)."""

    idx: np.ndarray  #: (m,) int: the last sample with the socket's force
    t_s: np.ndarray  #: (m,) [s] the data's release (from the first sample)
    t_declared_s: np.ndarray  #: (m,) [s] the declared socket's release (from the first sample)
    depth_m: np.ndarray  #: (m,) [m] the declared tip's depth at the data's release (midway k .. k+1)
    sd_m: np.ndarray  #: (m,) [m] its sd (module docstring)
    force_N: np.ndarray  #: (m,) [N] the force that let go

    @property
    def residual_m(self) -> np.ndarray:
        """(m,) [m] measured minus declared depth: ``-RELEASE_M - depth_m``."""
        return -contact_model.RELEASE_M - self.depth_m

    def to_json(self) -> dict:
        return {"t_s": [round(float(v), 4) for v in self.t_s],
                "declared_release_t_s": [round(float(v), 4) for v in self.t_declared_s],
                "declared_tip_depth_mm": [round(float(v) * 1e3, 3) for v in self.depth_m],
                "depth_sd_mm": [round(float(v) * 1e3, 4) for v in self.sd_m],
                "force_N": [round(float(v), 3) for v in self.force_N],
                "how": ("the data's releases: the force beyond the declared tool steps to a steady level from one sample "
                        f"to the next; the declared socket releases when the declared tip is {contact_model.RELEASE_M * 1e3:g} mm "
                        f"above the entrance; each release is a row of the fit: the tip's depth there (its sd: {SD_SAMPLES:g} "
                        "samples' axial travel)")}


def _tool_force(s) -> np.ndarray:
    """(n, 3) [N] the force beyond the declared tool's model (the declared socket's own prediction not
    taken out), sensor frame."""
    sock = contact_model.nominal_wrench(s.setup, s.R_ws, s.p_ws, contact_model.log_times(s))[:, :3]
    return np.asarray(s.wrench[:, :3], dtype=float) - (np.asarray(s.w_nom[:, :3], dtype=float) - sock)


def _drops(f: np.ndarray, min_force: float) -> tuple[np.ndarray, np.ndarray]:
    """The samples ``k`` where the force ``f`` (n, 3) lets go (module docstring): a step of at least
    ``min_force`` from sample k to the level of the ``STEADY`` samples after it, complete at k + 1, with
    the force steady before (within half the step) and after (within ``FALLEN`` of it). Relative to
    the level after, not to a free-space level: a drifting sensor's releases are found too.
    -> (k (d,), the step's size (d,) [N])."""
    n = len(f)
    if n < 2 * STEADY + 2:
        return np.zeros(0, int), np.zeros(0)
    win = np.lib.stride_tricks.sliding_window_view(f, STEADY, axis=0)  # (n - STEADY + 1, 3, STEADY): f[i:i+STEADY]
    k = np.arange(STEADY - 1, n - STEADY - 1)
    after = win[k + 1].mean(axis=2)  # (d, 3)
    step = np.linalg.norm(f[k] - after, axis=1)
    ok = step >= min_force
    k, after, step = k[ok], after[ok], step[ok]
    done = np.linalg.norm(f[k + 1] - after, axis=1) <= FALLEN * step
    before = np.linalg.norm(win[k - STEADY + 1] - f[k][:, :, None], axis=1).max(axis=1) <= 0.5 * step
    still = np.linalg.norm(win[k + 1] - after[:, :, None], axis=1).max(axis=1) <= FALLEN * step
    ok = done & before & still
    return k[ok], step[ok]


def find(s, sigma_f: float) -> Releases | None:
    """The releases of a log's declared socket that the data show (module docstring), or None: no socket
    declared, contacts not through the tip, a static log, or no release seen outside the set-up's
    ``[analysis] exclude_s`` windows (a release there is left out with the rest of the window). ``s``: the log's
    ``LogSignals`` (its ``contact`` the accounts' union); ``sigma_f`` [N] the force channels' noise."""
    setup = s.setup
    c = setup.contact
    if c.geometry != "socket" or c.mode != "tip" or s.static or not s.has_time or s.n < 4 * STEADY:
        return None
    tip = np.asarray(setup.tool.tip_sensor_m, dtype=float)
    st = contact_model.socket_terms(c, s.R_ws, s.p_ws, tip)
    if not st.gate.any():
        return None
    depth = (st.tip_w - np.asarray(c.entry_w_m, dtype=float)) @ st.axis_w
    drops, size = _drops(_tool_force(s), max(MIN_FORCE_NOISE * sigma_f, MIN_FORCE_FRAC * c.detect_force_N))
    t = np.asarray(s.t, dtype=float)
    edges = np.flatnonzero(np.diff(np.r_[0, st.gate.astype(int), 0]))
    starts, ends = edges[::2], edges[1::2]  # engaged on [start, end)
    left_out = setup.analysis.left_out(t - t[0])  # [analysis] exclude_s: a release there is no row either
    out = []
    for i, (a, b) in enumerate(zip(starts, ends)):
        stop = min(starts[i + 1] if i + 1 < len(starts) else s.n, np.searchsorted(t, t[b - 1] + SEARCH_S))
        d = np.flatnonzero((drops >= a) & (drops + 1 < stop))
        if len(d) and not left_out[drops[d[-1]]]:
            k = int(drops[d[-1]])
            out.append((k, t[k], t[b - 1], 0.5 * (depth[k] + depth[k + 1]),
                        max(SD_SAMPLES * abs(depth[k + 1] - depth[k]), MIN_SD_M), size[d[-1]]))
    if not out:
        return None
    cols = list(zip(*out))
    return Releases(np.array(cols[0], int), *(np.array(x, dtype=float) for x in cols[1:]))


def extra_rows(s, rel: Releases | None, design_t_s: np.ndarray, block: np.ndarray):
    """The releases as rows of a design (``stream.ExtraRows``; None without releases): each in the block
    of the design's row nearest in time. ``design_t_s`` (R,) [s] and ``block`` (R,): the design's rows."""
    from kinadapt_nn.diagnostics.stream import ExtraRows

    if rel is None or not len(design_t_s):
        return None
    order = np.argsort(design_t_s, kind="stable")  # the design's rows are free space first, then contact
    near = order[np.clip(np.searchsorted(design_t_s[order], rel.t_s), 0, len(order) - 1)]
    w = 1.0 / rel.sd_m
    return ExtraRows(rel.idx, rel.residual_m * w, w, np.asarray(block)[near].astype(int))


def tip_depth(s, idx: np.ndarray) -> np.ndarray:
    """(m, 3) [m/m] the tip nuisance's depth columns: a tip moved along the sensor's axis j moves the tip's
    depth by ``n . R_ws e_j`` (``tip._tip_columns``' third row of columns)."""
    n_ax = contact_model.socket_axis(s.setup.contact)
    return np.einsum("i,mij->mj", n_ax, np.asarray(s.R_ws, dtype=float)[idx])


__all__ = ["Releases", "find", "extra_rows", "tip_depth"]
