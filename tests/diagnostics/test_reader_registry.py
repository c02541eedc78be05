"""Log readers register like laws and features: the example reader (``examples/readers/json_lines.py``,
one module) reads exactly what the CSV reader reads, ``kinadapt diagnose`` runs on it end to end
(announced through the entry-point group, as another package would), and an unknown format is one
line listing the registered ones."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.diagnostics import readers
from kinadapt_nn.diagnostics.readers import LogReader, read_log, register, unregister, write_log
from kinadapt_nn.errors import KinadaptError
from tests.diagnostics.example_scripts import load_example, load_script
from tests.diagnostics.test_readers import WITH_QDOT, synth

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "readers" / "json_lines.py"
BUILT_IN = ("csv", "parquet", "bag", "trace")


@pytest.fixture
def jsonl():
    """The example reader, registered for one test."""
    mod = load_script(EXAMPLE, "json_lines")
    register(mod.READER)
    yield mod
    unregister("jsonl")


def _write_jsonl(path: Path, columns: dict[str, np.ndarray]) -> None:
    """One JSON object per row (``repr`` of a float round-trips exactly)."""
    n = len(next(iter(columns.values())))
    path.write_text("".join(json.dumps({k: v[i].item() for k, v in columns.items()}) + "\n" for i in range(n)))


def _one_line(path: Path, setup=WITH_QDOT) -> str:
    with pytest.raises(KinadaptError) as info:
        read_log(path, setup)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_the_example_reads_what_the_csv_reader_reads(jsonl, tmp_path):
    t, q, qdot, w = synth()
    write_log(tmp_path / "log.csv", t, q, qdot, w, WITH_QDOT.log)
    cols = {"t": t, **{f"q{j + 1}": q[:, j] for j in range(7)}, **{f"qd{j + 1}": qdot[:, j] for j in range(7)},
            **dict(zip(WITH_QDOT.log.wrench, w.T))}
    _write_jsonl(tmp_path / "log.jsonl", cols)
    a, b = read_log(tmp_path / "log.csv", WITH_QDOT), read_log(tmp_path / "log.jsonl", WITH_QDOT)
    for name in ("t_s", "q_rad", "qdot_rad_s", "wrench_log"):
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name))
    np.testing.assert_allclose(b.q_rad, q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(b.wrench_log, w, rtol=0, atol=1e-13)
    assert readers.log_format(tmp_path / "log.jsonl") == "jsonl" and b.source == str(tmp_path / "log.jsonl")


def test_the_example_reports_rows_by_line(jsonl, tmp_path):
    """A sample that lacks a column is named by its line; a file that is not JSON is one line."""
    t, q, qdot, w = synth()
    cols = {"t": t, **{f"q{j + 1}": q[:, j] for j in range(7)}, **{f"qd{j + 1}": qdot[:, j] for j in range(7)},
            **dict(zip(WITH_QDOT.log.wrench, w.T))}
    _write_jsonl(tmp_path / "gap.ndjson", cols)
    lines = (tmp_path / "gap.ndjson").read_text().splitlines()
    lines[9] = json.dumps({k: v for k, v in json.loads(lines[9]).items() if k != "q3"})
    (tmp_path / "gap.ndjson").write_text("\n".join(lines) + "\n")
    assert "line 10: column 'q3' is empty" in _one_line(tmp_path / "gap.ndjson")
    (tmp_path / "junk.jsonl").write_text("not json\n")
    assert "not readable JSON Lines" in _one_line(tmp_path / "junk.jsonl")


def test_an_unknown_format_lists_the_registered_ones(tmp_path):
    (tmp_path / "log.jsonl").write_text("{}\n")
    before = _one_line(tmp_path / "log.jsonl")
    assert "unknown format" in before and "JSON Lines" not in before and readers.SUPPORTED in before
    assert [r.name for r in readers.registered()] == list(BUILT_IN)
    mod = load_script(EXAMPLE, "json_lines")
    register(mod.READER)
    try:
        (tmp_path / "log.xyz").write_text("x\n")
        after = _one_line(tmp_path / "log.xyz")
        assert "JSON Lines (.jsonl, .ndjson)" in after and "CSV (.csv, .csv.gz)" in after
        with pytest.raises(KinadaptError, match="'nope' is not a registered log reader.*jsonl"):
            readers.lookup("nope")
    finally:
        unregister("jsonl")
    assert "JSON Lines" not in readers.SUPPORTED


def test_register_refuses_a_claimed_suffix_or_name():
    def read(path, log):  # never called
        raise AssertionError

    for reader, fragment in ((LogReader("csv_too", "x", "x", read, suffixes=(".csv",)), "'.csv', which log reader 'csv'"),
                             (LogReader("csv", "x", "x", read, suffixes=(".txt",)), "two log readers named 'csv'"),
                             (LogReader("txt", "x", "x", read, suffixes=("TXT",)), "lower case and start with '.'"),
                             (LogReader("txt", "x", "x", read), "neither suffixes nor folder_files")):
        with pytest.raises(KinadaptError, match=fragment):
            register(reader)
    assert [r.name for r in readers.registered()] == list(BUILT_IN)


def test_kinadapt_diagnose_reads_a_plugin_format_end_to_end(tmp_path):
    """The foreign rig's tool-gravity case rewritten as JSON Lines, the example announced through
    the ``kinadapt_nn.log_readers`` entry point (a package's metadata on the path, as ``pip
    install`` leaves it): ``kinadapt diagnose`` reads it and finds the hidden tool mass."""
    rig = load_example("foreign_rig")
    d = rig.make_case("tool_gravity", tmp_path, seed=0)
    import pyarrow.csv as pacsv

    table = pacsv.read_csv(d / "log.csv.gz")
    _write_jsonl(d / "log.jsonl", {c: table.column(c).to_numpy() for c in table.column_names})
    site = tmp_path / "site"
    meta = site / "json_lines_reader-0.1.dist-info"
    meta.mkdir(parents=True)
    (meta / "METADATA").write_text("Metadata-Version: 2.1\nName: json-lines-reader\nVersion: 0.1\n")
    (meta / "entry_points.txt").write_text(f"[{readers.ENTRY_POINT_GROUP}]\njsonl = json_lines:READER\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(EXAMPLE.parent), str(ROOT)])}
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "kinadapt_nn.app.cli", "diagnose", str(d / "log.jsonl"), "--setup",
                           str(d / "setup_csv.toml"), "--out", str(out), "--quiet"], env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads((out / "diagnosis.json").read_text())
    assert rep["source"] == str(d / "log.jsonl")
    truth = json.loads((d / "truth.json").read_text())["effects"]
    verdict = {e["effect"]: e["verdict"] for e in rep["ranking"]}
    assert "tool_gravity" in truth and verdict["tool_gravity"] == "present"
    mass = next(e for e in rep["ranking"] if e["effect"] == "tool_gravity")["estimate"]["mass"]["value"]
    assert abs(mass - truth["tool_gravity"]["mass"]) < 0.2 * truth["tool_gravity"]["mass"]
