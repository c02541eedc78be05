"""The hint table of the face-contact rig (issue 51, "hints that rank consistently"): the same unexplained face
contact, whatever else the log hides and the model holds, should be named ``contact_moment`` first or second.

    python benchmarks/hint_table.py [--seeds 3] [--seed0 100] [--cases NAME ...] [--jobs 1] [--out table.json]

Each case is a log of ``examples/contact_rig.py`` (standalone; it imports nothing from the package): the
20 x 20 mm box-peg face pressed, slid and twisted on a table (a moment about the declared tip no library
effect has) after the rich free-space phase, alone or beside one hidden effect, diagnosed as a user would
(``diagnose(read_log(log, setup), setup, effects_files=...)``, hints on):

* ``alone``: the true tool and mount declared (``flat_face_true_tool``): nothing but the face;
* ``tool_gravity + tool_inertia``: the guessed tool (0.5 kg on the axis for 0.62 kg off it), the mount
  estimated (``flat_face_alone_rich``), and the same after the weak free motion (``flat_face_alone``);
* ``ft_frame_rotation``, ``ft_bias_drift``, ``encoder_offset``: ``flat_face_rotation``, ``flat_face_drift``,
  ``flat_face_encoder`` (the guessed tool too, the mount declared);
* ``user effect``: the crosstalk ``Fx += 0.04 Fz`` with its effect file ``examples/effects/crosstalk_fx_fz.py``
  passed (``flat_face_crosstalk_mount_known``).

Printed per case and seed: the effects present (and undecided), the verdict on the model, the hints in
their order with the held-out share each explains, and the place of ``contact_moment`` (``-``: not listed);
then per case the worst place over the seeds and the count of cases with ``contact_moment`` in the first
two. Run with ``OMP_NUM_THREADS=1`` on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.diagnostics.example_scripts import load_example

EFFECTS = ROOT / "examples" / "effects"


class HintCase(NamedTuple):
    """One row group of the table: a rig case, what it hides beside the face, the user's effect files."""

    rig_case: str
    hides: str
    effects_files: tuple[str, ...] = ()


CASES: dict[str, HintCase] = {
    "alone": HintCase("flat_face_true_tool", "nothing (true tool and mount declared)"),
    "tool": HintCase("flat_face_alone_rich", "tool_gravity + tool_inertia (guessed tool), mount estimated"),
    "tool_weak": HintCase("flat_face_alone", "tool_gravity (guessed tool), weak free motion, mount estimated"),
    "rotation": HintCase("flat_face_rotation", "ft_frame_rotation 2.05 deg + the guessed tool"),
    "drift": HintCase("flat_face_drift", "ft_bias_drift + the guessed tool"),
    "encoder": HintCase("flat_face_encoder", "encoder_offset joint 4, 1 deg + the guessed tool"),
    "user_crosstalk": HintCase("flat_face_crosstalk_mount_known", "a crosstalk Fx += 0.04 Fz + the guessed tool; "
                               "the user's crosstalk_fx_fz.py passed", (str(EFFECTS / "crosstalk_fx_fz.py"),)),
}
TOP = 2  #: issue 51: contact_moment first or second


class Outcome(NamedTuple):
    """One diagnosis of one case and seed."""

    case: str
    seed: int
    present: list  #: effects present
    undecided: list  #: effects cannot_decide with an estimate (not the contact-model ones without columns)
    complete: bool
    hints: list  #: [(shape, held-out share)] in the report's order
    place: int | None  #: 1-based place of contact_moment; None: not listed
    wall_s: float


def run_one(case: str, seed: int) -> Outcome:
    """Write ``case`` with noise ``seed``, diagnose it with hints, read the hint list."""
    from kinadapt_nn.diagnostics.readers import read_log
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.diagnostics.userlog import diagnose

    hc = CASES[case]
    rig = load_example("contact_rig")
    tmp = Path(tempfile.mkdtemp(prefix="hint-table-"))
    try:
        d = rig.make_case(hc.rig_case, tmp, seed=seed)
        setup = load_setup(d / "setup.toml")
        t0 = time.perf_counter()
        rep = diagnose(read_log(d / "log.csv", setup), setup, effects_files=list(hc.effects_files)).report
        wall = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    hints = [(h["shape"], float(h["explains"])) for h in rep["unexplained"]["hints"]]
    shapes = [h for h, _ in hints]
    place = shapes.index("contact_moment") + 1 if "contact_moment" in shapes else None
    present = [e["effect"] for e in rep["ranking"] if e.get("verdict") == "present"]
    undecided = [e["effect"] for e in rep["ranking"] if e.get("verdict") == "cannot_decide" and e.get("estimate")]
    return Outcome(case, seed, present, undecided, bool(rep["model_complete"]), hints, place, wall)


def _one(args: tuple[str, int]) -> Outcome:
    return run_one(*args)


def format_table(res: list[Outcome]) -> str:
    lines = [f"{'case':15s} {'seed':>4s} {'cm':>3s}  {'complete':8s} hints (held-out share)  | present; undecided",
             "-" * 118]
    for o in res:
        hs = ", ".join(f"{h} {100 * x:.0f}%" for h, x in o.hints) or "(none)"
        lines.append(f"{o.case:15s} {o.seed:4d} {o.place or '-':>3}  {str(o.complete):8s} {hs}  | "
                     f"{', '.join(o.present) or '-'}; {', '.join(o.undecided) or '-'}")
    lines += ["", f"{'case':15s} {'hides':70s} worst place of contact_moment"]
    ok = 0
    for case in dict.fromkeys(o.case for o in res):
        places = [o.place for o in res if o.case == case]
        worst = None if None in places else max(places)
        ok += worst is not None and worst <= TOP
        lines.append(f"{case:15s} {CASES[case].hides:70s} {worst or 'not listed'} (seeds: "
                     f"{', '.join(str(p or '-') for p in places)})")
    n = len(dict.fromkeys(o.case for o in res))
    lines.append(f"\ncontact_moment in the first {TOP} in every seed: {ok}/{n} cases")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="The hint table of the face-contact rig (module docstring).")
    ap.add_argument("--seeds", type=int, default=3, help="noise seeds per case (default 3)")
    ap.add_argument("--seed0", type=int, default=100, help="first noise seed (default 100)")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES), help="default: all")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1: a shared machine)")
    ap.add_argument("--out", type=Path, help="JSON of every outcome")
    a = ap.parse_args(argv)
    tasks = [(c, s) for c in a.cases for s in range(a.seed0, a.seed0 + a.seeds)]
    t0 = time.perf_counter()
    if a.jobs <= 1:
        res = [_one(t) for t in tasks]
    else:
        with ProcessPoolExecutor(max_workers=a.jobs) as ex:
            res = list(ex.map(_one, tasks))
    print(format_table(res))
    print(f"{len(res)} diagnoses in {time.perf_counter() - t0:.0f} s wall, {a.jobs} job(s)")
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps([o._asdict() for o in res], indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
