"""The first run's compile on two cores (``controller.core``: ``compile_two_cores``): the callees it compiles ahead are
the ones the kernels use, with the types the kernels give them, and what it compiles computes the
same numbers as a kernel compiled in one piece."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from kinadapt_nn import compiled
from kinadapt_nn.config import load_config
from kinadapt_nn.controller.core import callee_plan
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.episode import run_episode

_EPISODE = ["run.progress=false", "run.duration_s=1.2"]


@pytest.mark.parametrize("features", ["adjoint", "neural", "rbf"])
def test_plan_lists_the_kernels_callees_with_their_cached_types(features):
    """Every planned (callee, types) is what compiling the kernel put in numba's cache (the kernel
    typed it so), and the plan covers the large callees of the step kernel."""
    ctrl = make_controller(load_config(None, ["run.progress=false", f"run.features={features}"]))
    ctrl.compile_kernels()
    plan = callee_plan(ctrl.kernel_calls())
    names = [fn.py_func.__name__ for fn, _ in plan]
    assert {"_front", "_law", "_act_head", "_act_tail"} <= set(names)
    assert "_filter_regressor" not in names  # inlined (inline="always"): typed inside the kernel, nothing apart
    assert len(names) == len(set(names))
    (_name, kernel, _args), = ctrl.kernel_calls()
    here = kernel.py_func.__globals__
    direct = {here[nm].py_func.__name__ for nm in kernel.py_func.__code__.co_names
              if compiled.is_kernel(here.get(nm)) and not compiled.inlined(here[nm])}
    # every part the kernel calls apart is planned: none is left to the kernel's own compile, on one core (the
    # drive and rank gate take what the rows part returns, typed by the kernel's local_types)
    assert direct - {kernel.py_func.__name__} <= set(names), direct - set(names)
    import numba

    if numba.config.OPT == 0:
        # unoptimised code keeps the laws' function addresses as "dynamic globals", which numba
        # refuses to cache (the same measured reason as tests/runs/test_episode.py's precompile test)
        pytest.skip("NUMBA_OPT=0: numba cannot cache kernels that hold function addresses")
    for fn, sig in plan:
        assert compiled.in_cache(fn, sig), (fn.py_func.__name__, sig)


def test_cold_compile_on_two_cores_types_every_callee_once_and_gives_the_same_episode(tmp_path):
    """A first run (empty numba cache folder, a fresh process) compiles through the helper process:
    each planned callee ends up compiled or loaded for its planned types only (a wrong type would
    leave a second signature), the law's step lands in the cache, and an episode run on those
    kernels equals, to the last bit, the same episode run here. That process compiles at LLVM's
    level 3 (``NUMBA_OPT`` set, which ``kernel_opt_level`` leaves to rule), this one's kernels at
    ``KERNEL_OPT`` (1) unless the environment says otherwise: the two levels give the same numbers."""
    code = f"""
import json, numpy as np
from kinadapt_nn import compiled
from kinadapt_nn.config import load_config
from kinadapt_nn.controller import core
from kinadapt_nn.controller.core import callee_plan
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.controller.laws.base import STEP_SIG
cfg = load_config(None, {_EPISODE!r})
ctrl = make_controller(cfg)
plan = callee_plan(ctrl.kernel_calls())
cold = not core.calls_cached(ctrl.kernel_calls(), ctrl.law_spec)
ctrl.compile_kernels()
bad = [fn.py_func.__name__ for fn, sig in plan if [tuple(s) for s in fn.signatures] != [tuple(sig)]]
law_cached = compiled.in_cache(ctrl.law_spec.step, STEP_SIG)
res = run_episode(cfg, ctrl=ctrl)
np.save({str(tmp_path / "theta.npy")!r}, res.trace["theta"])
print(json.dumps({{"cold": cold, "bad": bad, "n": len(plan), "law_cached": law_cached}}))
"""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), NUMBA_OPT="3")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["cold"] and got["n"] >= 5 and got["bad"] == [] and got["law_cached"]
    here = run_episode(load_config(None, _EPISODE))
    np.testing.assert_array_equal(np.load(tmp_path / "theta.npy"), here.trace["theta"])


def test_kernel_opt_level_sets_level_one_for_the_compile_only(monkeypatch):
    """Inside ``kernel_opt_level`` numba's level and the helpers' ``NUMBA_OPT`` are 1; after it
    (also after an error) both are back; a ``NUMBA_OPT`` the user set is not touched."""
    from numba.core import config

    from kinadapt_nn.controller.core import KERNEL_OPT, kernel_opt_level

    monkeypatch.delenv("NUMBA_OPT", raising=False)
    before = config.OPT
    with pytest.raises(RuntimeError):
        with kernel_opt_level():
            assert int(config.OPT) == KERNEL_OPT == 1 and os.environ["NUMBA_OPT"] == "1"
            raise RuntimeError("a failed compile")
    assert config.OPT is before and "NUMBA_OPT" not in os.environ
    monkeypatch.setenv("NUMBA_OPT", "2")
    with kernel_opt_level():
        assert config.OPT is before and os.environ["NUMBA_OPT"] == "2"
    assert os.environ["NUMBA_OPT"] == "2"
