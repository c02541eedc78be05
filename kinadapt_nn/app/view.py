"""``kinadapt view RUN``: replay a run folder offscreen to GIF/MP4, or in the MuJoCo viewer.

The scene is rebuilt from the run's ``config.toml`` and the logged joint positions are replayed
(kinematic replay: ``qpos`` set from the trace, ``mj_forward``). Headless rendering needs an
OpenGL backend: ``MUJOCO_GL=egl`` (Debian: ``libegl1`` + ``libgl1-mesa-dri``) or
``MUJOCO_GL=osmesa`` (Debian: ``libosmesa6``). GIF needs only Pillow; MP4 needs
``imageio-ffmpeg`` (``pip install imageio-ffmpeg``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from kinadapt_nn.errors import KinadaptError


def _frames(run: Path, fps: float, width: int, height: int, camera: str, max_s: float | None, progress: bool = False):
    import mujoco
    from tqdm import tqdm

    from kinadapt_nn.config import load_config
    from kinadapt_nn.sim.adapter import PegInHoleSim
    from kinadapt_nn.trace import Trace

    cfg = load_config(run / "config.toml")
    tr = Trace.load(run / "trace.npz")
    sim = PegInHoleSim(cfg)
    cameras = [sim.model.camera(i).name for i in range(sim.model.ncam)]
    if camera not in cameras:
        raise KinadaptError(f"--camera {camera!r}: the scene has {', '.join(repr(c) for c in cameras) or 'no cameras'}")
    t = tr["t_s"]
    if max_s is not None:
        t = t[t <= max_s]
    times = np.arange(t[0], t[-1], 1.0 / fps) if len(t) >= 2 else np.zeros(0)
    if len(times) == 0:
        within = f" in the first {max_s:g} s" if max_s else ""
        raise KinadaptError(f"'{run}': nothing to render ({len(t)} samples{within}; raise --max-s or --fps)")
    idx = np.searchsorted(tr["t_s"], times)
    try:
        renderer = mujoco.Renderer(sim.model, height, width)
    except Exception as exc:
        raise KinadaptError(
            f"offscreen rendering unavailable ({str(exc).splitlines()[0]}); set MUJOCO_GL=egl "
            "(apt-get install libegl1 libgl1-mesa-dri) or MUJOCO_GL=osmesa (apt-get install libosmesa6)"
        ) from None
    with renderer:
        for i in tqdm(idx, desc="view", unit="frame", disable=not progress, leave=False):
            sim.data.qpos[sim.ids.qpos_adr] = tr["q_rad"][i]
            mujoco.mj_forward(sim.model, sim.data)
            renderer.update_scene(sim.data, camera=camera)
            yield renderer.render().copy()


def render_run(run: Path, out: Path, fps: float = 25.0, width: int = 480, height: int = 360,
               camera: str = "side", max_s: float | None = None, progress: bool = False) -> int:
    """Write ``out`` (.gif or .mp4) atomically. Returns the number of frames. ``progress``: a bar on stderr."""
    run, out = Path(run), Path(out)
    if not (run / "trace.npz").is_file() or not (run / "config.toml").is_file():
        raise KinadaptError(f"'{run}' is not a run folder (needs config.toml and trace.npz)")
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise KinadaptError(f"video file '{out}': use a .gif or .mp4 name")
    os.environ.setdefault("MUJOCO_GL", "egl")
    frames = list(_frames(run, fps, width, height, camera, max_s, progress))
    out.parent.mkdir(parents=True, exist_ok=True)
    from kinadapt_nn.runio import atomic_write

    def write(tmp: str) -> None:
        if suffix == ".gif":
            from PIL import Image

            imgs = [Image.fromarray(f) for f in frames]
            imgs[0].save(tmp, format="GIF", save_all=True, append_images=imgs[1:], duration=int(1000 / fps), loop=0)
        else:
            try:
                import imageio.v2 as imageio
            except ImportError:
                raise KinadaptError("MP4 needs imageio + imageio-ffmpeg (pip install imageio imageio-ffmpeg); "
                                    "or write a .gif") from None
            with imageio.get_writer(tmp, fps=fps, format="FFMPEG") as w:
                for f in frames:
                    w.append_data(f)

    atomic_write(out, write, suffix=suffix)
    return len(frames)


def view_interactive(run: Path) -> None:
    """Replay in the interactive viewer (needs a display)."""
    import time

    import mujoco
    import mujoco.viewer

    from kinadapt_nn.config import load_config
    from kinadapt_nn.sim.adapter import PegInHoleSim
    from kinadapt_nn.trace import Trace

    cfg = load_config(Path(run) / "config.toml")
    tr = Trace.load(Path(run) / "trace.npz")
    sim = PegInHoleSim(cfg)
    with mujoco.viewer.launch_passive(sim.model, sim.data) as v:
        t0 = time.perf_counter()
        for i in range(0, len(tr), 10):
            if not v.is_running():
                break
            sim.data.qpos[sim.ids.qpos_adr] = tr["q_rad"][i]
            mujoco.mj_forward(sim.model, sim.data)
            v.sync()
            time.sleep(max(0.0, tr["t_s"][i] - (time.perf_counter() - t0)))
