"""Checkpoints of the pretrained Jacobian basis: save, load and verify (no simulator here).

A checkpoint is ``{"state_dict", "meta", "sha256"}`` written atomically with ``torch.save``;
``meta`` holds the network's structure, the joint normalisation and the training heads' mean
(and covariance, ``kinadapt_nn.learning.prior``) used online as theta's prior. Loading is
``weights_only`` (no pickled code runs) and checks the format, version and content hash.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch

from kinadapt_nn.errors import ModelFileError
from kinadapt_nn.learning.nets import JacobianBasisNet
from kinadapt_nn.learning.weights import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, check_meta  # noqa: F401


def atomic_torch_save(obj, path: Path) -> None:
    from kinadapt_nn.runio import atomic_write

    atomic_write(Path(path), lambda tmp: torch.save(obj, tmp))


def state_hash(state: dict[str, torch.Tensor], meta: dict) -> str:
    """sha256 over the tensors (name, dtype, shape, bytes) and the metadata JSON."""
    h = hashlib.sha256()
    for k in sorted(state):
        t = state[k].detach().cpu().contiguous()
        h.update(k.encode())
        h.update(str(t.dtype).encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(t.numpy().tobytes())
    h.update(json.dumps(meta, sort_keys=True).encode())
    return h.hexdigest()


def save_checkpoint(
    path: Path, net: JacobianBasisNet, theta_mean: np.ndarray, meta: dict, theta_std: np.ndarray | None = None
) -> None:
    state = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
    meta = dict(meta, format=CHECKPOINT_FORMAT, version=CHECKPOINT_VERSION, theta_mean=[float(x) for x in theta_mean])
    if theta_std is not None:
        meta["theta_std"] = [float(x) for x in theta_std]
    atomic_torch_save({"state_dict": state, "meta": meta, "sha256": state_hash(state, meta)}, Path(path))


def load_checkpoint(path: Path) -> tuple[JacobianBasisNet, dict]:
    """Load and verify a checkpoint. One-line ``ModelFileError`` for anything wrong with it."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"checkpoint '{path}' not found (run 'kinadapt pretrain --out DIR' or fix the path)")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt files
        raise ModelFileError(f"checkpoint '{path}' is corrupt or not a torch file ({type(exc).__name__})") from None
    if not isinstance(blob, dict) or not {"state_dict", "meta", "sha256"} <= set(blob):
        raise ModelFileError(f"checkpoint '{path}' is not a kinadapt checkpoint (missing state_dict/meta/sha256)")
    meta = blob["meta"]
    check_meta(path, meta)
    if state_hash(blob["state_dict"], meta) != blob["sha256"]:
        raise ModelFileError(f"checkpoint '{path}' failed its content hash (file modified or damaged)")
    try:
        net = JacobianBasisNet(meta["structure"], meta["n_features"], meta["hidden"], meta["q_mean"], meta["q_std"])
        net.load_state_dict(blob["state_dict"])
    except (KeyError, RuntimeError, ValueError) as exc:
        raise ModelFileError(f"checkpoint '{path}' does not match the network it describes ({exc})") from None
    net.double().eval()
    return net, meta


def checkpoint_bytes_equal(a: Path, b: Path) -> bool:
    """True when two checkpoints hold the same tensors (for resume tests)."""
    sa = torch.load(a, weights_only=True)["state_dict"]
    sb = torch.load(b, weights_only=True)["state_dict"]
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)



