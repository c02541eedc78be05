"""The work cell: bores in a sequence, the cell Jacobian error on held-out configurations, the
between-insertion refit (issue 21). Checked against independent computations: MuJoCo forward
kinematics of the held-out poses, the adjoint's exact representation of a rigid tool on the
nominal arm, and a stacked least-squares solution of the refit."""

from __future__ import annotations

import csv
import json

import mujoco
import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.cell import CellJacobianError
from kinadapt_nn.runs.refit import Refit

BORES = "cell.bores_w_m=[[0.45,0.0,0.30],[0.55,0.15,0.25],[0.38,-0.2,0.35]]"
SOCKET = ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]
ARM = ["arm.link_length_error_m=[0.0008,-0.0011,0.0004,0.0009,-0.0006,0.0012,-0.0003,0.0007]",
       "arm.joint_offset_rad=[0.003,-0.004,0.002,0.005,-0.003,0.004,-0.002]"]


@pytest.mark.parametrize("over, words", [
    (["cell.bores_w_m=[[0.45,0.0,0.3]]", "cell.order=[0,1]"], "cell.order names bore 1"),
    (["cell.refit_channels=[6]"], "refit_channels"),
    (["cell.bores_w_m=[[0.45,0.0,3.0]]"], "bore 0"),
])
def test_bad_cell_config_is_one_line(over, words):
    with pytest.raises(ConfigError) as e:
        load_config(None, over)
    msg = str(e.value)
    assert words in msg and "\n" not in msg


def test_order_cycles_over_the_bores():
    cfg = load_config(None, [BORES, "cell.order=[2,0]"])
    assert [cfg.cell.bore_of(i) for i in range(5)] == [2, 0, 2, 0, 2]
    cfg = load_config(None, [BORES])
    assert [cfg.cell.bore_of(i) for i in range(4)] == [0, 1, 2, 0]
    assert load_config(None, []).cell.bores(load_config(None, []).scene) == [(0.45, 0.0, 0.3)]


def test_heldout_poses_lie_about_their_bores_by_forward_kinematics():
    """The held-out configurations put the NOMINAL tip (CAD offset) where the docstring says: within
    the lateral band of its bore's axis, 10 mm above to 50 mm below the entrance, flange tilt within
    the spread -- checked by MuJoCo forward kinematics of the bare arm, not by the IK that made them."""
    from kinadapt_nn.robot import FLANGE_SITE, PANDA_MJCF
    from kinadapt_nn.sim.workspace import heldout_configurations

    cfg = load_config(None, [BORES, "cell.heldout_per_bore=5"])
    q, which = heldout_configurations(cfg)
    assert q.shape == (15, 7) and list(which) == [0] * 5 + [1] * 5 + [2] * 5
    q2, _ = heldout_configurations(cfg)
    assert np.array_equal(q, q2)  # a fixed set
    model = mujoco.MjModel.from_xml_path(str(PANDA_MJCF))
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
    l_nom = np.asarray(cfg.sensing.nominal_offset_f_m)
    bores = np.asarray(cfg.cell.bores(cfg.scene))
    for qi, b in zip(q, which):
        data.qpos[:7] = qi
        mujoco.mj_kinematics(model, data)
        R = data.site_xmat[site].reshape(3, 3)
        tip = data.site_xpos[site] + R @ l_nom
        d = tip - bores[b]
        assert np.all(np.abs(d[:2]) <= cfg.cell.heldout_lateral_m + 1e-6)
        assert -0.05 - 1e-6 <= d[2] <= 0.01 + 1e-6
        tilt = np.degrees(np.arccos(np.clip(-R[2, 2], -1.0, 1.0)))  # flange z from straight down
        assert tilt <= np.sqrt(2) * cfg.cell.heldout_tilt_deg + 1e-3


