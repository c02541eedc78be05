"""The live monitor against the offline diagnosis of the same run (issue 53, docs/monitor.md
"Agreement with the offline diagnosis").

Each side says, at the end of a run, which effects it finds and whether it can tell each from the others.

* The monitor: each open event names a shape (``shapes.SHAPES``). Its end-of-run look (``Event.at_end``:
  every shape fitted again on all the samples since the event's onset -- the log the offline diagnosis of
  the run judges) gives the best shape and its near-ties (``shapes.end_look``: ``encoder_offset`` among the
  rivals, never the best); without it the event as named live. An event with no tie is *decided*; with
  ties it is *undecided* among them.
* The diagnosis (``diagnosis.json``): the effects it judges ``present`` are decided; an effect it cannot
  decide on as a near-tie is undecided among its ``indistinguishable_from``. A hint shape (outside the
  library: a world-frame force) is named by its leading hint (``unexplained.hints[0]``, the one its summary
  reads as "looks like"), or -- when the diagnosis was given the monitor's own effect file of the shape
  (:func:`effect_file`, ``kinadapt diagnose RUN --effects FILE``: the way a hint's effect file is passed
  back) -- by that effect judged present.

:data:`OFFLINE_NAME` is the one map between the two vocabularies. The two **agree** when

1. the decided names are the same on both sides (the monitor's decided events against the diagnosis's
   present effects and leading hint), what an event only implies (below) aside;
2. every undecided event's name is one the diagnosis cannot decide on as a near-tie too (both name it and
   both say the log cannot tell it from others);
3. nothing an event implies is judged absent.

``same_ties`` is stricter: the undecided events' tie sets, within the monitor's vocabulary, are the
diagnosis's. ``names_equal`` is the plain comparison of name sets (undecided or not, implied included).

A payload's event implies more than its shape's name: a mass ``dm`` with its centre at ``c`` (sensor
frame, from O) adds ``I_c + dm (|c|^2 1 - c c^T)`` to the tool's inertia about O (parallel axes), and
``I_c`` only adds to the diagonal. Where the event's own estimate puts that lower bound above
``tool_inertia``'s relevant size, the payload changed the inertia by a relevant amount as surely as
it changed the weight, and the event implies ``tool_inertia`` (:func:`implied_names`); the monitor's
free-space shape does not fit the inertia (its motions are slow), so it is implied, not measured: the
diagnosis may find it present or, short of accelerations, leave it undecided, but not absent.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: the monitor's shape (every one of ``shapes.END_SHAPES``) -> what the offline diagnosis calls it: ("effect", a built-in effect's
#: name, judged ``present`` in ``ranking``) or ("hint", a hint shape of ``diagnostics.completeness.SHAPES``)
OFFLINE_NAME = {
    "tool_gravity": ("effect", "tool_gravity"),  # a payload picked up
    "tool_tilt": ("effect", "tool_tilt"),  # the tool turned in the grasp
    "ft_frame_rotation": ("effect", "ft_frame_rotation"),  # the sensor turned in its mount
    "ft_bias_drift": ("effect", "ft_bias_drift"),  # a drifting sensor
    "sensor_constant": ("effect", "ft_offset"),  # a constant wrench: the library's offset of an untared log
    "world_force": ("hint", "world_force"),  # a snag: a world-frame force is a hint shape, not a library effect
    "encoder_offset": ("effect", "encoder_offset"),  # a joint's encoder zero (the end-of-run look only)
}
#: the effect name of the monitor's effect file of hint shape ``S`` (:func:`effect_file`): ``monitor_S``
FILE_PREFIX = "monitor_"


def _name(shape: str) -> str:
    return ":".join(OFFLINE_NAME[shape])


def effect_file(event: dict, relevant_force_N: float) -> tuple[str, str] | None:
    """The effect file (file name, Python source in the public contract, ``kinadapt_nn.diagnostics.effect``)
    of an open event whose shape is a hint shape -- a world-frame force at the event's fitted point, its
    three components the parameters, each relevant at ``relevant_force_N`` [N] (the set-up's ``[analysis]``)
    -- for ``kinadapt diagnose RUN --effects FILE``; None for a library shape (the diagnosis has it)."""
    shape = _at_end(event)[0]
    if OFFLINE_NAME[shape][0] != "hint":
        return None
    if shape != "world_force":  # pragma: no cover - world_force is the only hint shape among SHAPES
        raise ValueError(shape)
    func = FILE_PREFIX + shape
    point = [round(float(x), 6) for x in event["estimate"]["point_s_m"]]
    rel = float(relevant_force_N)
    src = (f'"""The live monitor\'s event as an effect file: {event["line"]}.\n\n'
           "Pass it to the offline diagnosis of the run: kinadapt diagnose RUN --effects " f"{func}.py\n" '"""\n'
           "import numpy as np\n\nfrom kinadapt_nn.diagnostics import effect\n\n"
           f"POINT_S_M = np.array({point})  # [m] where the force acts on the tool, sensor frame (the monitor's fit)\n\n\n"
           f'@effect(params={{"fx_w": "N", "fy_w": "N", "fz_w": "N"}}, relevant=[{rel}, {rel}, {rel}],\n'
           '        doc="a constant world-frame force at POINT_S_M on the tool (the live monitor\'s event)")\n'
           f"def {func}(s):\n    C = np.zeros((s.n, 6, 3))\n    for axis in range(3):\n"
           "        u = s.R_ws[:, axis, :]  # the world axis in the sensor frame\n"
           "        C[:, :3, axis] = u\n        C[:, 3:, axis] = np.cross(POINT_S_M, u)\n    return C\n")
    return f"{func}.py", src


