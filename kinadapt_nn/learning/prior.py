"""The pretrained prior of the neural features: the training heads' mean and covariance.

Pretraining fits one closed-form head ``theta_i`` per training instance (tool x arm,
``nets.least_squares_heads``). Their spread is what the data set says about where a new tool's
head lies: ``theta_mean`` (p,) and ``theta_cov`` (p, p), stored in the checkpoint's meta. Online,
the kalman law (``kinadapt_nn.controller.laws.kalman``) starts ``theta`` at the nominal tool's head (0) with
covariance ``theta_cov + theta_mean theta_mean^T`` (the second moment about 0,
``NeuralFeatures.prior_cov``): directions the training tools never moved stay put unless the data
insist; the directions they did move are learned quickly (the learned prior metric of
control-oriented meta-learning / Neural-Fly's Kalman prior). ``theta_moment_calibrated_arm``: the
same second moment over the tools on the nominal arm only (rank 3: the tool offset), the prior of
``features.neural_prior = "calibrated_arm"``.

``python -m kinadapt_nn.learning.prior CHECKPOINT`` adds the statistics to a checkpoint that lacks them
(the network's weights are not touched; the data set is rebuilt from the checkpoint's own
pretraining config, deterministically).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def head_statistics(checkpoint: Path, progress: bool = False) -> tuple[np.ndarray, np.ndarray, int, dict]:
    """Rebuild the training set of ``checkpoint`` and fit every training head with its network.
    -> (mean (p,), covariance (p, p), number of heads, the calibrated-arm prior's meta entries
    (``pretrain.calibrated_arm_moment``))."""
    import torch

    from kinadapt_nn.learning.nets import least_squares_heads
    from kinadapt_nn.learning.checkpoint import load_checkpoint
    from kinadapt_nn.learning.pretrain import PretrainCfg, calibrated_arm_moment, make_dataset

    net, meta = load_checkpoint(Path(checkpoint))
    cfg = PretrainCfg.model_validate(meta["config"])
    data = make_dataset(cfg, progress=progress)
    nt = cfg.data.n_train
    with torch.no_grad():
        q = torch.as_tensor(data["q"][:nt], dtype=torch.float64)
        r = torch.as_tensor(data["r"][:nt], dtype=torch.float64)
        theta = least_squares_heads(net, q, r, cfg.train.ridge).cpu().numpy()
    return theta.mean(axis=0), np.cov(theta, rowvar=False), len(theta), calibrated_arm_moment(theta, data["arm_error"][:nt])


def add_head_statistics(checkpoint: Path, out: Path | None = None, progress: bool = False) -> Path:
    """Write ``theta_cov`` (and ``theta_mean``/``theta_std`` recomputed) into the checkpoint's meta:
    to ``out``, by default the checkpoint itself (a torch ``.pt`` one: the ``.safetensors`` beside it)."""
    from kinadapt_nn.learning.checkpoint import load_checkpoint, save_checkpoint
    from kinadapt_nn.learning.weights import CHECKPOINT_SUFFIX

    net, meta = load_checkpoint(Path(checkpoint))
    mean, cov, n, calibrated = head_statistics(checkpoint, progress)
    meta = dict(meta, theta_cov=[[float(x) for x in row] for row in cov], theta_cov_heads=int(n), **calibrated)
    out = Path(out) if out else Path(checkpoint).with_suffix(CHECKPOINT_SUFFIX)
    save_checkpoint(out, net, mean, meta, theta_std=np.sqrt(np.diag(cov)))  # weights as loaded (float64)
    return out


if __name__ == "__main__":  # pragma: no cover
    p = add_head_statistics(Path(sys.argv[1]), progress=True)
    print(f"wrote {p}")
