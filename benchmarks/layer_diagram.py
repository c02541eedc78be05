"""The package's layers drawn from the code itself: every subpackage of ``kinadapt_nn`` in its layer
(the table ``LAYERS`` of ``tests/test_layout.py``, the test that enforces it) and the imports between
layers as the source has them (``tests/test_layout.py``'s ``GRAPH``: every import read with ``ast``,
inside functions too).

    python benchmarks/layer_diagram.py [--out docs/figures/layers.png]

Left: the layer stack, bottom (0, the ground) to top (9, the command line), each layer's
subpackages with their module counts, and one arc per pair of units that import across layers
(importer -> imported, the line's width growing with the number of module-to-module imports).
Right: the same imports as a table (rows import columns); an import up a layer would land above
the diagonal, drawn red. The ground modules (the top-level files) are one unit of layer 0 beside
``compiled/``. Prints the layers and the counts; exits 1 when a subpackage has no layer in
``LAYERS`` (drawn in a red "unplaced" row) or when an import runs up a layer.
"""

from __future__ import annotations

import argparse
import math
import sys
import textwrap
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import matplotlib  # noqa: E402  (after the repository is on sys.path, for tests.test_layout)

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)

from tests import test_layout  # noqa: E402  (the layer table and the import graph)

GROUND = "ground modules"  # the top-level files of the package, layer 0


def subpackages(pkg: Path) -> list[str]:
    """The subpackages directly under ``pkg`` (folders holding an ``__init__.py``), sorted."""
    return sorted(p.parent.name for p in pkg.glob("*/__init__.py"))


def layer_table(pkg: Path, layers: dict[str, int]) -> tuple[dict[int, list[str]], list[str]]:
    """-> ({layer: [units]}, unplaced subpackages). Units: ``GROUND`` (the top-level files, layer 0)
    and each subpackage (``name/``) at its layer in ``layers``; a subpackage missing from ``layers``
    is unplaced (the layout test would count it as ground)."""
    table: dict[int, list[str]] = {0: [GROUND]}
    unplaced = []
    for name in subpackages(pkg):
        if name in layers:
            table.setdefault(layers[name], []).append(name + "/")
        else:
            unplaced.append(name + "/")
    return dict(sorted(table.items())), unplaced


def unit_of(module: str, pkg_names: set[str]) -> str:
    """``kinadapt_nn.runs.batch`` -> ``runs/``; a top-level module (or the package itself) -> ``GROUND``."""
    parts = module.split(".")
    return parts[1] + "/" if len(parts) >= 2 and parts[1] in pkg_names else GROUND


def cross_layer_imports(graph: dict[str, set[str]], pkg_names: set[str],
                        layer_of: dict[str, int | None]) -> Counter:
    """(importing unit, imported unit) -> the number of module-to-module imports between two units of
    different layers, or to or from an unplaced unit (layer None); ``graph``: module -> the package
    modules it imports."""
    count: Counter = Counter()
    for a, deps in graph.items():
        ua = unit_of(a, pkg_names)
        for b in deps:
            ub = unit_of(b, pkg_names)
            la, lb = layer_of.get(ua, 0), layer_of.get(ub, 0)
            if ua != ub and (la is None or lb is None or la != lb):
                count[(ua, ub)] += 1
    return count


def _module_counts(modules, pkg_names: set[str]) -> Counter:
    return Counter(unit_of(m, pkg_names) for m in modules)


def _stack(ax, table: dict[int, list[str]], unplaced: list[str], edges: Counter, n_mod: Counter,
           ground: list[str]) -> dict:
    """The layer stack with its arcs on ``ax``; -> unit -> (x, y) of its box's right edge."""
    rows = [*table.items(), *([("?", unplaced)] if unplaced else [])]
    anchor = {}
    for i, (lay, units) in enumerate(rows):
        y = float(i)
        bad = lay == "?"
        ax.axhspan(y - 0.45, y + 0.45, color="#fbe3e3" if bad else ("#f1f1f1" if i % 2 else "#e6eef7"), zorder=0)
        ax.text(-0.02, y, "unplaced" if bad else str(lay), ha="right", va="center", fontsize=11, weight="bold",
                color="#b00" if bad else "k")
        w = 0.5 / len(units)
        for k, u in enumerate(sorted(units, key=lambda u: u == GROUND)):  # the ground last: most arcs end there
            x0 = 0.05 + k * w
            ax.add_patch(plt.Rectangle((x0 + 0.01, y - 0.32), w - 0.02, 0.64, facecolor="white",
                                       edgecolor="#b00" if bad else "#345", lw=1.2, zorder=2))
            ax.text(x0 + w / 2, y, f"{u}\n{n_mod[u]} modules", ha="center", va="center",
                    fontsize=9 if len(units) == 1 else 8, zorder=3)
            anchor[u] = (x0 + w - 0.01, y)
    n_rows = len(rows)
    y_of = {u: xy[1] for u, xy in anchor.items()}
    for (a, b), n in sorted(edges.items(), key=lambda e: -e[1]):
        if a not in anchor or b not in anchor:
            continue
        up = y_of[b] > y_of[a]
        xa, ya = anchor[a]
        xb, yb = anchor[b]
        shift = 0.03 * (y_of[b] - y_of[a])  # spread the ends over the box's edge by the other end's layer
        ax.annotate("", xy=(xb, yb + 0.25 * shift), xytext=(xa, ya + 0.25 * shift), zorder=1,
                    arrowprops=dict(arrowstyle="-|>", lw=0.4 + 0.9 * math.log10(1 + n), shrinkA=0, shrinkB=0,
                                    color="#c00" if up else "#3a6ea5", alpha=0.75, mutation_scale=8,
                                    connectionstyle=f"arc3,rad={-0.5 if ya > yb else 0.5}"))
    ax.text(0.05, -0.55, textwrap.fill(f"{GROUND}: " + ", ".join(ground), 75), ha="left", va="top", fontsize=8)
    ax.set_xlim(-0.12, 1.02)
    ax.set_ylim(-0.9, n_rows - 0.4)
    ax.axis("off")
    ax.set_title("layers, bottom to top; arcs: imports across layers (importer -> imported)", fontsize=10)
    return anchor


