"""Run the documentation's commands and compare the numbers it quotes with what they print.

    python benchmarks/docs_check.py [--slow] [--only FILE[:LINE]] [--keep DIR] [--list] [--installed]

**Marking a block.** An HTML comment on the line before a fenced block (invisible when rendered):

    <!-- docs-check: run [slow] [timeout=600] [rc=0] -->
    ```bash
    kinadapt diagnose runs/... --out runs/wp
    ```

runs the block with ``bash -e`` (a trailing ``\\`` continues a line, as in a shell). Every marked
block of one file runs, in order, in one fresh working folder (a temp dir) that holds a link to
each top-level entry of the checkout but ``runs/``, so ``runs/...`` lands in the temp dir and a
later block uses what an earlier one wrote, exactly as a reader pasting them in order would.
``slow`` blocks (minutes: comparisons, sweeps) run only with ``--slow``; a block that needs a
``slow`` block's outputs is ``slow`` itself. Unmarked blocks (installs, placeholders such as
``my_log.csv``, the whole test suite) are never run.

``kinadapt`` and ``python`` in a block are this checkout's: a shim first on ``PATH`` runs
``python -m kinadapt_nn.app.cli`` with ``PYTHONPATH`` at the checkout (with ``--installed``: the
``kinadapt`` script already on ``PATH``, as in a fresh clone after ``pip install -e .``).

**Tracing prose to printed lines.** Before a paragraph (a headline list, say)

    <!-- docs-check: numbers from=benchmarks/results/readme_numbers.txt[,FILE...] [given="5.1 1000"] -->

every number in the paragraph (outside code spans and link targets) must be one that the named
files -- the saved output of the commands that measure them -- print, to the quoted precision
(``tol=`` / ``abs=`` as below); ``given`` lists the numbers that are inputs (a seed, a config
value, the paper's figure), not measurements. Nothing is run: the files are checked as they are,
so they must be the output of the session that wrote the paragraph.

**Marking what it prints.** After a run block, any number of

    <!-- docs-check: expect [tol=2%] [abs=0.001] -->

each before the paragraph it checks: a blockquote (``> ...``) is one quoted excerpt; in any
other paragraph, each inline code span is one. An excerpt must appear in the output of the file's
last run block (stdout and stderr), ``…`` standing for any text and every number in it compared
with the number printed at its place: equal to the quoted precision (half a unit of the last
quoted digit) unless ``tol=`` (relative) or ``abs=`` widens it. ``−`` and ``-`` are the same sign.

    <!-- docs-check: expect-table file=runs/compare/comparison.md [rows=1-12] ignore="wall [s]" [tol=...] -->

before a Markdown table compares it cell by cell with the table in that file (a path in the
working folder; ``rows=N-M``: the text quotes rows N to M of it), rows matched in order; the
``ignore`` columns (comma-separated) (speed: seconds, ratios -- which
are re-measured by ``benchmarks/readme_numbers.py`` and name the machine, never compared here) are
skipped.

Prints one line per block and per mismatch, then the totals; exit 1 on any mismatch or failed
block, 0 otherwise.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
MARK = re.compile(r"^\s*<!--\s*docs-check:\s*(run|expect-table|expect|numbers)\b(.*?)-->\s*$")
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
ELLIPSIS = "…"


@dataclass
class Expect:
    """One quoted excerpt (``kind`` "text") or table (``kind`` "table") and where it stands."""

    line: int  #: 1-based line of its marker
    kind: str
    text: str  #: the excerpt, or the table's Markdown
    attrs: dict


@dataclass
class Block:
    """A marked runnable block and the expectations that follow it."""

    file: str
    line: int  #: 1-based line of its marker
    code: str
    attrs: dict
    expects: list[Expect] = field(default_factory=list)


def parse_attrs(text: str) -> dict:
    """``slow timeout=600 ignore="wall [s]"`` -> ``{"slow": True, "timeout": "600", "ignore": "wall [s]"}``."""
    out: dict = {}
    for tok in shlex.split(text):
        key, eq, val = tok.partition("=")
        out[key] = val if eq else True
    return out


def _fence_at(lines: list[str], i: int) -> tuple[str, int]:
    """The fenced block whose opening fence is at or after line ``i`` -> (body, index after it)."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines) or not lines[i].lstrip().startswith("```"):
        raise ValueError(f"line {i + 1}: a docs-check 'run' marker must stand right before a ``` fence")
    j = i + 1
    while j < len(lines) and not lines[j].lstrip().startswith("```"):
        j += 1
    return "\n".join(lines[i + 1:j]), j + 1


