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
"""

from __future__ import annotations

from typing import NamedTuple

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


def monitor_names(monitor: dict) -> list[str]:
    """The offline names (``kind:name``) of a run's open events (``summary["monitor"]``), sorted, once each."""
    return sorted({":".join(OFFLINE_NAME[e["shape"]]) for e in monitor.get("events", []) if e.get("open", True)})


def diagnosis_names(report: dict) -> list[str]:
    """The names (``kind:name``) ``kinadapt diagnose`` gives (its ``diagnosis.json``): the effects judged
    present and the leading hint, sorted."""
    names = {f"effect:{e['effect']}" for e in report.get("ranking", []) if e.get("verdict") == "present"}
    hints = (report.get("unexplained") or {}).get("hints") or []
    if hints:
        names.add(f"hint:{hints[0]['shape']}")
    return sorted(names)


class Agreement(NamedTuple):
    """The monitor and the offline diagnosis of one run side by side."""

    monitor: list[str]  #: the monitor's open events' shapes, in order
    monitor_as_offline: list[str]  #: their offline names (``kind:name``, :data:`OFFLINE_NAME`), sorted
    diagnosis: list[str]  #: what the diagnosis names (:func:`diagnosis_names`)
    agree: bool  #: the two name sets are equal
    contained: bool  #: the monitor's names are among the diagnosis's


def agreement(monitor: dict, report: dict) -> Agreement:
    """The monitor's summary (``summary["monitor"]``) against the diagnosis's report (``diagnosis.json``)."""
    mon, dia = monitor_names(monitor), diagnosis_names(report)
    return Agreement([e["shape"] for e in monitor.get("events", []) if e.get("open", True)], mon, dia, mon == dia,
                     set(mon) <= set(dia))
