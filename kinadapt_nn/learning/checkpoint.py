"""Checkpoints of the pretrained Jacobian basis as a torch network: save, load and verify.

The file is safetensors with the metadata as JSON (``kinadapt_nn.learning.weights``, which the
online side reads without torch); ``meta`` holds the network's structure, the joint
normalisation and the training heads' mean (and covariance, ``kinadapt_nn.learning.prior``)
used online as theta's prior. Loading checks the format, version, content hash and shapes;
older torch ``.pt`` checkpoints are still read (``kinadapt_nn.learning.legacy``), and
``python -m kinadapt_nn.learning.checkpoint OLD.pt [NEW.safetensors]`` converts one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from kinadapt_nn.errors import ModelFileError
from kinadapt_nn.learning.legacy import read_torch_checkpoint
from kinadapt_nn.learning.nets import JacobianBasisNet
from kinadapt_nn.learning.weights import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_SUFFIX,
    CHECKPOINT_VERSION,
    check_meta,
    check_state,
    load_checkpoint_arrays,
    read_checkpoint_file,
    write_checkpoint_file,
)


def atomic_torch_save(obj, path: Path) -> None:
    """``torch.save`` atomically (the pretraining's resume state)."""
    from kinadapt_nn.runio import atomic_write

    atomic_write(Path(path), lambda tmp: torch.save(obj, tmp))


def save_checkpoint(
    path: Path, net: JacobianBasisNet, theta_mean: np.ndarray, meta: dict, theta_std: np.ndarray | None = None
) -> None:
    """Write ``net``'s weights and ``meta`` (plus format, version, theta's mean and sd) atomically."""
    state = {k: v.detach().cpu().numpy() for k, v in net.state_dict().items()}
    meta = dict(meta, format=CHECKPOINT_FORMAT, version=CHECKPOINT_VERSION, theta_mean=[float(x) for x in theta_mean])
    if theta_std is not None:
        meta["theta_std"] = [float(x) for x in theta_std]
    write_checkpoint_file(Path(path), state, meta)


def load_checkpoint(path: Path) -> tuple[JacobianBasisNet, dict]:
    """Load and verify a checkpoint (safetensors, or a torch ``.pt``) as a float64 network in eval
    mode. One-line ``ModelFileError`` for anything wrong with it."""
    state, meta = load_checkpoint_arrays(path)
    try:
        net = JacobianBasisNet(meta["structure"], meta["n_features"], meta["hidden"], meta["q_mean"], meta["q_std"])
        net.load_state_dict({k: torch.from_numpy(v) for k, v in state.items()})
    except (KeyError, RuntimeError, TypeError, ValueError) as exc:
        raise ModelFileError(f"checkpoint '{path}' does not match the network it describes ({exc})") from None
    net.double().eval()
    return net, meta


def checkpoint_bytes_equal(a: Path, b: Path) -> bool:
    """True when two safetensors checkpoints hold the same tensors, bit for bit (resume tests)."""
    sa, sb = read_checkpoint_file(a).state, read_checkpoint_file(b).state
    return sa.keys() == sb.keys() and all(sa[k].dtype == sb[k].dtype and np.array_equal(sa[k], sb[k]) for k in sa)


def convert_torch_checkpoint(pt: Path, out: Path | None = None) -> Path:
    """Write the torch ``.pt`` checkpoint ``pt`` as safetensors (default: beside it, same stem),
    its tensors and metadata unchanged, after the checks ``load_checkpoint`` makes."""
    pt = Path(pt)
    state, meta = read_torch_checkpoint(pt)
    check_meta(pt, meta)
    check_state(pt, state, meta)
    out = Path(out) if out is not None else pt.with_suffix(CHECKPOINT_SUFFIX)
    write_checkpoint_file(out, state, meta)
    return out


if __name__ == "__main__":  # pragma: no cover
    import sys

    if len(sys.argv) not in (2, 3):
        sys.exit("usage: python -m kinadapt_nn.learning.checkpoint OLD.pt [NEW.safetensors]")
    try:
        print(f"wrote {convert_torch_checkpoint(Path(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) == 3 else None)}")
    except ModelFileError as exc:
        sys.exit(f"kinadapt: {exc}")
