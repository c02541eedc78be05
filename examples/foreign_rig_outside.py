"""Foreign rig A, with effects OUTSIDE the diagnosis's library: test logs for ``kinadapt diagnose``.

A sibling of ``examples/foreign_rig.py`` (read its docstring for rig A: frames ``w``/``f``/``s``, the
sensor mount, the tool, the 15 s 500 Hz trajectory with its press-and-slide, the noise and the csv
conventions). Standalone on purpose, like it: this file imports nothing from ``kinadapt_nn``; it loads
``foreign_rig.py`` by its path and uses its trajectory, its MuJoCo wrench and its file layout. ::

    python examples/foreign_rig_outside.py --out DIR [--case NAME ...] [--seed N] [--self-test]

Every case hides ONE physical effect that the diagnosis's effect library does not model. The
effect changes the true tool-on-sensor wrench ``w`` (s axes, about the s origin) BEFORE the csv
sign flip (the csv logs the sensor-on-tool wrench ``-w``) and before the noise; the noise draws
are those of ``foreign_rig.case_signals("none", seed)``, so that ``effect_free`` here and
foreign_rig's ``none`` case are the same log, and any case minus ``effect_free`` is exactly the
(sign-flipped) effect. Cases:

``effect_free``  nothing hidden (foreign_rig's ``none``, written by this file).
``world_pull``   a hose clamped on the tool at ``P_CLAMP_S_M`` (s frame) pulls with a constant WORLD
                 force ``F_PULL_W_N``: ``w += (R_ws^T F, p x R_ws^T F)``.
``crosstalk``    a calibration-matrix error: the sensor reports ``(I + E) w`` with E sparse
                 (``CROSSTALK_E``, rows/cols Fx Fy Fz Tx Ty Tz).
``temperature``  a warm-up plus a cycling fan: an extra logged column ``temp_C`` (true temperature
                 T(t) plus N(0, 0.02 degC)); the offset follows the TRUE temperature:
                 ``w += K (T(t) - T(0))``.
``joint_drag``   a dragging cable whose pull depends on the joint velocities: ``w += D qdot_true``.
``pose_cable``   a cable from a fixed world anchor, a spring with zero rest length on the sensor
                 origin's position: ``F_w = k (anchor_w - p_ws)``, acting at the clamp point.

Per case ``DIR/<case>/``: ``log.csv.gz`` (foreign_rig's layout; the temperature case adds a last
column ``temp_C``), ``setup_csv.toml`` (foreign_rig's nominal csv setup; the temperature case adds
``extra = ["temp_C"]`` to ``[log]``) and ``truth.json`` (the hidden effect: ``expected_hint_shape``,
``acceptable_hint_shapes``, the true parameters in SI units in the tool-on-sensor convention, the
RMS and the standard deviation of the change per channel).
"""

from __future__ import annotations

import argparse
import functools
import gzip
import importlib.util
import io
import json
import math
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

_RIG_PY = Path(__file__).resolve().parent / "foreign_rig.py"


def _load_foreign_rig():
    """The sibling ``foreign_rig`` module (by path; shared with whoever loaded it first, so that
    its cached trajectory and wrench are computed once)."""
    mod = sys.modules.get("foreign_rig")
    if mod is not None and Path(getattr(mod, "__file__", "")).resolve() == _RIG_PY:
        return mod
    spec = importlib.util.spec_from_file_location("foreign_rig", _RIG_PY)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["foreign_rig"] = mod
    spec.loader.exec_module(mod)
    return mod


fr = _load_foreign_rig()

CHANNELS = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")