def test_cell_error_is_zero_for_the_true_offset_on_the_nominal_arm_and_not_with_arm_errors():
    """The adjoint at the true offset IS the true Jacobian on the nominal arm (closed form); on an arm
    with kinematic errors no offset represents it."""
    over = [BORES, "cell.heldout_per_bore=3", "tool.offset_f_m=[0.0031,-0.0042,0.1012]"]
    cfg = load_config(None, over)
    ctrl = make_controller(cfg)
    cell = CellJacobianError(cfg, ctrl)
    true = np.asarray(cfg.tool.offset_f_m)
    assert np.max(cell.errors(ctrl, true)) < 1e-12
    assert cell.median(ctrl) > 1e-3  # theta0 = 5 mm off
    cfg_a = load_config(None, [*over, *ARM])
    ctrl_a = make_controller(cfg_a)
    assert CellJacobianError(cfg_a, ctrl_a).median(ctrl_a, true) > 1e-3


def _synthetic_insertions(rf, rng, insertions: int, rows: int) -> np.ndarray:
    """Logged insertions for ``rf`` (``Refit``): regressors H (rows, 2, 3) and rates y = H theta_true
    plus noise, theta_true 2-3 mm from the prior. -> theta_true (3,)."""
    th_true = rf.theta_prior + np.array([0.002, -0.001, 0.003])
    for _ in range(insertions):
        H = rng.normal(size=(rows, 2, 3)) * 30.0
        y = np.einsum("kmp,p->km", H, th_true) + rng.normal(size=(rows, 2)) * 0.01
        rf.data.append((H, y))
    return th_true


def test_refit_is_the_stacked_least_squares_solution():
    """Refit.solve (information form, per-insertion residual weights) equals an independent stacked,
    whitened least-squares solve with the prior as extra rows, at the weights of its last pass."""
    cfg = load_config(None, [BORES, "cell.heldout_per_bore=1"])
    ctrl = make_controller(cfg)
    rf = Refit(ctrl, channels=(1, 2), prior_weight=2.0)
    th_true = _synthetic_insertions(rf, np.random.default_rng(0), insertions=3, rows=200)
    theta, P, _ = rf.solve()
    # the independent solve: weights from the residuals at the previous pass (re-derived here)
    th = rf.theta_prior.copy()
    for _ in range(3):
        rows, rhs = [np.linalg.cholesky(rf.prior_weight * rf._P0inv).T], [np.zeros(3)]
        for H, y in rf.data:
            r = y - np.einsum("kmp,p->km", H, th)
            w = 1.0 / np.sqrt((np.mean(r * r, axis=0) + rf.r_floor) * rf.n_eff)
            rows.append((H * w[None, :, None]).reshape(-1, 3))
            rhs.append(((y - np.einsum("kmp,p->km", H, rf.theta_prior)) * w).reshape(-1))
        x, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
        th = rf.theta_prior + x
    assert np.allclose(theta, th, atol=1e-12, rtol=0)
    assert np.allclose(theta, th_true, atol=2e-4)  # and the data pin the parameters
    assert np.all(np.linalg.eigvalsh(P) > 0)


class _Trace:
    """The few trace channels Refit.add reads (a logged insertion, controller side only)."""

    def __init__(self, arrays: dict, dt: float) -> None:
        self.arrays, self.meta = arrays, {"dt_s": dt}

    def __getitem__(self, k: str) -> np.ndarray:
        return self.arrays[k]


