"""kinadapt reproduce: the QP identities, the static estimator foil, the outputs."""

from __future__ import annotations

import json

import numpy as np

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import load_config
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.paper.qp_check import run_qp_checks
from kinadapt_nn.paper.static_estimator import static_offset_estimate


def test_qp_identities_with_a_real_solver():
    """quadprog's solution of eq. ident_qp equals the closed forms; QPaug gives thetadot = 0."""
    checks = {c.features: c for c in run_qp_checks(seed=3)}
    assert set(checks) == {"adjoint", "rbf", "neural"}
    for c in checks.values():
        assert c.ident_qp_max_abs_error <= 1e-8
        assert c.qpaug_thetadot_max_abs <= 1e-10
        assert c.qpaug_qdot_max_abs_error <= 1e-8
    assert checks["rbf"].scalar_closed_form_max_abs_error <= 1e-8


def test_static_wrench_balance_is_driven_off_by_a_contact_couple():
    """Remark ft_static: with the socket's angular spring (a couple) the static balance misses
    the offset by far more than the prediction-error law; without the couple it is exact."""
    base = ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]", "run.duration_s=3.0"]
    true = np.asarray(load_config(None, base).tool.offset_f_m)
    with_couple = run_episode(load_config(None, base))
    st = static_offset_estimate(with_couple.trace, make_controller(load_config(None, base)).kin)
    law_err = np.linalg.norm(with_couple.summary["offset_error_final_m"])
    assert np.linalg.norm(st - true) > 5 * law_err and np.linalg.norm(st - true) > 5e-3
    no_couple = run_episode(load_config(None, [*base, "scene.socket_k_rot_Nm_per_rad=0"]))
    st0 = static_offset_estimate(no_couple.trace, make_controller(load_config(None, base)).kin)
    assert np.linalg.norm(st0 - true) < 1e-4


def test_reproduce_only_qp_writes_json_and_markdown(tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["reproduce", "--only", "qp", "--out", str(out), "--quiet", "--jobs", "1"]) == 0
    r = json.loads((out / "reproduce.json").read_text())
    assert r["qp_max_abs_error"] <= 1e-8
    assert "| identification QP" in (out / "reproduce.md").read_text()
    assert main(["reproduce", "--only", "nonsense", "--out", str(tmp_path / "x"), "--quiet"]) == 2


def test_view_renders_a_gif_or_says_why(tmp_path):
    """kinadapt view on a real (short) run: a GIF with frames, or one line naming the GL problem."""
    import os
    import subprocess
    import sys

    run = tmp_path / "run"
    assert main(["online", "--out", str(run), "--quiet", "--set", "run.duration_s=0.4",
                 "--set", "run.tensorboard=false", "--set", "run.figure=false"]) == 1
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    env.pop("DISPLAY", None)
    p = subprocess.run([sys.executable, "-m", "kinadapt_nn.app.cli", "view", str(run), "--out", str(tmp_path / "v.gif"),
                        "--fps", "10", "--quiet"], env=env, capture_output=True, text=True)
    if p.returncode == 0:
        from PIL import Image

        im = Image.open(tmp_path / "v.gif")
        assert im.n_frames >= 3 and im.size == (480, 360)
    else:
        assert p.returncode == 2 and p.stderr.count("\n") == 1 and "MUJOCO_GL" in p.stderr
    assert main(["view", str(tmp_path / "nope"), "--out", str(tmp_path / "x.gif"), "--quiet"]) == 2


def test_the_video_part_says_each_step_before_it_runs(tmp_path, monkeypatch):
    """``part_video``'s two subprocesses (simulate, render: 13 s silent before) are each announced
    before they start -- checked by the order of the messages and the calls, not by a clock."""
    import subprocess

    from kinadapt_nn.paper import reproduce

    events = []

    def fake_run(cmd, **kw):
        events.append(("run", cmd[cmd.index("kinadapt_nn.app.cli") + 1]))
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(subprocess, "run", fake_run)
    out = reproduce.part_video(tmp_path, None, progress=lambda msg: events.append(("say", msg)))
    assert [e[0] for e in events] == ["say", "run", "say", "run"], events
    assert "simulating" in events[0][1] and events[1][1] == "online"
    assert "rendering" in events[2][1] and events[3][1] == "view"
    assert out["video"]["file"] == "rollout.gif"


class _Trace(dict):
    meta = {"truth_offset_f_m": [0.004, -0.003, 0.1]}


class _SweepRunner:
    """The gain sweep's episodes, synthetic: both laws the same curve (as the paper's setting gives)
    except the socket at Gamma = 8000, where the prediction law ends a decade lower."""

    def map(self, fn, jobs, what):
        out = []
        for job in jobs:
            over = " ".join(job.overrides)
            t = np.linspace(0.0, 5.0, 2000)
            theta = np.array([0.004, -0.003, 0.1]) + 5e-3 * np.exp(-t)[:, None] * np.array([1.0, 1.0, 0.2])
            if "socket" in over and "gamma=8000" in over and "prediction" in over:
                theta = np.array([0.004, -0.003, 0.1]) + (theta - [0.004, -0.003, 0.1]) * np.exp(-t / 2)[:, None]
            out.append(({"success": True, "seat_time_s": 4.8, "offset_error_lateral_final_m": 1e-4},
                        _Trace(t_s=t, V=1e-3 * np.exp(-t), theta=theta)))
        return out


def test_gain_sweep_shows_both_laws_says_where_they_coincide_and_keeps_labels_inside(tmp_path, monkeypatch):
    """gamma_sweep.png: the prediction law's curve was drawn over the composite's in the same
    style (the one hid the other), and the y label ran past its axes; now the laws are told apart
    by line style, a panel whose two curves coincide says so, and each y label fits its axes."""
    import matplotlib.pyplot as plt

    from kinadapt_nn.paper.reproduce import part_gain_sweep

    figs = []
    monkeypatch.setattr(plt, "close", figs.append)
    part_gain_sweep(tmp_path, _SweepRunner())
    assert (tmp_path / "gamma_sweep.png").is_file()
    fig, = figs
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    assert len(fig.axes) == 4
    for ax in fig.axes:
        lines = {ln.get_label().split()[0]: ln for ln in ax.get_lines() if ln.get_label().split()[0] in
                 ("composite", "prediction")}
        assert set(lines) == {"composite", "prediction"}, ax.get_title()
        c, p = lines["composite"], lines["prediction"]
        assert c.get_linestyle() != p.get_linestyle(), ax.get_title()  # told apart where they lie on each other
        assert p.get_zorder() > c.get_zorder() and c.get_linewidth() > p.get_linewidth()  # the narrow one on top
        said = " ".join(t.get_text() for t in ax.get_legend().get_texts())
        assert ("coincide" in said) == (ax.get_title() != "socket + dither, Gamma = 8000"), (ax.get_title(), said)
        lab, box = ax.yaxis.label.get_window_extent(r), ax.get_window_extent(r)
        assert box.y0 - 1 <= lab.y0 and lab.y1 <= box.y1 + 1, (ax.get_title(), lab, box)  # within its axes' height
        assert 0 <= lab.x0 and lab.y1 <= fig.bbox.y1
    plt.close(fig)
