"""One value's route through the package, traced as the code runs: the modules it visits and the
calls that run back up a layer.

    python benchmarks/trace_counts.py --follow MODULE:FUNCTION[:PARAM] [--value TEXT] [--no-forms] -- KINADAPT-ARGS...

Runs ``kinadapt KINADAPT-ARGS`` (``kinadapt_nn.app.cli.main``) in this process under
``sys.setprofile`` and follows one value: the argument ``PARAM`` of the first call of
``MODULE.FUNCTION`` (with ``--value``: every argument equal to the string TEXT from that first call
on, e.g. the name a config gives ``run.features``; PARAM may then be left out). A call of a package
function that receives a followed object (by identity; the parts of a pydantic model, its sub-models,
and of the command line's ``argparse.Namespace``, its values, count too) is a *stay* of the value in that function's module, and what such a call returns (and the
items of a returned tuple or list) is followed from then on: the value's later forms. A function
that a followed dataclass holds (a registry entry's ``build``) is called as its method: a stay. Numbers,
booleans and None are never followed (their identities are shared).

The route is the order in which the stays are first reached (each function once: a loop's later
iterations add nothing), consecutive stays in one module merged. Each module stands on a *floor*
of the import graph that ``tests/test_layout.py`` reads from the source (a module with no package
imports: floor 1; else one above the highest floor it imports), so a call passes the value down
to a lower floor; a stay on a higher floor than the one before it is a *call back up*: the value
went back to a caller (or a callback) above, to be handed down again. Printed: the route, one line
a stay (floor, module, the function first reached), then ``modules visited`` and ``back up``.
PARAM may name one part of the argument (``setup.tool``: the set-up's ``[tool]`` table);
``--no-forms`` follows the value and its parts alone, not what is made from it.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests import test_layout  # noqa: E402  (the import graph, read with ast)

PKG = "kinadapt_nn"
SCALARS = (type(None), bool, int, float, complex)


@functools.cache
def floor(module: str) -> int:
    """The module's floor in the package's import graph (no circles: ``tests/test_layout.py``)."""
    deps = test_layout.GRAPH.get(module, set())
    return 1 + max((floor(d) for d in deps), default=0)


def _module_of(name: str) -> str:
    """A frame's ``__name__`` -> the module in the import graph (``__main__`` and scripts: as is)."""
    return name if name in test_layout.GRAPH else name.rsplit(".", 1)[0] if "." in name else name


class Follower:
    """The profiler: which objects are followed, and where the value stayed (in first-reached order)."""

    def __init__(self, seed: tuple[str, str, str], value: str | None, forms: bool = True) -> None:
        self.seed, self.value, self.forms = seed, value, forms
        self.seeded = False
        self._keep: dict[int, object] = {}  # id -> the object (kept alive: its id stays its own)
        self._stays: set[int] = set()  # frames of stays still running (their return value is followed)
        self.route: list[tuple[str, str]] = []  # (module, qualname) in first-reached order
        self._seen: set[tuple[str, str]] = set()
        self._codes: set = set()  # functions a followed dataclass holds (a registry entry's ``build``)

    def follow(self, obj, depth: int = 0) -> None:
        if isinstance(obj, SCALARS) or id(obj) in self._keep or depth > 3:
            return
        self._keep[id(obj)] = obj
        if isinstance(obj, (tuple, list)) and len(obj) <= 8:
            for o in obj:
                self.follow(o, depth + 1)
        if isinstance(obj, argparse.Namespace):  # the command line's arguments: each is a part
            for o in vars(obj).values():
                self.follow(o, depth + 1)
        if dataclasses.is_dataclass(obj) and not isinstance(obj, type):  # a function it holds is its method
            for f in dataclasses.fields(obj):
                code = getattr(getattr(obj, f.name, None), "__code__", None)
                if code is not None:
                    self._codes.add(code)
        fields = getattr(type(obj), "model_fields", None)  # a pydantic model: its sub-models are its parts
        if fields:
            for name in fields:
                sub = getattr(obj, name, None)
                if hasattr(type(sub), "model_fields"):
                    self.follow(sub, depth + 1)

    def _followed(self, v, depth: int = 0) -> bool:
        if isinstance(v, SCALARS):
            return False
        if id(v) in self._keep or (self.value is not None and isinstance(v, str) and v == self.value):
            return True
        if depth == 0 and isinstance(v, (list, tuple)) and len(v) <= 64:  # a batch's list of them
            return any(self._followed(o, 1) for o in v)
        return False

    def _args(self, frame) -> list:
        code = frame.f_code
        n = code.co_argcount + code.co_kwonlyargcount + bool(code.co_flags & 0x04) + bool(code.co_flags & 0x08)
        vals = []
        for name in code.co_varnames[:n]:
            v = frame.f_locals.get(name)
            vals.extend(v if isinstance(v, tuple) and name != "self" and len(v) <= 8 else [v])
        return vals

    def __call__(self, frame, event, arg) -> None:
        if event == "return":
            if id(frame) in self._stays:
                self._stays.discard(id(frame))
                if self.forms:
                    self.follow(arg)
            return
        if event != "call":
            return
        name = frame.f_globals.get("__name__", "")
        code = frame.f_code
        if not name.startswith(PKG) or code.co_name.startswith("<"):
            return
        module = _module_of(name)
        if not self.seeded:
            mod, fn, param = self.seed
            if module != mod or code.co_name != fn:
                return
            self.seeded = True
            if param:
                name, *attrs = param.split(".")
                obj = frame.f_locals.get(name)
                for a in attrs:  # PARAM.FIELD...: one part of the argument
                    obj = getattr(obj, a)
                self.follow(obj)
            if self.value is not None:
                self.follow(self.value)
        if code in self._codes or any(self._followed(v) for v in self._args(frame)):
            self._stays.add(id(frame))
            fn = code.co_qualname
            if "<locals>" in fn and "self" in frame.f_locals:  # a generated method (a dataclass's __init__)
                fn = f"{type(frame.f_locals['self']).__qualname__}.{code.co_name}"
            key = (module, fn)
            if key not in self._seen:
                self._seen.add(key)
                self.route.append(key)