def _matrix(ax, order: list[str], edges: Counter, layer_of: dict[str, int]) -> None:
    """The cross-layer import counts, rows importing columns, the top layer first."""
    rows = order[::-1]
    n = len(order)
    for i, a in enumerate(rows):
        for j, b in enumerate(order):
            c = edges.get((a, b), 0)
            up = layer_of.get(b, 99) > layer_of.get(a, 99)
            face = "#c00" if (up and c) else ("#eeeeee" if up or layer_of.get(a) == layer_of.get(b) else
                                             ("#3a6ea5" if c else "white"))
            ax.add_patch(plt.Rectangle((j, n - 1 - i), 1, 1, facecolor=face, edgecolor="#ccc", lw=0.5,
                                       alpha=min(1.0, 0.25 + 0.25 * math.log10(1 + c)) if c else 1.0))
            if c:
                ax.text(j + 0.5, n - 0.5 - i, str(c), ha="center", va="center", fontsize=8)
    ax.set_xlim(0, n)
    ax.set_ylim(0, n)
    ax.set_xticks([j + 0.5 for j in range(n)], order, rotation=60, ha="right", fontsize=8)
    ax.set_yticks([n - 0.5 - i for i in range(n)], rows, fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("imported (layer 0 left)")
    ax.set_ylabel("importing")
    ax.set_title("module-to-module imports across layers\n(grey: same layer or up a layer, never allowed)",
                 fontsize=10)


def draw(out: Path, pkg: Path = test_layout.PKG, layers: dict[str, int] = test_layout.LAYERS,
         graph: dict[str, set[str]] = test_layout.GRAPH) -> dict:
    """Draw the diagram into ``out`` (PNG). -> {"table": {layer: [units]}, "unplaced": [...],
    "edges": {(a, b): n}, "up": [(a, b)], "drawn_labels": the stack's box labels as drawn}."""
    table, unplaced = layer_table(pkg, layers)
    pkg_names = set(subpackages(pkg))
    layer_of: dict[str, int | None] = {u: lay for lay, units in table.items() for u in units}
    layer_of.update({u: None for u in unplaced})
    edges = cross_layer_imports(graph, pkg_names, layer_of)
    up = sorted((a, b) for a, b in edges if None not in (layer_of[a], layer_of[b]) and layer_of[b] > layer_of[a])
    n_mod = _module_counts(graph, pkg_names)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 7.5), gridspec_kw={"width_ratios": [1.1, 1]})
    ground = sorted(p.stem for p in pkg.glob("*.py") if p.stem != "__init__")
    _stack(a1, table, unplaced, edges, n_mod, [*ground, "the package's __init__"])
    order = [u for units in table.values() for u in units]
    _matrix(a2, order, edges, layer_of)
    fig.suptitle(f"kinadapt_nn: {len(graph)} modules in {len(table)} layers, {sum(edges.values())} imports "
                 "across layers (from the source: benchmarks/layer_diagram.py)", fontsize=11)
    fig.tight_layout()
    labels = [t.get_text().split("\n")[0] for t in a1.texts if "\n" in t.get_text()]
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return {"table": table, "unplaced": unplaced, "edges": dict(edges), "up": up, "drawn_labels": labels}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "layers.png"), help="the PNG to write")
    args = ap.parse_args(argv)
    res = draw(Path(args.out))
    n_mod = _module_counts(test_layout.GRAPH, set(subpackages(test_layout.PKG)))
    for lay, units in reversed(res["table"].items()):
        print(f"layer {lay}: " + ", ".join(f"{u} ({n_mod[u]} modules)" for u in units))
    for (a, b), n in sorted(res["edges"].items(), key=lambda e: (-e[1], e[0])):
        print(f"  {a:16s} -> {b:16s} {n:3d} imports")
    print(f"cross-layer imports: {sum(res['edges'].values())} between {len(res['edges'])} pairs of units; "
          f"up a layer: {len(res['up'])}; unplaced subpackages: {len(res['unplaced'])}")
    print(f"wrote {args.out}")
    if res["unplaced"]:
        print("not in tests/test_layout.py's LAYERS: " + ", ".join(res["unplaced"]), file=sys.stderr)
    return 1 if res["unplaced"] or res["up"] else 0


if __name__ == "__main__":
    sys.exit(main())
