"""The CLI's contract on bad input and on bugs (kinadapt_nn.app.cli's exit-code table):

* bad input -- an option, a config value (NaN/inf anywhere, out of range), a damaged file --
  exits 2 with one line on stderr and writes nothing (no output folder, no MUJOCO_LOG.TXT);
* an internal error exits 3 with one line naming a log file that holds the traceback;
* the pretraining resume state is never unpickled (a planted pickle does not run);
* ``--version``, a description on every subcommand, ``kinadapt config`` lists every key.
"""

from __future__ import annotations

import argparse
import json
import math
import pickle
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import kinadapt_nn
from kinadapt_nn.app.cli import build_parser, main
from kinadapt_nn.config import ExperimentCfg, load_config
from kinadapt_nn.app.config_doc import describe
from kinadapt_nn.errors import ConfigError, KinadaptError
from kinadapt_nn.trace import Trace

TINY_PRETRAIN = ["data.n_train=12", "data.n_heldout=4", "data.n_support=8", "data.n_query=4", "train.steps=6",
                 "train.batch_instances=4", "train.eval_every=3", "train.checkpoint_every=3", "net.hidden=16",
                 "net.n_features=4"]


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    """Run in an empty folder (so a stray MUJOCO_LOG.TXT or output would show) with temp files in it."""
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    return work


