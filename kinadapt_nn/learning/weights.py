"""A checkpoint's tensors and metadata as numpy arrays, read without importing torch.

The online controller needs only the pretrained body's weights (numpy forward, in the kernel),
yet ``import torch`` costs ~1.2 s per process (measured on the 2-core VM): a ``kinadapt online``
with neural features, and every worker of ``compare`` / ``sweep``, paid it to read ~260 kB of
weights. torch's own file format is a zip archive: ``<root>/data.pkl`` (a pickle whose tensors
are ``torch._utils._rebuild_tensor_v2`` calls on storages named by key) and ``<root>/data/<key>``
(each storage's raw little-endian bytes). :func:`read_torch_file` reads exactly that with a
restricted unpickler -- like ``torch.load(weights_only=True)``, only the tensor rebuild, the
storage types and ``collections.OrderedDict`` may be named, so no pickled code runs. A file
it does not understand (another byte order, a legacy pre-zip file, a tensor subclass) is a
``ValueError`` (:class:`LayoutNotRead` from :func:`load_checkpoint_arrays`): the caller then
reads it with torch (``checkpoint.load_checkpoint``).

``tests/features/test_learned.py`` checks the arrays and metadata equal ``torch.load``'s.
"""

from __future__ import annotations

import hashlib
import json
import pickle
import zipfile
from collections import OrderedDict
from pathlib import Path

import numpy as np

N_ROWS = 5  #: adapted task rows of the Jacobian basis (F_lat x, F_lat y, M x, M y, M z)
N_JOINTS = 7  #: arm joints the basis is trained for (Panda)

#: torch storage type -> (numpy dtype, torch's dtype name as ``str(tensor.dtype)`` spells it)
_STORAGES = {
    "DoubleStorage": (np.float64, "torch.float64"),
    "FloatStorage": (np.float32, "torch.float32"),
    "HalfStorage": (np.float16, "torch.float16"),
    "LongStorage": (np.int64, "torch.int64"),
    "IntStorage": (np.int32, "torch.int32"),
    "ShortStorage": (np.int16, "torch.int16"),
    "CharStorage": (np.int8, "torch.int8"),
    "ByteStorage": (np.uint8, "torch.uint8"),
    "BoolStorage": (np.bool_, "torch.bool"),
}
_TORCH_NAME = {np.dtype(d): name for d, name in _STORAGES.values()}


class _Storage:
    """A storage type named in the pickle (``torch.DoubleStorage``, ...): its numpy dtype."""

    def __init__(self, name: str) -> None:
        self.dtype = np.dtype(_STORAGES[name][0])


def _rebuild_tensor(storage: np.ndarray, offset: int, size, stride, requires_grad=False, hooks=None,
                    metadata=None) -> np.ndarray:
    """``torch._utils._rebuild_tensor_v2`` in numpy: the view (size, stride in elements) of the
    storage from ``offset``, copied to a C-contiguous array."""
    size, stride = tuple(int(s) for s in size), tuple(int(s) for s in stride)
    if any(s < 0 for s in stride) or offset < 0:
        raise ValueError("negative offset or stride")
    last = offset + sum((n - 1) * s for n, s in zip(size, stride)) if all(size) else offset - 1
    if last >= storage.size:
        raise ValueError("a tensor runs past its storage")
    item = storage.itemsize
    view = np.lib.stride_tricks.as_strided(storage[offset:], shape=size, strides=tuple(s * item for s in stride))
    return np.array(view, copy=True, order="C")


class _Unpickler(pickle.Unpickler):
    def __init__(self, fh, archive: zipfile.ZipFile, root: str) -> None:
        super().__init__(fh)
        self._zip, self._root = archive, root
        self._loaded: dict[str, np.ndarray] = {}

    def find_class(self, module: str, name: str):
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if (module, name) == ("collections", "OrderedDict"):
            return OrderedDict
        if module == "torch" and name in _STORAGES:
            return _Storage(name)  # (only the persistent ids' type tag)
        raise ValueError(f"names {module}.{name}, which a weights file does not")

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"):
            raise ValueError("an unknown persistent id")
        typ, key = pid[1], str(pid[2])
        if not isinstance(typ, _Storage):
            raise ValueError("a storage without a known type")
        dtype = typ.dtype
        if key not in self._loaded:
            raw = self._zip.read(f"{self._root}/data/{key}")
            self._loaded[key] = np.frombuffer(raw, dtype=dtype.newbyteorder("<"))
        return self._loaded[key]


class LayoutNotRead(ValueError):
    """A file this module's reader does not understand; ``checkpoint.load_checkpoint`` (torch)
    reads it, and reports what is wrong with it."""


