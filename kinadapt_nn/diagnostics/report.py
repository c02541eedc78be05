"""``diagnosis.json``: the one format of every diagnosis (a user's log, a package run, pooled logs).

The stages fill the report (``userlog.diagnose`` -> ``Result.report``); this module owns how it
is written: the header (``format``, ``version``, ``kind``, where the log and its set-up came from),
the summary first, then the report's keys, then the wall time. The CLI only writes what these
return. Version 4: the keys of ``userlog._base_report`` plus completeness, ``--add`` and (package
runs) ``rerun``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

FORMAT = "kinadapt-diagnosis"
VERSION = 4


@dataclass(frozen=True)
class Provenance:
    """Where a diagnosed log and its set-up came from."""

    kind: Literal["user_log", "package_run"]  #: a robot's log with its setup file, or a run of this package
    source: str  #: the log (file or folder)
    setup_file: str  #: the setup file, or how the set-up was made (a package run: from its config)


def diagnosis_json(report: dict, prov: Provenance, wall_time_s: float) -> dict:
    """One log's ``diagnosis.json`` content: header, summary, the report's keys, wall time."""
    return {"format": FORMAT, "version": VERSION, "kind": prov.kind, "source": prov.source,
            "setup_file": prov.setup_file, "summary": report["summary"],
            **{k: v for k, v in report.items() if k != "summary"}, "wall_time_s": wall_time_s}


def pooled_json(logs: list[tuple[str, str, dict]], setup_file: str, wall_time_s: float) -> dict:
    """The top-level ``diagnosis.json`` of several logs of one set-up (``pooled``): ``logs`` =
    [(folder name, source, report)], each log's own diagnosis in its folder."""
    from kinadapt_nn.diagnostics.pooled import pool, summary_text

    pooled = pool([(name, rep) for name, _, rep in logs])
    pooled = {**pooled, "summary": summary_text(pooled)}
    return {"format": FORMAT, "version": VERSION, "kind": "pooled_logs", "setup_file": setup_file,
            "summary": pooled["summary"], "pooled": pooled,
            "logs": {name: {"source": src, "folder": name, "summary": rep["summary"]} for name, src, rep in logs},
            "wall_time_s": wall_time_s}


__all__ = ["FORMAT", "VERSION", "Provenance", "diagnosis_json", "pooled_json"]