def run_cli(capsys, *args: str) -> tuple[int, str, str]:
    rc = main(list(args))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def assert_one_line_bad_input(rc: int, err: str, *fragments: str) -> None:
    assert rc == 2, err
    assert err.startswith("kinadapt: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    for f in fragments:
        assert f in err, (f, err)


# ------------------------------------------------------------------------------ config values
NAN_CASES = [
    ("tool.offset_f_m", "[nan, 0, 0.1]"), ("tool.tilt_deg", "[nan, 0]"), ("start.tilt_deg", "[0, inf]"),
    ("start.lateral_w_m", "[nan, 0]"), ("scene.bore_entry_w_m", "[nan, 0, 0.3]"),
    ("sensing.nominal_offset_f_m", "[0, nan, 0.1]"), ("sensing.channel_scale", "[nan, 10, 10, 1, 1, 1]"),
    ("adaptation.initial_error_dir_f", "[nan, 0, 0]"), ("control.dither_rad_s", "[nan, 0, 0]"),
    ("control.k_depth_N_per_m", "inf"), ("excite.segments", "[[1, 0, 0, 0, 0, 0, -inf]]"),
]


@pytest.mark.parametrize(("key", "value"), NAN_CASES)
def test_non_finite_values_exit_2_one_line_nothing_written(cwd, capsys, key, value):
    rc, out, err = run_cli(capsys, "online", "--out", "run", "--quiet", "--set", f"{key}={value}")
    assert_one_line_bad_input(rc, err, key, "finite")
    assert out == "" and list(cwd.iterdir()) == []  # no run folder, no staging, no MUJOCO_LOG.TXT


def _numeric_leaves() -> list[tuple[str, str]]:
    """(key, JSON value) of every numeric leaf of the experiment config (scalars and vectors)."""
    rows = []
    for r in describe(ExperimentCfg()):
        v = json.loads(r.value)
        if isinstance(v, float) or (isinstance(v, list) and v and all(isinstance(x, float) for x in v)):
            rows.append((r.key, v))
    return rows


def test_every_float_key_refuses_nan_and_inf_naming_the_key():
    leaves = _numeric_leaves()
    assert len(leaves) > 80
    for key, v in leaves:
        for bad in ("nan", "inf", "-inf"):
            text = bad if isinstance(v, float) else "[" + ", ".join([bad] + [repr(x) for x in v[1:]]) + "]"
            with pytest.raises(ConfigError) as exc:
                load_config(None, [f"{key}={text}"])
            assert key in str(exc.value) and "finite" in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize(
    ("override", "fragment"),
    [
        ("tool.offset_f_m=[0, 0, -0.1]", "tool.offset_f_m"),  # tip behind the flange
        ("sensing.nominal_offset_f_m=[0.2, 0, 0.1]", "sensing.nominal_offset_f_m"),
        ("start.tilt_deg=[90, 0]", "start.tilt_deg"),
        ("tool.tilt_deg=[0, 60]", "tool.tilt_deg"),
        ("control.dither_rad_s=[5, 0, 0]", "control.dither_rad_s"),
        ("adaptation.initial_error_dir_f=[1e300, 1e300, 0]", "adaptation.initial_error_dir_f"),
        ("scene.bore_pose_error_m=[0.5, 0, 0]", "scene.bore_pose_error_m"),
        ("effects.ft_frame_rotation.rotvec_deg=[1e6, 0, 0]", "rotvec_deg"),
        ("run.seed=99999999999999999999", "run.seed"),
    ],
)
def test_out_of_range_vectors_are_config_errors(override, fragment):
    with pytest.raises(ConfigError, match=fragment.replace(".", r"\.")):
        load_config(None, [override])


@pytest.mark.parametrize(
    ("loader", "override"),
    [("kinadapt_nn.runs.sweep:load_sweep_config", "lateral_radius_m=nan"),
     ("kinadapt_nn.runs.sweep:load_sweep_config", "grid={'control.beta_ang'=[0.1, inf]}"),
     ("kinadapt_nn.runs.compare:load_compare_config", "link_sigma_m=inf"),
     ("kinadapt_nn.learning.pretrain:load_pretrain_config", "train.lr=nan")],
)
def test_every_config_file_kind_refuses_non_finite_numbers(loader, override):
    import importlib

    mod, _, fn = loader.partition(":")
    with pytest.raises(ConfigError, match="finite|greater"):
        getattr(importlib.import_module(mod), fn)(None, [override])


VECTOR_KEYS = {"tool.offset_f_m": 3, "tool.tilt_deg": 2, "start.lateral_w_m": 2, "start.tilt_deg": 2,
               "scene.bore_entry_w_m": 3, "sensing.nominal_offset_f_m": 3, "sensing.channel_scale": 6,
               "adaptation.initial_error_dir_f": 3, "control.dither_rad_s": 3, "faults.ft_bias_N": 3,
               "effects.ft_bias_drift.rate_f": 6, "effects.tool_gravity.com_f_m": 3}


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(sorted(VECTOR_KEYS)), data=st.data())
def test_vectors_with_any_non_finite_entry_are_refused(key, data):
    n = VECTOR_KEYS[key]
    values = data.draw(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=n, max_size=n))
    text = "[" + ", ".join(repr(x) if math.isfinite(x) else str(x) for x in values) + "]"  # str: nan, inf, -inf
    try:
        cfg = load_config(None, [f"{key}={text}"])
    except ConfigError as exc:
        assert "\n" not in str(exc) and key in str(exc)
        return
    assert all(math.isfinite(x) for x in values)  # accepted only when every entry is finite ...
    section, _, name = key.rpartition(".")
    node = cfg
    for part in section.split("."):
        node = getattr(node, part)
    assert all(math.isfinite(x) for x in getattr(node, name))  # ... and it arrives finite


# ------------------------------------------------------------------------------ every option
def _subparsers() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _value_options() -> list[tuple[str, str]]:
    return sorted((name, opt) for name, sp in _subparsers().items() for a in sp._actions
                  for opt in a.option_strings if opt.startswith("--") and a.nargs != 0 and opt != "--help")


OPTION_VALUES = st.one_of(st.integers(-10**9, 10**9).map(str), st.floats(allow_nan=True, allow_infinity=True).map(repr),
                          st.sampled_from(["nan", "inf", "-inf", "-1", "0", "", "1e999", "abc", "3.5"]),
                          st.text(max_size=10))


