"""The built-ins' online columns come from their one module (issue 52) and equal the columns the
controller used before: ``features/effect_library.py`` wrote them out by hand until the built-ins' model
side moved to ``kinadapt_nn/effects/``.

``tests/data/online_columns_before_52.npz`` holds two 160-sample windows of one excitation run
(``online/excite.toml``, 20 s, no hidden effect; a free-space reorientation at 4.75 s and a contact
stretch at 19.8 s): the online ``Signals`` fields and, per effect, the hand-written library's ``Terms``
on the window and on one-sample ``Signals`` every 20 samples (what the controller evaluates per step),
recorded with the library at commit e1e59c4. Here the same ``Signals`` go through today's ``LIBRARY``:

* the effects whose online side is written in their module (``online=fn``: tool tilt, contact
  stiffness, friction couple, grasp compliance, encoder offset) are the same arithmetic, so bit-equal;
  the grasp compliance has since (issue 49) the contact force's moment at the turned tip added to its
  level: without it, it equals the recorded one to rounding (1e-12 of the larger of its largest entry and 1);
* those derived from their diagnosis columns (``online=True`` through ``effects.online.from_wrench``:
  the payload, the sensor rotation, the drift) equal the hand-written ones to 1e-12 of the larger of the
  window's largest entry and g = 9.81 (rounding: a different order of the same products; the tared
  payload columns are differences of terms of the size of g, found 3.5e-14 apart; the rotation and the
  drift come out bit-equal), the drift with the opposite sign
  (its parameter is now the contract's, the tool's wrench on the sensor; ``DEFAULTS`` negates the
  simulator's drift, so column times parameter is unchanged: ``tests/diagnostics/test_effects.py``
  checks that product against the simulator);
* the encoder offset has one column more, the flange joint's, which is zero (its offset is the sensor
  rotation's ``rot_z``, as in the diagnosis).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.config import arm_mjcf_path, load_config
from kinadapt_nn.effects.builtin import BUILTINS
from kinadapt_nn.effects.online import Signals
from kinadapt_nn.features.effect_library import DEFAULTS, LIBRARY
from kinadapt_nn.robot import ArmKinematics

REPO = Path(__file__).resolve().parents[2]
REF = REPO / "tests" / "data" / "online_columns_before_52.npz"
WINDOWS = ("free", "contact")
#: the effects derived from their diagnosis columns (rounding-level agreement) and their parameter's sign
DERIVED_SIGN = {"tool_gravity": 1.0, "ft_frame_rotation": 1.0, "ft_bias_drift": -1.0}
ROUNDING = 1e-12  # relative to the larger of the window's largest entry and G_M_S2
G_M_S2 = 9.81  # [m/s^2] gravity: the size of the terms the tared payload columns subtract


def windows() -> dict[str, Signals]:
    """The recorded windows' online ``Signals`` (the controller's arm kinematics for the encoder offset)."""
    z = np.load(REF)
    kin = ArmKinematics(arm_mjcf_path(load_config(REPO / "online" / "excite.toml").scene))
    sigs = {}
    for w in WINDOWS:
        f = {name: z[f"{w}/sig/{name}"] for name in Signals._fields if name != "kin"}
        for name in ("dt_s", "t_tare_s"):
            f[name] = float(f[name])
        sigs[w] = Signals(**f, kin=kin)
    return sigs


@pytest.fixture(scope="module")
def ref():
    return np.load(REF), windows()


def _one(sig: Signals, i: int) -> Signals:
    n = len(sig.t_s)
    return Signals(*(f[i:i + 1] if isinstance(f, np.ndarray) and f.shape[:1] == (n,) else f for f in sig))


def _stacked(terms) -> np.ndarray:
    """(N, 6, k_level + k_rate): a ``Terms``' two parts side by side (an absent part: no columns)."""
    lev, rate = terms
    n = len(lev if lev is not None else rate)
    parts = [np.zeros((n, 6, 0)) if x is None else x for x in (lev, rate)]
    return np.concatenate(parts, axis=2)