def _paragraph_at(lines: list[str], i: int) -> tuple[list[str], int]:
    """The paragraph (lines up to a blank one) starting at or after line ``i``."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    j = i
    while j < len(lines) and lines[j].strip():
        j += 1
    return lines[i:j], j


def excerpts(par: list[str]) -> list[str]:
    """The quoted excerpts of a paragraph: a blockquote whole, else each inline code span."""
    if par and all(ln.lstrip().startswith(">") for ln in par):
        return [" ".join(ln.lstrip()[1:].strip() for ln in par)]
    return [m.strip() for m in re.findall(r"`([^`]+)`", " ".join(ln.strip() for ln in par), flags=re.DOTALL)]


def parse_doc(path: Path, name: str) -> list[Block]:
    """The marked blocks of one Markdown file, each with its expectations."""
    lines = path.read_text().splitlines()
    blocks: list[Block] = []
    i = 0
    while i < len(lines):
        m = MARK.match(lines[i])
        if not m:
            i += 1
            continue
        kind, attrs, at = m.group(1), parse_attrs(m.group(2)), i + 1
        if kind == "numbers":  # prose traced to saved output: no block needed
            par, i = _paragraph_at(lines, i + 1)
            blocks.append(Block(name, at, "", {**attrs, "numbers": True}, [Expect(at, "numbers", "\n".join(par), attrs)]))
            continue
        if kind == "run":
            code, i = _fence_at(lines, i + 1)
            blocks.append(Block(name, at, code, attrs))
            continue
        if not blocks:
            raise ValueError(f"{name}:{at}: a docs-check '{kind}' marker before any 'run' block")
        par, i = _paragraph_at(lines, i + 1)
        if kind == "expect-table":
            blocks[-1].expects.append(Expect(at, "table", "\n".join(par), attrs))
        else:
            blocks[-1].expects.extend(Expect(at, "text", x, attrs) for x in excerpts(par))
    return blocks


def _norm(text: str) -> str:
    return text.replace("−", "-").replace("\u2009", " ").replace("\u00a0", " ")


def _pattern(excerpt: str) -> tuple[re.Pattern, list[str]]:
    """A regex for ``excerpt`` (``…`` any text, whitespace any whitespace, each number a group)
    and the quoted numbers in order."""
    parts, nums, pos = [], [], 0
    text = _norm(excerpt).strip()
    for m in NUMBER.finditer(text):
        parts.append(_literal(text[pos:m.start()]))
        parts.append(r"([-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?)")
        nums.append(m.group(0))
        pos = m.end()
    parts.append(_literal(text[pos:]))
    return re.compile("".join(parts), re.DOTALL), nums


def _literal(text: str) -> str:
    """A regex for literal text: ``…`` any text (lazily), whitespace any whitespace (none needed
    beside a ``…``), everything else itself."""
    pieces = text.split(ELLIPSIS)
    out = []
    for k, piece in enumerate(pieces):
        if k:
            out.append(r".*?")
        toks = [t for t in re.split(r"(\s+)", piece) if t]
        for i, t in enumerate(toks):
            if not t.isspace():
                out.append(re.escape(t))
            elif (i == 0 and k > 0) or (i == len(toks) - 1 and k < len(pieces) - 1):
                out.append(r"\s*")
            else:
                out.append(r"\s+")
    return "".join(out)


def tolerance(quoted: str, attrs: dict) -> float:
    """[same unit as the number] the allowed |printed - quoted|: half a unit of the last quoted
    digit, or the marker's ``abs=`` / ``tol=`` (relative, ``2%`` or ``0.02``) when wider."""
    mant, _, exp = quoted.lower().partition("e")
    decimals = len(mant.partition(".")[2])
    tol = 0.5 * 10.0 ** (-decimals) * 10.0 ** (int(exp) if exp else 0) * (1 + 1e-9)
    if "abs" in attrs:
        tol = max(tol, float(attrs["abs"]))
    if "tol" in attrs:
        rel = attrs["tol"]
        rel = float(rel[:-1]) / 100 if rel.endswith("%") else float(rel)
        tol = max(tol, rel * abs(float(quoted)))
    return tol


