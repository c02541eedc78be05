"""``diagnosis.json``: the one format of every diagnosis (a user's log, a package run, pooled logs).

The stages (``userlog.diagnose``: read -> signals -> segmentation -> calibration -> checks -> rows
and selection -> completeness) each return a frozen result; their sections are put together once
into a ``Report`` -- read-only, nothing writes into it afterwards -- and the report writes itself
(``Report.to_json``): the header (``format``, ``version``, ``kind``, where the log and its set-up
came from), the summary first, then the sections, then the wall time. Read-only all the way down:
a section's mappings are ``FrozenMap``s and its lists tuples (``freeze``), so writing into
``report["ranking"][0]`` raises a ``TypeError``; ``to_json`` gives plain dicts and lists back. The CLI only writes what
this returns. Version 4: the sections of ``userlog._base_report`` plus completeness, ``--add`` and
(package runs) ``rerun``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Callable, Literal

import numpy as np

FORMAT = "kinadapt-diagnosis"
VERSION = 4


class FrozenMap(Mapping):
    """A read-only mapping over its own dict: no item assignment or deletion (``TypeError``), and,
    unlike ``types.MappingProxyType``, it pickles (a report handed between processes: a pool of
    diagnoses). ``json`` writes it through ``thaw``."""

    __slots__ = ("_d",)

    def __init__(self, items: Mapping | None = None) -> None:
        object.__setattr__(self, "_d", dict(items or {}))

    def __getitem__(self, key: Any) -> Any:
        return self._d[key]

    def __iter__(self) -> Iterator:
        return iter(self._d)

    def __len__(self) -> int:
        return len(self._d)

    def __setattr__(self, name: str, value: Any) -> None:
        raise TypeError("a report is read-only: build a new one (Report.with_section) or thaw() a copy")

    def __reduce__(self):
        return (FrozenMap, (self._d,))

    def __repr__(self) -> str:
        return f"FrozenMap({self._d!r})"


def freeze(value: Any) -> Any:
    """``value`` read-only all the way down: mappings -> ``FrozenMap`` (over a new dict), lists and
    tuples -> tuples, numpy arrays -> read-only copies; scalars as they are."""
    if isinstance(value, Mapping):
        return FrozenMap({k: freeze(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(freeze(v) for v in value)
    if isinstance(value, np.ndarray):
        out = value.copy()
        out.flags.writeable = False
        return out
    return value


def thaw(value: Any) -> Any:
    """A new plain copy of ``value`` (the inverse of ``freeze``: dicts and lists, for JSON)."""
    if isinstance(value, Mapping):
        return {k: thaw(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [thaw(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.copy()
    return value


@dataclass(frozen=True)
class Provenance:
    """Where a diagnosed log and its set-up came from."""

    kind: Literal["user_log", "package_run"]  #: a robot's log with its setup file, or a run of this package
    source: str  #: the log (file or folder)
    setup_file: str  #: the setup file, or how the set-up was made (a package run: from its config)


@dataclass(frozen=True)
class Report(Mapping):
    """One log's diagnosis: its sections (``diagnosis.json``'s keys after the header) and the summary
    made from them, read-only. A ``Mapping`` (``report["ranking"]``, ``report.get(...)``); a new
    section gives a new report (``with_section``)."""

    sections: Mapping[str, Any] = field(repr=False)  #: section name -> its content (JSON types)
    summary: str = ""  #: the paragraph a person reads first

    @classmethod
    def of(cls, sections: Mapping[str, Any], summary: Callable[[Mapping[str, Any]], str]) -> Report:
        """The report of ``sections`` (copied, read-only: ``freeze``) with ``summary(sections)`` as its summary."""
        sec = freeze(sections)
        return cls(sec, summary(sec))

    def with_section(self, name: str, content: Any) -> Report:
        """This report with one more section (the summary kept): a package run's ``rerun``."""
        return Report(FrozenMap({**self.sections, name: freeze(content)}), self.summary)

    def __getitem__(self, key: str) -> Any:
        return self.summary if key == "summary" else self.sections[key]

    def __iter__(self) -> Iterator[str]:
        yield "summary"
        yield from self.sections

    def __len__(self) -> int:
        return len(self.sections) + 1

    def to_json(self, prov: Provenance, wall_time_s: float) -> dict:
        """``diagnosis.json``'s content: header, summary, the sections (plain dicts), wall time."""
        return {"format": FORMAT, "version": VERSION, "kind": prov.kind, "source": prov.source,
                "setup_file": prov.setup_file, "summary": self.summary,
                **thaw(self.sections), "wall_time_s": wall_time_s}


def pooled_json(logs: list[tuple[str, str, Mapping]], setup_file: str, wall_time_s: float) -> dict:
    """The top-level ``diagnosis.json`` of several logs of one set-up (``pooled``): ``logs`` =
    [(folder name, source, report)], each log's own diagnosis in its folder."""
    from kinadapt_nn.diagnostics.pooled import pool, summary_text

    pooled = thaw(pool([(name, rep) for name, _, rep in logs]))  # plain JSON types, whatever it copied
    pooled = {**pooled, "summary": summary_text(pooled)}
    return {"format": FORMAT, "version": VERSION, "kind": "pooled_logs", "setup_file": setup_file,
            "summary": pooled["summary"], "pooled": pooled,
            "logs": {name: {"source": src, "folder": name, "summary": rep["summary"]} for name, src, rep in logs},
            "wall_time_s": wall_time_s}


__all__ = ["FORMAT", "VERSION", "Provenance", "Report", "freeze", "pooled_json", "thaw"]
