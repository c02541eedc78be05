"""The episode loop's and the scenes' kernels compile inside the one compile phase (its status
line), not behind the first episode's step bar: a compile phase is cold while any of them is
missing from numba's cache (``core.cache_probe``), and ``batch.compile_loop`` runs two control
steps inside the phase when it is."""

from __future__ import annotations

from types import SimpleNamespace

from kinadapt_nn.config import load_config
from kinadapt_nn.controller import core
from kinadapt_nn.runs import batch, loop
from kinadapt_nn.sim import scenes


def _probe(index: dict) -> SimpleNamespace:
    return SimpleNamespace(_cache=SimpleNamespace(_cache_file=SimpleNamespace(_load_index=lambda: index)))


def test_the_loop_and_scene_kernels_are_probed():
    probes = set(core._CACHE_PROBES)
    assert {loop._watch, loop._log_rows, loop._log_sample, *scenes.KERNELS} <= probes


def test_a_missing_probe_makes_the_cache_cold(monkeypatch):
    monkeypatch.setattr(core, "step_adjoint", _probe({"sig": 1}))
    monkeypatch.setattr(core, "_CACHE_PROBES", [_probe({"sig": 1}), _probe({"sig": 1})])
    assert core.kernels_cached()
    monkeypatch.setattr(core, "_CACHE_PROBES", [_probe({"sig": 1}), _probe({})])  # one index empty: not cached
    assert not core.kernels_cached()


def test_compile_loop_runs_two_steps_in_one_phase_when_cold(monkeypatch, tmp_path):
    cfg = load_config(None, [])
    calls = []
    phases = []
    real_enter = core.compiling.__enter__

    def enter(self):
        phases.append(self)
        return real_enter(self)

    monkeypatch.setattr(core.compiling, "__enter__", enter)
    monkeypatch.setattr(core, "_compile_record_path", lambda: tmp_path / "compile.json")  # not this machine's record
    monkeypatch.setattr(batch, "run_episodes", lambda cfgs, **k: calls.append(("traced", cfgs)) or [])
    monkeypatch.setattr(batch, "run_batch", lambda cfgs, **k: calls.append(("summary", cfgs)))
    monkeypatch.setattr(core, "kernels_cached", lambda: True)
    assert batch.compile_loop(cfg) == 0.0 and calls == [] and phases == []  # warm: nothing runs
    monkeypatch.setattr(core, "kernels_cached", lambda: False)
    wall = batch.compile_loop(cfg)
    assert [c[0] for c in calls] == ["traced", "summary"] and len(phases) == 1 and phases[0].cold
    assert wall == phases[0].wall_s > 0.0
    for _kind, cfgs in calls:  # two control steps of the same config, nothing else changed
        assert len(cfgs) == 1 and cfgs[0].run.duration_s == 2 * cfg.run.dt_s
        assert cfgs[0].model_copy(update={"run": cfg.run}) == cfg
