"""What a run builds from an experiment config: the features and theta0, and the controller.

This is where the truth firewall is cut: ``make_controller`` hands the controller
``KnownCfg.of(cfg)`` (what a real robot knows) and nothing else. The only declared uses of the
truth are experiment design: ``oracle`` (the true offset) and the adjoint's initial estimate
(true offset + the configured error).
"""

from __future__ import annotations


from pathlib import Path

import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path
from kinadapt_nn.controller.controller import Controller
from kinadapt_nn.features import AdjointFeatures
from kinadapt_nn.features.base import Features
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.sensing import channel_metric, nominal_sensor_map
from kinadapt_nn.known import BORE_AXIS_W

FAILURES = ("none", "timeout", "jam", "block_face", "divergence")


def one_blas_thread():
    """Context manager: the BLAS libraries loaded in this process (numpy's, and scipy's that the
    kernels call for the RBF's p x p products and eigh) at one thread while episodes step.

    The per-step products are small (p = 210 at most by default); OpenBLAS's threads win nothing
    on them and, with episodes in parallel processes (compare, sweep: one per core), spin against
    each other's: two RBF socket episodes side by side took 6.2 s each with OpenBLAS's default
    threads against 1.7 s at one thread (2-core VM).

    scipy's OpenBLAS is loaded first (``scipy.linalg.cython_lapack``, through which numba's
    ``np.linalg`` calls it; loading the kernels imports it anyway): the limit covers only the
    libraries loaded when it is set, and before this the first episode of a process ran scipy's
    BLAS at every core while later ones ran at one, so an RBF episode's numbers depended on
    whether it was its process's first (different roundings from t = 0.46 s on). Controllers are
    built under it too (:func:`make_controller`): the RBF's fit and prior are BLAS products whose
    roundings depend on the thread count."""
    import importlib

    from threadpoolctl import threadpool_limits

    importlib.import_module("scipy.linalg.cython_lapack")

    return threadpool_limits(1, user_api="blas")


def initial_estimate(cfg: ExperimentCfg) -> np.ndarray:
    """theta0 = true offset + ``initial_error_m`` along ``initial_error_dir_f`` (default: away
    from the flange axis, along the true lateral offset). Experiment design: the controller
    receives the number, never the truth it was derived from. -> (3,) in f [m]."""
    ad = cfg.adaptation
    true = np.asarray(cfg.tool.offset_f_m, dtype=float)
    direction = np.asarray(ad.initial_error_dir_f, dtype=float)
    if not np.any(direction):
        direction = np.array([true[0], true[1], 0.0])
        if not np.any(direction):
            direction = np.array([1.0, 0.0, 0.0])
    return true + ad.initial_error_m * direction / np.linalg.norm(direction)


def make_features(cfg: ExperimentCfg) -> tuple[Features, np.ndarray]:
    """``_base_features`` plus, with ``model.effects``, the library effects' columns
    (``kinadapt_nn.features.effects``; their parameters start at 0). BLAS at one thread meanwhile
    (:func:`one_blas_thread`: the same roundings wherever it is called from)."""
    with one_blas_thread():
        return _make_features(cfg)


def _make_features(cfg: ExperimentCfg) -> tuple[Features, np.ndarray]:
    feats, theta0 = _base_features(cfg)
    if cfg.model.effects:
        from kinadapt_nn.features.effects import EffectFeatures

        feats = EffectFeatures(feats, list(cfg.model.effects), KnownCfg.of(cfg), nominal_sensor_map(cfg.sensing, BORE_AXIS_W))
        theta0 = np.r_[theta0, np.zeros(feats.k)]
    return feats, theta0