def test_refit_recovers_a_sensor_timing_offset():
    """The measured rate is the prediction 0.7 ms later (an F/T reading that leads the encoders; to
    first order, the refit's own model of it):
    with the timing unknown the refit recovers both the offset and theta; without it, theta is
    pulled away by the acceleration-shaped residual."""
    cfg = load_config(None, [BORES, "cell.heldout_per_bore=1"])
    ctrl = make_controller(cfg)
    dt, N, m, p = 1e-3, 4000, 6, 3
    t = np.arange(N) * dt
    rng = np.random.default_rng(1)
    freqs = rng.uniform(10.0, 25.0, size=(p, m, 2))

    def phi(tt):  # (N, p, m): smooth regressor rows, 10-25 Hz (the admittance loop's band in contact)
        return 30.0 * np.sin(2 * np.pi * freqs[None, :, :, 0] * tt[:, None, None]) \
            + 20.0 * np.cos(2 * np.pi * freqs[None, :, :, 1] * tt[:, None, None])

    th_used = ctrl.theta0.copy()
    th_true = th_used + np.array([0.002, -0.001, 0.003])
    delta = 0.7e-3
    W = ctrl.W
    h = 1e-6  # the measured rate = the true prediction delta later, to first order in delta
    pred_true_later = np.einsum("kpm,p->km", phi(t) + delta * (phi(t + h) - phi(t - h)) / (2 * h), th_true)
    s_dot_pred = np.einsum("kpm,p->km", phi(t), th_used)
    arrays = {"law_Phi_fT": phi(t), "adapt_gate": np.ones(N), "drive_scale": np.ones(N), "theta": np.tile(th_used, (N, 1)),
              "eps_w": W * (pred_true_later - s_dot_pred), "s_dot_pred": s_dot_pred}
    fits = {}
    for sd in (0.0, 0.005):
        rf = Refit(ctrl, channels=(1, 2), prior_weight=1e-6, timing_sd_s=sd, decimate_s=dt)
        rf.add(_Trace(dict(arrays), dt))
        fits[sd] = (rf.solve()[0], rf.timing_s)
    theta_t, timing = fits[0.005]
    assert abs(timing - delta) < 0.05 * delta
    err_with = np.linalg.norm(theta_t - th_true)
    err_without = np.linalg.norm(fits[0.0][0] - th_true)
    assert err_with < 0.1 * err_without


def test_sample_cell_with_one_path_is_sample_workspace_bit_for_bit():
    """The default pretraining data (one bore) are unchanged by the work-cell sampling."""
    from kinadapt_nn.sim.workspace import sample_cell, sample_workspace

    path = np.linspace(0, 1, 12)[:, None] * np.ones((1, 7))
    a = sample_workspace(path, 40, 0.03, np.random.default_rng(5))
    b = sample_cell(path, 40, 0.03, np.random.default_rng(5))
    assert np.array_equal(a, b)
    c = sample_cell([path, path + 1.0], 40, 0.03, np.random.default_rng(5))
    assert np.sum(c.mean(axis=1) > 0.9) > 5 and np.sum(c.mean(axis=1) < 0.6) > 5  # both paths used


@pytest.fixture(scope="module")
def cell_run():
    from kinadapt_nn.runs.insertions import run_insertions

    cfg = load_config(None, ["run.progress=false", *SOCKET, BORES, "cell.order=[2,0]", "run.insertions=2",
                             "cell.heldout_per_bore=3", "cell.between=refit"])
    return cfg, run_insertions(cfg).summary


def test_cell_run_visits_the_bores_in_order_and_reports_per_insertion(cell_run):
    cfg, s = cell_run
    rows, cell = s["insertions"], s["cell"]
    assert [r["bore"] for r in rows] == [2, 0]
    assert rows[0]["bore_entry_w_m"] == [0.38, -0.2, 0.35]
    assert all(r["success"] for r in rows)  # each insertion seats on its own
    errs = cell["jacobian_error_cell_median"]
    assert len(errs) == 3 and cell["heldout_configurations"] == 9
    assert [r["jacobian_error_cell_median"] for r in rows] == errs[1:]
    assert errs[-1] < 0.5 * errs[0]  # the adjoint learns the 5 mm offset error in the cell
    assert rows[1]["refit"]["insertions_pooled"] == 2


def test_cell_run_is_reproducible(cell_run):
    from kinadapt_nn.runs.insertions import run_insertions

    cfg, s = cell_run
    s2 = run_insertions(cfg).summary
    assert s2["cell"]["jacobian_error_cell_median"] == s["cell"]["jacobian_error_cell_median"]