def read_torch_file(path: Path):
    """The object ``torch.save`` wrote to ``path`` (zip format), tensors as numpy arrays.
    ``ValueError`` for anything this reader does not understand; ``OSError`` if unreadable."""
    try:
        archive = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise ValueError("not a zip-format torch file") from None
    with archive:
        names = archive.namelist()
        pkl = [n for n in names if n.endswith("/data.pkl") and n.count("/") == 1]
        if len(pkl) != 1:
            raise ValueError("no data.pkl at the archive's root")
        root = pkl[0].split("/")[0]
        order = f"{root}/byteorder"
        if order in names and archive.read(order).strip() != b"little":
            raise ValueError("big-endian storages")
        with archive.open(pkl[0]) as fh:
            try:
                return _Unpickler(fh, archive, root).load()
            except ValueError:
                raise
            except Exception as exc:  # a damaged archive or pickle (bad CRC, truncated, ...)
                raise ValueError(f"unreadable ({type(exc).__name__})") from None


def state_hash_arrays(state: dict[str, np.ndarray], meta: dict) -> str:
    """``kinadapt_nn.learning.checkpoint.state_hash`` over numpy arrays: the same sha256 (name,
    torch dtype name, shape, bytes per tensor, then the metadata JSON)."""
    h = hashlib.sha256()
    for k in sorted(state):
        a = np.ascontiguousarray(state[k])
        h.update(k.encode())
        h.update(_TORCH_NAME[a.dtype.newbyteorder("=")].encode())
        h.update(str(tuple(a.shape)).encode())
        h.update(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes())
    h.update(json.dumps(meta, sort_keys=True).encode())
    return h.hexdigest()


CHECKPOINT_FORMAT = "kinadapt-jacobian-basis"
CHECKPOINT_VERSION = 1


def check_meta(path: Path, meta) -> None:
    """A checkpoint's metadata names our format and a version this code reads, else a one-line
    ``ModelFileError``."""
    from kinadapt_nn.errors import ModelFileError

    if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
        fmt = meta.get("format") if isinstance(meta, dict) else None
        raise ModelFileError(f"checkpoint '{path}' has format {fmt!r}, expected {CHECKPOINT_FORMAT!r}")
    if int(meta.get("version", -1)) > CHECKPOINT_VERSION:
        raise ModelFileError(f"checkpoint '{path}' has version {meta.get('version')}; upgrade kinadapt_nn to read it")


def load_checkpoint_arrays(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """A verified checkpoint (the checks of ``checkpoint.load_checkpoint``: format, version,
    content hash, the tensors the structure needs) -> (state_dict, meta), the state_dict as float64
    numpy arrays holding the values ``load_checkpoint``'s network holds (its layers are float32),
    without torch (:func:`read_torch_file`); :class:`LayoutNotRead` for a file whose layout it
    does not read (torch may). One-line ``ModelFileError`` for anything wrong with it."""
    from kinadapt_nn.errors import ModelFileError

    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"checkpoint '{path}' not found (run 'kinadapt pretrain --out DIR' or fix the path)")
    try:
        blob = read_torch_file(path)
    except ValueError as exc:  # not the plain zip layout: the caller has torch read it
        raise LayoutNotRead(f"checkpoint '{path}': {exc}") from None
    except OSError as exc:
        raise ModelFileError(f"checkpoint '{path}' cannot be read ({exc.strerror or exc})") from None
    if not isinstance(blob, dict) or not {"state_dict", "meta", "sha256"} <= set(blob):
        raise ModelFileError(f"checkpoint '{path}' is not a kinadapt checkpoint (missing state_dict/meta/sha256)")
    state, meta = blob["state_dict"], blob["meta"]
    check_meta(path, meta)
    if not (isinstance(state, dict) and all(isinstance(v, np.ndarray) for v in state.values())):
        raise ModelFileError(f"checkpoint '{path}' holds a state_dict that is not plain tensors")
    if state_hash_arrays(state, meta) != blob["sha256"]:
        raise ModelFileError(f"checkpoint '{path}' failed its content hash (file modified or damaged)")
    try:
        K, hidden = int(meta["n_features"]), int(meta["hidden"])
        out = N_ROWS * N_JOINTS * K if meta["structure"] == "basis" else K
        want = {"l1.weight": (hidden, N_JOINTS), "l1.bias": (hidden,), "l2.weight": (hidden, hidden),
                "l2.bias": (hidden,), "l3.weight": (out, hidden), "l3.bias": (out,), "q_mean": (N_JOINTS,),
                "q_std": (N_JOINTS,)}
        if meta["structure"] not in ("basis", "per_entry"):
            raise ValueError(f"structure {meta['structure']!r} not in ('basis', 'per_entry')")
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFileError(f"checkpoint '{path}' does not describe its network ({exc})") from None
    bad = [f"{k} {state[k].shape if k in state else 'missing'} (expected {s})" for k, s in want.items()
           if k not in state or state[k].shape != s]
    if bad or set(state) != set(want):
        extra = sorted(set(state) - set(want))
        raise ModelFileError(f"checkpoint '{path}' does not match the network it describes "
                             f"({'; '.join(bad + [f'unexpected {k}' for k in extra])})")
    # as checkpoint.load_checkpoint gives them: the layers are float32 parameters (torch's default,
    # the network that was trained and evaluated), the joint normalisation float64 buffers
    return {k: (v if k.startswith("q_") else v.astype(np.float32)).astype(np.float64) for k, v in state.items()}, meta
