"""Coverage of the diagnosis's 95 % intervals over re-noised logs of the independent rigs (issue 38, "Honest
numbers"): does ``estimate ± 1.96 sd`` contain the truth in 95 % of the draws?

    python benchmarks/interval_coverage.py [--seeds 50] [--cases A:tool_gravity contact:point ...] [--seed0 100]
                                  [--jobs 1] [--out coverage.json] [--log draws.jsonl] [--oracle-inertia]
    python benchmarks/interval_coverage.py --table-from draws.jsonl [more.jsonl ...]

A case is ``RIG:CASE`` of the standalone generators (they import nothing from the package; ``--cases list``
names them): ``A:*`` and ``B:*`` from ``examples/foreign_rig.py`` (rig A's csv.gz log; rig B),
``ur5e:*`` and ``iiwa14:*`` from ``examples/calibration_rig.py``, ``contact:*`` from ``examples/contact_rig.py``
(``point``; the unmodelled flat face ``flat_face_alone``, ``flat_face_alone_rich``, ``flat_face_rotation``,
``flat_face_drift``, ``flat_face_crosstalk_mount_known`` with the user's ``examples/effects/crosstalk_fx_fz.py``). Each seed writes the case afresh (new noise; the motion is the case's own, the
calibration rig's static poses change with the seed) and diagnoses it with the library call of a user's
command (``diagnose(read_log(log, setup), setup, hints=False)``). Compared with the truth:

* every parameter of each hidden effect (truth.json ``effects``, in the report's units and conventions; the
  contact rig's declared tool, 0.5 kg on the axis for a true 0.62 kg off it, is its ``tool_gravity``), and for
  ``tool_gravity`` the tool's total mass and centre of mass, counted where the effect is ``present``;
* the calibration (``sensor_mount``): the tool's total mass, its centre of mass in the true sensor axes and
  the mount's roll/pitch/yaw (wrapped to ±180 deg);
* the contact point (``effective_setup.contact_point``) where the rig presses through a known point.

Printed per case and quantity (and pooled over a quantity's parameters, ``(all)``): n, hits, coverage, the
Clopper-Pearson 95 % interval of the coverage, ``bias/sd`` = mean error / mean reported sd, ``t`` = mean
error / its standard error, ``scat/sd`` = sd of the errors / mean reported sd, the seeds with the effect
``present``, and for coverage below 90 % what breaks it (``bias``: |t| > 3 and at least half a reported sd;
``sd small``: the errors scatter more than 1.25x the reported sd). ``--oracle-inertia`` is a control: the
setup declares the true tool's inertia (read from the truth), so that what the effects leave out of the
inertia (``tool_gravity`` moves m and m c only) is no longer missing. ``--out`` writes every draw, the table
and the options as JSON; ``--log`` appends each diagnosis's outcome as a JSON line as it comes, so that runs
split over cases or seed ranges (or cut short) are merged into one table by ``--table-from``. Run with
``OMP_NUM_THREADS=1`` on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import beta

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.diagnostics.example_scripts import load_example

#: the README's worked example (a 0.25 kg payload on rig A), a heavier moving tool (1.3 + 0.25 kg), the same
#: payload on a static calibration log (no inertia involved), and the mostly-contact log (tool 0.62 kg, 0.5 declared)
DEFAULT_CASES = ("A:tool_gravity", "ur5e:moving_tool_gravity", "ur5e:tool_gravity", "contact:point")
Z95 = 1.959963984540054  # two-sided 95 % normal quantile
TARGET = 0.90  # issue 38: coverage >= 90 % per parameter
RPY = ("roll", "pitch", "yaw")
XYZ = ("x", "y", "z")


class Truth(NamedTuple):
    """What a case hides, in the report's units (kg, m, deg, the log's conventions)."""

    effects: dict[str, dict[str, float]]  #: effect -> parameter -> true value
    calibration: dict[str, float]  #: mass, com_x/y/z (true sensor axes), roll/pitch/yaw [deg]
    contact_point: dict[str, float] | None  #: x/y/z [m] in the true sensor axes; None: no contact
    inertia_o: np.ndarray  #: (3, 3) [kg m^2] the true tool's inertia about the sensor origin, declared axes


class Draw(NamedTuple):
    """One estimate of one quantity in one re-noised log."""

    case: str
    seed: int
    group: str  #: "effect <name>", "calibration" or "contact point"
    param: str
    truth: float
    value: float | None  #: None: not estimated (an effect not present, a COM without a relevant mass)
    sd: float | None
    verdict: str  #: the effect's verdict; "-" for the calibration and the contact point


class Row(NamedTuple):
    """Coverage of one quantity (or of all parameters of one group) of one case over the seeds."""

    case: str
    group: str
    param: str  #: "(all)" for the group's pooled row
    n: int  #: draws with an estimate and an sd
    hits: int  #: draws whose estimate ± 1.96 sd holds the truth
    coverage: float
    ci: tuple[float, float]  #: Clopper-Pearson 95 % interval of the coverage
    bias_over_sd: float  #: mean error / mean reported sd
    t_bias: float  #: mean error / its standard error (sd of the errors / sqrt n)
    scatter_over_sd: float  #: sd of the errors / mean reported sd
    present: str  #: "k/N" seeds with the effect present ("" for other groups)
    why: str  #: for coverage < TARGET: "bias", "sd small", both or "-"


# ==================================================================================================
# the rigs: write a case, name its log and setup, read its truth
# ==================================================================================================
def _rpy_deg(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) [deg] of ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    yaw, pitch, roll = Rotation.from_matrix(R).as_euler("ZYX", degrees=True)
    return float(roll), float(pitch), float(yaw)


def _hidden_rotation(effects: dict) -> np.ndarray:
    """R_hid: the true sensor axes in the declared ones (``ft_frame_rotation`` rotvec [deg]; identity if none)."""
    rot = effects.get("ft_frame_rotation")
    if rot is None:
        return np.eye(3)
    return Rotation.from_rotvec(np.deg2rad([rot["rot_x"], rot["rot_y"], rot["rot_z"]])).as_matrix()


def _calibration(mass: float, com, R_fs_true: np.ndarray, R_hid: np.ndarray) -> dict[str, float]:
    com_true = R_hid.T @ np.asarray(com, dtype=float)
    return {"mass": float(mass), **{f"com_{a}": float(c) for a, c in zip(XYZ, com_true)},
            **dict(zip(RPY, _rpy_deg(R_fs_true)))}


def _with_totals(effects: dict, total_mass: float, total_com) -> dict:
    """``tool_gravity`` also reports the tool's total mass and COM (declared + added): their truth."""
    if "tool_gravity" not in effects:
        return effects
    tot = {"total_mass": float(total_mass), **{f"total_com_{a}": float(c) for a, c in zip(XYZ, total_com)}}
    return {**effects, "tool_gravity": {**effects["tool_gravity"], **tot}}


