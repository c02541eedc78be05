"""Run folders: written completely or not at all.

Everything is written into a sibling staging folder; only when all files are in place is
it renamed to the requested name. An existing folder is refused unless ``overwrite`` is
set, and even then it is replaced only after the new run has been written.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from kinadapt_nn.errors import OutputExistsError


def check_output_dir(out: Path, overwrite: bool) -> None:
    """Refuse an existing output folder without ``overwrite`` (before any work is done)."""
    if out.exists() and not overwrite:
        raise OutputExistsError(f"output folder '{out}' already exists (pass --overwrite or choose another --out)")
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"output path '{out}' exists and is not a folder")


@contextmanager
def staged_output(out: Path, overwrite: bool) -> Iterator[Path]:
    """Yield a staging folder; on success it becomes ``out``; on error it is removed."""
    out = Path(out)
    check_output_dir(out, overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = out.parent / f".{out.name}.partial-{os.getpid()}"
    if stage.exists():
        shutil.rmtree(stage)
    stage.mkdir()
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        os.replace(out, old)
    os.replace(stage, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def atomic_write(path: Path, write: Callable[[str], None], suffix: str = ".tmp") -> None:
    """Write a file atomically: ``write(tmp_path)`` fills a temp file beside ``path``, which is
    then renamed over it; on any error the temp file is removed and ``path`` is untouched."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=suffix)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_text_atomic(path: Path, text: str) -> None:
    """``atomic_write`` for text."""
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")