def check_text(ex: Expect, output: str) -> list[str]:
    """Mismatches of one quoted excerpt against a block's output (empty: it matches)."""
    pat, nums = _pattern(ex.text)
    m = pat.search(_norm(output))
    if m is None:
        return [f"quoted output not found in what the block printed: {ex.text[:160]!r}"]
    bad = []
    for q, got in zip(nums, m.groups()):
        if not math.isclose(float(got), float(q), rel_tol=0.0, abs_tol=tolerance(q, ex.attrs)):
            bad.append(f"the text quotes {q}, the command printed {got} (in {ex.text[:80]!r}…)")
    return bad


def md_table(text: str) -> tuple[list[str], list[list[str]]]:
    """A Markdown table -> (header cells, rows of cells); the separator row dropped."""
    rows = [[c.strip() for c in ln.strip().strip("|").split("|")] for ln in text.splitlines() if ln.strip().startswith("|")]
    rows = [r for r in rows if not all(re.fullmatch(r":?-+:?", c) for c in r)]
    return (rows[0], rows[1:]) if rows else ([], [])


def check_table(ex: Expect, work: Path) -> tuple[list[str], int]:
    """Mismatches of a quoted table against the table in ``file=`` -> (mismatches, numbers compared)."""
    path = work / str(ex.attrs.get("file", ""))
    if not path.is_file():
        return [f"expect-table: the command wrote no {ex.attrs.get('file')!r}"], 0
    head, rows = md_table(ex.text)
    head_f, rows_f = md_table(path.read_text())
    if "rows" in ex.attrs:  # "N-M": the text quotes rows N..M (1-based) of the file's table
        lo, _, hi = str(ex.attrs["rows"]).partition("-")
        rows_f = rows_f[int(lo) - 1:int(hi or lo)]
    if head != head_f or len(rows) != len(rows_f):
        return [(f"expect-table: the columns or the row count differ: text {head} x {len(rows)}, "
                 f"file {head_f} x {len(rows_f)}")], 0
    skip = {c.strip() for c in str(ex.attrs.get("ignore", "")).split(",") if c.strip()}
    bad, n = [], 0
    for r, (a, b) in enumerate(zip(rows, rows_f), 1):
        for col, x, y in zip(head, a, b):
            if col in skip:
                continue
            if NUMBER.fullmatch(_norm(x)) and NUMBER.fullmatch(_norm(y)):
                n += 1
                if not math.isclose(float(_norm(y)), float(_norm(x)), rel_tol=0.0,
                                    abs_tol=tolerance(_norm(x), ex.attrs)):
                    bad.append(f"table row {r} ({' '.join(a[:3])}), column {col!r}: the text quotes {x}, the file has {y}")
            elif x != y:
                bad.append(f"table row {r}, column {col!r}: the text has {x!r}, the file {y!r}")
    return bad, n


