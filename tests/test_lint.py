"""ruff on the package, the benchmarks, the examples and the tests with pyproject.toml's rules:
the base rules plus complexity (C901, at most 15) and argument count (PLR0913, at most 8).
Skipped where ruff is not installed (it is in the dev extra). And function length: no function
in kinadapt_nn/ over 80 lines (read with ``ast``; ruff has no such rule)."""

from __future__ import annotations

import ast
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


MAX_FUNCTION_LINES = 80
# No exemptions: the numba kernels of controller/step_kernels.py are all within 80 lines as written, so
# none is exempted for speed. A kernel that must be longer (splitting it measured slower) is named
# here as "path name" (e.g. "kinadapt_nn/controller/core.py _step") with its measurement.
LONG_FUNCTION_EXEMPT: frozenset[str] = frozenset()


def long_functions(root: Path, limit: int = MAX_FUNCTION_LINES) -> list[str]:
    """'path:line name (N lines)' for every function or method under ``root`` whose ``def`` ..
    last line spans more than ``limit`` lines (decorators not counted; nested functions counted
    inside their parent and on their own)."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    found.append(f"{path.relative_to(root.parent)}:{node.lineno} {node.name} ({n} lines)")
    return found


def test_no_function_over_80_lines():
    """Every function in the package is at most MAX_FUNCTION_LINES = 80 lines (issue 52), the
    exempt list (LONG_FUNCTION_EXEMPT) aside: a longer one is split into named steps."""
    bad = [f for f in long_functions(ROOT / "kinadapt_nn")
           if f"{f.split(':')[0]} {f.split()[1]}" not in LONG_FUNCTION_EXEMPT]
    assert not bad, "functions over 80 lines: " + "; ".join(bad)


def test_the_length_check_counts_lines(tmp_path):
    """Positive control: an 81-line function is flagged, an 80-line one (and a short one beside it) is not."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    body = lambda k: "\n".join(f"    x{i} = {i}" for i in range(k))  # noqa: E731
    (pkg / "a.py").write_text(f"def long():\n{body(80)}\n\n\ndef fits():\n{body(79)}\n\n\ndef short():\n    pass\n")
    assert long_functions(pkg) == ["pkg/a.py:1 long (81 lines)"]


MAX_MODULE_LINES = 800
# No exemptions (issue 52): the controller's kernels, once core.py (1126 lines), are split by concern
# (controller/layout.py, step_kernels.py, features_kernels.py, arm_chain.py, core.py). A module
# that must stay longer is listed here as its path, with its measurement.
LONG_MODULE_EXEMPT: frozenset[str] = frozenset()


def test_no_module_over_800_lines():
    sizes = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in (ROOT / "kinadapt_nn").rglob("*.py")}
    bad = sorted(f"{k} ({n} lines)" for k, n in sizes.items() if n > MAX_MODULE_LINES and k not in LONG_MODULE_EXEMPT)
    assert not bad, "modules over 800 lines: " + ", ".join(bad)
    assert all(sizes[k] > MAX_MODULE_LINES for k in LONG_MODULE_EXEMPT), "an exempt module is short now: drop it"
