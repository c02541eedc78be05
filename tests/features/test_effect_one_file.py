"""One effect file, both model sides (issue 52): ``examples/effects/hose_weight.py``, written once in
the diagnosis's contract with ``online=True``, gives the diagnosis's columns and the controller's
online columns (``effects.online.from_wrench``). Both are checked against the simulator: a run with
the truth side's ``world_force`` (the hose's weight, straight down) at the example's clamp point,
against the same run without it.
The built-ins are written the same way (``kinadapt_nn/effects/builtin/``); that their online columns
equal the ones the controller used before, written out by hand, is ``test_builtin_online_columns.py``.
``python benchmarks/effect_model_sides.py`` prints the same figures."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.effects.contract import effect, load_effect_file
from kinadapt_nn.errors import ConfigError, KinadaptError
from kinadapt_nn.effects.online import Signals, Terms, contact_rate, to_level
from kinadapt_nn.features.effect_library import LIBRARY, online_of

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "effects" / "hose_weight.py"
HOSE_MASS_KG = 0.3  # [kg] the hidden hose's hanging mass
G_M_S2 = 9.81  # [m/s^2] the simulator's gravity


def _clamp_s_m() -> np.ndarray:
    """The example's clamp point (3,) [m], sensor frame (= the package's flange frame)."""
    spec = importlib.util.spec_from_file_location("hose_weight_example", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return np.asarray(mod.CLAMP_S_M, dtype=float)


def pull_runs(duration_s: float = 8.0) -> dict:
    """The excitation program's first ``duration_s`` (free-space reorientation) with and without a hidden
    hose weight (a world force ``-m g z_w``) at the example's clamp point -> {"none" | "pull": (online
    Signals, LogSignals)}."""
    from kinadapt_nn.diagnostics import ownrun
    from kinadapt_nn.diagnostics import signals as sg
    from tests.diagnostics.test_effects import _run

    point = "[" + ", ".join(str(float(v)) for v in _clamp_s_m()) + "]"
    force = f"[0.0, 0.0, {-HOSE_MASS_KG * G_M_S2}]"
    out = {}
    for key, sets in (("none", []), ("pull", ["effects.world_force.enabled=true", f"effects.world_force.point_f_m={point}",
                                              f"effects.world_force.force_w_N={force}"])):
        cfg, sig, _, raw = _run(sets, duration=duration_s)
        log, setup = ownrun.as_log(raw, cfg)
        out[key] = (sig, sg.from_log(log, setup))
    return out


def example_errors(pair: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The example's columns at the injected mass against the simulator, drive on after 0.6 s (moving or
    held: the simulated pull has no dynamics of its own) -> {"online" | "diagnosis": (max |error| (6,),
    max |prediction| (6,))}:
    the controller's level change (tared reading, level channels) and the logged wrench's change
    (internal convention, untared) between the runs with and without the pull."""
    sig0, s0 = pair["none"]
    sig1, s1 = pair["pull"]
    eff = load_effect_file(EXAMPLE)["hose_weight"]
    lev, _ = online_of(eff).columns(sig1)
    m = sig1.active & (sig1.t_s > 0.6)
    meas_on, pred_on = (to_level(sig1, sig1.w_env_w) - to_level(sig0, sig0.w_env_w))[m], (lev @ [HOSE_MASS_KG])[m]
    n = min(s0.n, s1.n, len(sig1.t_s))
    meas_dg, pred_dg = (s1.wrench - s0.wrench)[:n][m[:n]], (eff.evaluate(s1) @ [HOSE_MASS_KG])[:n][m[:n]]
    return {k: (np.abs(a - b).max(axis=0), np.abs(b).max(axis=0))
            for k, (a, b) in (("online", (meas_on, pred_on)), ("diagnosis", (meas_dg, pred_dg)))}


@pytest.fixture(scope="module")
def pull_pair():
    return pull_runs(8.0)


@pytest.fixture(scope="module")
def errors(pull_pair):
    return example_errors(pull_pair)


def test_the_example_has_both_sides():
    eff = load_effect_file(EXAMPLE)["hose_weight"]
    on = online_of(eff)
    assert eff.online is True and on.name == "hose_weight" and on.params == eff.params == ("hose_mass",)
    assert online_of(f"{EXAMPLE}:hose_weight").params == eff.params  # model.effects' form of a user's file


@pytest.mark.parametrize("side", ["online", "diagnosis"])
def test_the_example_matches_the_simulated_pull(errors, side):
    """Both sides of the one file at the injected pull against the simulator (``example_errors``): within
    1 % of the largest force / moment of the prediction, per group (the simulator's pull acts at the
    clamp through a massless body). A wrong sign, frame or tare fails by far more (the untared weight is
    2.9 N; the tared online change about 1 N)."""
    err, scale = errors[side]
    assert scale[:3].max() > 0.5 and scale[3:].max() > 0.05, scale  # the reorientation turns the pull in s
    assert np.all(err[:3] <= 0.01 * scale[:3].max()), (err, scale)
    assert np.all(err[3:] <= 0.01 * scale[3:].max() + 1e-4), (err, scale)


