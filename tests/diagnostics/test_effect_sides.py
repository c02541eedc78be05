"""The two model sides of each effect, the controller's online columns (``features.effect_library``,
level channels) and the diagnosis's (``effects.builtin``, the wrench on the sensor), on one
package run of the excitation program (issue 52: "the model side of an effect written once").

Both sides are one module per effect (``kinadapt_nn/effects/builtin/``); this pins where its two forms
are one formula: the diagnosis's columns, tared in the sensor frame at the online tare sample and mapped
the way the online library maps a wrench (``to_level(sig, [R_ws f; R_ws m])``), equal the online
columns up to one sign per effect. ``python benchmarks/effect_model_sides.py`` prints the
whole table, the effects that differ in substance included (tool_tilt, encoder_offset). The one-file
form (``@effect(..., online=True)``: the online columns derived from the diagnosis's by
``effects.online.from_wrench``) is tested in ``tests/features/test_effect_one_file.py`` against the
simulator, and the built-ins' online columns against the hand-written ones they replaced in
``tests/features/test_builtin_online_columns.py``."""

from __future__ import annotations

import numpy as np
import pytest

def sides(duration_s: float):
    """-> (online Signals, diagnosis LogSignals) of one excitation run without hidden effects."""
    from kinadapt_nn.diagnostics import ownrun
    from kinadapt_nn.diagnostics import signals as sg
    from tests.diagnostics.test_effects import _run

    cfg, sig, _, raw = _run([], duration=duration_s)
    log, setup = ownrun.as_log(raw, cfg)
    return sig, sg.from_log(log, setup)


def compare(sig, s) -> list[tuple[str, str, float, float, float, float]]:
    """-> (effect, parameter, scale a, relative misfit, RMS of the online column, RMS of the mapped
    diagnosis column) for every effect both sides have."""
    from kinadapt_nn.effects.builtin import BUILTINS
    from kinadapt_nn.effects.online import to_level
    from kinadapt_nn.features.effect_library import LIBRARY

    n = min(len(sig.t_s), s.n)
    if abs(sig.t_s[n - 1] - s.t[n - 1]) > 1e-9:
        raise SystemExit(f"the two sides' samples differ in time ({sig.t_s[n - 1]} vs {s.t[n - 1]} s)")
    i_tare = int(np.clip(np.searchsorted(sig.t_s, sig.t_tare_s), 0, n - 1))
    on = sig.active[:n]
    sig_n = type(sig)(*(f[:n] if isinstance(f, np.ndarray) and f.shape[:1] == (len(sig.t_s),) else f for f in sig))
    rows = []
    for name in (e for e in LIBRARY if e in BUILTINS):
        eff = BUILTINS[name].for_setup(s.setup)
        if eff.applies is not None and not eff.applies(s.setup):
            rows.append((name, "(not judged for this set-up)", np.nan, np.nan, np.nan, np.nan))
            continue
        lev, integ = LIBRARY[name].columns(sig)
        L = sum(x for x in (lev, integ) if x is not None)[:n]
        C = eff.evaluate(s)[:n]
        C = C - C[i_tare]  # tared in the sensor frame, as the online reading is
        for j in range(min(L.shape[2], C.shape[2])):
            w_w = np.concatenate([np.einsum("nij,nj->ni", s.R_ws[:n], C[:, :3, j]),
                                  np.einsum("nij,nj->ni", s.R_ws[:n], C[:, 3:, j])], axis=1)
            M = to_level(sig_n, w_w)
            lo, mo = L[on, :, j].ravel(), M[on].ravel()
            a = float(lo @ mo / max(mo @ mo, 1e-300))
            misfit = float(np.linalg.norm(lo - a * mo) / max(np.linalg.norm(lo), 1e-300))
            rows.append((name, f"{LIBRARY[name].params[j]} / {eff.params[j]}", a, misfit,
                         float(np.sqrt(np.mean(lo ** 2))), float(np.sqrt(np.mean(mo ** 2)))))
    return rows



@pytest.fixture(scope="module")
def rows():
    return {(r[0], r[1]): r[2:] for r in compare(*sides(20.0))}


#: effect -> the largest relative misfit allowed: exact closed forms share the formula (the contact
#: springs' displacement vs the integral of the tip velocity: the rectangle rule); tool_gravity's
#: accelerations are differentiated differently (a 2 ms moving average of central differences
#: online, Savitzky-Golay in the diagnosis)
SAME = {"ft_bias_drift": 0.01, "ft_frame_rotation": 0.01, "contact_stiffness": 0.01, "contact_friction_couple": 0.01,
        "grasp_compliance": 0.02, "tool_gravity": 0.15}


@pytest.mark.parametrize("name", sorted(SAME))
def test_one_formula_written_twice(rows, name):
    got = {k[1]: v for k, v in rows.items() if k[0] == name}
    assert got, f"{name}: not compared"
    for par, (a, misfit, rms_on, rms_diag) in got.items():
        assert rms_on > 0 and rms_diag > 0, (par, rms_on, rms_diag)  # the run excites it
        assert abs(abs(a) - 1.0) < 0.01 and misfit < SAME[name], (par, a, misfit)


def test_the_comparison_tells_different_models_apart(rows):
    """Positive control: the encoder offsets differ in substance (the diagnosis differentiates the
    declared tool's wrench in each joint; the online side also rotates the tared reading), and the
    comparison says so."""
    misfits = [v[1] for k, v in rows.items() if k[0] == "encoder_offset"]
    assert len(misfits) == 7 and max(misfits) > 0.5, misfits  # (the flange joint: no column on either side)