@settings(max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])  # capsys: read each time
@given(option=st.sampled_from(_value_options()), value=OPTION_VALUES)
def test_any_option_value_parses_in_range_or_is_one_line_exit_2(capsys, option, value):
    """Every option of every subcommand: parsing either yields an in-range, finite value or exits 2
    with one line (argparse's usage dump replaced)."""
    name, opt = option
    positional = {"view": ["RUN"], "diagnose": ["LOG"]}.get(name, [])
    try:
        args = build_parser().parse_args([name, *positional, f"{opt}={value}"])
    except SystemExit as exc:
        err = capsys.readouterr().err
        assert exc.code == 2 and err.startswith("kinadapt: error: ") and err.count("\n") == 1, err
        return
    parsed = getattr(args, opt[2:].replace("-", "_"))
    if isinstance(parsed, float):
        assert math.isfinite(parsed) and parsed > 0
    if isinstance(parsed, int) and not isinstance(parsed, bool):
        assert parsed >= 1


@pytest.mark.parametrize(
    "argv",
    [["reproduce", "--jobs", "0"], ["reproduce", "--jobs", "-3"], ["reproduce", "--jobs", "two"],
     ["view", "RUN", "--fps", "-1"], ["view", "RUN", "--fps", "nan"], ["view", "RUN", "--width", "0"],
     ["view", "RUN", "--height", "100000"], ["view", "RUN", "--max-s", "inf"], ["sweep", "--executor", "slurm"],
     ["online", "--bogus"], ["nonsense"], []],
)
def test_bad_options_exit_2_with_one_line(cwd, capsys, argv):
    rc, out, err = run_cli(capsys, *argv)
    assert_one_line_bad_input(rc, err, "--help")
    assert list(cwd.iterdir()) == []


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [(["online", "--set", "run.sede=3"], "unknown config key 'run.sede'; did you mean 'run.seed'?"),
     (["online", "--set", "effects.tool_gravity.enabeld=true"], "did you mean 'effects.tool_gravity.enabled'?"),
     (["online", "--set", "model.effects=['contact_stifness']"], "did you mean 'contact_stiffness'?"),
     (["online", "--set", "run.features=adjiont"], "did you mean 'adjoint'?"),
     (["online", "--set", "mode=kalmn"], "did you mean 'kalman'?"),
     (["compare", "--set", "n_tool=2"], "unknown config key 'n_tool'; did you mean 'n_tools'?"),
     (["pretrain", "--set", "train.setps=2"], "did you mean 'train.steps'?"),
     (["onlin"], "invalid choice: 'onlin'; did you mean 'online'?"),
     (["sweep", "--executor", "loacl"], "did you mean 'local'?"),
     (["diagnose", "LOG", "--add", "tool_gravty"], "unknown effect; did you mean 'tool_gravity'?")],
)
def test_a_misspelt_name_gets_the_closest_valid_one(cwd, capsys, argv, fragment):
    """A misspelt config key, effect name or subcommand: one line naming the closest valid one."""
    rc, out, err = run_cli(capsys, *argv)
    assert_one_line_bad_input(rc, err, fragment)
    assert out == "" and list(cwd.iterdir()) == []


def test_nothing_close_means_no_guess(capsys):
    with pytest.raises(ConfigError) as exc:
        load_config(None, ["tool.zzz=1"])
    assert "did you mean" not in str(exc.value) and "check the spelling" in str(exc.value)
    rc, _, err = run_cli(capsys, "xyzzy")
    assert rc == 2 and "did you mean" not in err


def test_bad_option_values_seen_by_the_commands(cwd, capsys):
    rc, _, err = run_cli(capsys, "reproduce", "--only", "everything", "--out", "r")
    assert_one_line_bad_input(rc, err, "--only")
    rc, _, err = run_cli(capsys, "diagnose", "LOG", "--theta", "nan,0,0.1", "--out", "d")
    assert_one_line_bad_input(rc, err, "--theta")
    assert list(cwd.iterdir()) == []


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("short") / "run"
    assert main(["online", "--out", str(out), "--quiet", "--set", "run.duration_s=0.2", "--set", "run.figure=false",
                 "--set", "run.tensorboard=false"]) == 1
    return out