def test_the_controller_evaluates_the_example_per_step_as_in_the_batch(pull_pair):
    """Per control step the controller evaluates the derived columns on a one-sample Signals (its own
    tare each time); the same numbers as on the whole run."""
    sig, _ = pull_pair["pull"]
    on = online_of(load_effect_file(EXAMPLE)["hose_weight"])
    batch, _ = on.terms(sig)
    for i in np.flatnonzero(sig.active)[::250]:
        one = Signals(*(f[i:i + 1] if isinstance(f, np.ndarray) and f.shape[:1] == (len(sig.t_s),) else f for f in sig))
        single, _ = on.terms(one)
        np.testing.assert_allclose(single[0], batch[i], rtol=1e-12, atol=1e-12)


def test_the_controller_builds_the_example_from_its_path(pull_pair):
    """``EffectFeatures`` (what ``model.effects`` builds) takes the example as ``PATH.py:NAME``: three
    parameter after the base's, adapted by the prediction rows only."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.build import make_features

    cfg = load_config(REPO / "online" / "excite.toml", ["run.tensorboard=false", "run.figure=false",
                                                        f'model.effects=["{EXAMPLE}:hose_weight"]'])
    feats, theta0 = make_features(cfg)
    assert feats.name.endswith("+hose_weight") and feats.k == 1 and len(theta0) == feats.p0 + 1
    assert not feats.track_rows[feats.p0:].any()


def test_model_effects_names_come_from_the_registry():
    """``model.effects`` keeps no list of its own: every online built-in of the registry (and only
    those) builds, a misspelt one is one line with the closest, and ``kinadapt config`` lists the
    registry's names."""
    from kinadapt_nn.app.config_doc import describe
    from kinadapt_nn.config import load_config
    from kinadapt_nn.effects.builtin import BUILTINS
    from kinadapt_nn.runs.build import make_features

    online = [n for n, e in BUILTINS.items() if e.online is not False]
    assert list(LIBRARY) == online
    feats, theta0 = make_features(load_config(None, [f"model.effects={online}"]))
    assert feats.name.endswith("+" + "+".join(online)) and len(theta0) == feats.p0 + feats.k
    for bad, closest in (("gravity", "tool_gravity"), ("tool_inertia", None)):  # tool_inertia: no online side
        with pytest.raises(ConfigError, match="model.effects") as exc:
            make_features(load_config(None, [f'model.effects=["{bad}"]']))
        assert "\n" not in str(exc.value) and (closest is None or f"did you mean '{closest}'" in str(exc.value))
    row = next(r for r in describe(load_config(None)) if r.key == "model.effects")
    assert all(n in row.meaning for n in online)


def test_contract_form_expresses_a_built_in_online_function(pull_pair):
    """``online=fn`` carries the controller's own columns in the same module: a contact stiffness written
    in the public form equals the library's entry."""

    @effect(params={"stiffness_factor_minus_1": "-"}, relevant=[0.1], doc="test: contact stiffness",
            online=lambda sig: Terms(None, contact_rate(sig, sig.twist_tip_w)[:, :, None]))
    def stiff(s):
        return np.zeros((s.n, 6, 1))

    sig, _ = pull_pair["none"]
    got, ref = online_of(stiff).columns(sig), LIBRARY["contact_stiffness"].columns(sig)
    assert got[0] is None and ref[0] is None
    np.testing.assert_array_equal(got[1], ref[1])


def test_online_errors_are_one_line(pull_pair, tmp_path):
    sig, _ = pull_pair["none"]

    @effect(params={"a": "-"}, relevant=[0.1], doc="reads the set-up", online=True)
    def needs_setup(s):
        return np.zeros((s.n, 6, 1)) * s.setup.tool.mass_kg

    @effect(params={"a": "-"}, relevant=[0.1], doc="diagnosis only")
    def diag_only(s):
        return np.zeros((s.n, 6, 1))

    with pytest.raises(KinadaptError, match=r"effect 'needs_setup' online: s.setup is not known online") as e:
        online_of(needs_setup).terms(sig)
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="has no online side"):
        online_of(diag_only)
    with pytest.raises(ConfigError, match="did you mean 'contact_stiffness'"):
        online_of("contact_stifness")
    with pytest.raises(ConfigError, match="did you mean 'hose_weight'"):
        online_of(f"{EXAMPLE}:hose_weigth")
    with pytest.raises(ConfigError, match="not found"):
        online_of(f"{tmp_path / 'none.py'}:x")
    with pytest.raises(KinadaptError, match="online must be"):
        effect(params={"a": "-"}, relevant=[0.1], doc="x", online="yes")(diag_only.columns)
