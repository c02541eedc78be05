"""``benchmarks/docs_check.py``: it finds a drifted number, accepts the quoted precision, and the
README's marked blocks print what the README quotes (slow)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.diagnostics.example_scripts import load_script

ROOT = Path(__file__).resolve().parents[1]


def _load():
    return load_script(ROOT / "benchmarks" / "docs_check.py", "docs_check")


dc = _load()

DOC = """# a page

<!-- docs-check: run -->
```bash
echo "Present: tool_gravity (mass 0.25 ± 0.00012 kg, com_y -0.0201 m) and more; falls from 30.9 to 1.34"
printf '| a | x [mm] | wall [s] |\\n|---|---|---|\\n| bore | 5.04 | 0.71 |\\n' > t.md
```

<!-- docs-check: expect -->
> Present: tool_gravity (mass 0.25 ± {sd} kg, com_y −0.0201 m) … falls from 30.9 to {after}

<!-- docs-check: expect-table file=t.md ignore="wall [s]" -->
| a | x [mm] | wall [s] |
|---|---|---|
| bore | {x} | 9.99 |
"""


def _check(tmp_path: Path, monkeypatch, doc: str = DOC, **quoted) -> dict:
    """docs_check on one page written from ``doc`` (its own checkout root, a temp folder)."""
    root = tmp_path / "checkout"
    root.mkdir()
    (root / "page.md").write_text(doc.format(**quoted))
    monkeypatch.setattr(dc, "ROOT", root)
    return dc.check_docs(["page.md"], [], False, tmp_path / "out", False)


def test_quoted_numbers_that_match_pass(tmp_path, monkeypatch):
    res = _check(tmp_path, monkeypatch, sd="0.00012", after="1.34", x="5.04")
    assert res["run"] == 1 and res["problems"] == []
    assert res["numbers"] == 5 + 1  # the excerpt's five and the table's one compared cell (not the wall column)


def test_a_drifted_number_is_named(tmp_path, monkeypatch):
    res = _check(tmp_path, monkeypatch, sd="0.00018", after="1.3", x="5.1")
    text = "\n".join(res["problems"])
    assert len(res["problems"]) == 2, text  # 0.00018 vs 0.00012; 5.1 vs 5.04 (1.3 is 1.34 at the quoted precision)
    assert "quotes 0.00018, the command printed 0.00012" in text and "quotes 5.1, the file has 5.04" in text


def test_text_not_printed_is_a_mismatch(tmp_path, monkeypatch):
    doc = DOC.replace("> Present: tool_gravity", "> Present: tool_tilt")
    res = _check(tmp_path, monkeypatch, doc, sd="0.00012", after="1.34", x="5.04")
    assert len(res["problems"]) == 1 and "not found" in res["problems"][0]


def test_a_failing_block_is_a_mismatch(tmp_path, monkeypatch):
    doc = DOC.replace('echo "Present', 'false\necho "Present')
    res = _check(tmp_path, monkeypatch, doc, sd="0.00012", after="1.34", x="5.04")
    assert res["problems"] == ["page.md:3: the block failed (exit 1)"]


def test_tolerance_is_the_quoted_precision_or_the_markers():
    assert dc.tolerance("0.25", {}) == pytest.approx(0.005)
    assert dc.tolerance("1.2e-3", {}) == pytest.approx(0.5e-4)
    assert dc.tolerance("40", {"tol": "5%"}) == pytest.approx(2.0)


@pytest.mark.slow
def test_readme_blocks_print_what_the_readme_quotes(capsys):
    """The README's marked blocks (the hidden payload example, ~40 s) against their quotes."""
    res = dc.check_docs(["README.md"], [], False, None, False)
    assert res["run"] >= 1 and res["numbers"] >= 10
    assert res["problems"] == [], "\n".join(res["problems"])


def test_prose_numbers_are_traced_to_the_saved_output(tmp_path, monkeypatch):
    """A ``numbers from=FILE`` paragraph: each number of its prose (code spans, link targets and list
    markers aside; ``given`` ones skipped) must be printed in FILE to the quoted precision."""
    out = tmp_path / "out.txt"
    out.write_text("seat_time_s=4.820 max|F|=1.80 N; right 24/24 logs; error 1.18 % -> 0.05 %\n")
    monkeypatch.setattr(dc, "ROOT", tmp_path)

    def check(text: str, given: str = "") -> list[str]:
        ex = dc.Expect(1, "numbers", text, {"from": "out.txt", "given": given})
        return dc.check_numbers(ex)[0]

    ok = ("1. **Seats.** At 4.820 s (paper: 5.1 s), max |F| 1.80 N, 24/24 logs, 1.18 % → 0.05 % "
          "([docs](docs/x2.md), `online/s3.toml`)")
    assert check(ok, given="5.1") == []
    assert len(check(ok)) == 1  # 5.1 is not printed: an input must be declared given
    bad = check(ok.replace("4.820", "4.83"), given="5.1")
    assert len(bad) == 1 and "4.83" in bad[0]
    assert check("max |F| 1.8 N", given="") == []  # a coarser quote of 1.80 is the same number
    assert dc.prose_numbers("see [eq. 3](docs/e.md#eq4) and `x=7`, iiwa14 at 2 s") == ["3", "2"]  # a label is prose
