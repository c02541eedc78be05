"""Arm configurations around the insertion workspace (for RBF centres and pretraining data).

The insertion path is solved by IK for the default start geometry at depths from above the
entrance to the bottom of the bore; samples add Gaussian joint noise around it. Set-up only
(it uses a scene model to place the tip), never the controller's loop.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.geometry import tilt_rotation
from kinadapt_nn.robot import Q_HOME_RAD
from kinadapt_nn.sim.adapter import R_W_F_DOWN, solve_start_ik
from kinadapt_nn.sim.scene import build_model


#: results of the IK-solved sets below, per process, by their inputs (a pure function of them:
#: a compare worker builds the same RBF centres and held-out set for every tool it runs)
_MEMO: dict[tuple, object] = {}
_MEMO_MAX = 64


def _memo(key: tuple, compute):
    """``compute()`` once per ``key`` in this process; the caller gets copies (arrays it may change)."""
    if key not in _MEMO:
        if len(_MEMO) >= _MEMO_MAX:
            _MEMO.pop(next(iter(_MEMO)))
        _MEMO[key] = compute()
    val = _MEMO[key]
    return tuple(v.copy() for v in val) if isinstance(val, tuple) else val.copy()


def insertion_path(cfg: ExperimentCfg, n: int = 12, depth_range_m: tuple[float, float] = (-0.01, 0.05)) -> np.ndarray:
    """Joint configurations with the tip on the bore axis at ``n`` depths. -> (n, 7)."""
    key = ("path", cfg.tool.model_dump_json(), cfg.scene.model_dump_json(), tuple(cfg.start.tilt_deg), int(n),
           tuple(float(d) for d in depth_range_m))
    return _memo(key, lambda: _insertion_path(cfg, n, depth_range_m))


def _insertion_path(cfg: ExperimentCfg, n: int, depth_range_m: tuple[float, float]) -> np.ndarray:
    model, ids = build_model(cfg.tool, cfg.scene)
    entry = np.asarray(cfg.scene.bore_entry_w_m, dtype=float)
    R = tilt_rotation(cfg.start.tilt_deg) @ R_W_F_DOWN
    qs, q = [], Q_HOME_RAD.copy()
    for depth in np.linspace(depth_range_m[0], depth_range_m[1], n):
        q = solve_start_ik(model, ids, entry + np.array([0.0, 0.0, -depth]), R, q)
        qs.append(q.copy())
    return np.array(qs)


def sample_workspace(path: np.ndarray, n: int, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` configurations: random points on the path plus N(0, sigma) joint noise. -> (n, 7)."""
    seg = rng.integers(0, len(path) - 1, n)
    u = rng.random(n)[:, None]
    base = (1 - u) * path[seg] + u * path[seg + 1]
    return base + rng.normal(0.0, sigma_rad, base.shape)


def sample_cell(paths, n: int, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """``sample_workspace`` over a work cell: ``paths`` one path (n_k, 7) -- exactly
    ``sample_workspace`` -- or a list of them (each sample on a path drawn uniformly). -> (n, 7)."""
    if isinstance(paths, np.ndarray):
        return sample_workspace(paths, n, sigma_rad, rng)
    which = rng.integers(0, len(paths), n)
    out = np.empty((n, paths[0].shape[1]))
    for k, path in enumerate(paths):
        sel = np.flatnonzero(which == k)
        if len(sel):
            out[sel] = sample_workspace(path, len(sel), sigma_rad, rng)
    return out


def cell_paths(cfg: ExperimentCfg, n: int = 12) -> list[np.ndarray]:
    """``insertion_path`` at every bore of the work cell (``cfg.cell``; one bore without a cell).
    -> list of (n, 7), one per bore, in ``cell.bores`` order."""
    out = []
    for entry in cfg.cell.bores(cfg.scene):
        c = cfg.model_copy(update={"scene": cfg.scene.model_copy(update={"bore_entry_w_m": tuple(entry)})})
        out.append(insertion_path(c, n=n))
    return out


def heldout_configurations(cfg: ExperimentCfg) -> tuple[np.ndarray, np.ndarray]:
    """The work cell's fixed held-out configurations (evaluation of the cell Jacobian error).

    Per bore ``cell.heldout_per_bore`` poses of the NOMINAL tool's tip (the CAD offset, so the set
    does not depend on the tool under test): on a line parallel to the bore axis at a lateral
    offset uniform in +-``heldout_lateral_m``, at a depth uniform in [-10 mm, 50 mm], with the
    flange tilted uniformly within +-``heldout_tilt_deg`` about world x and y; IK on the nominal
    arm from the bore's own insertion path. Drawn from ``cell.heldout_seed`` alone: the same set
    for every tool, features type and insertion. -> (q (N, 7) [rad], bore index (N,))."""
    tool = cfg.tool.model_copy(update={"offset_f_m": tuple(cfg.sensing.nominal_offset_f_m), "tilt_deg": (0.0, 0.0)})
    scene = cfg.scene.model_copy(update={"contact_model": "socket"})
    key = ("heldout", cfg.cell.model_dump_json(), tool.model_dump_json(), scene.model_dump_json())
    return _memo(key, lambda: _heldout_configurations(cfg.cell, tool, scene))


def _heldout_configurations(cc, tool, scene) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(cc.heldout_seed)
    model, ids = build_model(tool, scene)
    qs, which = [], []
    for b, entry in enumerate(cc.bores(scene)):
        q = Q_HOME_RAD.copy()
        for _ in range(cc.heldout_per_bore):
            lat = rng.uniform(-1.0, 1.0, 2) * cc.heldout_lateral_m
            depth = rng.uniform(-0.01, 0.05)
            tilt = rng.uniform(-1.0, 1.0, 2) * cc.heldout_tilt_deg
            target = np.asarray(entry, dtype=float) + np.array([lat[0], lat[1], -depth])
            q = solve_start_ik(model, ids, target, tilt_rotation(tilt) @ R_W_F_DOWN, q)
            qs.append(q.copy())
            which.append(b)
    return np.array(qs), np.array(which)