# --- the hidden effects (tool-on-sensor convention, SI units) ---------------------------------------
P_CLAMP_S_M = (0.0, 0.035, 0.10)  # [m] where the hose / cable is clamped on the tool, s frame
F_PULL_W_N = (2.0, 1.2, -0.6)  # [N] world_pull: constant world-frame pull on the tool
# crosstalk: (row, col) -> E entry; the sensor reports (I + E) w (force <- force: -, moment <- force: m)
CROSSTALK_E = {(1, 0): 0.04, (2, 2): 0.03, (3, 1): 0.010, (5, 0): -0.006}
TEMP_C0 = 24.0  # [degC] temperature at power-up (before the warm-up)
TEMP_WARMUP_K = 3.0  # [K] warm-up amplitude
TEMP_WARMUP_TAU_S = 20.0  # [s] warm-up time constant
TEMP_FAN_K = 1.2  # [K] fan-cycle amplitude
TEMP_FAN_PERIOD_S = 4.0  # [s]
TEMP_FAN_PHASE_RAD = 0.3
SIGMA_TEMP_C = 0.02  # [degC] noise of the logged temperature
TEMP_K = (0.25, -0.15, 0.35, 0.012, -0.009, 0.006)  # [N/K, N m/K] offset per K of the true temperature
_TEMP_NOISE_STREAM = 0x7E3A  # the temperature noise's own stream (the other draws stay foreign_rig's)
# joint_drag: (row, joint index 0..6) -> D entry [N/(rad/s), N m/(rad/s)]
DRAG_D = {(0, 0): 1.5, (1, 3): -2.0, (4, 5): 0.08}
CABLE_K_N_M = 8.0  # [N/m] pose_cable stiffness (zero rest length)
CABLE_ANCHOR_W_M = (0.20, -0.16, 0.80)  # [m] ~0.29 m from the home sensor origin (0.307, 0, 0.578)

CASES: dict[str, str] = {
    "effect_free": "no hidden effect: foreign_rig's 'none' case (same samples, same noise), written by this file",
    "world_pull": "a hose clamped at (0, 0.035, 0.10) m (sensor frame) pulls the tool with a constant world-frame "
                  "force (2.0, 1.2, -0.6) N",
    "crosstalk": "F/T calibration-matrix error: the sensor reports (I + E) w with Fy += 0.04 Fx, Fz gain +3 %, "
                 "Tx += 0.010 m * Fy, Tz += -0.006 m * Fx",
    "temperature": "sensor warm-up + cycling fan (logged column temp_C): the wrench offset follows the temperature, "
                   "K = (0.25, -0.15, 0.35) N/K, (0.012, -0.009, 0.006) N m/K",
    "joint_drag": "a dragging cable whose pull depends on the joint velocities: Fx += 1.5 qdot1, Fy += -2.0 qdot4 "
                  "[N/(rad/s)], Ty += 0.08 qdot6 [N m/(rad/s)]",
    "pose_cable": "a cable (8 N/m, zero rest length) from a fixed world anchor ~0.29 m away pulls the clamp point "
                  "(0, 0.035, 0.10) m with k (anchor - sensor origin)",
}

_HINTS: dict[str, tuple[str, ...]] = {  # expected hint shape first
    "world_pull": ("world_force",),
    "crosstalk": ("wrench_linear",),
    "temperature": ("extra:temp_C",),
    "joint_drag": ("joint_velocity",),
    "pose_cable": ("world_force", "joint_position"),
}


# ==================================================================================================
# the rig's kinematics and the hidden changes
# ==================================================================================================
@functools.lru_cache(maxsize=1)
def sensor_pose() -> tuple[np.ndarray, np.ndarray]:
    """(R_ws (N, 3, 3), p_ws (N, 3) [m]) of the sensor frame (MuJoCo site ``ft``) along rig A's
    TRUE trajectory; columns of R_ws = the sensor axes in the world (cached, read-only)."""
    tr = fr.trajectory()
    m = fr.build_model()
    d = mujoco.MjData(m)
    sid = m.site("ft").id
    r, p = np.empty((len(tr.q), 3, 3)), np.empty((len(tr.q), 3))
    for i, q in enumerate(tr.q):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        r[i] = d.site_xmat[sid].reshape(3, 3)
        p[i] = d.site_xpos[sid]
    r.setflags(write=False)
    p.setflags(write=False)
    return r, p


