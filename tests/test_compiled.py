"""Compile management lives in one subpackage (``kinadapt_nn/compiled/``): no numba internals
elsewhere in the package, and a kernel cached with a callee from another file is recompiled after
that file is edited (numba alone would keep the old callee)."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import kinadapt_nn

PKG = Path(kinadapt_nn.__file__).parent
ROOT = PKG.parent
#: numba's private API: its cache's internals, compiled overloads' entries, its core and experimental
#: modules, LLVM helpers, the optimisation level's internals, a dispatcher's target options
INTERNALS = re.compile(r"\._cache\b|_cache_file|_load_index|_index_key|_cache_path|\.overloads\b|numba\.core|nb\.core|"
                       r"numba\.experimental|_get_jit_address|cgutils|targetctx|targetoptions|_OptLevel|cpu_target")


def test_numba_internals_only_in_the_compile_module():
    found = {}
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).as_posix()
        if rel.startswith("compiled/"):
            continue
        hits = [f"{i}: {line.strip()}" for i, line in enumerate(path.read_text().splitlines(), 1)
                if INTERNALS.search(line.split("#")[0])]
        if hits:
            found[rel] = hits
    assert not found, found
    for f in ("build.py", "cache.py", "address.py"):  # positive control: the pattern sees them
        assert INTERNALS.search((PKG / "compiled" / f).read_text()), f


_KERNEL = """
import numba as nb
from callee import g

@nb.njit(cache=True)
def f(x):
    return g(x) + 1.0
"""

_RUN = """
import sys
sys.path.insert(0, {folder!r})
from kinadapt_nn import compiled
import callee, kernel
if {check}:
    print("dropped", compiled.invalidate_stale([kernel.f, callee.g], [{folder!r} + "/kernel.py",
                                                {folder!r} + "/callee.py"], kernel.f))
print("value", kernel.f(1.0))
"""


def _run(folder: Path, check: bool) -> tuple[float, str]:
    proc = subprocess.run([sys.executable, "-c", _RUN.format(folder=str(folder), check=check)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = dict(line.split(" ", 1) for line in proc.stdout.splitlines())
    return float(out["value"]), out.get("dropped", "")


def test_an_edited_callee_in_another_file_is_recompiled(tmp_path):
    (tmp_path / "kernel.py").write_text(textwrap.dedent(_KERNEL))
    callee = tmp_path / "callee.py"
    callee.write_text("import numba as nb\n\n@nb.njit(cache=True)\ndef g(x):\n    return 10.0 * x\n")
    assert _run(tmp_path, check=True)[0] == 11.0  # compiled and cached, the fingerprint recorded
    assert list((tmp_path / "__pycache__").glob("kernel.f-*.nbi"))
    callee.write_text("import numba as nb\n\n@nb.njit(cache=True)\ndef g(x):\n    return 20.0 * x\n")
    assert _run(tmp_path, check=False)[0] == 11.0  # numba alone: the kernel's cache keeps the old callee
    assert _run(tmp_path, check=True) == (21.0, "True")  # the edit seen: stale code dropped, recompiled
    assert _run(tmp_path, check=True) == (21.0, "False")  # unchanged since: loaded from the cache


def test_the_controllers_fingerprint_covers_every_kernel_file():
    """Every file of the controller that defines a numba kernel (the kernels moved out of core.py
    included) and the layout their constants come from are in the fingerprint the compile phase
    checks (``core.kernel_sources``)."""
    import importlib

    from kinadapt_nn.controller import core

    pkg = PKG.resolve()
    files = sorted(f.resolve() for f in (pkg / "controller").rglob("*.py"))
    for f in files:  # load them all, as a run with any law does
        importlib.import_module("kinadapt_nn." + ".".join(f.relative_to(pkg).with_suffix("").parts).removesuffix(
            ".__init__"))
    with_kernels = {f for f in files if "@nb.njit" in f.read_text()}
    assert {"step_kernels.py", "features_kernels.py", "arm_chain.py", "dense.py", "kalman.py"} <= {
        f.name for f in with_kernels}  # positive control: the scan sees the moved kernels
    sources = {Path(s).resolve() for s in core.kernel_sources()}
    assert with_kernels | {pkg / "controller" / "layout.py"} <= sources, sorted(
        str(f) for f in with_kernels - sources)
