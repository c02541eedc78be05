"""The rollout figure drawn in a second process, so ``kinadapt online`` does not wait on matplotlib.

Rendering the nine-panel figure costs about as much as a whole episode (matplotlib's import,
its font and text caches, the drawing). ``FigureWorker.start()`` starts the figure process
before the episode: it imports matplotlib and draws a throw-away figure (warming those caches)
on the second core while the episode runs; the episode's process never imports matplotlib.
``submit`` hands over (trace, summary, config, png path) and returns at once (a thread writes
them into the pipe while the caller goes on writing the run folder); ``wait`` returns once the
PNG is written. The figure is the same ``figures.rollout_figure``: only where it is drawn
changes.

Where ``fork`` is safe (Linux and other POSIX systems, not macOS) the process is a fork of the
caller (``multiprocessing``'s fork context): it inherits numpy, pydantic and the config module
already imported, and only imports matplotlib. Elsewhere it is a fresh interpreter,
``python -m kinadapt_nn.app.figure_worker``, fed through its stdin.

If the worker cannot be started or fails, ``wait`` says so (``FigureWorkerError``) and the
caller draws the figure in its own process instead.
"""

from __future__ import annotations

import logging
import os
import pickle
import sys
import threading
from pathlib import Path

from kinadapt_nn.errors import KinadaptError

log = logging.getLogger(__name__)


class FigureWorkerError(KinadaptError):
    """The figure process failed (its last error line is in the message)."""


def can_fork() -> bool:
    """True where the figure process is a fork of this one (POSIX; not macOS, where a fork of a
    process that has loaded system frameworks may crash)."""
    return hasattr(os, "fork") and sys.platform != "darwin"


class FigureWorker:
    """A warm figure process: ``start`` before the episode, ``submit`` after it, then ``wait``."""

    def __init__(self) -> None:
        self._path: Path | None = None
        self._sender: threading.Thread | None = None

    @classmethod
    def start(cls, fork: bool | None = None) -> FigureWorker:
        """A started worker: forked where ``can_fork()`` (or ``fork``), else a fresh interpreter."""
        return _ForkedWorker() if (can_fork() if fork is None else fork) else _SpawnedWorker()

    def submit(self, trace, summary: dict, cfg, png_path: Path) -> None:
        """Send the run to the worker; it writes ``png_path`` (returns at once: a thread writes
        the pipe, which the worker reads once warm)."""
        self._path = Path(png_path)
        job = (trace, summary, cfg, str(png_path))
        self._sender = threading.Thread(target=self._send, args=(job,), name="figure-submit", daemon=True)
        self._sender.start()

    def wait(self, timeout_s: float = 300.0) -> Path:
        """Block until the PNG is written; its path, or ``FigureWorkerError``."""
        if self._sender is not None:
            self._sender.join(timeout_s)
        error = self._finish(timeout_s)
        if error is None and (self._path is None or not self._path.is_file()):
            error = "no figure was written"
        if error is not None:
            self.close()
            raise FigureWorkerError(f"the figure process failed: {error}")
        return self._path

    def _send(self, job: tuple) -> None:
        raise NotImplementedError

    def _finish(self, timeout_s: float) -> str | None:
        """End the worker (end of input if nothing was submitted); None, or what went wrong."""
        raise NotImplementedError

    def close(self) -> None:
        """Stop the worker if it is still running (an error or interruption before ``wait``)."""
        raise NotImplementedError


class _ForkedWorker(FigureWorker):
    """The worker as a fork of this process, talking through a ``multiprocessing`` pipe."""

    def __init__(self) -> None:
        import multiprocessing

        super().__init__()
        ctx = multiprocessing.get_context("fork")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_forked_main, args=(child,), name="kinadapt-figure", daemon=True)
        self._proc.start()
        child.close()

    def _send(self, job: tuple) -> None:
        try:
            self._conn.send(job)
        except (BrokenPipeError, OSError):  # the worker died early: wait() reports it
            pass

    def _finish(self, timeout_s: float) -> str | None:
        if self._sender is None:  # nothing submitted: the worker ends on end-of-file
            self._conn.close()
            self._proc.join(timeout_s)
            return None
        if not self._conn.poll(timeout_s):
            return f"it did not finish within {timeout_s:g} s"
        try:
            error = self._conn.recv()
        except (EOFError, OSError):
            self._proc.join(5.0)
            return f"it ended without an answer (exit {self._proc.exitcode})"
        self._proc.join(timeout_s)
        return error

    def close(self) -> None:
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._conn.close()