def temperature_true(t: np.ndarray) -> np.ndarray:
    """True sensor temperature [degC] at ``t`` [s from the first sample]."""
    t = np.asarray(t, dtype=float)
    return (TEMP_C0 + TEMP_WARMUP_K * (1.0 - np.exp(-t / TEMP_WARMUP_TAU_S))
            + TEMP_FAN_K * np.sin(2.0 * np.pi * t / TEMP_FAN_PERIOD_S + TEMP_FAN_PHASE_RAD))


def _matrix(entries: dict[tuple[int, int], float], shape: tuple[int, int]) -> np.ndarray:
    a = np.zeros(shape)
    for (i, j), v in entries.items():
        a[i, j] = v
    return a


def _wrench_of_world_force(f_w: np.ndarray) -> np.ndarray:
    """(N, 6) tool-on-sensor change from world forces ``f_w`` (N, 3) [N] on the tool at the clamp."""
    r_ws, _ = sensor_pose()
    f_s = np.einsum("nji,nj->ni", r_ws, f_w)  # R_ws^T F
    return np.hstack([f_s, np.cross(np.asarray(P_CLAMP_S_M), f_s)])


def cable_force_w() -> np.ndarray:
    """pose_cable: the cable's world force on the tool (N, 3) [N] along the true trajectory."""
    _, p_ws = sensor_pose()
    return CABLE_K_N_M * (np.asarray(CABLE_ANCHOR_W_M)[None, :] - p_ws)


def hidden_change(name: str) -> np.ndarray:
    """The change (N, 6) [N, N m] of the noiseless tool-on-sensor wrench (s axes, about the s
    origin) that case ``name`` hides (zeros for ``effect_free``)."""
    if name not in CASES:
        raise KeyError(f"unknown case '{name}' (choose from {', '.join(CASES)})")
    tr = fr.trajectory()
    w = np.asarray(fr.true_wrench())
    if name == "effect_free":
        return np.zeros_like(w)
    if name == "world_pull":
        return _wrench_of_world_force(np.tile(np.asarray(F_PULL_W_N), (len(w), 1)))
    if name == "crosstalk":
        return w @ _matrix(CROSSTALK_E, (6, 6)).T
    if name == "temperature":
        temp = temperature_true(tr.t)
        return (temp - temp[0])[:, None] * np.asarray(TEMP_K)[None, :]
    if name == "joint_drag":
        return tr.qd @ _matrix(DRAG_D, (6, 7)).T
    if name == "pose_cable":
        return _wrench_of_world_force(cable_force_w())
    raise AssertionError(name)


def case_signals(name: str, seed: int = 0, noise: bool = True) -> dict:
    """The logged signals of case ``name`` (csv conventions, like ``foreign_rig.case_signals``).

    ``t``, ``q``, ``qdot`` as foreign_rig's ``none`` case; ``wrench`` (N, 6) the sensor-on-tool
    wrench = foreign_rig's ``none`` wrench - ``change`` (same noise draws); ``change`` (N, 6) the
    hidden change of the tool-on-sensor wrench; ``w_tool_on_sensor_s`` (N, 6) the noiseless
    tool-on-sensor wrench WITH the hidden effect (= foreign_rig's + ``change``); ``extra`` {column:
    (N,)} extra logged columns (``temp_C`` for the temperature case, with its own noise stream).
    """
    base = fr.case_signals("none", seed, noise=noise)
    dw = hidden_change(name)
    sig = {"t": base["t"], "q": base["q"], "qdot": base["qdot"],
           "wrench": base["wrench"] - dw,  # csv: sensor_on_tool; x - 0.0 == x, so effect_free is bitwise 'none'
           "change": dw, "w_tool_on_sensor_s": base["w_tool_on_sensor_s"] + dw, "extra": {}}
    if name == "temperature":
        temp = temperature_true(base["t"])
        if noise:
            temp = temp + np.random.default_rng([int(seed), _TEMP_NOISE_STREAM]).normal(0.0, SIGMA_TEMP_C, temp.shape)
        sig["extra"]["temp_C"] = temp
    return sig


# ==================================================================================================
# files
# ==================================================================================================
_EXTRA_FMT = {"temp_C": "%.4f"}


