"""The identification-floor ladder: scenarios that change the bias b and the excitation.

For each scenario, ``measure`` runs the oracle (the prediction error with the true offset IS the
filtered bias b) and the composite law, and returns b_rms, sigma_min (sqrt of the smallest
eigenvalue of the contact-phase regressor Gram) and the final lateral offset error, so the
O(b / sigma_min) floor of Theorem ft_rigid can be checked (``benchmarks/identification_floor.py``,
``kinadapt reproduce``).
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.paper import PAPER_SETTING

LADDER: list[tuple[str, list[str]]] = [
    ("bore, no dither (paper setting)", []),
    ("bore, dither 0.05 rad/s", ["control.dither_rad_s=[0.05,0.05,0.05]"]),
    ("bore soft contact, dither 0.05", ["control.dither_rad_s=[0.05,0.05,0.05]", "scene.contact_timeconst_s=0.05"]),
    ("socket k=0.3 k_t, dither 0.05", ["scene.contact_model=socket", "scene.socket_k_lat_N_per_m=6000",
                                       "control.dither_rad_s=[0.05,0.05,0.05]"]),
    ("socket k=0.6 k_t, dither 0.05", ["scene.contact_model=socket", "scene.socket_k_lat_N_per_m=12000",
                                       "control.dither_rad_s=[0.05,0.05,0.05]"]),
    ("socket k=0.85 k_t, dither 0.05", ["scene.contact_model=socket", "scene.socket_k_lat_N_per_m=17000",
                                        "control.dither_rad_s=[0.05,0.05,0.05]"]),
    ("socket matched, dither 0.05", ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]),
    ("socket matched, dither 0.02", ["scene.contact_model=socket", "control.dither_rad_s=[0.02,0.02,0.02]"]),
    ("socket matched, dither 0.01", ["scene.contact_model=socket", "control.dither_rad_s=[0.01,0.01,0.01]"]),
]


def measure(item: tuple[str, list[str]]) -> dict:
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.episode import run_episode

    name, over = item
    base = ["run.progress=false", "run.stop_after_seat_s=1.5", *PAPER_SETTING]  # the paper's law and bore contact
    oracle = run_episode(load_config(None, base + over + ["run.features=oracle"])).summary
    comp = run_episode(load_config(None, base + over))
    cfg = load_config(None, base + over)
    true = np.asarray(cfg.tool.offset_f_m)
    tr = comp.trace
    last = tr["t_s"] >= tr["t_s"][-1] - 1.5
    lat_err = np.hypot(*(tr["theta"][last, :2] - true[:2]).T)
    gram = oracle["regressor_gram"]
    sigma_min = float(np.sqrt(min(gram["eigenvalues"]))) if gram else float("nan")
    b = oracle["pred_error_rms_contact_w"] or float("nan")
    err = float(np.sqrt(np.mean(lat_err**2)))
    return {
        "scenario": name,
        "success": comp.summary["success"],
        "seat_time_s": comp.summary["seat_time_s"],
        "b_rms_w": b,
        "sigma_min": sigma_min,
        "b_over_sigma_m": b / sigma_min,
        "lateral_error_rms_last_m": err,
        "lateral_error_final_m": comp.summary["offset_error_lateral_final_m"],
        "ratio": err / (b / sigma_min),
    }




#: markers of the ladder's points, in turn (with the colour: a point found by its look as by its number)
MARKERS = "osD^vP*Xh<>p"


def floor_figure(rows: list[dict], path) -> None:
    """Final lateral error vs b_rms / sigma_min (log-log) with the 1:1 line, the 5 mm start and
    the Omega cap. Each scenario is a numbered point (its own colour and marker); the numbers sit
    where they overlap nothing (``figures.place_labels``: the matched sockets' points nearly
    coincide) and the key beside the axes names each number's scenario with its two values."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kinadapt_nn.figures import place_labels

    fig, ax = plt.subplots(figsize=(10.0, 5.2), constrained_layout=True)
    x = np.array([r["b_over_sigma_m"] for r in rows]) * 1e3
    y = np.array([r["lateral_error_rms_last_m"] for r in rows]) * 1e3
    keys = []
    for i, (r, xi, yi) in enumerate(zip(rows, x, y)):
        keys.append(ax.loglog([xi], [yi], MARKERS[i % len(MARKERS)], color=f"C{i % 10}", ms=6, mfc="none", mew=1.4,
                              label=f"{i + 1}  {r['scenario']}  ({xi:.3g} mm, {yi:.3g} mm)")[0])
    lo, hi = np.nanmin(x) / 2, np.nanmax(x) * 2
    refs = [ax.loglog([lo, hi], [lo, hi], "k:", lw=0.8, label="error = b / sigma_min")[0],
            ax.axhline(5.0, color="r", ls="--", lw=0.8, label="initial error 5 mm"),
            ax.axhline(1e3 * np.hypot(0.018, 0.017), color="gray", ls="-.", lw=0.8,
                       label="estimate pinned at the Omega box")]
    ax.set_xlabel("b_rms / sigma_min [mm] (oracle run)")
    ax.set_ylabel("lateral offset error, last 1.5 s RMS [mm]")
    ax.set_title("Bias floor O(b / sigma_min) as the contact model is made less ideal")
    ax.legend(handles=refs, fontsize=8, loc="upper left")
    fig.legend(handles=keys, fontsize=8, loc="outside right upper",
               title="scenario (b_rms / sigma_min, error)", title_fontsize=8)
    place_labels(ax, x, y, [str(i + 1) for i in range(len(rows))], fontsize=8)
    fig.savefig(path, dpi=130)
    plt.close(fig)
