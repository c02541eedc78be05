"""The live monitor against the offline diagnosis of the same run (issue 53, docs/monitor.md
"Agreement with the offline diagnosis").

At the end of a run the monitor's open events name shapes (``shapes.SHAPES``); ``kinadapt diagnose``
of the run names the library effects it judges ``present`` and, when its model stays incomplete, a
leading hint shape ("It looks like ..."). :data:`OFFLINE_NAME` is the one map between the two
vocabularies: each monitor shape is either a library effect (judged present or not) or a hint shape
(only a hint names it: a world-frame force is not in the library). The two **agree** when the set of
the monitor's open events' names, mapped, equals the set the diagnosis names: its present effects and
its leading hint (``unexplained.hints[0]``, the one its summary reads as "looks like"). A hint counts
only in the first place: a diagnosis that names a world force second to another shape does not say
it is one.

A payload's event implies more than its shape's name: a mass ``dm`` with its centre at ``c`` (sensor
frame, from O) adds ``I_c + dm (|c|^2 1 - c c^T)`` to the tool's inertia about O (parallel axes), and
``I_c`` only adds to the diagonal. Where the event's own estimate puts that lower bound above
``tool_inertia``'s relevant size, the payload changed the inertia by a relevant amount as surely as
it changed the weight, and the monitor's event names ``tool_inertia`` too (:func:`implied_names`); the
monitor's free-space shape does not fit the inertia (its motions are slow), so it is implied, not
estimated.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: the monitor's shape (every one of ``shapes.SHAPES``) -> what the offline diagnosis calls it: ("effect", a built-in effect's name, judged
#: ``present`` in ``ranking``) or ("hint", a hint shape of ``diagnostics.completeness.SHAPES``)
OFFLINE_NAME = {
    "tool_gravity": ("effect", "tool_gravity"),  # a payload picked up
    "tool_tilt": ("effect", "tool_tilt"),  # the tool turned in the grasp
    "ft_frame_rotation": ("effect", "ft_frame_rotation"),  # the sensor turned in its mount
    "ft_bias_drift": ("effect", "ft_bias_drift"),  # a drifting sensor
    "sensor_constant": ("effect", "ft_offset"),  # a constant wrench: the library's offset of an untared log
    "world_force": ("hint", "world_force"),  # a snag: a world-frame force is a hint shape, not a library effect
}


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


def monitor_names(monitor: dict) -> list[str]:
    """The offline names (``kind:name``) of a run's open events (``summary["monitor"]``) and what they
    imply (:func:`implied_names`), sorted, once each."""
    opened = [e for e in monitor.get("events", []) if e.get("open", True)]
    return sorted({":".join(OFFLINE_NAME[e["shape"]]) for e in opened} | {n for e in opened for n in implied_names(e)})


def diagnosis_names(report: dict) -> list[str]:
    """The names (``kind:name``) ``kinadapt diagnose`` gives (its ``diagnosis.json``): the effects judged
    present and the leading hint, sorted."""
    names = {f"effect:{e['effect']}" for e in report.get("ranking", []) if e.get("verdict") == "present"}
    hints = (report.get("unexplained") or {}).get("hints") or []
    if hints:
        names.add(f"hint:{hints[0]['shape']}")
    return sorted(names)


def diagnosis_candidates(report: dict) -> list[str]:
    """What the diagnosis does not rule out: its names (:func:`diagnosis_names`), the effects it
    cannot decide on (a near-tie, too little excitation) and every hint it lists, sorted."""
    names = set(diagnosis_names(report))
    names |= {f"effect:{e['effect']}" for e in report.get("ranking", []) if e.get("verdict") == "cannot_decide"
              and e.get("judged", True)}
    names |= {f"hint:{h['shape']}" for h in ((report.get("unexplained") or {}).get("hints") or [])}
    return sorted(names)


class Agreement(NamedTuple):
    """The monitor and the offline diagnosis of one run side by side."""

    monitor: list[str]  #: the monitor's open events' shapes, in order
    monitor_as_offline: list[str]  #: their offline names (``kind:name``, :data:`OFFLINE_NAME`) and what they imply, sorted
    diagnosis: list[str]  #: what the diagnosis names (:func:`diagnosis_names`)
    agree: bool  #: the two name sets are equal
    contained: bool  #: the monitor's names are among the diagnosis's
    #: no contradiction: what the diagnosis names the monitor names, and what the monitor names the
    #: diagnosis names or cannot decide on (:func:`diagnosis_candidates`); weaker than ``agree``
    compatible: bool


def agreement(monitor: dict, report: dict) -> Agreement:
    """The monitor's summary (``summary["monitor"]``) against the diagnosis's report (``diagnosis.json``)."""
    mon, dia = monitor_names(monitor), diagnosis_names(report)
    return Agreement([e["shape"] for e in monitor.get("events", []) if e.get("open", True)], mon, dia, mon == dia,
                     set(mon) <= set(dia), set(dia) <= set(mon) and set(mon) <= set(diagnosis_candidates(report)))
