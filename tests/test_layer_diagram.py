"""``benchmarks/layer_diagram.py`` draws the package's layers from the code: every subpackage is placed
in the layer table it draws (a new subpackage missing from ``tests/test_layout.py``'s ``LAYERS`` fails
here), and the imports it counts across layers are those of the layout test's graph."""

from __future__ import annotations

from pathlib import Path

from tests import test_layout
from tests.diagnostics.example_scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
ld = load_script(ROOT / "benchmarks" / "layer_diagram.py", "layer_diagram")


def _subpackages_on_disk(pkg: Path) -> list[str]:
    """Every folder of ``pkg`` that holds Python files (not only those with an ``__init__.py``)."""
    return sorted(d.name for d in pkg.iterdir() if d.is_dir() and any(d.rglob("*.py")))


def test_the_diagram_places_every_subpackage(tmp_path):
    out = tmp_path / "layers.png"
    res = ld.draw(out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000
    subs = _subpackages_on_disk(test_layout.PKG)
    assert len(subs) >= 10
    missing = [s for s in subs if s + "/" not in res["drawn_labels"]]
    assert not missing, f"subpackages not in the drawn layer table: {missing} (add them to tests/test_layout.py's LAYERS)"
    assert res["unplaced"] == [] and res["up"] == []
    placed = {u: lay for lay, units in res["table"].items() for u in units}
    assert all(placed[s + "/"] == test_layout.LAYERS[s] for s in subs)


def test_the_counted_imports_are_the_layout_graphs(tmp_path):
    """Cross-layer imports counted by the diagram = the layout test's module pairs on different layers."""
    res = ld.draw(tmp_path / "layers.png")
    expected = sum(1 for a, deps in test_layout.GRAPH.items() for b in deps
                   if test_layout.layer(a) != test_layout.layer(b))
    assert sum(res["edges"].values()) == expected > 0
    assert res["edges"].get(("runs/", "controller/"), 0) > 0  # the episode loop steps the controller


def test_a_subpackage_without_a_layer_is_drawn_unplaced(tmp_path):
    """Control: a package with a folder missing from the layer table -> listed and drawn as unplaced."""
    pkg = tmp_path / "pkg"
    for name in ("low", "high", "extra"):
        (pkg / name).mkdir(parents=True)
        (pkg / name / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    graph = {"pkg": set(), "pkg.low": set(), "pkg.high": {"pkg.low"}, "pkg.extra": {"pkg.high"}}
    res = ld.draw(tmp_path / "x.png", pkg=pkg, layers={"low": 1, "high": 2}, graph=graph)
    assert res["unplaced"] == ["extra/"] and "extra/" in res["drawn_labels"]
    assert res["edges"] == {("high/", "low/"): 1, ("extra/", "high/"): 1}
    up = ld.draw(tmp_path / "y.png", pkg=pkg, layers={"low": 2, "high": 1, "extra": 3}, graph=graph)
    assert up["up"] == [("high/", "low/")]
