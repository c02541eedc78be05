"""A kinadapt log reader (one module): JSON Lines logs, ``*.jsonl`` / ``*.ndjson``.

One JSON object per line, one line per sample, keyed by the column names the setup's ``[log]``
section declares (extra keys are ignored)::

    {"t": 0.000, "q1": 0.1, ..., "q7": 0.2, "fx": 1.5, "fy": -0.2, ..., "tz": 0.01}

Register it before ``kinadapt diagnose`` reads a log -- in Python::

    from kinadapt_nn.diagnostics.readers import register
    import json_lines
    register(json_lines.READER)

or, for the command line, announce it from your package's ``pyproject.toml``::

    [project.entry-points."kinadapt_nn.log_readers"]
    jsonl = "json_lines:READER"
"""

from __future__ import annotations

from pathlib import Path

from kinadapt_nn.diagnostics.readers import LogReader, from_table
from kinadapt_nn.errors import KinadaptError


def read(path: Path, log):
    """A JSON Lines log -> ``UserLog`` (validated like every format: ``from_table`` picks the setup's
    columns, checks them and converts units); a one-line ``KinadaptError`` for a file that does not parse."""
    import pyarrow as pa
    import pyarrow.json as pajson

    try:
        table = pajson.read_json(path)  # (N rows) one column per key
    except (pa.ArrowException, OSError) as exc:
        why = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        raise KinadaptError(f"log '{path}' is not readable JSON Lines ({why}); write one JSON object per line") \
            from None
    return from_table(path, table, log, lambda i: f"line {i + 1}", "lines")


READER = LogReader("jsonl", "JSON Lines (.jsonl, .ndjson)", "a JSON Lines log", read, suffixes=(".jsonl", ".ndjson"))