def payload_inertia_kg_m2(estimate: dict) -> np.ndarray:
    """(3,) [kg m^2] the least the payload of a ``tool_gravity`` event adds to the diagonal of the tool's
    inertia about O: its mass (less 2 sd) as a point at its centre of mass, ``dm (|c|^2 - c_i^2)``."""
    c = np.asarray(estimate["com_s_m"], dtype=float)
    dm = max(float(estimate["mass_kg"]) - 2.0 * float(estimate.get("mass_sd_kg") or 0.0), 0.0)
    return dm * (float(c @ c) - c * c)


def implied_names(event: dict) -> list[str]:
    """The offline names one open event implies beyond its shape's (module docstring): a payload whose
    least added inertia about O is beyond ``tool_inertia``'s relevant size -> ``effect:tool_inertia``."""
    if event["shape"] != "tool_gravity" or not event.get("estimate"):
        return []
    from kinadapt_nn.diagnostics.userlog import BUILTINS  # the library (wherever the built-ins live)

    relevant = float(np.min(BUILTINS["tool_inertia"].relevant[:3]))  # dI_xx, dI_yy, dI_zz
    return ["effect:tool_inertia"] if float(np.max(payload_inertia_kg_m2(event["estimate"]))) > relevant else []


def _at_end(event: dict) -> tuple[str, list[str]]:
    """(shape, ties) of an event at the end of the run: its end-of-run look, or as named live."""
    end = event.get("at_end")
    return (end["shape"], list(end["ties"])) if end else (event["shape"], list(event.get("ties") or []))


def _opened(monitor: dict) -> list[dict]:
    return [e for e in monitor.get("events", []) if e.get("open", True)]


def monitor_names(monitor: dict) -> list[str]:
    """The offline names (``kind:name``) of a run's open events at the end (``summary["monitor"]``) and
    what they imply, undecided or not, sorted, once each."""
    opened = _opened(monitor)
    return sorted({_name(_at_end(e)[0]) for e in opened} | {n for e in opened for n in implied_names(e)})


def _monitor_sides(monitor: dict) -> tuple[set, dict, set]:
    """(decided names, {undecided name: its ties' names}, implied names) of the open events."""
    decided, undecided, implied = set(), {}, set()
    for e in _opened(monitor):
        shape, ties = _at_end(e)
        if ties:
            undecided[_name(shape)] = {_name(t) for t in ties}
        else:
            decided.add(_name(shape))
        implied |= set(implied_names(e))
    return decided, undecided, implied


def _offline(effect: str) -> str:
    """A diagnosis's effect name as an offline name: ``effect:NAME``, the monitor's effect file of shape S
    (``monitor_S``) as S's."""
    shape = effect[len(FILE_PREFIX):] if effect.startswith(FILE_PREFIX) else None
    return _name(shape) if shape in OFFLINE_NAME else f"effect:{effect}"


