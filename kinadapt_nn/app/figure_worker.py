"""The rollout figure drawn in a second process, so ``kinadapt online`` does not wait on matplotlib.

Rendering the nine-panel figure costs about as much as a whole episode (matplotlib's import,
its font and text caches, the layout). ``FigureWorker.start()`` launches
``python -m kinadapt_nn.app.figure_worker`` before the episode: it imports matplotlib and draws a
throw-away figure (warming those caches) on the second core while the episode runs; the
episode's process never imports matplotlib. ``submit`` sends (trace, summary, config, png path)
through a pipe; ``wait`` returns once the PNG is written. The figure is the same
``figures.rollout_figure``: only where it is drawn changes.

If the worker cannot be started or fails, ``wait`` says so (``FigureWorkerError``) and the
caller draws the figure in its own process instead.
"""

from __future__ import annotations

import logging
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

from kinadapt_nn.errors import KinadaptError

log = logging.getLogger(__name__)


class FigureWorkerError(KinadaptError):
    """The figure process failed (its stderr's last line is in the message)."""


class FigureWorker:
    """A warm figure process: ``start`` before the episode, ``submit`` after it, then ``wait``."""

    def __init__(self, proc: subprocess.Popen, stderr):
        self._proc = proc
        self._stderr = stderr  # a temp file (a pipe could fill up and block the worker)
        self._path: Path | None = None

    @classmethod
    def start(cls) -> FigureWorker:
        root = str(Path(__file__).resolve().parents[1])
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
        stderr = tempfile.TemporaryFile()
        proc = subprocess.Popen([sys.executable, "-m", "kinadapt_nn.app.figure_worker"], stdin=subprocess.PIPE,
                                stdout=subprocess.DEVNULL, stderr=stderr, env=env)
        return cls(proc, stderr)

    def submit(self, trace, summary: dict, cfg, png_path: Path) -> None:
        """Send the run to the worker; it writes ``png_path`` (returns at once)."""
        self._path = Path(png_path)
        try:
            pickle.dump((trace, summary, cfg, str(png_path)), self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.close()
        except (BrokenPipeError, OSError):  # the worker died early: wait() reports it
            pass

    def wait(self, timeout_s: float = 300.0) -> Path:
        """Block until the PNG is written; its path, or ``FigureWorkerError``."""
        if not self._proc.stdin.closed:  # nothing submitted: the worker ends on end-of-file
            self._proc.stdin.close()
        try:
            self._proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.close()
            raise FigureWorkerError(f"the figure process did not finish within {timeout_s:g} s") from None
        if self._proc.returncode != 0 or self._path is None or not self._path.is_file():
            self._stderr.seek(0)
            err = self._stderr.read().decode(errors="replace")
            last = err.strip().splitlines()[-1:] or ["no message"]
            raise FigureWorkerError(f"the figure process failed (exit {self._proc.returncode}): {last[0]}")
        return self._path

    def close(self) -> None:
        """Stop the worker if it is still running (an error or interruption before ``wait``)."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        for f in (self._proc.stdin, self._stderr):
            if not f.closed:
                f.close()


def _warm_up() -> None:
    """Draw a small throw-away figure with what the rollout figure uses (fonts, log-axis tick
    labels, legends, the layout engine), so the real one is drawn warm."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    import kinadapt_nn.figures  # noqa: F401  (its imports: config, trace)

    fig, ax = plt.subplots(1, 2, figsize=(4, 2), constrained_layout=True)
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


def main() -> int:
    try:
        _warm_up()
        try:
            trace, summary, cfg, path = pickle.load(sys.stdin.buffer)
        except EOFError:  # the parent ended without a figure to draw
            return 0
        from kinadapt_nn.figures import rollout_figure, save_figure

        save_figure(rollout_figure(trace, summary, cfg), Path(path))
        return 0
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