def test_compare_writes_one_row_per_insertion(tmp_path):
    from kinadapt_nn.runs.compare import load_compare_config, run_compare

    cfg = load_compare_config(None, ["features=['adjoint']", "families=['nominal']", "n_tools=1", "jobs=1",
                                     "scenarios={cell=['scene.contact_model=socket',"
                                     "'control.dither_rad_s=[0.05,0.05,0.05]',"
                                     "'cell.bores_w_m=[[0.45,0.0,0.30],[0.55,0.15,0.25]]',"
                                     "'cell.heldout_per_bore=2','run.insertions=2']}"])
    rows = run_compare(cfg, tmp_path, progress=False)
    with open(tmp_path / "comparison.csv") as fh:
        table = list(csv.DictReader(fh))
    assert [r["insertion"] for r in table] == ["all", "0", "1", "2"]
    cell = [float(r["jacobian_error_cell_median"]) for r in table[1:]]
    assert cell[2] < cell[0]
    assert float(table[0]["jacobian_error_cell_median"]) == cell[-1]
    assert (tmp_path / "cell_learning.png").stat().st_size > 10_000
    assert rows[1]["insertion"] == 0
    json.dumps(rows)


def _same(a, b, path=""):
    """a == b to the last bit (NaN == NaN), wall times (the episodes' and the one-time compile's) left out."""
    if isinstance(a, dict):
        timing = {"wall_time_s", "compile_time_s"}
        assert set(a) - timing == set(b) - timing, path
        for k in set(a) - timing:
            _same(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray):
        assert np.array_equal(a, b, equal_nan=True), path
    elif isinstance(a, float) and a != a:
        assert isinstance(b, float) and b != b, path
    else:
        assert a == b, (path, a, b)


@pytest.mark.parametrize("over", [["run.features=rbf"], ["cell.between=refit", BORES, "cell.heldout_per_bore=2"]])
def test_insertion_prefixes_are_the_shorter_runs(over):
    """run_insertion_prefixes(cfg, [1, 2]) gives, for each count, what run_insertions gives with
    run.insertions set to it: summary and trace to the last bit (RBF: its p x p BLAS work; a
    cell with a refit between insertions: the regressor rows kept, the cell error per insertion)."""
    from kinadapt_nn.runs.insertions import run_insertion_prefixes, run_insertions

    base = ["run.progress=false", *SOCKET, "run.duration_s=1.5", *over]
    both = run_insertion_prefixes(load_config(None, base), [2, 1])
    assert sorted(both) == [1, 2]
    for k in (1, 2):
        alone = run_insertions(load_config(None, [*base, f"run.insertions={k}"]))
        _same(alone.summary, both[k].summary)
        _same(dict(alone.trace.arrays), dict(both[k].trace.arrays))
    assert "insertions" in both[2].summary and len(both[2].summary["insertions"]) == 2


