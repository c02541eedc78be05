"""ruff on the package, the benchmarks, the examples and the tests with pyproject.toml's rules:
the base rules plus complexity (C901, at most 15) and argument count (PLR0913, at most 8).
Skipped where ruff is not installed (it is in the dev extra)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _ruff() -> list[str]:
    """The ruff binary of this interpreter's ruff package (not one that happens to be on PATH)."""
    pytest.importorskip("ruff", reason="ruff is not installed (pip install -e '.[dev]')")
    from ruff.__main__ import find_ruff_bin

    return [str(find_ruff_bin())]


def test_ruff_passes_with_the_complexity_rules():
    cmd = [*_ruff(), "check", "--no-cache", "--output-format", "concise", "kinadapt_nn", "benchmarks", "examples",
           "tests"]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, f"ruff found:\n{p.stdout}{p.stderr}"


def test_the_rules_catch_a_long_argument_list(tmp_path):
    """Positive control: the project's config flags a 9-argument function and a complexity-16 one
    (so a pass above is not a config that checks nothing)."""
    src = tmp_path / "bad.py"
    branches = "\n".join(f"    if x == {i}:\n        return {i}" for i in range(16))
    src.write_text(f"def many(a, b, c, d, e, f, g, h, i):\n    return a\n\n\ndef branchy(x):\n{branches}\n    return -1\n")
    p = subprocess.run([*_ruff(), "check", "--no-cache", "--config", str(ROOT / "pyproject.toml"),
                        "--output-format", "concise", str(src)], capture_output=True, text=True, timeout=60)
    assert "PLR0913" in p.stdout and "C901" in p.stdout, p.stdout + p.stderr
