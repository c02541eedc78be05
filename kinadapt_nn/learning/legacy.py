"""Checkpoints from before safetensors: torch ``.pt`` files, read with torch.

Such a file is ``torch.save({"state_dict", "meta", "sha256"})``: the same tensors and metadata
as a safetensors checkpoint (``kinadapt_nn.learning.weights``), its hash over torch's dtype
names. It is read with ``torch.load(weights_only=True)`` (tensors, dicts, lists, strings and
numbers only; no pickled code runs), so reading one needs torch;
``python -m kinadapt_nn.learning.checkpoint OLD.pt`` converts one to safetensors.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from kinadapt_nn.errors import ModelFileError


def torch_state_hash(state: dict, meta: dict) -> str:
    """The sha256 a ``.pt`` checkpoint carries: per tensor (by name) its name, torch dtype,
    shape and bytes, then the metadata JSON."""
    h = hashlib.sha256()
    for k in sorted(state):
        t = state[k].detach().cpu().contiguous()
        h.update(k.encode())
        h.update(str(t.dtype).encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(t.numpy().tobytes())
    h.update(json.dumps(meta, sort_keys=True).encode())
    return h.hexdigest()


def read_torch_checkpoint(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """(tensors as stored, metadata) of a ``.pt`` checkpoint, its hash verified. One-line
    ``ModelFileError`` if it is damaged, not ours, or torch is not installed."""
    try:
        import torch
    except ModuleNotFoundError:
        raise ModelFileError(
            f"checkpoint '{path}' is a torch .pt file and torch is not installed: install torch, or convert it "
            f"where torch is ('python -m kinadapt_nn.learning.checkpoint {path}') and use the .safetensors file"
        ) from None
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 -- torch raises many types for corrupt files
        raise ModelFileError(f"checkpoint '{path}' is corrupt or not a torch file ({type(exc).__name__})") from None
    if not isinstance(blob, dict) or not {"state_dict", "meta", "sha256"} <= set(blob):
        raise ModelFileError(f"checkpoint '{path}' is not a kinadapt checkpoint (missing state_dict/meta/sha256)")
    state, meta = blob["state_dict"], blob["meta"]
    if not (isinstance(state, dict) and all(isinstance(v, torch.Tensor) for v in state.values())):
        raise ModelFileError(f"checkpoint '{path}' holds a state_dict that is not plain tensors")
    try:
        ok = torch_state_hash(state, meta) == blob["sha256"]
    except (TypeError, ValueError):  # metadata that is not JSON, a tensor numpy cannot hold
        ok = False
    if not ok:
        raise ModelFileError(f"checkpoint '{path}' failed its content hash (file modified or damaged)")
    return {k: v.numpy() for k, v in state.items()}, meta