def write_csv_gz(path: Path, sig: dict) -> None:
    """foreign_rig's ``log.csv.gz`` (same header, formats and gzip header) plus ``sig["extra"]``'s
    columns at the end."""
    extra = sig.get("extra", {})
    stamps = fr.STAMP0_NS + np.round(sig["t"] * 1e9).astype(np.int64)
    block = np.hstack([sig["q"], sig["qdot"], sig["wrench"], *(np.asarray(v)[:, None] for v in extra.values())])
    buf = io.StringIO()
    fmt = ["%.10f"] * 7 + ["%.8f"] * 7 + ["%.6f"] * 6 + [_EXTRA_FMT.get(k, "%.6f") for k in extra]
    np.savetxt(buf, block, fmt=fmt, delimiter=",")
    header = ",".join((fr.CSV_TIME, *fr.CSV_Q, *fr.CSV_QDOT, *fr.CSV_WRENCH, *extra))
    body = "\n".join(f"{s},{line}" for s, line in zip(stamps.tolist(), buf.getvalue().splitlines()))
    with open(path, "wb") as fh, gzip.GzipFile(filename="", mode="wb", fileobj=fh, mtime=0) as gz:
        gz.write((header + "\n" + body + "\n").encode())


def setup_text(extra: tuple[str, ...] = ()) -> str:
    """foreign_rig's nominal csv setup (untared); ``extra`` columns declared in ``[log]``."""
    text = fr.setup_toml("csv", False)
    if not extra:
        return text
    start = text.index("[log]\n")
    end = text.index("\n\n", start)  # the blank line that closes [log]
    line = "extra = [" + ", ".join(json.dumps(c) for c in extra) + "]"
    return text[:end] + "\n" + line + text[end:]


def _params(name: str) -> tuple[dict, dict]:
    """(true parameters, their units) of case ``name``, tool-on-sensor convention, SI."""
    if name == "world_pull":
        p = dict(zip(("fx_w", "fy_w", "fz_w"), F_PULL_W_N))
        p["clamp_s_m"] = list(P_CLAMP_S_M)
        return p, {"fx_w": "N", "fy_w": "N", "fz_w": "N", "clamp_s_m": "m"}
    if name == "crosstalk":
        p = {f"e_{CHANNELS[i]}_{CHANNELS[j]}": v for (i, j), v in CROSSTALK_E.items()}
        return p, {k: ("m" if k[2] == "T" else "-") for k in p}
    if name == "temperature":
        keys = [f"k_{c.lower()}" for c in CHANNELS]
        return dict(zip(keys, TEMP_K)), {k: ("N/K" if k[2] == "f" else "N m/K") for k in keys}
    if name == "joint_drag":
        p = {f"d_{CHANNELS[i]}_qdot{j + 1}": v for (i, j), v in DRAG_D.items()}
        return p, {k: ("N/(rad/s)" if k[2] == "F" else "N m/(rad/s)") for k in p}
    if name == "pose_cable":
        mean_f = cable_force_w().mean(axis=0)
        p = {"k_N_per_m": CABLE_K_N_M, "anchor_w_m": list(CABLE_ANCHOR_W_M), "clamp_s_m": list(P_CLAMP_S_M),
             "mean_force_w_N": [float(x) for x in mean_f]}
        return p, {"k_N_per_m": "N/m", "anchor_w_m": "m", "clamp_s_m": "m", "mean_force_w_N": "N"}
    return {}, {}


# the same parameters under the names of the user effect files in examples/effects/
_EFFECT_FILE = {
    "world_pull": ("examples/effects/cable_pull.py", lambda: dict(zip(("fx_w", "fy_w", "fz_w"), F_PULL_W_N))),
    "crosstalk": ("examples/effects/crosstalk.py",
                  lambda: {"fy_from_fx": CROSSTALK_E[1, 0], "fz_gain": CROSSTALK_E[2, 2],
                           "tx_from_fy": CROSSTALK_E[3, 1], "tz_from_fx": CROSSTALK_E[5, 0]}),
    "temperature": ("examples/effects/temperature_bias.py",
                    lambda: dict(zip((f"k_{c.lower()}" for c in CHANNELS), TEMP_K))),
}


