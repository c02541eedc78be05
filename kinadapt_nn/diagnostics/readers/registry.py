"""The log-reader contract and its registry: a format = one ``LogReader``, registered by one line.

A reader is a module that defines

* ``read(path: Path, log: LogCfg) -> UserLog`` -- the file's columns named by the setup's ``[log]``
  section, validated and converted by ``base.assemble`` (or, for a table of named columns,
  ``tables.from_table``, which picks the setup's columns and calls ``assemble``); bad input is a
  one-line ``KinadaptError`` naming the file, the row and the column;
* ``READER = LogReader(name, doc, what, read, suffixes=..., folder_files=...)``.

The built-ins (``csv_log``, ``parquet_log``, ``ros2_bag``, ``run_trace``) are written exactly so and
registered in ``readers/__init__.py``. A reader of another package registers with
``register(READER)`` when imported, or without any import through the entry-point group
``kinadapt_nn.log_readers`` (``jsonl = "mypkg.jsonl_log:READER"`` in its ``pyproject.toml``), which
``kinadapt diagnose`` loads on first use. ``examples/readers/json_lines.py`` is a complete one.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING

from kinadapt_nn.diagnostics.readers.base import UserLog, clean, first_line
from kinadapt_nn.errors import KinadaptError, did_you_mean

if TYPE_CHECKING:
    from kinadapt_nn.diagnostics.setup import LogCfg

#: the entry-point group another package's readers are announced in
ENTRY_POINT_GROUP = "kinadapt_nn.log_readers"
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class LogReader:
    """One log format: how it is recognised and read."""

    name: str  #: short lower-case name ("csv")
    doc: str  #: the format as listed in messages: "CSV (.csv, .csv.gz)"
    what: str  #: the format in a sentence: "a CSV log"
    read: Callable[[Path, LogCfg], UserLog]  #: (path, the setup's [log] section) -> the validated log
    suffixes: tuple[str, ...] = ()  #: lower-case file-name endings of this format (".csv.gz")
    folder_files: tuple[str, ...] = ()  #: a folder holding one of these files is a log of this format


_READERS: dict[str, LogReader] = {}
_plugins_loaded = False


def register(reader: LogReader) -> LogReader:
    """Add ``reader`` (returned, so that ``READER = register(LogReader(...))`` works); a one-line
    ``KinadaptError`` for a malformed reader or a name, suffix or folder file already registered."""
    if not isinstance(reader, LogReader):
        raise KinadaptError(f"register({clean(reader)}): a log reader is a LogReader "
                            "(kinadapt_nn.diagnostics.readers.LogReader)")
    if not _NAME.match(reader.name):
        raise KinadaptError(f"log reader name {reader.name!r}: use lower-case letters, digits and '_'")
    if not reader.suffixes and not reader.folder_files:
        raise KinadaptError(f"log reader '{reader.name}' declares neither suffixes nor folder_files; "
                            "say which files it reads")
    bad = [s for s in reader.suffixes if not s.startswith(".") or s != s.lower()]
    if bad:
        raise KinadaptError(f"log reader '{reader.name}': suffix {bad[0]!r} must be lower case and start with '.'")
    if reader.name in _READERS and _READERS[reader.name] is not reader:
        raise KinadaptError(f"two log readers named '{reader.name}'; rename one")
    for other in _READERS.values():
        if other.name == reader.name:
            continue
        taken = set(other.suffixes) & set(reader.suffixes) or set(other.folder_files) & set(reader.folder_files)
        if taken:
            raise KinadaptError(f"log reader '{reader.name}' claims {sorted(taken)[0]!r}, which log reader "
                                f"'{other.name}' reads; give it its own suffix")
    _READERS[reader.name] = reader
    return reader


def unregister(name: str) -> None:
    """Remove the reader ``name`` (a test's clean-up); a one-line error naming the registered ones."""
    lookup(name)
    del _READERS[name]


def _load_plugins() -> None:
    """Register the readers other packages announce (``ENTRY_POINT_GROUP``), once."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            reader = ep.load()
        except Exception as exc:  # noqa: BLE001 -- any failure of another package's import is its error
            raise KinadaptError(f"log reader '{ep.name}' ({ep.value}, entry point {ENTRY_POINT_GROUP}) could not "
                                f"be imported: {first_line(exc)}") from None
        if _READERS.get(getattr(reader, "name", None)) is not reader:
            register(reader)


def registered() -> tuple[LogReader, ...]:
    """Every registered reader, the built-ins first."""
    _load_plugins()
    return tuple(_READERS.values())


def lookup(name: str) -> LogReader:
    """The reader ``name``; a one-line error listing the registered ones otherwise."""
    _load_plugins()
    try:
        return _READERS[name]
    except KeyError:
        hint = did_you_mean(name, _READERS)
        raise KinadaptError(f"{name!r} is not a registered log reader (registered: {', '.join(_READERS)})"
                            f"{'; ' + hint if hint else ''}") from None


def supported() -> str:
    """The registered formats for messages: "CSV (.csv, .csv.gz), ... or a kinadapt run (...)"."""
    docs = [r.doc for r in registered()]
    return docs[0] if len(docs) == 1 else ", ".join(docs[:-1]) + " or " + docs[-1]


def unreadable(path: Path, what: str, why: str) -> KinadaptError:
    """A file of a known format that its reader cannot parse: one line naming it and the formats."""
    return KinadaptError(f"log '{path}' is not a readable {what} ({why}); supported formats: {supported()}")


def reader_for(path: Path) -> LogReader:
    """The reader of ``path`` by its name (a folder: by the files it holds; the longest matching
    suffix wins); a one-line error naming the registered formats otherwise."""
    readers = registered()
    if not path.exists():
        raise KinadaptError(f"log '{path}' not found; give a log file or folder ({supported()})")
    if path.is_dir():
        for r in readers:
            if any((path / f).is_file() for f in r.folder_files):
                return r
        holds = " nor ".join(f"{r.what} (no {', '.join(r.folder_files)})" for r in readers if r.folder_files)
        raise KinadaptError(f"folder '{path}' is neither {holds}; supported formats: {supported()}")
    name = path.name.lower()
    hits = [(len(s), r) for r in readers for s in r.suffixes if name.endswith(s)]
    if hits:
        return max(hits, key=lambda h: h[0])[1]
    raise KinadaptError(f"log '{path}': unknown format (suffix '{clean(''.join(path.suffixes))}'); "
                        f"supported formats: {supported()}")
