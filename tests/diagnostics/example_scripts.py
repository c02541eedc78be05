"""The standalone example generators (``examples/<name>.py``: the foreign rig, the outside-library
rig, the calibration rig) imported once per test session under their own names (their dataclasses
look their module up in ``sys.modules`` while it loads)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def load_example(name: str) -> ModuleType:
    """``examples/<name>.py`` as module ``name`` (loaded once)."""
    return load_script(EXAMPLES / f"{name}.py", name)


def load_script(path: Path, name: str) -> ModuleType:
    """The script at ``path`` as module ``name`` (loaded once): examples, benchmarks."""
    mod = sys.modules.get(name)
    if mod is not None and Path(mod.__file__).resolve() == path:
        return mod
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