def truth(name: str, seed: int = 0) -> dict:
    """The truth.json content of case ``name``."""
    dw = hidden_change(name)
    params, units = _params(name)
    hints = _HINTS.get(name, ())
    out = {"case": name, "description": CASES[name], "outside_library": name != "effect_free",
           "expected_hint_shape": hints[0] if hints else None, "acceptable_hint_shapes": list(hints),
           "params": params, "units": units,
           "convention": "params and rms_change act on the tool-on-sensor wrench (s axes, about the s origin); "
                         "the csv logs the sensor-on-tool wrench (its negation)",
           "rms_change": {c: float(v) for c, v in zip(CHANNELS, np.sqrt(np.mean(dw**2, axis=0)))},
           "std_change": {c: float(v) for c, v in zip(CHANNELS, np.std(dw, axis=0))},  # what a constant offset leaves
           "noise_sd": dict(zip(CHANNELS, [fr.SIGMA_FORCE_N] * 3 + [fr.SIGMA_TORQUE_NM] * 3))}
    if name in _EFFECT_FILE:
        path, p = _EFFECT_FILE[name]
        out["effect_file"] = {"path": path, "params": p()}
    if name == "temperature":
        out["temperature"] = {"column": "temp_C", "t0_C": TEMP_C0, "warmup_K": TEMP_WARMUP_K,
                              "warmup_tau_s": TEMP_WARMUP_TAU_S, "fan_K": TEMP_FAN_K,
                              "fan_period_s": TEMP_FAN_PERIOD_S, "fan_phase_rad": TEMP_FAN_PHASE_RAD,
                              "noise_sd_C": SIGMA_TEMP_C,
                              "bias": "K (T_true(t) - T_true(0)); T_true = t0 + warmup (1 - exp(-t/tau)) "
                                      "+ fan sin(2 pi t / period + phase)"}
    tr = fr.trajectory()
    out["seed"] = int(seed)
    out["rig"] = {"name": "A", "table_z_m": tr.table_z_m, "contact_s": list(tr.contact_s), "mu": fr.MU,
                  "normal_force_N": fr.NORMAL_FORCE_N}
    return out


def make_case(name: str, out_dir: Path, seed: int = 0) -> Path:
    """Write case ``name`` into ``out_dir/name/`` (log.csv.gz, setup_csv.toml, truth.json) and
    return that folder."""
    if name not in CASES:
        raise KeyError(f"unknown case '{name}' (choose from {', '.join(CASES)})")
    case_dir = Path(out_dir) / name
    case_dir.mkdir(parents=True, exist_ok=True)
    sig = case_signals(name, seed)
    write_csv_gz(case_dir / "log.csv.gz", sig)
    (case_dir / "setup_csv.toml").write_text(setup_text(tuple(sig["extra"])))
    (case_dir / "truth.json").write_text(json.dumps(truth(name, seed), indent=2) + "\n")
    return case_dir


