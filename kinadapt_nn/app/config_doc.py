"""Every key of a config with its value, unit and meaning (``kinadapt config``).

The units and meanings are written once, as the field comments of the config classes
(``kinadapt_nn.config``: ``name: type = default  # [unit] meaning``); they are read from the
source here (``ast`` finds the fields, ``tokenize`` the comments), so the listing cannot drift
from the code. A field's pydantic ``description``, when given, takes precedence. A field with no
comment of its own takes the comment lines right above it, else its class docstring's first line.
"""

from __future__ import annotations

import ast
import functools
import inspect
import io
import json
import re
import tokenize
from typing import NamedTuple

from pydantic import BaseModel


class KeyDoc(NamedTuple):
    """One leaf key of a config."""

    key: str  # dotted key, as ``--set`` takes it (``control.gain_trans``)
    value: str  # its value as TOML/JSON text
    unit: str  # e.g. "m", "N m/rad", "-" (dimensionless); "" when the comment names none
    meaning: str  # the rest of the field comment


@functools.lru_cache(maxsize=None)
def _module_comments(filename: str) -> tuple[dict[str, dict[str, tuple[int, int]]], dict[int, str], frozenset[int]]:
    """Of a source file: class name -> field name -> (first line, last line); line -> comment text;
    the lines that hold nothing but a comment."""
    with open(filename, encoding="utf-8") as fh:
        source = fh.read()
    tokens = [t for t in tokenize.generate_tokens(io.StringIO(source).readline) if t.type == tokenize.COMMENT]
    comments = {t.start[0]: t.string.lstrip("#").strip() for t in tokens}
    alone = frozenset(t.start[0] for t in tokens if t.line.lstrip().startswith("#"))
    fields: dict[str, dict[str, tuple[int, int]]] = {}
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ClassDef):
            fields[node.name] = {st.target.id: (st.lineno, st.end_lineno or st.lineno) for st in node.body
                                 if isinstance(st, ast.AnnAssign) and isinstance(st.target, ast.Name)}
    return fields, comments, alone


def field_comments(model: type[BaseModel]) -> dict[str, str]:
    """Field name -> its source comment ("" when none or when the source is unavailable)."""
    out: dict[str, str] = {}
    for cls in reversed(model.__mro__):
        if not (isinstance(cls, type) and issubclass(cls, BaseModel)) or cls is BaseModel:
            continue
        try:
            filename = inspect.getsourcefile(cls)
            fields, comments, alone = _module_comments(filename) if filename else ({}, {}, frozenset())
        except (OSError, TypeError, SyntaxError):
            continue
        for name, (first, last) in fields.get(cls.__name__, {}).items():
            text = comments.get(last, "")
            if not text:  # the comment block right above the field
                above, line = [], first - 1
                while line in alone:
                    above.insert(0, comments[line])
                    line -= 1
                text = " ".join(above)
            out[name] = text
    return out


_UNIT = re.compile(r"^\[([^\]]*)\]\s*(.*)$")


def _split_unit(comment: str) -> tuple[str, str]:
    m = _UNIT.match(comment)
    return (m.group(1), m.group(2)) if m else ("", comment)


def _registered(key: str) -> list[str] | None:
    """The names a key takes from a registry, read from it (``run.features``: the features
    types; ``model.effects``: the online effects), else None."""
    if key == "run.features":
        from kinadapt_nn.features import FEATURES

        return list(FEATURES)
    if key == "model.effects":
        from kinadapt_nn.features.effect_library import LIBRARY

        return [*LIBRARY, "PATH.py:NAME"]
    return None


def describe(cfg: BaseModel, prefix: str = "") -> list[KeyDoc]:
    """Every leaf key of ``cfg`` (nested sections recursed), in declaration order; a key that
    names a registry entry lists the registered names."""
    cls = type(cfg)
    comments = field_comments(cls)
    doc_line = inspect.cleandoc(cls.__dict__.get("__doc__") or "").split("\n")[0]  # its own, not BaseModel's
    rows: list[KeyDoc] = []
    for name, info in cls.model_fields.items():
        value = getattr(cfg, name)
        key = f"{prefix}{name}"
        if isinstance(value, BaseModel):
            rows += describe(value, key + ".")
            continue
        unit, meaning = _split_unit(info.description or comments.get(name, ""))
        text = json.dumps(cfg.model_dump(mode="json")[name])
        names = _registered(key)
        meaning = f"{meaning or doc_line} (one of: {', '.join(names)})" if names else meaning or doc_line
        rows.append(KeyDoc(key, text, unit, meaning))
    return rows


def format_keys(rows: list[KeyDoc]) -> str:
    """One line per key: ``key = value   [unit]  meaning``, aligned."""
    kv = [f"{r.key} = {r.value}" for r in rows]
    width = min(max(map(len, kv), default=0), 56)
    units = [f"[{r.unit}]" if r.unit else "" for r in rows]
    lines = [f"{a:<{width}}  {u:<16}  {r.meaning}".rstrip() for a, u, r in zip(kv, units, rows)]
    return "\n".join(lines) + "\n"