def prose_numbers(text: str) -> list[str]:
    """The numbers of prose: outside inline code spans and link targets, list markers (``1.``) and
    numbers inside words (``S2``, ``5x``'s ``5`` stays) aside."""
    text = re.sub(r"`[^`]*`", " ", text)
    text = re.sub(r"\]\([^)]*\)", "]", text)  # [label](target): the target is not prose
    text = re.sub(r"(?m)^\s*\d+\.\s", " ", text)
    out = []
    for m in NUMBER.finditer(_norm(text)):
        before = text[m.start() - 1] if m.start() else " "
        if before.isalpha() or before == "_":
            continue
        out.append(m.group(0).lstrip("+"))
    return out


def check_numbers(ex: Expect) -> tuple[list[str], int]:
    """Every number of a traced paragraph against the numbers its ``from=`` files print."""
    files = [f for f in str(ex.attrs.get("from", "")).split(",") if f]
    printed = []
    for f in files:
        path = ROOT / f
        if not path.is_file():
            return [f"numbers: the file {f!r} (the measuring command's saved output) is missing"], 0
        printed += [float(x) for x in NUMBER.findall(_norm(path.read_text()))]
    given = {g for g in str(ex.attrs.get("given", "")).split() if g}
    bad, n = [], 0
    for q in prose_numbers(ex.text):
        if q in given or q.lstrip("-") in given:
            continue
        n += 1
        tol = tolerance(q, ex.attrs)
        if not any(math.isclose(abs(v), abs(float(q)), rel_tol=0.0, abs_tol=tol) for v in printed):
            bad.append(f"the text says {q}; no file of {files} prints it (to the quoted precision)")
    return bad, n


def _shims(bin_dir: Path, installed: bool) -> dict:
    """The environment of a block: this checkout's ``kinadapt`` and ``python`` first on PATH."""
    bin_dir.mkdir(parents=True, exist_ok=True)
    shims = {"python": "", "python3": ""} | ({} if installed else {"kinadapt": " -m kinadapt_nn.app.cli"})
    for name, args in shims.items():  # scripts, not links: a venv's python finds its venv by its own path
        (bin_dir / name).write_text(f'#!/bin/sh\nexec "{sys.executable}"{args} "$@"\n')
        (bin_dir / name).chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}")
    if not installed:
        env["PYTHONPATH"] = f"{ROOT}{os.pathsep}{env['PYTHONPATH']}" if env.get("PYTHONPATH") else str(ROOT)
    return env


def _workdir(base: Path) -> Path:
    """A fresh working folder: a link to each top-level entry of the checkout but ``runs``."""
    base.mkdir(parents=True)
    for p in ROOT.iterdir():
        if p.name not in ("runs", ".git") and not p.name.startswith(".venv"):
            (base / p.name).symlink_to(p)
    return base


def run_block(b: Block, work: Path, env: dict) -> tuple[int | None, str, float]:
    """Run a block's code in ``work`` -> (exit code or None on timeout, stdout + stderr, wall s)."""
    t0 = time.perf_counter()
    try:
        p = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", b.code], check=False, cwd=work, env=env, text=True,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=float(b.attrs.get("timeout", 900)))
        return p.returncode, p.stdout, time.perf_counter() - t0
    except subprocess.TimeoutExpired as e:
        out = e.stdout.decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
        return None, out, time.perf_counter() - t0


