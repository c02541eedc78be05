"""Where MuJoCo's own log goes: never the working directory.

MuJoCo appends its warnings and errors (e.g. "Nan, Inf or huge value in QACC") to a log file,
by default ``MUJOCO_LOG.TXT`` in the current directory. ``mujoco_log_to(path)`` points that file
elsewhere for the duration of a ``with`` block and restores the previous setting afterwards:
MuJoCo >= 4 through ``mujoco.MjLogConfig.logfile``; older MuJoCo through a warning callback
(``mujoco.set_mju_user_warning``) that appends to ``path`` and forwards to ``logging``.
The CLI uses it around every command (``kinadapt_nn.app.cli``); worker processes forked inside
the block inherit the setting.
"""

from __future__ import annotations

import logging
import os
import secrets
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

log = logging.getLogger("kinadapt.mujoco")


def fresh_log_path() -> Path:
    """A new file name in the temp dir (the file is created by MuJoCo only when it has something to say)."""
    return Path(tempfile.gettempdir()) / f"kinadapt-{os.getpid()}-{secrets.token_hex(4)}-MUJOCO_LOG.TXT"


@contextmanager
def mujoco_log_to(path: Path) -> Iterator[Path]:
    """Send MuJoCo's log to ``path`` (its folder must exist) inside the block."""
    import mujoco

    path = Path(path).resolve()
    if hasattr(mujoco, "MjLogConfig"):
        old = mujoco.MjLogConfig.get()
        cfg = mujoco.MjLogConfig.get()
        cfg.logfile = str(path)
        cfg.set()
        try:
            yield path
        finally:
            old.set()
        return

    def warn(msg: str) -> None:
        log.warning("%s", msg.strip())
        with open(path, "a") as fh:
            fh.write(f"WARNING {time.ctime()}: {msg.strip()}\n")

    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(warn)
    try:
        yield path
    finally:
        mujoco.set_mju_user_warning(previous)
