"""The outside-the-library logs (examples/foreign_rig_outside.py) and the user effect files
(examples/effects/): physics, conventions and files.

Nothing here imports ``kinadapt_nn``: the two example modules are loaded by path, the hidden changes
are recomputed independently (flange site x declared mount for the sensor axes, literal parameter
values), and the effect files are run with a stand-in for ``kinadapt_nn.diagnostics.effect`` (their
import is answered by a stub inside their own namespace; ``sys.modules`` is not touched).
"""

from __future__ import annotations

import builtins
import gzip
import json
import tomllib
import types
from pathlib import Path

import mujoco
import numpy as np
import pytest
from tests.diagnostics.example_scripts import load_example

ROOT = Path(__file__).resolve().parents[2]
RIG_PY = ROOT / "examples" / "foreign_rig.py"
OUTSIDE_PY = ROOT / "examples" / "foreign_rig_outside.py"
EFFECTS = ROOT / "examples" / "effects"
SEED = 5
CASES = ("effect_free", "world_pull", "crosstalk", "temperature", "joint_drag", "pose_cable")
CSV_TOL = 2e-6  # two values printed with 6 decimals


fr = load_example("foreign_rig")
fo = load_example("foreign_rig_outside")


def _read_csv(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(header, stamps (N,) int64 [ns], the other columns (N, k))."""
    with gzip.open(path, "rt") as fh:
        header = fh.readline().strip().split(",")
        rows = [line.split(",") for line in fh.read().splitlines()]
    return header, np.array([int(r[0]) for r in rows], dtype=np.int64), np.array([[float(x) for x in r[1:]]
                                                                                   for r in rows])


@pytest.fixture(scope="module")
def case_dirs(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("outside")
    return {n: fo.make_case(n, out, seed=SEED) for n in CASES}


@pytest.fixture(scope="module")
def logs(case_dirs) -> dict[str, tuple[list[str], np.ndarray, np.ndarray]]:
    return {n: _read_csv(d / "log.csv.gz") for n, d in case_dirs.items()}


@pytest.fixture(scope="module")
def pose() -> tuple[np.ndarray, np.ndarray]:
    """(R_ws, p_ws) of the sensor from the FLANGE site and the declared mount (not the ft site)."""
    tr = fr.trajectory()
    m = fr.build_model()
    d = mujoco.MjData(m)
    fl = m.site(fr.FLANGE_SITE).id
    r_fs, p_fs = fr.rpy_matrix_deg(fr.SENSOR_RPY_F_DEG), np.asarray(fr.SENSOR_POS_F_M)
    r, p = np.empty((len(tr.q), 3, 3)), np.empty((len(tr.q), 3))
    for i, q in enumerate(tr.q):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        r_wf = d.site_xmat[fl].reshape(3, 3)
        r[i], p[i] = r_wf @ r_fs, d.site_xpos[fl] + r_wf @ p_fs
    return r, p


def _pull(r_ws: np.ndarray, f_w: np.ndarray, clamp=(0.0, 0.035, 0.10)) -> np.ndarray:
    """Tool-on-sensor change (N, 6) of world forces f_w (N, 3) at the clamp point (s frame)."""
    f_s = np.einsum("nji,nj->ni", r_ws, f_w)
    return np.hstack([f_s, np.cross(np.asarray(clamp), f_s)])


def _temperature(t: np.ndarray) -> np.ndarray:
    return 24.0 + 3.0 * (1.0 - np.exp(-t / 20.0)) + 1.2 * np.sin(2.0 * np.pi * t / 4.0 + 0.3)


K_TEMP = np.array([0.25, -0.15, 0.35, 0.012, -0.009, 0.006])


def _expected_change(name: str, pose) -> np.ndarray:
    """The hidden change of the tool-on-sensor wrench (N, 6), recomputed here."""
    tr = fr.trajectory()
    r_ws, p_ws = pose
    w = np.asarray(fr.true_wrench())
    if name == "effect_free":
        return np.zeros_like(w)
    if name == "world_pull":
        return _pull(r_ws, np.tile([2.0, 1.2, -0.6], (len(w), 1)))
    if name == "crosstalk":
        e = np.zeros((6, 6))
        e[1, 0], e[2, 2], e[3, 1], e[5, 0] = 0.04, 0.03, 0.010, -0.006
        return (e @ w.T).T
    if name == "temperature":
        temp = _temperature(tr.t)
        return np.outer(temp - temp[0], K_TEMP)
    if name == "joint_drag":
        out = np.zeros_like(w)
        out[:, 0], out[:, 1], out[:, 4] = 1.5 * tr.qd[:, 0], -2.0 * tr.qd[:, 3], 0.08 * tr.qd[:, 5]
        return out
    if name == "pose_cable":
        return _pull(r_ws, 8.0 * (np.array([0.20, -0.16, 0.80]) - p_ws))
    raise KeyError(name)


def test_generator_does_not_import_the_package():
    src = OUTSIDE_PY.read_text()
    assert "import kinadapt_nn" not in src and "from kinadapt_nn" not in src
    assert set(fo.CASES) == set(CASES)


def test_self_test():
    err = fo.self_test(stride=25)
    assert max(err.values()) < 1e-9


def test_effect_free_is_foreign_rigs_none(case_dirs, tmp_path):
    """(a) the same signals and the same log.csv.gz bytes as foreign_rig's 'none' case."""
    a, b = fr.case_signals("none", SEED), fo.case_signals("effect_free", SEED)
    for k in ("t", "q", "qdot", "wrench"):
        assert np.array_equal(a[k], b[k]), k
    ref = fr.make_case("none", tmp_path, seed=SEED)
    assert (ref / "log.csv.gz").read_bytes() == (case_dirs["effect_free"] / "log.csv.gz").read_bytes()
    assert (ref / "setup_csv.toml").read_text() == (case_dirs["effect_free"] / "setup_csv.toml").read_text()


@pytest.mark.parametrize("case", CASES[1:])
def test_change_is_the_hidden_effect(case, logs, pose):
    """(b) case - effect_free (same noise draws) = - the hidden change (csv: sensor_on_tool), and
    only the wrench differs; the change is well above the noise."""
    _, s0, free = logs["effect_free"]
    _, s1, data = logs[case]
    assert np.array_equal(s0, s1)
    assert np.array_equal(data[:, :14], free[:, :14])  # q, qdot untouched
    expect = _expected_change(case, pose)
    np.testing.assert_allclose(-(data[:, 14:20] - free[:, 14:20]), expect, atol=CSV_TOL, rtol=0)
    np.testing.assert_allclose(fo.hidden_change(case), expect, atol=1e-12, rtol=0)  # unrounded
    noise = np.array([fr.SIGMA_FORCE_N] * 3 + [fr.SIGMA_TORQUE_NM] * 3)
    assert np.max(np.std(expect, axis=0) / noise) > 2.5  # some channel well above the noise


def test_temperature_column(logs):
    header, _, data = logs["temperature"]
    temp = data[:, header.index("temp_C") - 1]
    dev = temp - _temperature(fr.trajectory().t)
    assert abs(dev.mean()) < 0.002 and dev.std() == pytest.approx(0.02, rel=0.1)
    assert temp.max() - temp.min() > 3.0


def test_files(case_dirs, logs):
    """(c) columns, setup files, truth files."""
    base = ["stamp_ns", *(f"pos_j{j}" for j in range(1, 8)), *(f"vel_j{j}" for j in range(1, 8)),
            "F_x", "F_y", "F_z", "T_x", "T_y", "T_z"]
    nominal = fr.setup_toml("csv", False)
    for n, d in case_dirs.items():
        assert sorted(x.name for x in d.iterdir()) == ["log.csv.gz", "setup_csv.toml", "truth.json"]
        header, stamps, data = logs[n]
        assert header == base + (["temp_C"] if n == "temperature" else [])
        assert data.shape == (fr.N_SAMPLES, len(header) - 1)
        assert stamps[0] == fr.STAMP0_NS and np.all(np.diff(stamps) == 2_000_000)
        text = (d / "setup_csv.toml").read_text()
        cfg, ref = tomllib.loads(text), tomllib.loads(nominal)
        if n == "temperature":
            assert cfg["log"].pop("extra") == ["temp_C"]
        else:
            assert text == nominal
        assert cfg == ref
        t = json.loads((d / "truth.json").read_text())
        assert t["case"] == n and t["seed"] == SEED and t["outside_library"] is (n != "effect_free")
        assert (t["expected_hint_shape"] in t["acceptable_hint_shapes"]) if n != "effect_free" else (
            t["expected_hint_shape"] is None)
    t = {n: json.loads((d / "truth.json").read_text()) for n, d in case_dirs.items()}
    assert t["world_pull"]["params"] == {"fx_w": 2.0, "fy_w": 1.2, "fz_w": -0.6, "clamp_s_m": [0.0, 0.035, 0.1]}
    assert t["world_pull"]["expected_hint_shape"] == "world_force"
    assert t["crosstalk"]["params"] == {"e_Fy_Fx": 0.04, "e_Fz_Fz": 0.03, "e_Tx_Fy": 0.010, "e_Tz_Fx": -0.006}
    assert t["crosstalk"]["expected_hint_shape"] == "wrench_linear"
    assert t["temperature"]["params"] == dict(zip(("k_fx", "k_fy", "k_fz", "k_tx", "k_ty", "k_tz"), K_TEMP.tolist()))
    assert t["temperature"]["expected_hint_shape"] == "extra:temp_C"
    assert t["joint_drag"]["params"] == {"d_Fx_qdot1": 1.5, "d_Fy_qdot4": -2.0, "d_Ty_qdot6": 0.08}
    assert t["joint_drag"]["expected_hint_shape"] == "joint_velocity"
    assert set(t["pose_cable"]["acceptable_hint_shapes"]) == {"world_force", "joint_position"}


# ==================================================================================================
# the user effect files, run with a stand-in decorator
# ==================================================================================================
def _run_effect_file(path: Path) -> tuple[dict, dict]:
    """Execute an effect file; ``from kinadapt_nn.diagnostics import effect`` gets a recording stub.
    -> (its namespace, {function name: the decorator's kwargs})."""
    recorded: dict[str, dict] = {}

    def effect(**kw):
        def deco(fn):
            recorded[fn.__name__] = kw
            return fn
        return deco

    stub = types.SimpleNamespace(effect=effect)
    real_import = builtins.__import__

    def imp(name, globals=None, locals=None, fromlist=(), level=0):
        if name == "kinadapt_nn.diagnostics":
            return stub
        if name.split(".")[0] == "kinadapt_nn":
            raise ImportError(f"an effect file should need only kinadapt_nn.diagnostics.effect, not {name}")
        return real_import(name, globals, locals, fromlist, level)

    ns = {"__builtins__": {**vars(builtins), "__import__": imp}, "__name__": f"effect_file_{path.stem}"}
    exec(compile(path.read_text(), str(path), "exec"), ns)
    return ns, recorded


@pytest.fixture(scope="module")
def state(pose):
    """What an effect sees (noiseless truth of the rig; only the attributes the files use)."""
    tr = fr.trajectory()
    return types.SimpleNamespace(t=tr.t, q=tr.q, qdot=tr.qd, R_ws=pose[0], p_ws=pose[1],
                                 wrench=np.asarray(fr.true_wrench()),
                                 extra={"temp_C": _temperature(tr.t)})


@pytest.mark.parametrize("stem, case", [("cable_pull", "world_pull"), ("crosstalk", "crosstalk"),
                                        ("temperature_bias", "temperature")])
def test_effect_files(stem, case, state, pose, case_dirs):
    path = EFFECTS / f"{stem}.py"
    src = path.read_text()
    assert len(src.splitlines()) <= 30 and src.lstrip().startswith('"""') and "kinadapt effect file" in src
    ns, rec = _run_effect_file(path)
    kw = rec[stem]
    assert set(kw) <= {"params", "relevant", "doc", "excite", "one_of"} and isinstance(kw["doc"], str)
    names = list(kw["params"])
    assert len(kw["relevant"]) == len(names) and all(r > 0 for r in kw["relevant"])
    cols = ns[stem](state)
    assert cols.shape == (len(state.t), 6, len(names))
    truth = json.loads((case_dirs[case] / "truth.json").read_text())["effect_file"]
    assert truth["path"] == f"examples/effects/{stem}.py" and list(truth["params"]) == names
    theta = np.array([truth["params"][n] for n in names])
    expect = _expected_change(case, pose)
    np.testing.assert_allclose(cols @ theta, expect, atol=1e-12, rtol=0)
