"""The checkpoint file of the pretrained Jacobian basis, read and written with numpy (no torch).

The online controller needs only the body's weights (its numpy forward runs in the kernel), so
it reads them with ``safetensors.numpy``: ``import torch`` would cost every ``kinadapt online``
with neural features, and every worker of ``compare`` / ``sweep``, more than the run's setup.

A checkpoint is one ``.safetensors`` file (a JSON header, then each tensor's raw little-endian
bytes; nothing in it is unpickled or run):

* its tensors: the network's state_dict under torch's names (``l1.weight`` .. ``l3.bias``,
  ``q_mean``, ``q_std``; float64, as trained);
* its header's ``metadata`` (str -> str), two entries: ``meta``, the checkpoint's metadata as
  JSON (``format`` and ``version`` of its schema, the structure and sizes, the joint
  normalisation, theta's prior, the pretraining config, ...), and ``sha256``,
  :func:`content_hash` over the tensors and that JSON (safetensors checks the file's layout,
  not its bytes: the hash catches a flipped bit).

Checkpoints written before (torch ``.pt`` files, told by their zip signature, not their name)
are read through ``torch.load(weights_only=True)`` (``kinadapt_nn.learning.legacy``; the
conversion: ``python -m kinadapt_nn.learning.checkpoint OLD.pt``).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from kinadapt_nn.errors import ModelFileError

N_ROWS = 5  #: adapted task rows of the Jacobian basis (F_lat x, F_lat y, M x, M y, M z)
N_JOINTS = 7  #: arm joints the basis is trained for (Panda)

CHECKPOINT_FORMAT = "kinadapt-jacobian-basis"
CHECKPOINT_VERSION = 1  #: of the metadata's schema (unchanged by the move from .pt to safetensors)
CHECKPOINT_SUFFIX = ".safetensors"
_ZIP_MAGIC = b"PK\x03\x04"  # a torch .pt file (a zip archive)


class CheckpointArrays(NamedTuple):
    """A checkpoint's contents as numpy arrays."""

    state: dict[str, np.ndarray]  #: the network's state_dict by torch's names (shapes: ``expected_shapes``)
    meta: dict  #: the metadata (structure, sizes, theta's prior, the pretraining config, ...)


def content_hash(state: dict[str, np.ndarray], meta_json: str) -> str:
    """sha256 over the tensors (name, dtype, shape, little-endian bytes; by name) and the
    metadata JSON as stored."""
    h = hashlib.sha256()
    for k in sorted(state):
        a = np.ascontiguousarray(state[k])
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        h.update(k.encode())
        h.update(a.dtype.str.encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    h.update(meta_json.encode())
    return h.hexdigest()


def write_checkpoint_file(path: Path, state: dict[str, np.ndarray], meta: dict) -> None:
    """Write ``state`` and ``meta`` (which names its ``format`` and ``version``) atomically."""
    from safetensors.numpy import save_file

    from kinadapt_nn.runio import atomic_write

    state = {k: np.ascontiguousarray(v) for k, v in state.items()}
    meta_json = json.dumps(meta, sort_keys=True)
    header = {"meta": meta_json, "sha256": content_hash(state, meta_json)}
    atomic_write(Path(path), lambda tmp: save_file(state, tmp, metadata=header))


def read_checkpoint_file(path: Path) -> CheckpointArrays:
    """The tensors (as stored) and metadata of a safetensors checkpoint, its hash verified.
    One-line ``ModelFileError`` for a file that is damaged or not one of ours."""
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(path), framework="np") as f:
            header = f.metadata() or {}
            state = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 (safe_open is not iterable)
    except (SafetensorError, ValueError, TypeError) as exc:  # truncated, bad header, unknown dtype
        why = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ModelFileError(f"checkpoint '{path}' is not a readable safetensors file ({why})") from None
    except OSError as exc:
        raise ModelFileError(f"checkpoint '{path}' cannot be read ({exc.strerror or exc})") from None
    if not {"meta", "sha256"} <= set(header):
        raise ModelFileError(f"checkpoint '{path}' is not a kinadapt checkpoint (no 'meta'/'sha256' in its "
                             f"safetensors metadata; write it with 'kinadapt pretrain')")
    try:
        meta = json.loads(header["meta"])
    except ValueError:
        raise ModelFileError(f"checkpoint '{path}' has metadata that is not JSON") from None
    if content_hash(state, header["meta"]) != header["sha256"]:
        raise ModelFileError(f"checkpoint '{path}' failed its content hash (file modified or damaged)")
    return CheckpointArrays(state, meta)