def _reference(z, w: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(window (N, 6, k_level + k_rate), per step (steps, 6, k_level + k_rate)) recorded before."""
    lev, rate = z[f"{w}/{name}/level"], z[f"{w}/{name}/rate"]
    parts = [x for x in (lev, rate) if x.size]
    return np.concatenate(parts, axis=2), z[f"{w}/{name}/per_step"]


def _new(sig: Signals, steps: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    eff = LIBRARY[name]
    return _stacked(eff.terms(sig)), np.stack([_stacked(eff.terms(_one(sig, int(i))))[0] for i in steps])


def _as_before(name: str, new: np.ndarray, k_level: int) -> np.ndarray:
    """Today's columns in the layout recorded before: the encoder offset without its flange joint's
    (zero) column, in its level and its rate part."""
    if name != "encoder_offset":
        return new
    k = len(LIBRARY[name].params)
    assert k == 7 and new.shape[-1] == 2 * k
    assert not new[..., k - 1].any() and not new[..., 2 * k - 1].any()  # the flange joint: no column
    return np.concatenate([new[..., :k - 1], new[..., k:2 * k - 1]], axis=-1)


def _turned_contact_force(sig: Signals) -> np.ndarray:
    """(N, 6, 1) the grasp's level from the contact force at the turned tip, per unit compliance: the
    contact moment across the flange axis turns the tool, the nominal tip ``R l_nom`` moves by
    ``M_perp x R l_nom`` and the contact force on the tool (``-w_env``) acts there: ``(M_perp x R l_nom) x f``
    in the moment channels, where S's contact rows apply (``gate``)."""
    M = sig.s[:, 3:]
    z = sig.R_wf[:, :, 2]
    M_perp = M - (M * z).sum(axis=1, keepdims=True) * z
    lever = np.einsum("nij,j->ni", sig.R_wf, sig.l_nom_f)
    out = np.zeros((len(M), 6, 1))
    out[:, 3:, 0] = sig.gate[:, None] * np.cross(np.cross(M_perp, lever), -sig.w_env_w[:, :3])
    return out


def test_every_recorded_effect_is_still_online():
    z = np.load(REF)
    recorded = {k.split("/")[1] for k in z.files if k.startswith("free/") and not k.startswith("free/sig")} - {"steps"}
    assert recorded == set(LIBRARY) == set(DEFAULTS)
    assert len(recorded) == 8


@pytest.mark.parametrize("window", WINDOWS)
@pytest.mark.parametrize("name", sorted(LIBRARY))
def test_online_columns_equal_the_hand_written_ones(ref, window, name):
    z, sigs = ref
    old, old_steps = _reference(z, window, name)
    new, new_steps = _new(sigs[window], z[f"{window}/steps"], name)
    new, new_steps = _as_before(name, new, 0), _as_before(name, new_steps, 0)
    assert new.shape == old.shape and new_steps.shape == old_steps.shape
    if name == "grasp_compliance":  # since issue 49 the contact force acts at the moved tip: that level added
        sig = sigs[window]
        steps = z[f"{window}/steps"].astype(int)
        extra = _turned_contact_force(sig)
        scale = max(np.abs(old).max(), 1.0)
        np.testing.assert_allclose(new - extra, old, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(new_steps - extra[steps], old_steps, rtol=0, atol=1e-12 * scale)
        if window == "contact":
            assert np.abs(extra[:, 3:]).max() > 0.02 * np.abs(old[:, 3:]).max()  # control: the added level is there (moments)
        return
    if name in DERIVED_SIGN:
        scale = max(np.abs(old).max(), np.abs(old_steps).max())
        assert scale > 0.02  # the window exercises the effect (N, N m per unit parameter)
        sign = DERIVED_SIGN[name]
        tol = ROUNDING * max(scale, G_M_S2)
        assert np.abs(new - sign * old).max() <= tol
        assert np.abs(new_steps - sign * old_steps).max() <= tol
        assert np.abs(new + sign * old).max() > 0.1 * scale  # control: the sign is not a matter of rounding
    else:
        np.testing.assert_array_equal(new, old)
        np.testing.assert_array_equal(new_steps, old_steps)


def test_the_contact_window_exercises_the_contact_effects(ref):
    """Control: the bit-equality above is not zeros against zeros."""
    z, _ = ref
    for name in ("tool_tilt", "contact_stiffness", "contact_friction_couple", "grasp_compliance", "encoder_offset"):
        old, _ = _reference(z, "contact", name)
        assert np.abs(old).max() > 0.1, name


def test_each_online_side_is_its_modules():
    """The library's columns are the built-in's own: its ``online`` function, or ``from_wrench`` of its
    diagnosis columns; the parameters are the diagnosis's."""
    for name, on in LIBRARY.items():
        eff = BUILTINS[name]
        assert on.params == eff.params and on.units == eff.units, name
        if eff.online is True:
            assert name in DERIVED_SIGN and on.terms.__qualname__.startswith("from_wrench")
        else:
            assert on.terms is eff.online and eff.online.__module__ == f"kinadapt_nn.effects.builtin.{name}"


def test_the_columns_at_the_tare_follow_the_tare(ref):
    """``from_wrench`` keeps the columns at the tare between steps (one tare per episode): another tare
    gives what a fresh derivation gives, not the kept columns."""
    from kinadapt_nn.effects.online import from_wrench

    _, sigs = ref
    sig = sigs["free"]
    other = sig._replace(R_tare=sig.R_wf[80].copy(), t_tare_s=sig.t_tare_s + 1.0)
    kept, _ = LIBRARY["tool_gravity"].terms(sig)
    moved, _ = LIBRARY["tool_gravity"].terms(other)
    fresh, _ = from_wrench(BUILTINS["tool_gravity"].columns, "tool_gravity")(other)
    np.testing.assert_array_equal(moved, fresh)
    assert np.abs(moved - kept).max() > 0.1  # the tare pose matters (gravity turns in the sensor frame)
    np.testing.assert_array_equal(LIBRARY["tool_gravity"].terms(sig)[0], kept)  # and back