def inertia_o(*bodies: tuple[float, tuple[float, ...], tuple[float, ...]]) -> np.ndarray:
    """(3, 3) [kg m^2] about the sensor origin of bodies (mass [kg], COM (3,) [m], inertia about the COM
    (ixx, iyy, izz, ixy, ixz, iyz) [kg m^2]): ``sum I_c + m (|c|^2 1 - c c^T)`` (parallel axes)."""
    out = np.zeros((3, 3))
    for m, c, (ixx, iyy, izz, ixy, ixz, iyz) in bodies:
        c = np.asarray(c, dtype=float)
        out += np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]) + m * (c @ c * np.eye(3) - np.outer(c, c))
    return out


class ForeignRig:
    """``examples/foreign_rig.py`` rig A (csv.gz log) or B."""

    def __init__(self, letter: str):
        self.mod, self.letter = load_example("foreign_rig"), letter

    def cases(self) -> list[str]:
        return list(self.mod.cases(self.letter))

    def make(self, case: str, out: Path, seed: int) -> tuple[Path, Path, dict]:
        d = self.mod.make_case(case, out, seed=seed, rig=self.letter)
        files = ("log.csv.gz", "setup_csv.toml") if self.letter == "A" else ("log.csv", "setup.toml")
        return d / files[0], d / files[1], json.loads((d / "truth.json").read_text())

    def truth(self, t: dict) -> Truth:
        rg, eff = self.mod.RIGS[self.letter], t["effects"]
        bodies = [(rg.tool_mass_kg, rg.tool_com_s_m, rg.tool_inertia_com_kg_m2)]
        if "tool_gravity" in eff:  # a near-point mass (1e-8 kg m^2 about its own COM)
            g = eff["tool_gravity"]
            bodies.append((g["mass"], (g["com_x"], g["com_y"], g["com_z"]), (0.0,) * 6))
        mass = sum(b[0] for b in bodies)
        com = sum(b[0] * np.asarray(b[1]) for b in bodies) / mass
        R_hid = _hidden_rotation(eff)
        cal = _calibration(mass, com, self.mod.rpy_matrix_deg(rg.sensor_rpy_f_deg) @ R_hid, R_hid)
        tip = R_hid.T @ np.asarray(rg.tool_tip_s_m)
        return Truth(_with_totals(eff, mass, com), cal, dict(zip(XYZ, map(float, tip))), inertia_o(*bodies))