def _base_features(cfg: ExperimentCfg) -> tuple[Features, np.ndarray]:
    """Features object and the initial parameters for ``run.features``.

    Nothing here uses the truth except the two declared cases: ``oracle`` (the true offset) and
    the adjoint's initial estimate (true offset + the configured error, experiment design)."""
    S = nominal_sensor_map(cfg.sensing, BORE_AXIS_W)
    l_nom = np.asarray(cfg.sensing.nominal_offset_f_m, dtype=float)
    ad = cfg.adaptation
    adjoint = AdjointFeatures(S, l_nom, np.array([ad.omega_lateral_m, ad.omega_lateral_m, ad.omega_axial_m]))
    kind = cfg.run.features
    if kind == "oracle":
        return adjoint, np.asarray(cfg.tool.offset_f_m, dtype=float)
    adjoint.P0 = np.diag([ad.prior_sd_lateral_m**2, ad.prior_sd_lateral_m**2, ad.prior_sd_axial_m**2])
    if kind == "adjoint":
        return adjoint, initial_estimate(cfg)
    if kind == "rbf":
        from kinadapt_nn.features.rbf import RBFFeatures, auto_width
        from kinadapt_nn.sim.workspace import insertion_path, sample_workspace

        fc = cfg.features
        nominal = cfg.model_copy(update={"tool": cfg.tool.model_copy(update={"offset_f_m": tuple(l_nom), "tilt_deg": (0.0, 0.0)}),
                                         "arm": type(cfg.arm)()})
        if len(cfg.cell.bores(cfg.scene)) > 1:  # a work cell: the K centres shared out over its bores
            centres = _cell_centres(nominal, fc.rbf_n_centres, fc.rbf_centres, fc.rbf_seed)
        elif fc.rbf_centres == "path":
            centres = insertion_path(nominal, n=fc.rbf_n_centres)
        else:
            path = insertion_path(nominal)
            centres = sample_workspace(path, fc.rbf_n_centres, 0.03, np.random.default_rng(fc.rbf_seed))
        width = fc.rbf_width_rad or auto_width(centres)
        feats = RBFFeatures(adjoint, l_nom, centres, width)
        from kinadapt_nn.controller.controller import ArmKinematics

        feats.P0 = feats.prior_from_adjoint(ArmKinematics(arm_mjcf_path(cfg.scene)), adjoint.P0, ad.rbf_prior_floor)
        return feats, np.zeros(feats.n_params)
    if kind == "neural":
        from kinadapt_nn.features.neural import NeuralFeatures
        from kinadapt_nn.robot import MODELS_DIR

        name = cfg.features.neural_checkpoint
        ckpt = Path(name) if name else MODELS_DIR / "neural_default.safetensors"
        if not ckpt.is_absolute() and not ckpt.exists():  # a shipped model named by its file name ("neural_cell.safetensors")
            shipped = MODELS_DIR / ckpt.name
            if ckpt.suffix == ".pt":  # a shipped model's name before safetensors: its conversion, the same weights (test)
                shipped = shipped.with_suffix(".safetensors")
            ckpt = shipped if shipped.is_file() else ckpt
        feats = NeuralFeatures(adjoint, l_nom, ckpt, channel_metric(cfg.sensing))
        feats.P0 = feats.prior_cov(cfg.features.neural_prior)  # the pretraining heads' second moment about the nominal head
        return feats, np.zeros(feats.n_params)  # the head of the nominal tool (zero residual)
    raise ValueError(f"unknown features {kind!r}")  # pragma: no cover (validated by the config)


def _cell_centres(nominal: ExperimentCfg, k: int, how: str, seed: int) -> np.ndarray:
    """RBF centres over a work cell: ``k`` in all, shared out over the bores in turn (bore b gets
    ``k // nb`` plus one of the remainder), on each bore's insertion path (evenly in depth) or
    sampled about it. -> (k', 7) with k' = max(k, number of bores)."""
    from kinadapt_nn.sim.workspace import cell_paths, sample_workspace

    paths = cell_paths(nominal, n=12)
    nb = len(paths)
    rng = np.random.default_rng(seed)
    out = []
    for b, path in enumerate(paths):
        kb = max(1, k // nb + (1 if b < k % nb else 0))
        if how == "path":
            idx = np.round(np.linspace(0, len(path) - 1, kb + 2)[1:-1]).astype(int)
            out.append(path[idx])
        else:
            out.append(sample_workspace(path, kb, 0.03, rng))
    return np.concatenate(out)


def law_name(cfg: ExperimentCfg) -> str:
    return "frozen" if cfg.run.features == "oracle" else cfg.adaptation.mode


def make_controller(cfg: ExperimentCfg) -> Controller:
    """The controller of ``cfg`` (its features, theta0 and law), built with BLAS at one thread
    (:func:`one_blas_thread`)."""
    with one_blas_thread():
        feats, theta0 = make_features(cfg)
        return Controller(KnownCfg.of(cfg), feats, theta0)