def test_cells_stepped_together_equal_each_cell_alone():
    """Work cells that differ only in the tool run insertion i as one batch (run_cells on
    runs.batch.run_episodes, controllers carried between insertions, a refit in between): each
    cell's prefixes equal run_insertion_prefixes of that cell alone, summary (its insertion rows
    and cell errors) and trace to the last bit, but the wall times. Cells with other bores are
    refused."""
    from kinadapt_nn.runs.insertions import run_cells, run_insertion_prefixes
    from kinadapt_nn.runs.sweep import SweepCfg, tool_overrides

    base = ["run.progress=false", *SOCKET, "run.duration_s=1.5", "cell.between=refit", BORES,
            "cell.heldout_per_bore=2"]
    cfgs = [load_config(None, [*base, *tool_overrides(SweepCfg(), s)]) for s in range(3)]
    reports: list[float] = []
    together = run_cells(cfgs, [2, 1], on_insertion=reports.append)
    # the job runner's progress in episodes: fractions while each batch steps (every 250 of its
    # 1500 steps), the rest as it ends; 2 insertions x 3 cells in all
    assert len(reports) > 4 and all(0.0 <= r <= 3.0 for r in reports)
    assert sum(reports) == pytest.approx(6.0, abs=1e-9)
    for cfg, both in zip(cfgs, together):
        alone = run_insertion_prefixes(cfg, [1, 2])
        assert sorted(both) == [1, 2]
        for k in (1, 2):
            _same(alone[k].summary, both[k].summary)
            _same(dict(alone[k].trace.arrays), dict(both[k].trace.arrays))
    assert len({tuple(r[2].summary["cell"]["jacobian_error_cell_median"]) for r in together}) == 3  # 3 tools
    other = load_config(None, [*base, "cell.bores_w_m=[[0.45,0.0,0.30],[0.55,0.15,0.25]]"])
    with pytest.raises(ConfigError, match="cell.bores_w_m"):
        run_cells([cfgs[0], other], [1])


def test_compare_simulates_runs_that_differ_in_insertions_once(tmp_path):
    """``kinadapt compare``: scenarios that differ only in run.insertions form one group (the
    default compare's 72 runs are 48 simulations); a scenario's row is what its runs alone give."""
    from kinadapt_nn.runs.compare import compare_jobs, compare_tasks, draw_tools, load_compare_config, run_compare
    from kinadapt_nn.runs.insertions import run_insertions

    jobs = compare_jobs(load_compare_config(None), tmp_path)
    cells = [[t.jobs[p] for p in ps] for t in compare_tasks(jobs) for ps in t.cells]
    assert len(cells) == 48 and sorted(len(c) for c in cells) == [1] * 24 + [2] * 24
    assert all({j.scenario for j in c} == {"socket_dither", "socket_dither_x3"} for c in cells if len(c) == 2)

    short = [*SOCKET, "run.duration_s=1.5"]
    cfg = load_compare_config(None, ["features=['adjoint']", "families=['nominal']", "n_tools=1", "jobs=1",
                                     f"scenarios={{one={short!r},two={[*short, 'run.insertions=2']!r}}}"])
    rows = run_compare(cfg, tmp_path, progress=False)
    tool = draw_tools(cfg)["nominal"][0]
    for scen, n in (("one", 1), ("two", 2)):
        alone = run_insertions(load_config(None, ["run.progress=false", *short, *tool, "run.features=adjoint",
                                                  f"run.insertions={n}"])).summary
        row = next(r for r in rows if r["scenario"] == scen and r["insertion"] in (None, "all"))
        assert row["jacobian_rel_error_final_median"] == alone["jacobian_rel_error_final"]
        assert row["offset_error_lateral_final_m_median"] == alone["offset_error_lateral_final_m"]