def test_view_refuses_an_unknown_camera_listing_the_cameras(cwd, capsys, short_run):
    rc, _, err = run_cli(capsys, "view", str(short_run), "--out", "v.gif", "--camera", "nope", "--quiet")
    assert_one_line_bad_input(rc, err, "'nope'", "'side'")
    assert list(cwd.iterdir()) == []


# ------------------------------------------------------------------------------ traces
def _trace(n: int = 200, dt: float = 0.001) -> dict[str, np.ndarray]:
    t = np.arange(n) * dt
    return {"t_s": t, "q_rad": np.zeros((n, 7)), "qdot_rad_s": np.zeros((n, 7)), "wrench_raw_f": np.zeros((n, 6))}


@pytest.mark.parametrize(
    ("edit", "fragment"),
    [(lambda a: a["t_s"].__setitem__(50, a["t_s"][49]), "sample 50"),  # time does not increase
     (lambda a: a["t_s"].__setitem__(slice(100, None), a["t_s"][100:] + 0.5), "gap"),
     (lambda a: a["wrench_raw_f"].__setitem__((70, 2), np.nan), "not finite"),
     (lambda a: [a.__setitem__(k, v[:20]) for k, v in list(a.items())], "only 20")],
)
def test_diagnose_applies_the_log_readers_rules_to_traces(cwd, capsys, edit, fragment):
    arrays = _trace()
    edit(arrays)
    Trace(arrays=arrays, meta={}).save(cwd / "trace.npz")
    rc, _, err = run_cli(capsys, "diagnose", "trace.npz", "--out", "d", "--quiet")
    assert_one_line_bad_input(rc, err, "trace.npz", fragment)
    assert sorted(p.name for p in cwd.iterdir()) == ["trace.npz"]