class _SpawnedWorker(FigureWorker):
    """The worker as ``python -m kinadapt_nn.app.figure_worker``, fed through its stdin."""

    def __init__(self) -> None:
        import subprocess
        import tempfile

        super().__init__()
        root = str(Path(__file__).resolve().parents[2])
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
        self._stderr = tempfile.TemporaryFile()  # (a pipe could fill up and block the worker)
        self._proc = subprocess.Popen([sys.executable, "-m", "kinadapt_nn.app.figure_worker"], stdin=subprocess.PIPE,
                                      stdout=subprocess.DEVNULL, stderr=self._stderr, env=env)

    def _send(self, job: tuple) -> None:
        try:
            pickle.dump(job, self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.close()
        except (BrokenPipeError, OSError):  # the worker died early: wait() reports it
            pass

    def _finish(self, timeout_s: float) -> str | None:
        import subprocess

        if not self._proc.stdin.closed:  # nothing submitted: the worker ends on end-of-file
            self._proc.stdin.close()
        try:
            self._proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return f"it did not finish within {timeout_s:g} s"
        if self._proc.returncode != 0:
            self._stderr.seek(0)
            last = self._stderr.read().decode(errors="replace").strip().splitlines()[-1:] or ["no message"]
            return f"exit {self._proc.returncode}: {last[0]}"
        return None

    def close(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        for f in (self._proc.stdin, self._stderr):
            if not f.closed:
                f.close()


def _warm_up() -> None:
    """Draw a small throw-away figure with what the rollout figure uses (fonts, log-axis tick
    labels in mathtext, legends), so the real one is drawn warm."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    import kinadapt_nn.figures  # noqa: F401  (its imports: config, trace)

    fig, ax = plt.subplots(1, 2, figsize=(4, 2))
    x = np.linspace(0, 1, 50)
    ax[0].plot(x, x, label="a")
    ax[0].legend(fontsize=7)
    ax[0].set_title("t", fontsize=10)
    ax[0].set_xlabel("x")
    ax[1].semilogy(x, 1e-3 + x, label="b")
    ax[1].legend(fontsize=8)
    fig.suptitle("s")
    fig.text(0.0, 0.0, "w", fontsize=8)
    fig.savefig(io.BytesIO(), format="png", dpi=30)
    plt.close(fig)


def _draw(trace, summary: dict, cfg, path: str) -> None:
    from kinadapt_nn.figures import rollout_figure, save_figure

    save_figure(rollout_figure(trace, summary, cfg), Path(path))


def _forked_main(conn) -> None:
    """The forked worker: import matplotlib, warm up unless the job is already waiting (a short
    episode: warming up would only delay it), take one job from ``conn``, draw it, answer None or
    the error."""
    try:
        import kinadapt_nn.figures  # noqa: F401  (matplotlib)

        if not conn.poll():
            _warm_up()
        try:
            job = conn.recv()
        except EOFError:  # the parent ended without a figure to draw
            return
        _draw(*job)
        conn.send(None)
    except KeyboardInterrupt:
        pass
    except Exception as exc:  # reported by the parent's wait(), which then draws the figure itself
        conn.send(f"{type(exc).__name__}: {exc}")


def main() -> int:
    """The spawned worker: warm up, read one job from stdin, draw it."""
    try:
        _warm_up()
        try:
            job = pickle.load(sys.stdin.buffer)
        except EOFError:  # the parent ended without a figure to draw
            return 0
        _draw(*job)
        return 0
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