def route_counts(route: list[tuple[str, str]]) -> tuple[list[tuple[str, str]], int, int]:
    """-> (the route with consecutive stays in one module merged, modules visited, calls back up)."""
    merged: list[tuple[str, str]] = []
    for mod, fn in route:
        if not merged or merged[-1][0] != mod:
            merged.append((mod, fn))
    up = sum(floor(b[0]) > floor(a[0]) for a, b in zip(merged, merged[1:]))
    return merged, len({m for m, _ in merged}), up


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--" not in argv:
        print("usage: trace_counts.py --follow MODULE:FUNCTION:PARAM [--value TEXT] -- KINADAPT-ARGS...",
              file=sys.stderr)
        return 2
    cut = argv.index("--")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--follow", required=True, help="MODULE:FUNCTION:PARAM, where the value enters")
    ap.add_argument("--value", help="also follow every argument equal to this string (a config value)")
    ap.add_argument("--no-forms", action="store_true", help="follow the value and its parts only, not what the "
                    "calls that receive it return")
    args = ap.parse_args(argv[:cut])
    seed = tuple(args.follow.split(":"))
    if len(seed) == 2 and args.value:
        seed = (*seed, "")
    if len(seed) != 3:
        print(f"--follow {args.follow}: give MODULE:FUNCTION:PARAM (or MODULE:FUNCTION with --value), e.g. "
              "kinadapt_nn.config:load_config:overrides", file=sys.stderr)
        return 2
    from kinadapt_nn.app.cli import main as kinadapt

    tr = Follower(seed, args.value, forms=not args.no_forms)
    sys.setprofile(tr)
    try:
        rc = kinadapt(argv[cut + 1:])
    finally:
        sys.setprofile(None)
    if not tr.seeded:
        print(f"{args.follow} was never called: nothing followed", file=sys.stderr)
        return 1
    merged, n_mod, up = route_counts(tr.route)
    print(f"following {args.follow}" + (f" and the value {args.value!r}" if args.value else "")
          + (" (no later forms)" if args.no_forms else "")
          + f" through: kinadapt {' '.join(argv[cut + 1:])}  (exit {rc})")
    prev = None
    for mod, fn in merged:
        mark = "UP" if prev is not None and floor(mod) > floor(prev) else "  "
        print(f"  {mark} floor {floor(mod):2d}  {mod:42s} {fn}")
        prev = mod
    print(f"modules visited: {n_mod}; stays: {len(merged)}; back up: {up}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
