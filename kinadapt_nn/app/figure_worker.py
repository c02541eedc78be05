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

Once the episode has ended, drawing the figure is what ``kinadapt online`` waits on: 0.80-0.86 s
warm from ``submit`` to ``wait`` returning (measured: the default run, a two-core machine, the
median of five, two sessions). So where it forks and ``os.cpu_count() >= 2`` the worker shares
it with a fork of itself made when the job arrives (warm: matplotlib imported, caches filled):
each builds the whole figure, the worker draws panels 0-3 and the suptitle and footer, the fork
panels 4-8 (``SPLIT_AT``); the fork sends its pixels back, the worker lays its own over them and
writes the PNG (``_draw_shared``, ``_draw_part``): 0.54-0.59 s from ``submit`` to ``wait``,
measured alike with both parts forked at ``start``, with pixels at most one 8-bit level from
``save_figure``'s (at anti-aliased edges). Forking at the job keeps one warm-up beside the
episode: two warm-ups at ``start`` slowed the episode's process on two cores as much as the
split saved. The gain needs the second core free.

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
    def start(cls, fork: bool | None = None, parts: int | None = None) -> FigureWorker:
        """A started worker: forked where ``can_fork()`` (or ``fork``), else a fresh interpreter.

        ``parts``: how many forked processes share the drawing, 1 or 2 (default: 2 where
        ``os.cpu_count() >= 2``, else 1); the fresh interpreter is always one."""
        if not (can_fork() if fork is None else fork):
            return _SpawnedWorker()
        if parts is None:
            parts = 2 if (os.cpu_count() or 1) >= 2 else 1
        return _ForkedWorker(parts)

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
    """The worker as a fork of this process, talking through a ``multiprocessing`` pipe.

    ``parts=1``: it draws and writes the whole figure. ``parts=2``: when the job arrives it forks
    itself -- warm, matplotlib imported -- and the two share the drawing (``_draw_shared``): the
    fork draws panels ``SPLIT_AT``..8 and sends its pixels back, the worker draws panels
    0..``SPLIT_AT - 1`` with the figure-level texts, lays them over the fork's, writes the PNG and
    answers. Forking at the job, not at ``start``, keeps one warm-up (matplotlib's import and a
    throw-away figure) beside the episode instead of two."""

    def __init__(self, parts: int = 1) -> None:
        import multiprocessing

        super().__init__()
        if parts not in (1, 2):
            raise ValueError(f"parts must be 1 or 2, not {parts}")
        ctx = multiprocessing.get_context("fork")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_forked_main, args=(child, parts, self._conn), name="kinadapt-figure",
                                 daemon=True)
        self._proc.start()
        child.close()  # (so a worker that dies is seen as end-of-file)

    def _send(self, job: tuple) -> None:
        _send_bytes(self._conn, pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL))

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
        if self._sender is not None:  # (its write fails once the worker is gone; then the pipe closes)
            self._sender.join(5.0)
        self._conn.close()


def _send_bytes(conn, data: bytes) -> None:
    try:
        conn.send_bytes(data)
    except (BrokenPipeError, OSError):  # the part died early: wait() reports it
        pass


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
    labels in mathtext, legends), at the PNG's dpi, so the real one is drawn warm: matplotlib
    caches parsed mathtext per (text, dpi, font) and the glyphs per size, so the log axis spans
    the decades the rollout figure's log panels label (1e-6 .. 1e2)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from kinadapt_nn.figures import SAVE_DPI  # (its imports: config, trace)

    fig, ax = plt.subplots(1, 2, figsize=(4, 2))
    x = np.linspace(0, 1, 50)
    ax[0].plot(x, x, label="a")
    ax[0].legend(fontsize=7)
    ax[0].set_title("t", fontsize=10)
    ax[0].set_xlabel("x")
    ax[1].semilogy(x, np.logspace(-6, 2, len(x)), label="b")
    ax[1].legend(fontsize=8)
    fig.suptitle("s")
    fig.text(0.0, 0.0, "w", fontsize=8)
    fig.savefig(io.BytesIO(), format="png", dpi=SAVE_DPI)  # (also loads PIL's PNG encoder)
    plt.close(fig)


def _draw(trace, summary: dict, cfg, path: str) -> None:
    from kinadapt_nn.figures import rollout_figure, save_figure

    save_figure(rollout_figure(trace, summary, cfg), Path(path))


#: the two forked parts' split of the rollout figure's panels (``fig.axes`` order, row by row):
#: part 0 draws 0 .. SPLIT_AT - 1 and the figure-level texts, part 1 the rest. Measured warm on a
#: two-core machine: the first four panels ~0.41-0.45 s, the other five ~0.42-0.50 s (part 0
#: also lays the two over each other and writes the PNG).
SPLIT_AT = 4


class _PartFailed(Exception):
    """Part 1 failed or died (raised in part 0, which answers for both)."""


