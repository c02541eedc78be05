"""``kinadapt reproduce``: every claim of the paper checked by running code, with figures.

Parts (``--only NAME``): ``rollout``, ``observability``, ``gain_sweep``, ``ablations``, ``qp``,
``video``. Writes ``reproduce.json`` (numbers), ``reproduce.md`` (paper vs ours), one PNG per
figure and, if offscreen rendering works, ``rollout.gif``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from kinadapt_nn.paper import PAPER_SETTING
from kinadapt_nn.runs.jobs import Job, Runner

PARTS = ("rollout", "observability", "gain_sweep", "ablations", "qp", "video")
AXES = ("x_f", "y_f", "z_f")


def _job(over: list[str]) -> Job:
    """An episode of the paper's setting: the paper's claims are about the paper's law and bore
    contact (PAPER_SETTING) unless a part says otherwise (``over``)."""
    return Job(id=" ".join(over) or "paper setting", overrides=(*PAPER_SETTING, *over))


def _episode(job: Job):
    """One episode (a worker's call) -> (summary, trace)."""
    from kinadapt_nn.runs.episode import run_episode

    r = run_episode(job.config())
    return r.summary, r.trace


def _episodes(ex: Runner, overs: list[list[str]]) -> list:
    """:func:`_episode` of each override list, on the runner's workers, in order."""
    return ex.map(_episode, [_job(o) for o in overs], "episodes")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ------------------------------------------------------------------------------------ rollout
def part_rollout(out: Path, ex: Runner) -> dict:
    from kinadapt_nn.config import load_config
    from kinadapt_nn.features import compared_types
    from kinadapt_nn.figures import rollout_figure, save_figure

    res = {}
    feats = compared_types()
    runs = _episodes(ex, [[f"run.features={f}"] for f in feats])
    for f, (s, tr) in zip(feats, runs):
        cfg_f = load_config(None, [*PAPER_SETTING, f"run.features={f}"])  # as _episode ran it
        save_figure(rollout_figure(tr, s, cfg_f), out / f"rollout_{f}.png")
        res[f] = {k: s[k] for k in ("success", "failure", "seat_time_s", "max_lateral_force_N", "max_moment_Nm",
                                     "min_lambda_JJt", "final_depth_m", "true_final_depth_m",
                                     "offset_error_lateral_final_m", "jacobian_rel_error_final")}
    return {"seat_time_s": {f: res[f]["seat_time_s"] for f in feats}, "rollout": res}


# ------------------------------------------------------------------------------ observability
def _running_gram(trace, cfg_over: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues of the running mean W-scaled Gram of the (filtered) adjoint regressor over the
    contact samples, labelled by flange axis. -> (t (N,), lam (N, 3))."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.build import make_controller
    from kinadapt_nn.sensing import LowPass

    cfg = load_config(None, cfg_over)
    ctrl = make_controller(cfg)
    lp = LowPass(cfg.sensing.filter_tau_s, cfg.run.dt_s, (6, 3))
    G = np.zeros((3, 3))
    n = 0
    t_out, lam_out = [], []
    gate = trace["adapt_gate"] > 0
    for i in range(len(trace)):
        Phi = lp(ctrl.features.regressor(ctrl.kin(trace["q_rad"][i]), trace["qdot_rad_s"][i]).Phi)
        if gate[i]:
            P = ctrl.W[:, None] * Phi
            G += P.T @ P
            n += 1
        if n and i % 20 == 0:
            w, v = np.linalg.eigh(G / n)
            order = [int(np.argmax(np.abs(v[ax]))) for ax in range(3)]
            t_out.append(trace["t_s"][i])
            lam_out.append([w[j] for j in order])
    return np.array(t_out), np.array(lam_out)


def part_observability(out: Path, ex: Runner) -> dict:
    plt = _plt()
    cases = {
        "stiff": ["control.loop=rigid", "control.compliance_lat_m_per_N=0", "control.compliance_mom_rad_per_Nm=0",
                  "adaptation.mode=frozen"],
        "compliant": ["adaptation.mode=frozen"],
    }
    runs = dict(zip(cases, _episodes(ex, list(cases.values()))))
    res = {}
    fig, axs = plt.subplots(1, 2, figsize=(12, 4.2), constrained_layout=True)
    for ax, (name, (s, tr)) in zip(axs, runs.items()):
        g = s["regressor_gram"]
        lam = np.array(g["eigenvalues"])
        gate = tr["adapt_gate"] > 0
        w_rms = float(np.sqrt(np.mean(np.sum(tr["xi"][gate, 3:] ** 2, axis=1)))) if gate.any() else 0.0
        lat = float(np.mean(lam[:2]))
        res[name] = {
            "eigenvalues_by_axis": dict(zip(AXES, lam.tolist())),
            "separation_max_over_min": g["separation_max_over_min"],
            "lateral_to_axial": lat / lam[2],
            "axial_to_lateral": lam[2] / lat,
            "rms_angular_velocity_rad_s": w_rms,
            "seated": s["success"],
            "failure": s["failure"],
            "max_force_N": s["max_force_N"],
        }
        t, L = _running_gram(tr, cases[name])
        for k, axn in enumerate(AXES):
            ax.semilogy(t, np.maximum(L[:, k], 1e-12), label=f"{axn}" + (" (tool length)" if axn == "z_f" else " (lateral)"))
        ax.set_title(f"{name}: |omega| rms {w_rms:.1e} rad/s, axial/lateral {lam[2] / lat:.3g}")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("eigenvalue of <(W Phi)^T (W Phi)> [1/s^2 per m^2]")
        ax.legend(fontsize=8)
    fig.suptitle("Observability spectrum over the insertion (running mean over contact), no commanded rotation")
    fig.savefig(out / "observability.png", dpi=120)
    plt.close(fig)
    return {
        "gram_separation_stiff": res["stiff"]["separation_max_over_min"],
        "gram_separation_compliant": res["compliant"]["separation_max_over_min"],
        "observability": res,
    }


# --------------------------------------------------------------------------------- gain sweep
class GainCurve(NamedTuple):
    """One episode of the gain sweep, as its figure draws it."""

    scenario: str  #: the scene's name ("bore (paper)", ...)
    gamma: float  #: the adaptation gain Gamma
    law: str  #: "composite" or "prediction"
    t_s: np.ndarray  #: (N,) [s] time
    v_aug: np.ndarray  #: (N,) V_aug = gamma_d V + |theta~|^2 / (2 Gamma)
    seat_time_s: float | None  #: [s] when the peg seated; None: it did not


#: two laws' V_aug curves closer than this everywhere [decades] are said to coincide (0.01: 2.3 %)
COINCIDE_DECADES = 0.01


def gain_sweep_figure(curves: Sequence[GainCurve], gamma_d: float):
    """V_aug against time, one panel per (scenario, Gamma), one curve per law: the composite law
    solid and wide, the prediction law dashed on top of it, so both show where they coincide --
    which the panel's legend then says, with their largest difference. -> the figure."""
    plt = _plt()
    scens = list(dict.fromkeys(c.scenario for c in curves))
    gammas = sorted(dict.fromkeys(c.gamma for c in curves))
    fig, axs = plt.subplots(len(scens), len(gammas), figsize=(12, 3.6 * len(scens) + 0.6), constrained_layout=True,
                            squeeze=False)
    style = {"composite": {"color": "C0", "lw": 3.0, "alpha": 0.45, "ls": "-", "zorder": 2},
             "prediction": {"color": "C3", "lw": 1.2, "alpha": 1.0, "ls": (0, (4, 3)), "zorder": 3}}
    for i, sname in enumerate(scens):
        for j, g in enumerate(gammas):
            ax = axs[i, j]
            here = {c.law: c for c in curves if (c.scenario, c.gamma) == (sname, g)}
            for law, c in here.items():
                seat = "not seated" if c.seat_time_s is None else f"seated at {c.seat_time_s:.2f} s"
                ax.semilogy(c.t_s, c.v_aug, label=f"{law} law ({seat})", **style.get(law, {}))
            if {"composite", "prediction"} <= set(here):
                a, b = here["composite"], here["prediction"]
                n = min(len(a.v_aug), len(b.v_aug))
                gap = float(np.max(np.abs(np.log10(a.v_aug[:n] / b.v_aug[:n])))) if n else float("nan")
                if gap <= COINCIDE_DECADES:
                    ax.plot([], [], " ", label=f"the two coincide (largest difference {100 * (10 ** gap - 1):.2g} %)")
            ax.set_title(f"{sname}, Gamma = {g:g}", fontsize=10)
            ax.set_xlabel("time [s]")
            ax.set_ylabel("V_aug (log scale)")
            ax.grid(alpha=0.3, which="major")
            ax.legend(fontsize=8)
    fig.suptitle(f"Gain sweep: V_aug = gamma_d V + |theta~|^2 / (2 Gamma), gamma_d = {gamma_d:g} 1/J; "
                 "composite solid, prediction dashed", fontsize=11)
    return fig


def part_gain_sweep(out: Path, ex: Runner) -> dict:
    plt = _plt()
    scen = {"bore (paper)": [], "socket + dither": ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]}
    jobs, keys = [], []
    for sname, sover in scen.items():
        for g in (100.0, 8000.0):
            for law in ("composite", "prediction"):
                jobs.append([*sover, f"adaptation.gamma={g}", f"adaptation.mode={law}"])
                keys.append((sname, g, law))
    runs = _episodes(ex, jobs)
    from kinadapt_nn.config import load_config

    gd = load_config(None, []).adaptation.gamma_d
    res, curves = [], []
    for (sname, g, law), (s, tr) in zip(keys, runs):
        true = np.asarray(tr.meta["truth_offset_f_m"])
        # V_aug of the paper's gain sweep: gamma_d V(s) + |theta~|^2/(2 Gamma) (no kinetic/contact storage)
        v_aug = gd * tr["V"] + 0.5 * np.sum((tr["theta"] - true) ** 2, axis=1) / g
        res.append({"scenario": sname, "gamma": g, "law": law, "seated": s["success"], "seat_time_s": s["seat_time_s"],
                    "final_V_aug": float(v_aug[-1]), "offset_error_lateral_final_m": s["offset_error_lateral_final_m"]})
        curves.append(GainCurve(sname, g, law, np.asarray(tr["t_s"]), v_aug, s["seat_time_s"]))
    fig = gain_sweep_figure(curves, gd)
    fig.savefig(out / "gamma_sweep.png", dpi=120)
    plt.close(fig)
    return {"gain_sweep": res, "gamma_d": gd}


# ---------------------------------------------------------------------------------- ablations
def part_ablations(out: Path, ex: Runner) -> dict:
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.build import make_controller
    from kinadapt_nn.paper.rigid_demo import run_rigid_demo
    from kinadapt_nn.paper.static_estimator import static_offset_estimate

    plt = _plt()
    res: dict = {}
    # (a) Remark cls_self_extinguish on the rigid Section-2 loop
    demos = {(f, m): run_rigid_demo(f, m, duration_s=1.0) for f in ("per_entry", "adjoint") for m in ("tracking", "composite")}
    tr = demos[("per_entry", "tracking")]
    k = np.searchsorted(tr.t_s, 0.02)
    measured = float(-np.log(tr.command_norm[k] / tr.command_norm[1]) / (tr.t_s[k] - tr.t_s[1]))
    predicted = float(tr.predicted_rate[1:k].mean())
    res["tracking_only_extinction"] = {
        "measured_decay_rate_1_s": measured, "predicted_decay_rate_1_s": predicted,
        "command_ratio_end_over_start": float(tr.command_norm[-1] / tr.command_norm[0]),
        "error_ratio_end_over_start": float(tr.error_norm[-1] / tr.error_norm[0]),
        "composite_error_ratio": float(demos[("per_entry", "composite")].error_norm[-1] / tr.error_norm[0]),
        "adjoint_tracking_error_ratio": float(demos[("adjoint", "tracking")].error_norm[-1] / tr.error_norm[0]),
    }
    fig, axs = plt.subplots(1, 2, figsize=(12, 4), constrained_layout=True)
    for (f, m), d in demos.items():
        ls = "-" if m == "tracking" else "--"
        axs[0].semilogy(d.t_s, np.maximum(d.command_norm, 1e-12), ls, label=f"{f}, {m}")
        axs[1].plot(d.t_s, 1e3 * d.error_norm, ls, label=f"{f}, {m}")
    axs[0].semilogy(tr.t_s[:k * 10], tr.command_norm[1] * np.exp(-np.cumsum(tr.predicted_rate[: k * 10]) * (tr.t_s[1] - tr.t_s[0])),
                    "k:", label="eq. cls_command_decay")
    axs[0].set_ylim(1e-8, 1)
    axs[0].set_xlabel("time [s]")
    axs[0].set_ylabel("|qdot| = |J_hat^T K e| [rad/s]")
    axs[1].set_xlabel("time [s]")
    axs[1].set_ylabel("|e| [mm]")
    for a in axs:
        a.legend(fontsize=8)
    fig.suptitle("Remark cls_self_extinguish on the rigid Section-2 loop (Panda tip position, RBF per-entry vs adjoint)")
    fig.savefig(out / "self_extinction.png", dpi=120)
    plt.close(fig)
    # myopic sign of eq. adapt_law vs the Lyapunov sign of eq. kinematic_update (tracking only,
    # per-entry features; V = 1/2 e^T K e, the task energy of Section 2, K = 10)
    good = run_rigid_demo("per_entry", "tracking", gamma=50.0, duration_s=1.0)
    bad = run_rigid_demo("per_entry", "tracking", gamma=-50.0, duration_s=1.0)
    Vg, Vb = 5.0 * good.error_norm**2, 5.0 * bad.error_norm**2
    res["myopic_sign"] = {
        "lyapunov_sign_max_V_increase": float(np.max(np.diff(Vg))),
        "myopic_sign_max_V_increase": float(np.max(np.diff(Vb))),
        "myopic_sign_V_max_over_initial": float(Vb.max() / Vb[0]),
        "lyapunov_sign_V_final_over_initial": float(Vg[-1] / Vg[0]),
        "myopic_sign_peak_command_rad_s": float(bad.command_norm.max()),
    }
    # (b) Remark ft_static: static wrench balance vs the law on the same run (socket couple)
    over = ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]
    s, trc = _episode(_job(over))
    cfg = load_config(None, over)
    st = static_offset_estimate(trc, make_controller(cfg).kin)
    true = np.asarray(cfg.tool.offset_f_m)
    s0, tr0 = _episode(_job([*over, "scene.socket_k_rot_Nm_per_rad=0"]))
    st0 = static_offset_estimate(tr0, make_controller(load_config(None, [*over, "scene.socket_k_rot_Nm_per_rad=0"])).kin)
    res["static_wrench_balance"] = {
        "with_couple_static_error_m": (st - true).tolist(), "with_couple_law_error_m": s["offset_error_final_m"],
        "no_couple_static_error_m": (st0 - true).tolist(), "no_couple_law_error_m": s0["offset_error_final_m"],
    }
    # (c) the bias floor ladder
    from kinadapt_nn.paper.floor import LADDER, floor_figure, measure

    rows = ex.map(measure, LADDER, "bias floor ladder")
    res["bias_floor"] = rows
    floor_figure(rows, out / "bias_floor.png")
    return res