def _verdicts(report: dict) -> dict:
    """{offline name: ranking entry} of the diagnosis (:func:`_offline`)."""
    return {_offline(e["effect"]): e for e in report.get("ranking", [])}


def diagnosis_names(report: dict) -> list[str]:
    """The names (``kind:name``) ``kinadapt diagnose`` gives (its ``diagnosis.json``): the effects judged
    present (a monitor's effect file under its shape's name) and the leading hint, sorted."""
    names = {n for n, e in _verdicts(report).items() if e.get("verdict") == "present"}
    hints = (report.get("unexplained") or {}).get("hints") or []
    if hints:
        names.add(f"hint:{hints[0]['shape']}")
    return sorted(names)


def _tie_of(entry: dict | None) -> set | None:
    """The names an undecided near-tie leaves open (the effect's own and ``indistinguishable_from``), or
    None where the verdict is no near-tie."""
    if not entry or entry.get("verdict") != "cannot_decide" or not entry.get("indistinguishable_from"):
        return None
    return {_offline(entry["effect"]), *(_offline(n) for n in entry["indistinguishable_from"])}


def diagnosis_candidates(report: dict) -> list[str]:
    """What the diagnosis does not rule out: its names (:func:`diagnosis_names`), the effects it
    cannot decide on (a near-tie, too little excitation) and every hint it lists, sorted."""
    names = set(diagnosis_names(report))
    names |= {n for n, e in _verdicts(report).items() if e.get("verdict") == "cannot_decide" and e.get("judged", True)}
    names |= {f"hint:{h['shape']}" for h in ((report.get("unexplained") or {}).get("hints") or [])}
    return sorted(names)


class Agreement(NamedTuple):
    """The monitor and the offline diagnosis of one run side by side."""

    monitor: list[str]  #: the monitor's open events' shapes at the end (``at_end``, else as named), in order
    monitor_as_offline: list[str]  #: their offline names (``kind:name``, :data:`OFFLINE_NAME`) and what they imply, sorted
    diagnosis: list[str]  #: what the diagnosis names (:func:`diagnosis_names`)
    agree: bool  #: the module docstring's three conditions
    same_ties: bool  #: ``agree``, and each undecided event's ties (within the monitor's vocabulary) are the diagnosis's
    names_equal: bool  #: the two name sets are equal, undecided or not
    contained: bool  #: the monitor's names are among the diagnosis's
    #: no contradiction: what the diagnosis names the monitor names, and what the monitor names the
    #: diagnosis names or cannot decide on (:func:`diagnosis_candidates`); weaker than ``agree``
    compatible: bool
    undecided: dict  #: {the monitor's undecided name: its ties' names}


def agreement(monitor: dict, report: dict) -> Agreement:
    """The monitor's summary (``summary["monitor"]``) against the diagnosis's report (``diagnosis.json``)."""
    mon, dia = monitor_names(monitor), diagnosis_names(report)
    decided, undecided, implied = _monitor_sides(monitor)
    verdicts = _verdicts(report)
    vocab = {_name(s) for s in OFFLINE_NAME}
    ok = decided == set(dia) - implied - set(undecided)  # 1: decided names (an implied one the diagnosis may name)
    # 2: each undecided name a near-tie of the diagnosis too (a present one fails 1: it is then a diagnosis name)
    ties_dia = {n: _tie_of(verdicts.get(n)) for n in undecided}
    ok = ok and all(t is not None for t in ties_dia.values()) and not (set(undecided) & set(dia))
    ok = ok and all((verdicts.get(n) or {}).get("verdict") != "absent" for n in implied)  # 3
    same = ok and all(({n} | undecided[n]) == (ties_dia[n] & vocab) for n in undecided)
    cand = set(diagnosis_candidates(report))
    return Agreement([_at_end(e)[0] for e in _opened(monitor)], mon, dia, ok, same, mon == dia, set(mon) <= set(dia),
                     set(dia) <= set(mon) and set(mon) <= cand, {n: sorted(t) for n, t in undecided.items()})