@pytest.mark.parametrize("name", ["robot.csv", "robot.csv.gz", "robot.parquet", "robot_bag"])
def test_a_robot_log_without_setup_is_told_to_pass_one(cwd, capsys, name):
    """A user's own log given without --setup: one line saying to pass one (and where a template
    comes from), never a complaint about an .npz archive."""
    from kinadapt_nn.diagnostics.readers import write_log
    from kinadapt_nn.diagnostics.setup import LogCfg

    if name.endswith("_bag"):
        (cwd / name).mkdir()
        (cwd / name / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    else:
        t = np.arange(100) * 0.01
        write_log(cwd / name, t, np.zeros((100, 7)), None, np.ones((100, 6)), LogCfg())
    rc, _, err = run_cli(capsys, "diagnose", name, "--out", "d", "--quiet")
    assert_one_line_bad_input(rc, err, name, "pass --setup SETUP.toml", "kinadapt setup-template")
    assert "npz" not in err
    assert sorted(p.name for p in cwd.iterdir()) == [name]


def test_trace_load_refuses_time_going_back_and_pickles(tmp_path):
    arrays = _trace()
    arrays["t_s"][10] = 0.0
    Trace(arrays=arrays, meta={}).save(tmp_path / "back.npz")
    with pytest.raises(KinadaptError, match=r"back\.npz', sample 10: the time 't_s' does not increase"):
        Trace.load(tmp_path / "back.npz")
    (tmp_path / "pickle.npz").write_bytes(pickle.dumps({"t_s": [1, 2, 3]}))
    with pytest.raises(KinadaptError) as exc:
        Trace.load(tmp_path / "pickle.npz")
    msg = str(exc.value)
    assert "pickle.npz" in msg and "allow_pickle" not in msg and "\n" not in msg


# ------------------------------------------------------------------------------ pretraining resume state
class _Plant:
    """A pickle that would create ``marker`` when unpickled."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_a_planted_resume_state_is_never_unpickled(tmp_path, capsys):
    out, marker = tmp_path / "p", tmp_path / "PWNED"
    out.mkdir()
    torch.save({"net": _Plant(marker)}, out / "train_state.pt")
    torch.load(out / "train_state.pt", weights_only=False)  # the plant is real: unpickling runs it ...
    assert marker.exists()
    marker.unlink()
    sets = sum((["--set", s] for s in TINY_PRETRAIN), [])
    rc, _, err = run_cli(capsys, "pretrain", "--out", str(out), "--quiet", *sets)
    assert_one_line_bad_input(rc, err, "train_state.pt", "--overwrite")
    assert not marker.exists()  # ... and kinadapt never unpickles it


@pytest.mark.parametrize("content", [b"", b"garbage", pickle.dumps({"format": "kinadapt-train-state"}, protocol=2)])
def test_a_damaged_resume_state_is_one_line_and_overwrite_starts_afresh(tmp_path, capsys, content):
    out = tmp_path / "p"
    out.mkdir()
    (out / "train_state.pt").write_bytes(content)
    sets = sum((["--set", s] for s in TINY_PRETRAIN), [])
    rc, _, err = run_cli(capsys, "pretrain", "--out", str(out), "--quiet", *sets)
    assert_one_line_bad_input(rc, err, "resume state", "--overwrite")
    if content:
        return  # one full (tiny) training run is enough
    rc, _, err = run_cli(capsys, "pretrain", "--out", str(out), "--quiet", "--overwrite", *sets)
    assert rc == 0, err
    assert (out / "model.safetensors").is_file() and not (out / "train_state.pt").exists()


def test_the_resume_state_loads_weights_only(tmp_path):
    from kinadapt_nn.learning.pretrain import load_pretrain_config, load_train_state, pretrain

    cfg = load_pretrain_config(None, TINY_PRETRAIN)
    assert pretrain(cfg, tmp_path, progress=False, stop_after=3) == {"interrupted_at": 3}
    st = torch.load(tmp_path / "train_state.pt", weights_only=True)  # no pickled objects in it
    assert st["step"] == 3 and st["rng"]["bit_generator"] == "PCG64"
    assert load_train_state(tmp_path / "train_state.pt", cfg.model_dump(mode="json"))["step"] == 3
    with pytest.raises(ConfigError, match="different pretrain config"):
        load_train_state(tmp_path / "train_state.pt", {**cfg.model_dump(mode="json"), "seed": 1})


# ------------------------------------------------------------------------------ internal errors, MuJoCo's log
def _boom(*_a, **_k):
    raise RuntimeError("boom: an injected bug")


def test_an_internal_error_exits_3_naming_a_log_with_the_traceback(cwd, capsys, monkeypatch):
    import kinadapt_nn.sim.scenes

    monkeypatch.setattr(kinadapt_nn.sim.scenes, "PegInHoleSim", _boom)  # a bug inside the episode
    rc, _, err = run_cli(capsys, "online", "--out", "run", "--quiet")
    assert rc == 3 and err.count("\n") == 1 and err.startswith("kinadapt: internal error (RuntimeError")
    log = Path(err.split("the traceback is in ")[1].split(" -- ")[0])
    assert log.parent == Path(tempfile.tempdir)
    text = log.read_text()
    assert "Traceback" in text and "RuntimeError: boom: an injected bug" in text
    assert list(cwd.iterdir()) == []


def test_an_internal_error_of_an_in_place_command_logs_into_its_folder(cwd, capsys, monkeypatch):
    import kinadapt_nn.learning.pretrain

    def crash(cfg, out, progress=True):
        Path(out).mkdir(parents=True)
        _boom()

    monkeypatch.setattr(kinadapt_nn.learning.pretrain, "pretrain", crash)
    rc, _, err = run_cli(capsys, "pretrain", "--out", "p", "--quiet")
    assert rc == 3 and "p/kinadapt_error.log" in err
    assert "boom" in (cwd / "p" / "kinadapt_error.log").read_text()


def _mujoco_warning() -> None:
    import mujoco

    m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><joint/><geom size='.1'/></body></worldbody></mujoco>")
    d = mujoco.MjData(m)
    d.qpos[0] = np.nan
    mujoco.mj_checkPos(m, d)  # MuJoCo logs "Nan, Inf or huge value in QPOS"


def test_mujoco_log_goes_to_the_run_folder_never_the_working_directory(cwd, capsys, monkeypatch):
    import kinadapt_nn.sim.scenes

    real = kinadapt_nn.sim.scenes.PegInHoleSim

    def warn_then_build(cfg):
        _mujoco_warning()
        return real(cfg)

    monkeypatch.setattr(kinadapt_nn.sim.scenes, "PegInHoleSim", warn_then_build)
    rc, _, err = run_cli(capsys, "online", "--out", "run", "--set", "run.duration_s=0.1", "--set", "run.figure=false",
                         "--set", "run.tensorboard=false", "--set", "run.progress=false")
    assert rc == 1
    assert "QPOS" in (cwd / "run" / "MUJOCO_LOG.TXT").read_text()
    assert "run/MUJOCO_LOG.TXT" in err
    assert sorted(p.name for p in cwd.iterdir()) == ["run"]

    def warn_then_crash(cfg):
        _mujoco_warning()
        _boom()

    monkeypatch.setattr(kinadapt_nn.sim.scenes, "PegInHoleSim", warn_then_crash)
    rc, _, err = run_cli(capsys, "online", "--out", "run2", "--quiet")
    assert rc == 3 and sorted(p.name for p in cwd.iterdir()) == ["run"]
    log = Path(err.split("the traceback is in ")[1].split(" -- ")[0]).read_text()
    mj = Path(log.split("MuJoCo's log: ")[1].strip())
    assert mj.parent == Path(tempfile.tempdir) and "QPOS" in mj.read_text()


# ------------------------------------------------------------------------------ help, version, config
def test_version(capsys):
    rc, out, _ = run_cli(capsys, "--version")
    assert rc == 0 and out == f"kinadapt {kinadapt_nn.__version__}\n"
    from importlib.metadata import version

    assert version("kinadapt_nn") == kinadapt_nn.__version__


def test_every_subcommand_and_option_is_described():
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in action._choices_actions}
    for name, sp in action.choices.items():
        assert helps.get(name) and sp.description and len(sp.description) > 40, name
        for a in sp._actions:
            assert a.help, (name, a.option_strings or a.dest)


def test_config_lists_every_key_with_value_unit_and_meaning(capsys):
    rc, out, err = run_cli(capsys, "config", "--set", "run.seed=7")
    assert rc == 0 and err == ""
    lines = {ln.split(" = ")[0]: ln for ln in out.splitlines() if not ln.startswith("#")}
    keys = [r.key for r in describe(ExperimentCfg())]
    assert list(lines) == keys and len(keys) > 100
    assert lines["run.seed"].startswith("run.seed = 7 ") and "seeds every random draw" in lines["run.seed"]
    assert "[m]" in lines["tool.offset_f_m"] and "flange frame" in lines["tool.offset_f_m"]
    assert "[N m/rad]" in lines["sensing.stiffness_rot_Nm_per_rad"]
    assert "channel metric W" in lines["sensing.channel_scale"]  # a comment above the field
    for r in describe(ExperimentCfg()):
        assert r.meaning, r.key
    rc, _, err = run_cli(capsys, "config", "--set", "tool.tilt_deg=[nan, 0]")
    assert_one_line_bad_input(rc, err, "tool.tilt_deg")