def test_compare_batches_single_episodes_with_the_rows_of_single_runs(tmp_path, monkeypatch):
    """``kinadapt compare`` steps the tools of the same scenarios, features and law together
    (``runs.insertions.run_cells`` on ``runs.batch.run_episodes``), single episodes and each
    tool's insertion prefixes alike; its table is the one-tool-at-a-time path's to the last bit,
    but the wall times."""
    import kinadapt_nn.runs.compare as C

    jobs = C.compare_jobs(C.load_compare_config(None), tmp_path)
    tasks = C.compare_tasks(jobs)
    assert len(tasks) == 6 and all(len(t.cells) == 8 for t in tasks)
    assert sorted(len(t.jobs) for t in tasks) == [8] * 3 + [16] * 3  # bore: 8 tools; socket: 8 tools x (1, 3) insertions
    assert sorted(t.episodes for t in tasks) == [8] * 3 + [24] * 3  # the bar's unit: insertions simulated
    assert all({j.scenario for j in t.jobs} in ({"bore"}, {"socket_dither", "socket_dither_x3"}) for t in tasks)
    assert sorted(j.id for t in tasks for j in t.jobs) == sorted(j.id for j in jobs)
    short = ["run.duration_s=1.5", "start.lateral_jitter_m=0.0003"]
    cfg = C.load_compare_config(None, ["features=['adjoint','neural']", "n_tools=2", "jobs=1",
                                       f"scenarios={{one={short!r},two={[*short, 'run.insertions=2']!r}}}"])
    tables = {}
    for mode in ("batch", "single"):
        if mode == "single":
            monkeypatch.setattr(C, "BATCH_MAX", 1)  # one tool per task: its prefixes, no batch
        out = tmp_path / mode
        out.mkdir()
        rows = C.run_compare(cfg, out, progress=False)
        tables[mode] = [{k: v for k, v in r.items() if k != "wall_time_s_median"} for r in rows]
    _same(tables["batch"], tables["single"])
    assert len(tables["batch"]) == 4 + 4 * 4 and all(r["episodes"] == 2 for r in tables["batch"])  # two: all, 0, 1, 2


def test_refit_prior_choice_is_the_gaussian_evidence_difference():
    """With a second prior, Refit's log-evidence gain equals the difference of the two dense
    Gaussian marginal likelihoods N(yc; 0, H P H' + R/w) at the weights of its last pass, and the
    refit acts on the simpler prior's estimate exactly when the gain is below the threshold."""
    cfg = load_config(None, [BORES, "cell.heldout_per_bore=1"])
    ctrl = make_controller(cfg)
    rng = np.random.default_rng(1)
    P0 = np.asarray(Refit(ctrl).P0)
    alt = np.diag(np.diag(P0)) * np.array([1.0, 1e-6, 1e-6])  # a narrower prior
    rf = Refit(ctrl, channels=(1, 2), prior_weight=2.0, alt_prior_cov=alt, alt_evidence_per_insertion=1e9)
    _synthetic_insertions(rf, rng, insertions=2, rows=30)
    theta_alt, _, _ = rf.solve()
    gain = rf.log_evidence_gain
    assert rf.chose_alt
    th = rf.theta_prior.copy()  # the weights of the last pass, re-derived
    for it in range(3):
        ws = []
        for H, y in rf.data:
            r = y - np.einsum("kmp,p->km", H, th)
            ws.append(1.0 / ((np.mean(r * r, axis=0) + rf.r_floor) * rf.n_eff))
        if it < 2:
            Lam = rf.prior_weight * rf._P0inv + sum(np.einsum("kmp,kmq->pq", H * w[None, :, None], H)
                                                   for (H, _), w in zip(rf.data, ws))
            eta = sum(np.einsum("kmp,km->p", H * w[None, :, None], y - np.einsum("kmp,p->km", H, rf.theta_prior))
                      for (H, y), w in zip(rf.data, ws))
            th = rf.theta_prior + np.linalg.solve(Lam, eta)
    Hs = np.concatenate([H.reshape(-1, 3) for H, _ in rf.data])
    yc = np.concatenate([(y - np.einsum("kmp,p->km", H, rf.theta_prior)).reshape(-1) for H, y in rf.data])
    Rd = np.concatenate([np.tile(1.0 / w, len(H)) for (H, _), w in zip(rf.data, ws)])

    def loglik(C):
        S = Hs @ (C / rf.prior_weight) @ Hs.T + np.diag(Rd)
        return -0.5 * (yc @ np.linalg.solve(S, yc) + np.linalg.slogdet(S)[1])

    assert gain == pytest.approx(loglik(P0) - loglik(alt), rel=1e-8, abs=1e-6)
    rf.alt["per_insertion"] = (gain - 1.0) / len(rf.data)  # below the gain: the refit's own prior
    theta_own, _, _ = rf.solve()
    assert not rf.chose_alt and not np.allclose(theta_own, theta_alt)