def _draw_part(trace, summary: dict, cfg, path: str, part: int, link) -> None:
    """Draw part ``part`` (0 or 1) of the rollout figure at the PNG's dpi with Agg, in a figure
    the same size in pixels as ``save_figure``'s ((14 x 10) in x 120 dpi = 1680 x 1200 px).

    Part 1 draws its panels over the opaque figure background and sends its pixels through
    ``link`` (a header ``("pixels", (width, height))``, then the (height, width, 4) uint8 RGBA
    rows as bytes; ``("error", message)`` instead if it fails). Part 0 draws its panels and the
    figure-level texts over a transparent background (Agg's RGBA is not premultiplied), lays them
    over part 1's pixels (``PIL.Image.alpha_composite``, the "over" operator) and writes ``path``
    as ``save_figure`` would (PNG, zlib level ``PNG_COMPRESS_LEVEL``, the dpi and Software
    metadata matplotlib writes): to a temporary file beside it, then renamed, so a crash leaves
    no half-written PNG."""
    import matplotlib
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgba
    from PIL import Image, PngImagePlugin

    from kinadapt_nn.figures import PNG_COMPRESS_LEVEL, SAVE_DPI, rollout_figure

    fig = rollout_figure(trace, summary, cfg)
    face = matplotlib.rcParams["savefig.facecolor"]  # the background savefig would give it
    if isinstance(face, str) and face == "auto":
        face = fig.get_facecolor()
    for k, a in enumerate(fig.axes):
        a.set_visible((k < SPLIT_AT) == (part == 0))
    if part == 0:
        fig.patch.set_alpha(0.0)
    else:
        fig.patch.set_facecolor(face)
        for artist in (*fig.texts, *fig.legends, *fig.lines, *fig.patches, *fig.images):  # (texts: suptitle, footer)
            artist.set_visible(False)
    fig.set_dpi(SAVE_DPI)
    fig.canvas.draw()
    pixels = memoryview(fig.canvas.buffer_rgba())  # (height, width, 4) uint8, RGBA
    size = (pixels.shape[1], pixels.shape[0])  # (width, height) [px]
    if part == 1:
        link.send(("pixels", size))
        link.send_bytes(pixels.cast("B"))
        plt.close(fig)
        return
    try:
        kind, what = link.recv()
        if kind != "pixels":
            raise _PartFailed(f"part 1: {what}")
        if what != size:
            raise _PartFailed(f"part 1 drew {what[0]} x {what[1]} px, part 0 {size[0]} x {size[1]}")
        under = Image.frombuffer("RGBA", size, link.recv_bytes(), "raw", "RGBA", 0, 1)
    except (EOFError, OSError) as exc:
        raise _PartFailed("part 1 ended without its pixels") from exc
    image = Image.alpha_composite(under, Image.frombuffer("RGBA", size, pixels, "raw", "RGBA", 0, 1))
    plt.close(fig)
    if to_rgba(face)[3] >= 1.0:  # opaque: RGB (a quarter less to compress)
        image = image.convert("RGB")
    info = PngImagePlugin.PngInfo()
    info.add_text("Software", f"Matplotlib version{matplotlib.__version__}, https://matplotlib.org/")
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        image.save(tmp, format="PNG", compress_level=PNG_COMPRESS_LEVEL, dpi=(SAVE_DPI, SAVE_DPI), pnginfo=info)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _draw_shared(trace, summary: dict, cfg, path: str) -> None:
    """The figure drawn by this process and a fork of it (``_draw_part``): the fork draws part 1
    and sends its pixels through a pipe made for it, this process part 0 and writes the PNG. A
    fork that fails sends its error instead; one that dies is end-of-file (``_PartFailed``)."""
    import multiprocessing

    recv, send = multiprocessing.Pipe(duplex=False)
    pid = os.fork()
    if pid == 0:  # the fork: part 1, then exit without running the parent's clean-up
        code = 0
        try:
            recv.close()
            try:
                _draw_part(trace, summary, cfg, path, part=1, link=send)
            except Exception as exc:
                send.send(("error", f"{type(exc).__name__}: {exc}"))
        except BaseException:
            code = 1
        finally:
            os._exit(code)
    send.close()
    try:
        _draw_part(trace, summary, cfg, path, part=0, link=recv)
    finally:
        recv.close()
        try:
            os.waitpid(pid, 0)
        except ChildProcessError:
            pass


def _forked_main(conn, parts: int = 1, parent_end=None) -> None:
    """The forked worker: close the parent's end of the pipe (``parent_end``: so a parent that
    dies is seen as end-of-file), import matplotlib, warm up unless the job is already waiting (a
    short episode: warming up would only delay it), take one job from ``conn``, draw it -- alone
    (``parts`` 1) or with a fork of itself (2, ``_draw_shared``) -- and answer None or the error."""
    if parent_end is not None:
        parent_end.close()
    try:
        import kinadapt_nn.figures  # noqa: F401  (matplotlib)

        if not conn.poll():
            _warm_up()
        try:
            job = pickle.loads(conn.recv_bytes())
        except EOFError:  # the parent ended without a figure to draw
            return
        (_draw_shared if parts == 2 else _draw)(*job)
        conn.send(None)
    except KeyboardInterrupt:
        pass
    except Exception as exc:  # reported by the parent's wait(), which then draws the figure itself
        error = str(exc) if isinstance(exc, _PartFailed) else f"{type(exc).__name__}: {exc}"
        try:
            conn.send(error)
        except (BrokenPipeError, OSError):  # (the parent already gone)
            pass


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