class CalibrationRig:
    """``examples/calibration_rig.py`` (static logs of both arms, the ur5e's moving logs; no contact)."""

    def __init__(self, arm: str):
        self.mod, self.arm = load_example("calibration_rig"), arm

    def cases(self) -> list[str]:
        return list(self.mod.cases(self.arm))

    def make(self, case: str, out: Path, seed: int) -> tuple[Path, Path, dict]:
        d = self.mod.make_case(self.arm, case, out, seed=seed)
        return d / "log.csv", d / "setup.toml", json.loads((d / "truth.json").read_text())

    def truth(self, t: dict) -> Truth:
        eff, tool = t["effects"], t["tool"]
        R_true = self.mod.rpy_matrix_deg(t["sensor_mount"]["true_rpy_flange_deg"])  # incl. the hidden rotation
        cal = _calibration(tool["true_mass_kg"], tool["true_com_sensor_m"], R_true, _hidden_rotation(eff))
        rg = self.mod.MOVING_RIG if t["kind"] == "moving" else self.mod.STATIC_RIGS[self.arm]
        case = self.mod.cases(self.arm)[t["case"]]
        bodies = [(rg.tool_mass_kg, rg.tool_com_s_m, rg.tool_inertia_com_kg_m2)]
        if case.payload is not None:  # a point mass
            bodies.append((case.payload[0], case.payload[1], (0.0,) * 6))
        return Truth(_with_totals(eff, tool["true_mass_kg"], tool["true_com_sensor_m"]), cal, None, inertia_o(*bodies))


