"""What a run builds from an experiment config: the features and theta0, and the controller.

This is where the truth firewall is cut: ``make_controller`` hands the controller
``KnownCfg.of(cfg)`` (what a real robot knows) and nothing else, and the registered features
type's builder gets the same plus the nominal workspace and the two declared uses of the truth,
both experiment design (:func:`features_context`): the initial offset estimate (true offset + the
configured error) and the true offset (the oracle baseline's).
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.controller.controller import Controller
from kinadapt_nn.features import FeaturesContext, FeaturesSpec, features_spec
from kinadapt_nn.features.base import Features
from kinadapt_nn.known import BORE_AXIS_W, KnownCfg
from kinadapt_nn.sensing import nominal_sensor_map


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


def make_features(cfg: ExperimentCfg, spec: FeaturesSpec | None = None) -> tuple[Features, np.ndarray]:
    """The features and theta0 of the registered type ``run.features`` (``features.FEATURES``; an
    unregistered name is a one-line ConfigError; ``spec``: that type's entry, when the caller has
    looked it up already) plus, with ``model.effects``, the library effects' columns
    (``kinadapt_nn.features.effects``; their parameters start at 0). BLAS at one thread meanwhile
    (:func:`one_blas_thread`: the same roundings wherever it is called from)."""
    with one_blas_thread():
        spec = features_spec(cfg.run.features) if spec is None else spec
        feats, theta0 = spec.build(features_context(cfg))
        if cfg.model.effects:
            from kinadapt_nn.features.effects import EffectFeatures

            feats = EffectFeatures(feats, list(cfg.model.effects), KnownCfg.of(cfg),
                                   nominal_sensor_map(cfg.sensing, BORE_AXIS_W))
            theta0 = np.r_[theta0, np.zeros(feats.k)]
        return feats, theta0


def batch_features(cfgs: list[ExperimentCfg]) -> list[tuple[Features, np.ndarray]]:
    """(features, theta0) of each episode of a batch that shares its known side: built per episode
    where the type's theta0 is experiment design (``FeaturesSpec.theta0_per_episode``) or effect
    columns keep per-episode state (``model.effects``), else the first episode's, shared."""
    spec = features_spec(cfgs[0].run.features)  # looked up once for the batch
    if spec.theta0_per_episode or cfgs[0].model.effects:
        return [make_features(c, spec) for c in cfgs]
    return [make_features(cfgs[0], spec)] * len(cfgs)


def features_context(cfg: ExperimentCfg) -> FeaturesContext:
    """What the builder of ``run.features`` is given: the known side (``KnownCfg.of``), the nominal
    workspace and the two declared uses of the truth -- the initial offset estimate (true offset
    + the configured error, experiment design) and the true offset (the oracle baseline's)."""
    return FeaturesContext(known=KnownCfg.of(cfg), workspace=NominalWorkspace(cfg),
                           offset_estimate_f_m=initial_estimate(cfg),
                           true_offset_f_m=np.asarray(cfg.tool.offset_f_m, dtype=float))


class NominalWorkspace:
    """``features.Workspace`` on the known model: the nominal (CAD) tool, untilted, on the nominal
    arm at the cell's known bores (``sim.workspace``'s IK; set-up only)."""

    def __init__(self, cfg: ExperimentCfg) -> None:
        tool = cfg.tool.model_copy(update={"offset_f_m": tuple(cfg.sensing.nominal_offset_f_m), "tilt_deg": (0.0, 0.0)})
        self._nominal = cfg.model_copy(update={"tool": tool, "arm": type(cfg.arm)()})
        self.n_bores = len(cfg.cell.bores(cfg.scene))

    def paths(self, n: int) -> list[np.ndarray]:
        from kinadapt_nn.sim.workspace import cell_paths, insertion_path

        return cell_paths(self._nominal, n=n) if self.n_bores > 1 else [insertion_path(self._nominal, n=n)]

    def sample(self, path: np.ndarray, n: int, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
        from kinadapt_nn.sim.workspace import sample_workspace

        return sample_workspace(path, n, sigma_rad, rng)


def make_controller(cfg: ExperimentCfg) -> Controller:
    """The controller of ``cfg`` (its features, theta0 and law), built with BLAS at one thread
    (:func:`one_blas_thread`)."""
    with one_blas_thread():
        feats, theta0 = make_features(cfg)
        return Controller(KnownCfg.of(cfg), feats, theta0)
