"""The monitor's figure: the residual (reading - nominal model) per channel against its noise, and the events.

    python -m kinadapt_nn.monitor.figure RUN_DIR [--out PNG]

RUN_DIR: a run of ``kinadapt online --monitor`` (its ``trace.npz`` holds ``monitor_residual`` and its
``summary.json`` the events).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from kinadapt_nn.monitor.shapes import CHANNELS


def monitor_figure(t: np.ndarray, residual: np.ndarray, mon: dict):
    """Two panels over time t (N,) [s]: the force residual [N] and the moment residual [N m] (N, 6),
    each channel's +-3 noise sd shaded, every event's time (dashed) and the time it was named (dotted:
    from then on its fitted shape is part of the model, the residual is what is left) marked and its
    line written. -> the figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sd = np.asarray(mon["noise_sd"])
    fig, axes = plt.subplots(2, 1, figsize=(9.0, 5.6), sharex=True, constrained_layout=True)
    colors = ("tab:blue", "tab:orange", "tab:green")
    for ax, (a, unit) in zip(axes, ((0, "N"), (3, "N m"))):
        for i in range(3):
            ax.plot(t, residual[:, a + i], lw=0.8, color=colors[i], label=CHANNELS[a + i])
        band = 3.0 * float(np.max(sd[a:a + 3]))
        ax.axhspan(-band, band, color="0.85", zorder=0, label=f"±3 noise sd ({band:.2g} {unit})")
        ax.set_ylabel(f"reading − model [{unit}]")
        ax.legend(loc="upper left", fontsize=8, ncol=4)
        for e in mon["events"]:
            ax.axvline(e["t_s"], color="tab:red", lw=1.0, ls="--")
            ax.axvline(e["t_named_s"], color="tab:red", lw=0.8, ls=":")
    text = "\n".join(f"{e['line']}  (named at {e['t_named_s']:.2f} s: its shape then joins the model)"
                      for e in mon["events"])
    if text:
        axes[0].text(0.99, 0.62, text, transform=axes[0].transAxes, ha="right", va="top", fontsize=8,
                     color="tab:red", bbox=dict(facecolor="white", edgecolor="tab:red", alpha=0.9))
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(f"live monitor: residual of the wrist F/T reading against the nominal model "
                      f"({len(mon['events'])} event(s); blank: calibrating or contact, not judged)", fontsize=9)
    return fig


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Draw a --monitor run's residual and events.")
    ap.add_argument("run", type=Path, help="a run folder of kinadapt online --monitor")
    ap.add_argument("--out", type=Path, default=None, help="PNG (default: RUN/monitor.png)")
    a = ap.parse_args(argv)
    z = np.load(a.run / "trace.npz")
    mon = json.loads((a.run / "summary.json").read_text())["monitor"]
    fig = monitor_figure(z["t_s"], z["monitor_residual"], mon)
    out = a.out or a.run / "monitor.png"
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