class ContactRig:
    """``examples/contact_rig.py``: the point contact, and the flat face pressed, slid and twisted (a moment about
    the tip no library effect has) with nothing else hidden (``flat_face_alone``, ``flat_face_alone_rich``) or
    beside a hidden rotation of the sensor's measuring axes (``flat_face_rotation``), a drift (``flat_face_drift``)
    or a crosstalk diagnosed with the user's effect file (``flat_face_crosstalk_mount_known``)."""

    def __init__(self):
        self.mod = load_example("contact_rig")

    def cases(self) -> list[str]:
        return ["point", "flat_face_alone", "flat_face_alone_rich", "flat_face_rotation", "flat_face_drift",
                "flat_face_crosstalk_mount_known"]

    def effects_files(self, case: str) -> list[str]:
        """The user's effect files a case is diagnosed with (its crosstalk's)."""
        return [str(ROOT / "examples" / "effects" / "crosstalk_fx_fz.py")] if "crosstalk" in case else []

    def make(self, case: str, out: Path, seed: int) -> tuple[Path, Path, dict]:
        d = self.mod.make_case(case, out, seed=seed)
        return d / "log.csv", d / "setup.toml", json.loads((d / "truth.json").read_text())

    def truth(self, t: dict) -> Truth:
        """The declared tool (0.5 kg, COM on the axis) is not the true one (0.62 kg, off-axis): a hidden
        ``tool_gravity`` of dm = true - declared mass and dm c = the first moments' difference (the sensor body's
        axes); a rotation of the measuring axes is ``ft_frame_rotation``. A flat face has no contact point (its
        pressure centre moves with the friction and the twist): the contact point is compared only for ``point``."""
        m, c = t["tool_mass_kg"], np.asarray(t["tool_com_sensor_m"])
        m_d, c_d = t["declared"]["tool_mass_kg"], np.asarray(t["declared"]["tool_com_sensor_m"])
        dm, dmc = m - m_d, m * c - m_d * c_d
        eff = {"tool_gravity": {"mass": dm, **{f"com_{a}": float(v) for a, v in zip(XYZ, dmc / dm)}},
               **t.get("effects", {})}
        if "crosstalk" in t:
            eff["crosstalk_fx_fz"] = {"fx_from_fz": float(t["crosstalk"]["fx_from_fz"])}
        R_hid = _hidden_rotation(eff)
        cal = _calibration(m, c, self.mod.rpy_matrix_deg(t["sensor_rpy_flange_deg"]) @ R_hid, R_hid)
        point = dict(zip(XYZ, map(float, t["contact_point_sensor_m"]))) if "face" not in t else None
        return Truth(_with_totals(eff, m, c), cal, point, inertia_o((m, c, t["tool_inertia_com_kg_m2"])))


def rigs() -> dict[str, ForeignRig | CalibrationRig | ContactRig]:
    return {"A": ForeignRig("A"), "B": ForeignRig("B"), "ur5e": CalibrationRig("ur5e"),
            "iiwa14": CalibrationRig("iiwa14"), "contact": ContactRig()}


def all_cases() -> list[str]:
    return [f"{k}:{c}" for k, r in rigs().items() for c in r.cases()]


# ==================================================================================================
# one draw: write, diagnose, compare
# ==================================================================================================
def _report_draws(case: str, seed: int, truth: Truth, rep: dict) -> list[Draw]:
    out = []
    verdicts = {e["effect"]: e for e in rep["ranking"]}
    for name, params in truth.effects.items():
        e = verdicts.get(name, {"verdict": "not judged", "estimate": {}})
        present = e["verdict"] == "present"
        for p, v in params.items():
            est = e["estimate"].get(p, {}) if present else {}
            out.append(Draw(case, seed, f"effect {name}", p, v, est.get("value"), est.get("sd"), e["verdict"]))
    sm = rep["sensor_mount"]
    est = {"mass": (sm["tool_mass_kg"], sm["tool_mass_sd_kg"]),
           **{f"com_{a}": (c, s) for a, c, s in zip(XYZ, sm["tool_com_sensor_m"], sm["tool_com_sd_m"])},
           **{a: (v, s) for a, v, s in zip(RPY, sm["rpy_flange_deg"], sm["sd_deg"])}}
    for p, v in truth.calibration.items():
        value, sd = est[p]
        if p in RPY and value is not None:  # wrap to the truth's branch
            value = v + (value - v + 180.0) % 360.0 - 180.0
        out.append(Draw(case, seed, "calibration", p, v, value, sd, "-"))
    cp = (rep.get("effective_setup") or {}).get("contact_point")
    if truth.contact_point is not None:
        for k, (p, v) in enumerate(truth.contact_point.items()):
            value, sd = (cp["point_sensor_m"][k], cp["sd_m"][k]) if cp else (None, None)
            out.append(Draw(case, seed, "contact point", p, v, value, sd, "-"))
    return out


class Outcome(NamedTuple):
    """What one (case, seed) gave."""

    draws: list[Draw]
    false_alarms: list[str]  #: effects reported present that the case does not hide
    wall_s: float  #: the diagnosis alone (not the writing of the log)
    error: str | None  #: the exception's message where the diagnosis failed


