"""The features registry (features/): the example type (examples/features/adjoint_mm.py),
registered with one line, runs an episode by ``run.features=<name>`` alone; the registry names every built-in type, the
config's default and the choices that help texts list, and refuses other names in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import load_config
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.features import FEATURES, compared_types, features_spec
from kinadapt_nn.runs.build import make_features
from kinadapt_nn.runs.episode import run_episode
from tests.diagnostics.example_scripts import EXAMPLES, load_script

BUILT_IN = ("adjoint", "rbf", "neural", "oracle")
ARCHITECTURE = Path(__file__).resolve().parents[2] / "docs" / "architecture.md"


# ------------------------------------------------------------ the example type (examples/features/)
EXAMPLE = load_script(EXAMPLES / "features" / "adjoint_mm.py", "adjoint_mm")
ADJOINT_MM, MM = EXAMPLE.SPEC, EXAMPLE.MM


@pytest.fixture
def adjoint_mm(monkeypatch):
    monkeypatch.setitem(FEATURES, ADJOINT_MM.name, ADJOINT_MM)  # the one registry line, for this test only
    return ADJOINT_MM


def test_the_example_features_type_runs_an_episode(adjoint_mm):
    """Two files (examples/features/adjoint_mm.py and the registry line): ``run.features=adjoint_mm``
    builds it, the controller adapts its theta (from Python: no kernel knows it) and the episode's
    theta is the adjoint's own episode's in millimetres -- the kalman law is invariant to the unit
    of theta, so the two agree to rounding."""
    over = ["run.progress=false", "run.duration_s=2.0", "adaptation.act_sd_ratio=1.0"]  # act on every direction
    mm = run_episode(load_config(None, [*over, "run.features=adjoint_mm"]))
    ref = run_episode(load_config(None, over))
    s = mm.summary
    assert s["features"] == "adjoint_mm" and s["law"] == "kalman" and s["n_params"] == 3
    th_mm, th_ref = mm.trace["theta"], ref.trace["theta"]
    assert np.all(np.isfinite(th_mm))
    # the estimate moved (6.7e-5 m on the rattle-free default contact), far above the 1e-9 m compared below
    assert np.max(np.abs(th_ref[-1] - th_ref[0])) > 1e-5
    # rounding only (measured 1e-16 m here); 1e-9 m, 1e-9 rad leave room for other BLAS builds
    np.testing.assert_allclose(th_mm / MM, th_ref, rtol=0, atol=1e-9)  # [m]
    np.testing.assert_allclose(mm.trace["q_rad"], ref.trace["q_rad"], rtol=0, atol=1e-9)
    assert "adjoint_mm" in compared_types()  # compare and reproduce would run it by default


def test_the_registry_names_every_type_and_refuses_others(capsys, tmp_path):
    assert tuple(FEATURES) == BUILT_IN
    assert load_config(None, []).run.features == next(iter(FEATURES))  # the default is the registry's first
    assert compared_types() == ["adjoint", "rbf", "neural"]  # every type but the baseline (the oracle)
    for name, spec in FEATURES.items():
        assert spec.name == name and spec.doc and spec.cost > 0
    with pytest.raises(ConfigError) as exc:
        make_features(load_config(None, ["run.features=neural_net"]))
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("config key 'run.features': 'neural_net' is not a registered")
    assert "choose from adjoint, rbf, neural, oracle" in msg and msg.endswith("did you mean 'neural'?")
    assert "did you mean" not in str(pytest.raises(ConfigError, features_spec, "zzzz").value)
    # the command line: one line, exit 2; `kinadapt config` lists the registered names
    assert main(["online", "--quiet", "--out", str(tmp_path / "run"), "--set", "features=adjiont"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "did you mean 'adjoint'?" in err and not (tmp_path / "run").exists()
    assert main(["config"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("run.features = "))
    assert line.endswith("(one of: adjoint, rbf, neural, oracle)")


def test_the_oracle_fixes_its_own_law():
    """The oracle's features run the frozen law whatever ``adaptation.mode`` says; other types run
    the configured one."""
    from kinadapt_nn.runs.build import make_controller

    ctrl = make_controller(load_config(None, ["run.features=oracle", "adaptation.mode=composite"]))
    assert ctrl.features.fixed_law == "frozen" and ctrl.law_spec.name == ctrl.mode == "frozen"
    assert make_controller(load_config(None, ["adaptation.mode=composite"])).mode == "composite"


def test_the_docs_table_is_the_registry():
    """docs/architecture.md, "Adding a features type": one row per registered type, as the
    registry says it."""
    want = [f"| `{n}` | {s.doc} | {'yes' if s.theta0_per_episode else 'no'} | "
            f"{'reference' if s.baseline else 'yes'} | {s.cost:g} |" for n, s in FEATURES.items()]
    text = ARCHITECTURE.read_text().split("## Adding a features type", 1)[1].split("\n## ", 1)[0]
    assert [ln for ln in text.splitlines() if ln.startswith("| `")] == want