def check_meta(path: Path, meta) -> None:
    """A checkpoint's metadata names our format and a version this code reads, else a one-line
    ``ModelFileError``."""
    if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
        fmt = meta.get("format") if isinstance(meta, dict) else None
        raise ModelFileError(f"checkpoint '{path}' has format {fmt!r}, expected {CHECKPOINT_FORMAT!r}")
    try:
        version = int(meta.get("version", -1))
    except (TypeError, ValueError):
        version = None
    if version is None or version > CHECKPOINT_VERSION:
        raise ModelFileError(f"checkpoint '{path}' has version {meta.get('version')!r}; "
                             f"upgrade kinadapt_nn to read it")


def expected_shapes(meta: dict) -> dict[str, tuple[int, ...]]:
    """The state_dict's tensor shapes for the network ``meta`` describes (``nets.JacobianBasisNet``).
    ``KeyError`` / ``TypeError`` / ``ValueError`` if ``meta`` does not describe one."""
    K, hidden = int(meta["n_features"]), int(meta["hidden"])
    if meta["structure"] not in ("basis", "per_entry"):
        raise ValueError(f"structure {meta['structure']!r} not in ('basis', 'per_entry')")
    out = N_ROWS * N_JOINTS * K if meta["structure"] == "basis" else K
    return {"l1.weight": (hidden, N_JOINTS), "l1.bias": (hidden,), "l2.weight": (hidden, hidden),
            "l2.bias": (hidden,), "l3.weight": (out, hidden), "l3.bias": (out,), "q_mean": (N_JOINTS,),
            "q_std": (N_JOINTS,)}


def check_state(path: Path, state: dict[str, np.ndarray], meta: dict) -> None:
    """The tensors are those of the network ``meta`` describes (names, shapes, floats), else a
    one-line ``ModelFileError``."""
    try:
        want = expected_shapes(meta)
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFileError(f"checkpoint '{path}' does not describe its network ({exc})") from None
    bad = [f"{k} {state[k].shape if k in state else 'missing'} (expected {s})" for k, s in want.items()
           if k not in state or state[k].shape != s]
    bad += [f"unexpected {k}" for k in sorted(set(state) - set(want))]
    bad += [f"{k} is {v.dtype}" for k, v in state.items() if k in want and v.dtype.kind != "f"]
    if bad:
        raise ModelFileError(f"checkpoint '{path}' does not match the network it describes ({'; '.join(bad)})")


def is_torch_file(path: Path) -> bool:
    """True for a torch ``.pt`` file (a zip archive), whatever its name."""
    with open(path, "rb") as fh:
        return fh.read(4) == _ZIP_MAGIC


def load_checkpoint_arrays(path: Path) -> CheckpointArrays:
    """A verified checkpoint (format, version, content hash, the tensors its network needs) as
    float64 arrays holding the values ``checkpoint.load_checkpoint``'s network holds. One-line
    ``ModelFileError`` for anything wrong with it. A torch ``.pt`` checkpoint is read with torch
    (``legacy.read_torch_checkpoint``); a safetensors one without."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"checkpoint '{path}' not found (run 'kinadapt pretrain --out DIR' or fix the path)")
    try:
        legacy = is_torch_file(path)
    except OSError as exc:
        raise ModelFileError(f"checkpoint '{path}' cannot be read ({exc.strerror or exc})") from None
    if legacy:
        from kinadapt_nn.learning.legacy import read_torch_checkpoint

        state, meta = read_torch_checkpoint(path)
    else:
        state, meta = read_checkpoint_file(path)
    check_meta(path, meta)
    check_state(path, state, meta)
    # the values nets.JacobianBasisNet holds once they are loaded into it (checkpoint.load_checkpoint):
    # its layers are float32 parameters (torch's default; the float64 weights as trained are rounded),
    # its joint normalisation float64 buffers
    state = {k: (v if k.startswith("q_") else v.astype(np.float32)).astype(np.float64) for k, v in state.items()}
    return CheckpointArrays(state, meta)