def oracle_inertia(setup, truth: Truth) -> list[float]:
    """The inertia about the COM to declare so that the nominal tool's inertia about the sensor origin is the
    true tool's (``tool_gravity`` moves only m and m c; the diagnosis adds ``m_d (|c_d|^2 1 - c_d c_d^T)`` of
    the declared mass and COM to the declared inertia). A control, not a user's option: it reads the truth."""
    I_c = truth.inertia_o - inertia_o((setup.tool.mass_kg, setup.tool.com_sensor_m, (0.0,) * 6))
    return [float(v) for v in (I_c[0, 0], I_c[1, 1], I_c[2, 2], I_c[0, 1], I_c[0, 2], I_c[1, 2])]


def with_inertia(truth: Truth, setup) -> Truth:
    """The truth of ``tool_inertia``: the true tool's inertia about the sensor origin minus the declared one
    (``physical.nominal_inertials``), where some entry is at least a tenth of its relevant size."""
    from kinadapt_nn.effects.builtin.tool_inertia import ENTRIES, RELEVANT_INERTIA_KG_M2
    from kinadapt_nn.diagnostics.physical import nominal_inertials

    dI = truth.inertia_o - nominal_inertials(setup)[2]
    if np.max(np.abs(dI)) < 0.1 * RELEVANT_INERTIA_KG_M2:
        return truth
    hidden = {n: float(dI[cells[0]]) for n, cells in ENTRIES.items()}
    return truth._replace(effects={**truth.effects, "tool_inertia": hidden})


def draw(case: str, seed: int, oracle: bool = False) -> Outcome:
    """Write ``case`` with noise ``seed`` into a temporary folder, diagnose it, compare with the truth
    (``oracle``: declare the true tool's inertia, ``oracle_inertia``)."""
    from kinadapt_nn.diagnostics import readers
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.diagnostics.userlog import diagnose
    from kinadapt_nn.errors import KinadaptError

    rig_name, name = case.split(":", 1)
    rig = rigs()[rig_name]
    tmp = Path(tempfile.mkdtemp(prefix="coverage-"))
    try:
        log, setup_path, truth_json = rig.make(name, tmp, seed)
        truth = rig.truth(truth_json)
        setup = load_setup(setup_path)
        if oracle:
            setup = load_setup(setup_path, [f"tool.inertia_com_kg_m2={oracle_inertia(setup, truth)}"])
        truth = with_inertia(truth, setup)
        t0 = time.perf_counter()
        try:
            files = rig.effects_files(name) if hasattr(rig, "effects_files") else []
            rep = diagnose(readers.read_log(log, setup), setup, effects_files=files, hints=False).report
        except KinadaptError as exc:  # a refused diagnosis is a result too
            return Outcome([], [], time.perf_counter() - t0, f"{type(exc).__name__}: {exc}")
        wall = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    fa = [e["effect"] for e in rep["ranking"] if e["verdict"] == "present" and e["effect"] not in truth.effects]
    return Outcome(_report_draws(case, seed, truth, rep), fa, wall, None)


def _draw_args(args: tuple[str, int, bool]) -> tuple[str, int, Outcome]:
    return args[0], args[1], draw(*args)


