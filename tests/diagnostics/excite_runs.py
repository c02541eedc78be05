"""One package run of the excitation program (``online/excite.toml``) diagnosed as a new user does:
the run with its hidden effects, then ``kinadapt diagnose`` of its trace with a set-up generated from
its config less those effects (``ownrun.as_log``). Shared by the slow tests that judge such runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
QUIET = ["run.tensorboard=false", "run.figure=false", "run.progress=false"]


def diagnosed_excite_run(sets: list[str], hints: bool = False, name: str = "excite"):
    """``sets``: config overrides (``"effects.X.enabled=true"``, ...). -> (the run's config, the set-up the
    diagnosis used, its report)."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics import ownrun, userlog
    from kinadapt_nn.diagnostics.importers import RawLog
    from kinadapt_nn.runs.episode import run_episode

    cfg = load_config(REPO / "online" / "excite.toml", [*QUIET, *sets])
    tr = run_episode(cfg).trace
    raw = RawLog(*(np.asarray(tr[k]) for k in ("t_s", "q_rad", "qdot_rad_s", "wrench_raw_f")), name)
    seen = cfg.model_copy(update={"effects": type(cfg.effects)()})  # the diagnosis does not know them
    log, setup = ownrun.as_log(raw, seen)
    return cfg, setup, userlog.diagnose(log, setup, hints=hints).report
