"""Shared fixtures: one default oracle episode per test session (it takes ~1 s)."""

from __future__ import annotations

import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.episode import EpisodeResult, run_episode


@pytest.fixture(scope="session")
def default_episode() -> EpisodeResult:
    return run_episode(load_config(None, ["run.progress=false"]))