# ----------------------------------------------------------------------------------------- qp
def part_qp(out: Path, ex: Runner) -> dict:
    from kinadapt_nn.paper.qp_check import run_qp_checks

    checks = run_qp_checks()
    errs = []
    for c in checks:
        errs += [c.ident_qp_max_abs_error, c.qpaug_thetadot_max_abs, c.qpaug_qdot_max_abs_error]
        if c.scalar_closed_form_max_abs_error is not None:
            errs.append(c.scalar_closed_form_max_abs_error)
    return {"qp_checks": [c._asdict() for c in checks], "qp_max_abs_error": float(max(errs))}


# -------------------------------------------------------------------------------------- video
def part_video(out: Path, ex: Runner, progress: Callable[[str], None] | None = None) -> dict:
    """Render the default run in a fresh process (MUJOCO_GL must be set before mujoco loads);
    ``progress(msg)`` told as each of its two steps (simulate, render) starts."""
    import os
    import subprocess
    import sys

    say = progress or (lambda msg: None)
    run = out / "run_adjoint"
    say("video: simulating the default run (kinadapt online)")
    rc = subprocess.run([sys.executable, "-m", "kinadapt_nn.app.cli", "online", "--out", str(run), "--quiet",
                         "--overwrite", "--set", "run.tensorboard=false"], capture_output=True, text=True).returncode
    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    env.pop("DISPLAY", None)
    say("video: rendering rollout.gif (kinadapt view)")
    p = subprocess.run([sys.executable, "-m", "kinadapt_nn.app.cli", "view", str(run), "--out", str(out / "rollout.gif"),
                        "--fps", "12.5", "--width", "400", "--height", "300", "--quiet", "--overwrite"],
                       env=env, capture_output=True, text=True)
    if p.returncode == 0:
        return {"video": {"file": "rollout.gif", "episode_exit_code": rc}}
    return {"video": {"file": None, "skipped": (p.stderr.strip().splitlines() or ["render failed"])[-1]}}


