"""``benchmarks/cell_learning.py`` writes only where it is told: the README's figure in
docs/figures is replaced only with ``--figure``, never by a run given ``--seeds``/``--from`` and
``--out``."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from tests.diagnostics.example_scripts import load_script

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def bench(tmp_path, monkeypatch):
    """The script, its repository root moved to ``tmp_path`` (a default that writes into
    ``ROOT/docs/figures`` shows there), its reading of the compare tables stubbed out, and one
    finished compare folder."""
    mod = load_script(ROOT / "benchmarks" / "cell_learning.py", "cell_learning")
    monkeypatch.setattr(mod, "ROOT", tmp_path / "root")
    monkeypatch.setattr(mod, "report", lambda folder, label: {})
    monkeypatch.setattr(mod, "goals", lambda out, name: None)
    done = tmp_path / "seed8113"
    done.mkdir()
    (done / "cell_learning.png").write_bytes(b"png")
    return mod, done


def test_without_figure_nothing_is_written_to_docs(bench, tmp_path, monkeypatch, capsys):
    mod, done = bench
    monkeypatch.setattr(sys, "argv", ["cell_learning.py", "--from", str(done), "--out", str(tmp_path / "out")])
    mod.main()
    assert not (tmp_path / "root").exists()
    assert str(done / "cell_learning.png") in capsys.readouterr().out  # where the figure is, said


def test_figure_copies_where_told(bench, tmp_path, monkeypatch):
    mod, done = bench
    dest = tmp_path / "figs" / "cell.png"
    monkeypatch.setattr(sys, "argv", ["cell_learning.py", "--from", str(done), "--figure", str(dest)])
    mod.main()
    assert dest.read_bytes() == b"png" and not (tmp_path / "root").exists()