def check_block(b: Block, work: Path, env: dict) -> tuple[list[str], int]:
    """Run one block and check its expectations -> (problems, numbers compared)."""
    if b.attrs.get("numbers"):
        bad, n = check_numbers(b.expects[0])
        where = f"{b.file}:{b.line}"
        print(f"{where} numbers traced to {b.attrs.get('from')}: {n} number(s), {len(bad)} mismatch(es)", flush=True)
        for p in bad:
            print(f"  MISMATCH {where}: {p}", flush=True)
        return [f"{where}: {p}" for p in bad], n
    rc, out, wall = run_block(b, work, env)
    ok_rc = {int(x) for x in str(b.attrs.get("rc", "0")).split(",")}
    where = f"{b.file}:{b.line}"
    if rc is None or rc not in ok_rc:
        why = "timed out" if rc is None else f"exit {rc}"
        print(f"{where} run FAILED ({why}, {wall:.1f} s); last output: {out.strip()[-400:]!r}", flush=True)
        return [f"{where}: the block failed ({why})"], 0
    problems, n = [], 0
    for ex in b.expects:
        if ex.kind == "table":
            bad, k = check_table(ex, work)
        else:
            bad, k = check_text(ex, out), len(_pattern(ex.text)[1])
        n += k
        problems += [f"{b.file}:{ex.line}: {x}" for x in bad]
    print(f"{where} run ok ({wall:.1f} s): {len(b.expects)} quoted excerpt(s), {n} number(s) compared, "
          f"{len(problems)} mismatch(es)", flush=True)
    for p in problems:
        print(f"  MISMATCH {p}", flush=True)
    return problems, n


def select(blocks: list[Block], only: list[str], slow: bool) -> tuple[list[Block], list[Block]]:
    """The blocks to run and those skipped (``slow`` without ``--slow``; outside ``--only``)."""
    def wanted(b: Block) -> bool:
        if not only:
            return True
        return any(o == b.file or o == f"{b.file}:{b.line}" for o in only)

    chosen = [b for b in blocks if wanted(b)]
    run = [b for b in chosen if slow or not b.attrs.get("slow")]
    return run, [b for b in chosen if b not in run]


def check_docs(files: list[str], only: list[str], slow: bool, keep: Path | None, installed: bool) -> dict:
    """Run the marked blocks of ``files`` (paths relative to the checkout) and compare -> totals."""
    blocks = [b for f in files for b in parse_doc(ROOT / f, f)]
    run, skipped = select(blocks, only, slow)
    for b in skipped:
        print(f"{b.file}:{b.line} skipped ({'slow: --slow runs it' if b.attrs.get('slow') else 'not in --only'})")
    tmp = tempfile.TemporaryDirectory(prefix="docs_check_") if keep is None else None
    base = Path(tmp.name) if tmp else keep
    env = _shims(base / "bin", installed)
    problems, numbers, works = [], 0, {}
    for b in run:
        work = works.get(b.file) or _workdir(base / re.sub(r"\W", "_", b.file))
        works[b.file] = work
        bad, n = check_block(b, work, env)
        problems += bad
        numbers += n
    if tmp:
        tmp.cleanup()
    print(f"docs_check: {len(run)} block(s) run, {len(skipped)} skipped, {numbers} number(s) compared, "
          f"{len(problems)} mismatch(es)")
    return {"run": len(run), "skipped": len(skipped), "numbers": numbers, "problems": problems}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--slow", action="store_true", help="also run the blocks marked slow (minutes each)")
    ap.add_argument("--only", action="append", default=[], help="FILE or FILE:LINE (the marker's line); repeatable")
    ap.add_argument("--keep", type=Path, help="run in this (new) folder and keep it, instead of a temp dir")
    ap.add_argument("--list", action="store_true", help="list the marked blocks and exit")
    ap.add_argument("--installed", action="store_true",
                    help="use the kinadapt script on PATH instead of this checkout's code")
    a = ap.parse_args(argv)
    if a.keep is not None and a.keep.exists():
        ap.error(f"--keep {a.keep}: exists; name a new folder")
    if a.list:
        for f in DOCS:
            for b in parse_doc(ROOT / f, f):
                print(f"{b.file}:{b.line} {'slow ' if b.attrs.get('slow') else ''}"
                      f"({len(b.expects)} expectation(s)): "
                      + (f"numbers traced to {b.attrs.get('from')}" if b.attrs.get("numbers") else b.code.splitlines()[0][:90]))
        return 0
    res = check_docs(DOCS, a.only, a.slow, a.keep, a.installed)
    return 1 if res["problems"] else 0


if __name__ == "__main__":
    sys.exit(main())