# ==================================================================================================
# self-test
# ==================================================================================================
def self_test(tol: float = 1e-9, stride: int = 5) -> dict[str, float]:
    """Check the hidden changes by independent routes; returns the largest errors, raises
    AssertionError beyond ``tol``.

    (1) world_pull and pose_cable through MuJoCo's physics: every ``stride``-th sample, the pull
    applied through ``xfrc_applied`` (with the table's tip force) and read by foreign_rig's sensor
    path equals ``true_wrench + change``; (2) the sensor axes from the ``ft`` site equal the flange
    site's axes times the declared mount rotation; (3) effect_free equals foreign_rig's ``none``
    case (bitwise); (4) the temperature change is 0 at t = 0 and K (T - T0) elsewhere.
    """
    tr = fr.trajectory()
    m = fr.build_model()
    d = mujoco.MjData(m)
    ids = fr._Ids(m)
    fl = m.site(fr.FLANGE_SITE).id
    r_ws, p_ws = sensor_pose()
    w0 = np.asarray(fr.true_wrench())
    pulls = {"world_pull": np.tile(np.asarray(F_PULL_W_N), (len(tr.t), 1)), "pose_cable": cable_force_w()}
    changes = {n: hidden_change(n) for n in pulls}
    err = {"world_pull_physics": 0.0, "pose_cable_physics": 0.0, "sensor_axes": 0.0, "sensor_origin": 0.0,
           "effect_free": 0.0, "temperature": 0.0}
    r_fs = fr.rpy_matrix_deg(fr.SENSOR_RPY_F_DEG)
    clamp = np.asarray(P_CLAMP_S_M)
    for i in range(0, len(tr.t), stride):
        d.qpos[:], d.qvel[:], d.qacc[:] = tr.q[i], tr.qd[i], tr.qdd[i]
        mujoco.mj_kinematics(m, d)
        r_wf = d.site_xmat[fl].reshape(3, 3)
        err["sensor_axes"] = max(err["sensor_axes"], float(np.abs(r_wf @ r_fs - r_ws[i]).max()))
        p_s = d.site_xpos[fl] + r_wf @ np.asarray(fr.SENSOR_POS_F_M)
        err["sensor_origin"] = max(err["sensor_origin"], float(np.abs(p_s - p_ws[i]).max()))
        p_clamp_w = d.site_xpos[ids.ft] + d.site_xmat[ids.ft].reshape(3, 3) @ clamp
        f_tip = tr.f_tip_w[i]
        tau_tip = np.cross(d.site_xpos[ids.tip] - d.xipos[ids.tool], f_tip)
        for n, f in pulls.items():
            d.xfrc_applied[ids.tool, :3] = f_tip + f[i]
            d.xfrc_applied[ids.tool, 3:] = tau_tip + np.cross(p_clamp_w - d.xipos[ids.tool], f[i])
            w = fr._read_tool_on_sensor(m, d, ids)
            e = float(np.abs(w - (w0[i] + changes[n][i])).max())
            err[f"{n}_physics"] = max(err[f"{n}_physics"], e)
    seed = 0
    a, b = fr.case_signals("none", seed), case_signals("effect_free", seed)
    err["effect_free"] = max(float(np.abs(a[k] - b[k]).max()) for k in ("t", "q", "qdot", "wrench"))
    temp = temperature_true(tr.t)
    dt = hidden_change("temperature")
    err["temperature"] = max(float(np.abs(dt[0]).max()),
                             float(np.abs(dt - np.outer(temp - TEMP_C0 - TEMP_FAN_K * math.sin(TEMP_FAN_PHASE_RAD),
                                                        TEMP_K)).max()))
    bad = {k: v for k, v in err.items() if not v <= tol}
    if bad:
        raise AssertionError(f"foreign_rig_outside self-test failed: {bad}")
    return err


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Write rig-A test logs that hide an effect outside the diagnosis's "
                                            "library, for `kinadapt diagnose`.")
    p.add_argument("--out", type=Path, required=True, help="output folder (one subfolder per case)")
    p.add_argument("--case", nargs="+", default=None, choices=list(CASES), help="cases (default: all)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--self-test", action="store_true",
                   help="check foreign_rig's MuJoCo wrench and this file's hidden changes first")
    a = p.parse_args(argv)
    if a.self_test:
        print("foreign_rig self-test max errors:", {k: f"{v:.1e}" for k, v in fr.self_test().items()})
        print("outside self-test max errors:", {k: f"{v:.1e}" for k, v in self_test().items()})
    for name in (list(CASES) if a.case is None else a.case):
        t0 = time.perf_counter()
        d = make_case(name, a.out, a.seed)
        rms = truth(name, a.seed)["rms_change"]
        print(f"{d}: {', '.join(sorted(x.name for x in d.iterdir()))} ({time.perf_counter() - t0:.2f} s); "
              f"RMS change {' '.join(f'{c} {v:.3g}' for c, v in rms.items())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
