"""numba's on-disk cache of the kernels: what it holds, where, and dropping a kernel's cached code
when a file its callees come from was edited (``kinadapt_nn.compiled``). Every function that reads
numba's private cache state degrades to "not cached" (or does nothing) when numba moves it."""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Iterable
from pathlib import Path

#: the file beside the kernels' cache that holds their sources' fingerprint
STAMP_FILE = "kinadapt_kernel_sources.sha256"


def in_cache(fn, sig) -> bool:
    """True when numba's on-disk cache holds ``fn`` compiled for ``sig`` by this source and this
    machine's code generator (the key numba's loader looks up); False when it cannot be told."""
    try:
        cache = fn._cache
        return cache._index_key(sig, fn.targetctx.codegen()) in cache._cache_file._load_index()
    except Exception:  # numba's cache internals moved: not known to be cached
        return False


def cached_any(fn) -> bool | None:
    """True when numba's on-disk cache holds ``fn`` compiled for some signature by this source
    (the index is empty when missing or written for another version of the file); None when that
    cannot be told."""
    try:
        return bool(fn._cache._cache_file._load_index())
    except Exception:  # numba's cache internals moved
        return None


def cache_dir(fn) -> Path | None:
    """The folder of ``fn``'s cached code (``NUMBA_CACHE_DIR`` when set, else ``__pycache__``
    beside its source, else numba's user-wide one); None when it cannot be told."""
    try:
        return Path(fn._cache._cache_path)
    except Exception:  # numba's cache internals moved
        return None


def sources_fingerprint(paths: Iterable[Path]) -> str:
    """sha256 over the contents of ``paths`` (sorted by name)."""
    h = hashlib.sha256()
    for p in sorted(Path(x) for x in paths):
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def invalidate_stale(dispatchers: Iterable, sources: Iterable[Path], stamp_fn) -> bool:
    """Drop the cached code of the modules of ``dispatchers`` when the fingerprint of ``sources``
    (every file their kernels' code comes from) differs from the one recorded beside ``stamp_fn``'s
    cache; then record the new one. -> True when stale code was dropped. numba's own check covers
    a kernel's own file only (module docstring). Does nothing when the cache cannot be located."""
    stamp_dir = cache_dir(stamp_fn)
    if stamp_dir is None:
        return False
    stamp = stamp_dir / STAMP_FILE
    now = sources_fingerprint(sources)
    try:
        if stamp.read_text().strip() == now:
            return False
    except OSError:
        pass
    dropped = False
    for folder, stems in _cache_files(dispatchers).items():
        for f in folder.glob("*.nb[ic]"):
            if f.name.split(".", 1)[0] in stems:
                with contextlib.suppress(OSError):  # another process dropped it first
                    f.unlink()
                    dropped = True
    with contextlib.suppress(OSError):  # a read-only cache location: checked again next time
        stamp_dir.mkdir(parents=True, exist_ok=True)
        stamp.write_text(now + "\n")
    return dropped


def _cache_files(dispatchers: Iterable) -> dict[Path, set[str]]:
    """cache folder -> the source-file stems whose cached code lives there (numba names a cache
    file ``<stem>.<qualname>-<line>.pyXY.nb[ic]``)."""
    out: dict[Path, set[str]] = {}
    for fn in dispatchers:
        folder = cache_dir(fn)
        if folder is not None:
            out.setdefault(folder, set()).add(Path(fn.py_func.__code__.co_filename).stem)
    return out


__all__ = ["STAMP_FILE", "cache_dir", "cached_any", "in_cache", "invalidate_stale", "sources_fingerprint"]
