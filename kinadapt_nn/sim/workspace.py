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


def insertion_path(cfg: ExperimentCfg, n: int = 12, depth_range_m: tuple[float, float] = (-0.01, 0.05)) -> np.ndarray:
    """Joint configurations with the tip on the bore axis at ``n`` depths. -> (n, 7)."""
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