# ==================================================================================================
# the table
# ==================================================================================================
def clopper_pearson(hits: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact binomial interval of a proportion hits / n."""
    a = (1.0 - level) / 2.0
    lo = 0.0 if hits == 0 else float(beta.ppf(a, hits, n - hits + 1))
    hi = 1.0 if hits == n else float(beta.ppf(1.0 - a, hits + 1, n - hits))
    return lo, hi


def _row(case: str, group: str, param: str, ds: list[Draw], n_seeds: int) -> Row:
    ok = [d for d in ds if d.value is not None and d.sd is not None]
    err = np.array([d.value - d.truth for d in ok])
    sd = np.array([d.sd for d in ok])
    hits = int(np.sum(np.abs(err) <= Z95 * sd))
    n = len(ok)
    cov = hits / n if n else float("nan")
    msd = float(sd.mean()) if n else float("nan")
    scat = float(err.std(ddof=1)) if n > 1 else float("nan")
    t = float(err.mean() / (scat / math.sqrt(n))) if n > 1 and scat > 0 else float("nan")
    b, s = (float(err.mean()) / msd, scat / msd) if n and msd > 0 else (float("nan"), float("nan"))
    why = ""
    if n and cov < TARGET:
        parts = (["bias"] if abs(t) > 3 and abs(b) >= 0.5 else []) + (["sd small"] if s > 1.25 else [])
        why = " + ".join(parts) or "-"
    present = ""
    if group.startswith("effect"):
        seeds = {d.seed for d in ds if d.verdict == "present"}
        present = f"{len(seeds)}/{n_seeds}"
    return Row(case, group, param, n, hits, cov, clopper_pearson(hits, n) if n else (float("nan"),) * 2, b, t, s,
               present, why)


def table(draws: list[Draw], n_seeds: dict[str, int]) -> list[Row]:
    """A row per (case, group, parameter), after each group's pooled row."""
    rows = []
    keys = list(dict.fromkeys((d.case, d.group) for d in draws))
    for case, group in keys:
        ds = [d for d in draws if d.case == case and d.group == group]
        params = list(dict.fromkeys(d.param for d in ds))
        pooled = _row(case, group, "(all)", ds, n_seeds[case])
        rows.append(pooled._replace(bias_over_sd=float("nan"), t_bias=float("nan"), scatter_over_sd=float("nan"),
                                    why=""))
        rows += [_row(case, group, p, [d for d in ds if d.param == p], n_seeds[case]) for p in params]
    return rows


def format_table(rows: list[Row]) -> str:
    head = (f"{'case':26s} {'quantity':26s} {'param':13s} {'n':>4s} {'hits':>4s} {'cover':>6s} {'95% CI':>13s} "
            f"{'bias/sd':>8s} {'t':>7s} {'scat/sd':>7s} {'present':>7s}  miss")
    lines = [head, "-" * len(head)]
    for r in rows:
        ci = f"[{r.ci[0]:.2f}, {r.ci[1]:.2f}]" if r.n else "-"
        lines.append(f"{r.case:26s} {r.group:26s} {r.param:13s} {r.n:4d} {r.hits:4d} {r.coverage:6.2f} {ci:>13s} "
                     f"{r.bias_over_sd:8.2f} {r.t_bias:7.1f} {r.scatter_over_sd:7.2f} {r.present:>7s}  {r.why}")
    return "\n".join(lines).replace(" nan", "   -")


# ==================================================================================================
def _run(cases: list[str], seeds: list[int], jobs: int, oracle: bool, log: Path | None = None
         ) -> dict[tuple[str, int], Outcome]:
    """Every (case, seed) diagnosed; ``log``: each outcome appended as one JSON line as it comes (a run cut
    short keeps what it did: ``--table-from``)."""
    tasks = [(c, s, oracle) for s in seeds for c in cases]
    out: dict[tuple[str, int], Outcome] = {}
    t0 = time.perf_counter()

    def note(case: str, seed: int, o: Outcome) -> None:
        out[(case, seed)] = o
        status = o.error or f"{o.wall_s:.1f} s"
        print(f"[{len(out)}/{len(tasks)} {time.perf_counter() - t0:7.0f} s] {case} seed {seed}: {status}",
              file=sys.stderr, flush=True)
        if log is not None:
            with log.open("a") as fh:
                fh.write(json.dumps({"case": case, "seed": seed, "oracle": oracle, "wall_s": o.wall_s,
                                     "false_alarms": o.false_alarms, "error": o.error,
                                     "draws": [d._asdict() for d in o.draws]}) + "\n")

    if jobs <= 1:
        for t in tasks:
            note(*_draw_args(t))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as ex:
            for c, s, o in ex.map(_draw_args, tasks):
                note(c, s, o)
    return out


def read_logs(paths: list[Path]) -> dict[tuple[str, int], Outcome]:
    """The outcomes of ``--log`` files (JSON lines; a later line of the same case and seed wins)."""
    out: dict[tuple[str, int], Outcome] = {}
    for p in paths:
        for line in p.read_text().splitlines():
            if not line.strip():
                continue
            r = json.loads(line)
            out[(r["case"], r["seed"])] = Outcome([Draw(**d) for d in r["draws"]], r["false_alarms"], r["wall_s"],
                                                  r["error"])
    return out


def summary(res: dict[tuple[str, int], Outcome]) -> tuple[list[Row], str]:
    """The table's rows and the per-case lines (diagnosed, wall, false alarms) of the outcomes ``res``."""
    cases = list(dict.fromkeys(c for c, _ in res))
    seeds = {c: sorted(s for cc, s in res if cc == c) for c in cases}
    draws = [d for c in cases for s in seeds[c] for d in res[(c, s)].draws]
    n_seeds = {c: sum(res[(c, s)].error is None for s in seeds[c]) for c in cases}
    lines = []
    for c in cases:
        w = np.array([res[(c, s)].wall_s for s in seeds[c]])
        fa: dict[str, int] = {}
        for s in seeds[c]:
            for e in res[(c, s)].false_alarms:
                fa[e] = fa.get(e, 0) + 1
        errs = [res[(c, s)].error for s in seeds[c] if res[(c, s)].error]
        lines.append(f"{c}: {n_seeds[c]}/{len(seeds[c])} diagnosed (seeds {seeds[c][0]}-{seeds[c][-1]}), diagnosis "
                     f"{np.median(w):.1f} s median ({w.max():.1f} max); present though not hidden: {fa or 'none'}"
                     + (f"; failed: {errs[0]} ..." if errs else ""))
    return table(draws, n_seeds), "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description="Coverage of the diagnosis's 95 % intervals over re-noised logs of the "
                                             "independent rigs (module docstring).")
    ap.add_argument("--seeds", type=int, default=50, help="re-noised logs per case (default 50)")
    ap.add_argument("--seed0", type=int, default=100, help="first noise seed (default 100; the tests use 0-3)")
    ap.add_argument("--cases", nargs="+", default=list(DEFAULT_CASES), metavar="RIG:CASE",
                    help=f"default: {' '.join(DEFAULT_CASES)}; 'list' prints the choices")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1: a shared machine)")
    ap.add_argument("--out", type=Path, help="JSON of every draw, the table and these options")
    ap.add_argument("--log", type=Path, help="append each diagnosis's outcome to this JSON-lines file as it comes")
    ap.add_argument("--table-from", type=Path, nargs="+", metavar="LOG",
                    help="diagnose nothing: the table of these --log files (several runs' outcomes merged)")
    ap.add_argument("--oracle-inertia", action="store_true",
                    help="control: declare the true tool's inertia (read from the truth) in the setup")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = _parser()
    a = ap.parse_args(argv)
    choices = all_cases()
    if a.cases == ["list"]:
        print("\n".join(choices))
        return 0
    bad = [c for c in a.cases if c not in choices]
    if bad:
        ap.error(f"unknown case(s) {', '.join(bad)} (choose from {', '.join(choices)})")
    t0 = time.perf_counter()
    if a.table_from:
        res = read_logs(a.table_from)
    else:
        res = _run(a.cases, list(range(a.seed0, a.seed0 + a.seeds)), a.jobs, a.oracle_inertia, a.log)
    wall = time.perf_counter() - t0
    rows, lines = summary(res)
    print(format_table(rows))
    print()
    print(lines)
    if not a.table_from:
        print(f"{len(res)} diagnoses in {wall:.0f} s wall, {a.jobs} job(s)"
              + ("; the true tool's inertia declared (--oracle-inertia)" if a.oracle_inertia else ""))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({
            "options": {"seeds": a.seeds, "seed0": a.seed0, "cases": a.cases, "jobs": a.jobs,
                        "oracle_inertia": a.oracle_inertia, "table_from": [str(p) for p in a.table_from or []]},
            "wall_s": wall, "table": [r._asdict() for r in rows],
            "draws": [d._asdict() for o in res.values() for d in o.draws],
            "runs": [{"case": c, "seed": s, "wall_s": o.wall_s, "false_alarms": o.false_alarms, "error": o.error}
                     for (c, s), o in res.items()]}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
