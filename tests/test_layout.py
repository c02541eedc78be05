"""The package layout is the architecture: layers, no import circles, and the truth firewall.

Every import is read from the source (``ast``), including imports inside functions and under
``TYPE_CHECKING``, so a lazy import cannot slip past. Layers, bottom to top::

    0  the ground modules (errors, config, known, robot, geometry, sensing, trace, runio, figures)
       and compiled/ (compile management of the numba kernels, used from sim/ up)
    1  sim/          the simulated world and its truth
    2  learning/     the network, its checkpoints, pretraining
    3  effects/      the physical effects' model side: the @effect contract, the built-ins, the
                     declared socket (used by the diagnosis and the controller's online columns)
    4  features/     J_hat = Y(q) theta (controller side)
    5  controller/   sensing -> value force -> admittance -> law (controller side)
    6  runs/         episodes, batches, sweeps, comparisons
    7  diagnostics/  model vs measurement
    8  monitor/      the live monitor
    9  paper/        the preprint's claims
   10  app/          the command line, views

An import may go to the same layer or a lower one, never up, and no two modules import each
other through any chain. From the controller side (controller/, features/) no chain of imports
may reach the simulator, the runs, the diagnosis or pretraining; nor from effects/, which features/
reads.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import kinadapt_nn

PKG = Path(kinadapt_nn.__file__).parent
LAYERS = {"compiled": 0, "sim": 1, "learning": 2, "effects": 3, "features": 4, "controller": 5, "runs": 6,
          "diagnostics": 7, "monitor": 8, "paper": 9, "app": 10}
CONTROLLER_SIDE = ("kinadapt_nn.controller", "kinadapt_nn.features", "kinadapt_nn.effects")  # (effects: read by features)
FORBIDDEN_FROM_CONTROLLER = ("kinadapt_nn.sim", "kinadapt_nn.runs", "kinadapt_nn.diagnostics", "kinadapt_nn.paper",
                             "kinadapt_nn.app", "kinadapt_nn.learning.pretrain", "kinadapt_nn.learning.prior")


def _all_modules() -> dict[str, Path]:
    mods = {}
    for path in PKG.rglob("*.py"):
        rel = path.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = path
    return mods


MODULES = _all_modules()


def imports_of(name: str) -> set[str]:
    """The package's modules that module ``name`` imports anywhere in its source (parents of an
    imported module included: importing ``a.b.c`` runs ``a/__init__`` and ``a/b/__init__``)."""
    path = MODULES[name]
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    found: set[str] = set()
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        for t in targets:
            parts = t.split(".")
            for k in range(1, len(parts) + 1):
                cand = ".".join(parts[:k])
                if cand in MODULES and cand != name and not name.startswith(cand + "."):  # own package: loading already
                    found.add(cand)
    return found


GRAPH = {m: imports_of(m) for m in MODULES}


def reach(start: str) -> dict[str, str]:
    """Every module reachable from ``start`` -> the module that imports it on the first path found."""
    seen: dict[str, str] = {}
    todo = [start]
    while todo:
        m = todo.pop()
        for n in GRAPH[m]:
            if n not in seen and n != start:
                seen[n] = m
                todo.append(n)
    return seen


def _chain(start: str, end: str, via: dict[str, str]) -> str:
    path = [end]
    while path[-1] != start:
        path.append(via[path[-1]])
    return " -> ".join(reversed(path))


def layer(mod: str) -> int:
    parts = mod.split(".")
    return LAYERS.get(parts[1], 0) if len(parts) >= 2 else 0


def test_the_walker_sees_imports_inside_functions():
    """Positive control: the walker must find what a lazy import reaches (runs -> sim)."""
    assert "kinadapt_nn.sim.adapter" in reach("kinadapt_nn.runs.episode")
    assert "kinadapt_nn.runs.episode" in reach("kinadapt_nn.app.cli")  # imported inside cmd_online (app/online.py)


@pytest.mark.parametrize("start", sorted(m for m in MODULES if m.startswith(CONTROLLER_SIDE)))
def test_the_controller_side_never_reaches_the_simulator(start):
    via = reach(start)
    bad = [m for m in via if m.startswith(FORBIDDEN_FROM_CONTROLLER)]
    assert not bad, "truth firewall broken: " + "; ".join(_chain(start, b, via) for b in bad)


@pytest.mark.parametrize("start", sorted(m for m in MODULES if m.startswith(CONTROLLER_SIDE)))
def test_the_controller_side_never_takes_the_experiment_config(start):
    """Controller and features are built from ``KnownCfg`` (what a real robot knows), never from
    the experiment config that holds the true tool, the arm errors and the hidden effects."""
    src = MODULES[start].read_text()
    for name in ("ExperimentCfg", "load_config", "true_bore_entry"):
        assert name not in src, f"{start} mentions {name}: take kinadapt_nn.known.KnownCfg instead"


def test_no_import_runs_back_up_a_layer():
    bad = [f"{a} -> {b}" for a, deps in GRAPH.items() for b in deps if layer(b) > layer(a)]
    assert not bad, "imports that run back up: " + ", ".join(sorted(bad))


def test_no_import_circles():
    circles = sorted(f"{a} <-> {b}" for a in GRAPH for b in GRAPH[a] if a < b and a in reach(b))
    assert not circles, "import circles: " + ", ".join(circles)


def test_at_most_ten_top_level_modules():
    top = sorted(p.name for p in PKG.glob("*.py"))
    assert len(top) <= 10, top