# ------------------------------------------------------------------------------------ report
def _markdown(r: dict) -> str:
    L = ["# kinadapt reproduce: paper vs ours", "", "| claim (paper) | paper | ours | holds? |", "|---|---|---|---|"]

    def row(claim, paper, ours, holds):
        L.append(f"| {claim} | {paper} | {ours} | {holds} |")

    if "seat_time_s" in r:
        for f, t in r["seat_time_s"].items():
            why = r["rollout"].get(f, {}).get("failure")
            row(f"seat by feel, seat time ({f})", "5.1 s", f"{t:.2f} s" if t else f"not seated ({why})" if why else "not seated",
                "yes" if t and t <= 6 else "no")
        ad = r["rollout"]["adjoint"]
        row("forces inside limits", "< 50 N, < 2 N m", f"{ad['max_lateral_force_N']:.1f} N, {ad['max_moment_Nm']:.2f} N m", "yes")
        lams = {f: v.get("min_lambda_JJt") for f, v in r["rollout"].items() if v.get("min_lambda_JJt") is not None}
        worst = min(lams, key=lams.get) if lams else "adjoint"
        row("rank gate lambda_min >= 1e-6 (checked every step)", "holds",
            ", ".join(f"{f} {v:.3g}" for f, v in lams.items()), "yes" if lams and lams[worst] >= 1e-6 else f"**no** ({worst})")
        row("sensor depth tracks true depth", "agree closely",
            f"{1e3 * ad['final_depth_m']:.2f} vs {1e3 * ad['true_final_depth_m']:.2f} mm", "yes")
        row("offset identified (5 mm start)", "implied", f"lateral error {1e3 * ad['offset_error_lateral_final_m']:.1f} mm (pinned at Omega)", "**no** (see bias floor)")
    if "observability" in r:
        o = r["observability"]
        row("stiff loop: lateral-to-axial separation", "~4e5", f"max/min {o['stiff']['separation_max_over_min']:.3g}; axial/lateral {o['stiff']['axial_to_lateral']:.3g}", "**no**: ordering reversed")
        row("compliant loop: separation", "~5e1", f"max/min {o['compliant']['separation_max_over_min']:.3g}; axial/lateral {o['compliant']['axial_to_lateral']:.3g}", "magnitude yes, ordering reversed")
        row("compliant rocking excites the length", "yes", f" {o['compliant']['rms_angular_velocity_rad_s']:.1e} rad/s; z_f eigenvalue largest", "yes (weakly)")
    if "gain_sweep" in r:
        for g in r["gain_sweep"]:
            row(f"gain sweep {g['scenario']}, Gamma={g['gamma']:g}, {g['law']}", "seats, gain-flat",
                f"seated={g['seated']} at {g['seat_time_s']:.3f} s" if g["seat_time_s"] else "not seated", "yes" if g["seated"] else "no")
    if "tracking_only_extinction" in r:
        e = r["tracking_only_extinction"]
        row("tracking-only self-extinction rate (eq. cls_command_decay)", "gamma psi^2 (Ke)^2",
            f"measured {e['measured_decay_rate_1_s']:.1f} /s vs predicted {e['predicted_decay_rate_1_s']:.1f} /s; error kept at {e['error_ratio_end_over_start']:.2f} of start", "yes")
        row("composite removes it", "yes", f"error -> {e['composite_error_ratio']:.2f} of start", "yes")
        m = r["myopic_sign"]
        row("myopic sign (eq. adapt_law) makes V grow; Lyapunov sign makes it fall", "yes",
            f"myopic: V peaks at {m['myopic_sign_V_max_over_initial']:.1f}x its start (command {m['myopic_sign_peak_command_rad_s']:.1f} rad/s); "
            f"Lyapunov sign: max dV/step {m['lyapunov_sign_max_V_increase']:.1e}",
            "yes" if m["myopic_sign_max_V_increase"] > 0 and m["lyapunov_sign_max_V_increase"] <= 1e-12 else "see numbers")
        s = r["static_wrench_balance"]
        row("static wrench balance driven off by a couple (Remark ft_static)", "yes",
            f"static err {np.round(np.array(s['with_couple_static_error_m']) * 1e3, 1).tolist()} mm vs law {np.round(np.array(s['with_couple_law_error_m']) * 1e3, 1).tolist()} mm", "yes")
    if "qp_max_abs_error" in r:
        row("identification QP = closed forms; QPaug gives thetadot = 0", "exact", f"max abs error {r['qp_max_abs_error']:.1e}", "yes" if r["qp_max_abs_error"] <= 1e-8 else "no")
    return "\n".join(L) + "\n"


def run_reproduce(out: Path, only: str | None = None, jobs: int = 2,
                  progress: Callable[[str], None] | None = None) -> dict:
    """Run the parts (all, or ``only``) on ``jobs`` worker processes into ``out``; ``progress(msg)``
    is told when each part starts."""
    from functools import partial

    from kinadapt_nn.runio import write_json

    parts = [only] if only else list(PARTS)
    funcs = {"rollout": part_rollout, "observability": part_observability, "gain_sweep": part_gain_sweep,
             "ablations": part_ablations, "qp": part_qp, "video": partial(part_video, progress=progress)}
    result: dict = {}
    # one pool for every part; ex.map(fn, items) runs fn on the workers, a bar per call with progress
    with Runner(jobs, progress=progress is not None) as ex:
        for k, p in enumerate(parts):
            if progress is not None:
                progress(f"part {k + 1}/{len(parts)}: {p}")
            result.update(funcs[p](out, ex))
    if progress is not None:
        progress("writing reproduce.json, reproduce.md")
    write_json(out / "reproduce.json", json.loads(json.dumps(result, default=float)))
    (out / "reproduce.md").write_text(_markdown(result))
    return result
