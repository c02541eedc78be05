"""One exception hierarchy; the CLI turns every ``KinadaptError`` into one line, exit 2."""

import difflib
from collections.abc import Iterable


class KinadaptError(Exception):
    """Base class of every error the package raises on purpose."""


class ConfigError(KinadaptError):
    """A configuration value, key or file is wrong (message says what and how to fix it)."""


class ModelFileError(KinadaptError):
    """A model (MJCF) or checkpoint file is missing or unreadable."""


class OutputExistsError(KinadaptError):
    """The output folder exists and ``--overwrite`` was not given."""


class SensorError(KinadaptError):
    """A sensor sample is not finite (NaN or inf) or has the wrong shape."""


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """``"did you mean 'run.seed'?"`` naming the choice closest to a misspelt ``word``
    (``difflib.get_close_matches``), or ``""`` when none is close enough."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1)
    return f"did you mean '{close[0]}'?" if close else ""


def registered(table: dict, name: str, where: str, kind: str):
    """``table[name]`` of a registry, or a one-line ``ConfigError``: ``{where}{name!r} is not a
    registered {kind} (choose from ...)`` with the closest name."""
    if name in table:
        return table[name]
    hint = did_you_mean(name, table)
    raise ConfigError(f"{where}{name!r} is not a registered {kind} (choose from {', '.join(table)})"
                      f"{'; ' + hint if hint else ''}")
