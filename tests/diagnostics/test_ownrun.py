"""A package run as a user's log (issue 37): the declared socket's nominal wrench, the contact-model
effects as built-ins in the public form, and the set-up generated from a run's config."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kinadapt_nn.config import load_config
from kinadapt_nn.diagnostics import userlog
from kinadapt_nn.effects import contact_model
from kinadapt_nn.effects.builtin import BUILTINS, CONTACT_MODEL_EFFECTS
from kinadapt_nn.diagnostics.ownrun import as_log as ownrun_as_log
from kinadapt_nn.diagnostics.ownrun import setup_of_run
from kinadapt_nn.diagnostics.setup import ContactDeclCfg, SetupCfg, ToolDeclCfg, load_setup
from kinadapt_nn.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
K_LAT, K_ROT = 2.0e4, 20.0
TIP = np.array([0.0, 0.0, 0.1])


def _socket_setup(tip=TIP) -> SetupCfg:
    return SetupCfg(tool=ToolDeclCfg(tip_sensor_m=tuple(tip)),
                    contact=ContactDeclCfg(geometry="socket", entry_w_m=(0.0, 0.0, 0.0), axis_w=(0.0, 0.0, -1.0),
                                           stiffness_lat_N_per_m=K_LAT, stiffness_rot_Nm_per_rad=K_ROT))


def _path():
    """A sensor pointing down (tip below it) that descends through the entrance plane z = 0,
    slides 2 mm in x and turns 0.05 rad about world x while engaged, rises out and comes back."""
    n = 400
    R_down = Rotation.from_euler("x", np.pi).as_matrix()  # sensor z points down: the tip is below it
    z_tip = np.r_[np.linspace(0.004, -0.003, 100), np.full(100, -0.003), np.linspace(-0.003, 0.004, 100),
                  np.linspace(0.004, -0.002, 100)]
    x = np.r_[np.zeros(100), np.linspace(0.0, 0.002, 100), np.full(100, 0.002), np.full(100, 0.005)]
    ang = np.r_[np.zeros(100), np.linspace(0.0, 0.05, 100), np.full(100, 0.05), np.full(100, 0.05)]
    R = np.stack([Rotation.from_euler("x", a).as_matrix() @ R_down for a in ang])
    tip_w = np.stack([x, np.zeros(n), z_tip], axis=1)
    p_ws = tip_w - R @ TIP
    return R, p_ws, tip_w, ang


def test_socket_wrench_is_the_two_springs_from_the_anchor():
    """Closed form, sample by sample: engaged from the first sample at or below the plane until
    the tip is 1 mm back above it; f = -k_lat (tip - tip_0) across the axis, tau = -k_rot angle;
    on the sensor: [R^T f; R^T tau + tip x R^T f]. A second entry anchors anew."""
    R, p_ws, tip_w, ang = _path()
    setup = _socket_setup()
    st = contact_model.socket_terms(setup.contact, R, p_ws, TIP)
    depth = -tip_w[:, 2]
    first = int(np.argmax(depth >= 0))
    release = first + int(np.argmax(depth[first:] < -contact_model.RELEASE_M))
    second = release + int(np.argmax(depth[release:] >= 0))
    expect_gate = np.zeros(len(depth), bool)
    expect_gate[first:release] = True
    expect_gate[second:] = True
    np.testing.assert_array_equal(st.gate, expect_gate)
    w = contact_model.nominal_wrench(setup, R, p_ws)
    for i in (first + 150, release - 1, len(depth) - 1):
        a = first if i < release else second
        d = tip_w[i] - tip_w[a]
        f_w = -K_LAT * np.array([d[0], d[1], 0.0])
        tau_w = -K_ROT * np.array([ang[i] - ang[a], 0.0, 0.0])
        f_s, tau_s = R[i].T @ f_w, R[i].T @ tau_w
        np.testing.assert_allclose(w[i], np.r_[f_s, tau_s + np.cross(TIP, f_s)], atol=1e-9)
    assert abs(w[first + 150, 0]) > 1.0 and np.all(w[~expect_gate] == 0.0)
    # no geometry declared: no contact wrench
    assert not contact_model.nominal_wrench(SetupCfg(), R, p_ws).any()


def test_socket_tip_derivative_is_the_finite_difference_of_its_wrench():
    """``contact_model.tip_derivative`` against central differences of ``nominal_wrench`` with the
    declared tip moved (1 micrometre: the engagement does not change), on every engaged sample."""
    R, p_ws, _, _ = _path()
    setup = _socket_setup()
    gate = contact_model.socket_terms(setup.contact, R, p_ws, TIP).gate
    for dtip in (np.array([0.0, -0.1, 0.0]), np.array([0.0, 0.0, 0.1]), np.array([0.02, 0.03, 0.01])):
        h = 1e-5
        w = [contact_model.nominal_wrench(_socket_setup(TIP + sgn * h * dtip), R, p_ws) for sgn in (1.0, -1.0)]
        fd = (w[0] - w[1]) / (2 * h)
        an = contact_model.tip_derivative(setup, R, p_ws, dtip)
        assert np.abs(fd[gate]).max() > 1.0  # the spring's lever and displacement both move
        np.testing.assert_allclose(an[gate], fd[gate], rtol=0, atol=1e-6 * np.abs(fd).max())
        assert not an[~gate].any()


def test_chunks_never_cut_a_socket_engagement():
    """The socket's springs are anchored where the tip entered (not sample-local): the streamed
    passes move a chunk boundary to a sample with no engagement within the halo, so every engaged
    run is inside one chunk and its wrench is the whole log's."""
    from kinadapt_nn.diagnostics import stream

    R, p_ws, _, _ = _path()
    setup = _socket_setup()
    s = SimpleNamespace(setup=setup, R_ws=R, p_ws=p_ws, n=len(R))
    gate = contact_model.socket_terms(setup.contact, R, p_ws, TIP).gate
    halo = 3
    cuts = stream.bounds(s, 50, halo)
    assert cuts[0][0] == 0 and cuts[-1][1] == len(R) and all(b == c for (_, b), (c, _) in zip(cuts, cuts[1:]))
    assert len(cuts) > 1
    for a, _ in cuts[1:]:
        assert not gate[max(0, a - halo):a + halo + 1].any(), a
    whole = contact_model.nominal_wrench(setup, R, p_ws)
    for a, b in cuts:
        lo = max(0, a - halo)
        part = contact_model.nominal_wrench(setup, R[lo:b], p_ws[lo:b])[a - lo:]
        np.testing.assert_allclose(part, whole[a:b], atol=1e-12)
    assert stream.bounds(SimpleNamespace(setup=SetupCfg(), n=len(R)), 50, halo) == stream.chunks(len(R), 50)


def _signals(setup, R, p_ws, wrench, w_nom, omega_s):
    return SimpleNamespace(setup=setup, R_ws=R, p_ws=p_ws, wrench=wrench, w_nom=w_nom, omega_s=omega_s, n=len(R),
                           t=np.arange(len(R)) * 0.001, g_s=np.tile([0.0, 0.0, -9.81], (len(R), 1)), a_s=np.zeros((len(R), 3)))


def test_friction_couple_and_grasp_compliance_columns_closed_form():
    """Engaged, sensor axes = world, 12 N of contact force, turning about z at 0.2 rad/s: the
    friction column is -|f| w/(|w| + eps) in the moments. A contact moment of 1 N m about x_s turns
    the grasp by c per unit compliance: the tip moves by (c e_x) x tip, the lateral spring pushes
    back, the angular spring resists, and the 12 N contact force now acts at the moved tip (the tool
    is massless: no weight moves): M_x = -k_rot - k_lat |tip|^2 + |tip| 12 N per unit c."""
    from kinadapt_nn.effects.builtin.contact_friction_couple import OMEGA_EPS_RAD_S

    n = 5
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    setup = _socket_setup(tip=np.array([0.0, 0.0, -0.1]))
    p_ws = np.tile([0.0, 0.0, 0.098], (n, 1))  # tip at z = -0.002: engaged at the first sample, not moved
    w_nom = contact_model.nominal_wrench(setup, R, p_ws)
    assert not w_nom.any()
    wrench = np.tile([0.0, 0.0, 12.0, 1.0, 0.0, 0.0], (n, 1))
    omega = np.tile([0.0, 0.0, 0.2], (n, 1))
    s = _signals(setup, R, p_ws, wrench, w_nom, omega)
    C = BUILTINS["contact_friction_couple"].evaluate(s)
    np.testing.assert_allclose(C[:, 5, 0], -12.0 * 0.2 / (0.2 + OMEGA_EPS_RAD_S))
    assert not C[:, :5, 0].any()
    G = BUILTINS["grasp_compliance"].evaluate(s)[0, :, 0]
    tip = np.array([0.0, 0.0, -0.1])
    f = -K_LAT * np.cross([1.0, 0.0, 0.0], tip)  # across the axis (already: along y)
    turned = np.cross(np.cross([1.0, 0.0, 0.0], tip), [0.0, 0.0, 12.0])  # the contact force at the moved tip
    np.testing.assert_allclose(G, np.r_[f, np.array([-K_ROT, 0.0, 0.0]) + np.cross(tip, f) + turned], atol=1e-9)
    assert G[3] == pytest.approx(-K_ROT - K_LAT * 0.01 + 0.1 * 12.0)


def test_contact_model_effects_are_judged_only_with_a_declared_geometry():
    setup = _socket_setup()
    lib = userlog.library(setup)
    assert set(CONTACT_MODEL_EFFECTS) == {"contact_stiffness", "contact_friction_couple", "grasp_compliance"}
    assert set(CONTACT_MODEL_EFFECTS) <= set(userlog.judged(lib, setup))
    assert not set(CONTACT_MODEL_EFFECTS) & set(userlog.judged(userlog.library(SetupCfg()), SetupCfg()))
    with pytest.raises(ConfigError, match="geometry") as e:
        load_setup(None, ['contact.geometry="socket"', 'contact.mode="exclude"',
                          "contact.stiffness_rot_Nm_per_rad=1.0"])
    assert len(str(e.value).splitlines()) == 1
    with pytest.raises(ConfigError, match="stiffness"):
        load_setup(None, ['contact.geometry="socket"'])


def test_setup_of_a_package_run():
    """The generated set-up: the controller's arm, the sensor at the flange, the raw reading (the
    flange's wrench on the tool, not tared), the peg on the nominal axis (box inertia as the
    simulator builds it), the known bore entrance and the nominal map's stiffnesses."""
    from kinadapt_nn.sim.scene import _box_inertia

    cfg = load_config(REPO / "online" / "excite.toml")
    s = setup_of_run(cfg)
    assert Path(s.arm.mjcf).name == "panda.xml" and s.arm.flange_site == "flange"
    assert s.log.wrench_acts == "sensor_on_tool" and not s.log.tared and s.log.sign == -1.0
    assert s.tool.mass_kg == cfg.tool.mass_kg
    np.testing.assert_allclose(s.tool.tip_sensor_m, cfg.sensing.nominal_offset_f_m)
    np.testing.assert_allclose(s.tool.com_sensor_m, [0.0, 0.0, 0.1 - 0.5 * cfg.tool.length_m])
    half = np.array([cfg.tool.side_m / 2, cfg.tool.side_m / 2, cfg.tool.length_m / 2])
    np.testing.assert_allclose(s.tool.inertia_com_kg_m2[:3], _box_inertia(cfg.tool.mass_kg, half), rtol=1e-12)
    c = s.contact
    assert c.geometry == "socket" and c.mode == "tip"
    np.testing.assert_allclose(c.entry_w_m, cfg.scene.bore_entry_w_m)
    assert (c.stiffness_lat_N_per_m, c.stiffness_rot_Nm_per_rad) == (cfg.sensing.stiffness_lat_N_per_m,
                                                                     cfg.sensing.stiffness_rot_Nm_per_rad)
    s2 = setup_of_run(cfg, tip_sensor_m=[0.003, -0.002, 0.1])
    assert s2.tool.tip_sensor_m == (0.003, -0.002, 0.1)


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """A short insertion of the default program (free space, then contact in the bore)."""
    from kinadapt_nn.app.cli import main

    out = tmp_path_factory.mktemp("ownrun") / "run"
    assert main(["online", "--out", str(out), "--quiet", "--set", "run.duration_s=3.0", "--set",
                 "run.tensorboard=false", "--set", "run.figure=false"]) in (0, 1)
    return out


@pytest.mark.slow
def test_diagnose_a_package_run_as_a_log_with_add_effects_and_figures(short_run, tmp_path, capsys):
    """``kinadapt diagnose RUN`` (``--as-log``: an accepted alias): the run's trace and generated set-up
    through the one pipeline; a user's effect file (--effects) and --add work on it; the contact-model
    effects are judged (the set-up declares the bore as a socket), the report says which set-up it used;
    the own-run pipeline's options are gone (one line, nothing written)."""
    import json

    from kinadapt_nn.app.cli import main

    out = tmp_path / "d"
    fx = REPO / "examples" / "effects" / "cable_pull.py"
    assert main(["diagnose", str(short_run), "--as-log", "--effects", str(fx), "--add", "tool_gravity", "--out",
                 str(out), "--quiet"]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["kind"] == "package_run" and d["format"] == "kinadapt-diagnosis"
    judged = {e["effect"] for e in d["ranking"] if e.get("judged", True)}
    assert set(CONTACT_MODEL_EFFECTS) | {"cable_pull", "tool_gravity"} <= judged and not d["not_judged"]
    assert d["library"]["cable_pull"]["source"].endswith("cable_pull.py")
    assert "tool_gravity" in d["added"] and d["residual_rms_after"]["total_w"] <= d["residual_rms_before"]["total_w"]
    assert 'geometry = "socket"' in (out / "setup.toml").read_text()
    assert (out / "effects.png").stat().st_size > 10_000 and (out / "residual.png").stat().st_size > 10_000
    capsys.readouterr()
    assert main(["diagnose", str(short_run), "--theta", "0,0,0.1", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--theta" in err[0] and not (tmp_path / "x").exists()


def test_contact_accounts_use_contact_where_either_says_so_and_name_the_disputed_windows():
    """``userlog.ContactAccounts``: the data's and the declared geometry's contact OR-ed; what they
    dispute beyond the data's widening margin is named, and the text says which way it went."""
    t = np.arange(0.0, 4.0, 0.001)
    data = (t > 1.0) & (t < 2.0)  # widened by margin_s = 0.1 s on each side already
    declared = (t > 1.1) & (t < 3.0)  # the bore: the tip below the entrance from 1.1 s
    setup = SetupCfg(contact=ContactDeclCfg(mode="exclude", zone="entrance", axis_w=(0.0, 0.0, -1.0)))
    acc = userlog.ContactAccounts.of(data, declared, t, setup)
    np.testing.assert_array_equal(acc.used, data | declared)
    (a, b), = acc.report["disputed_windows_s"]  # 1.0-1.1 s is within the data's margin: not disputed
    assert abs(a - 2.0) < 2e-3 and abs(b - 2.999) < 2e-3, (a, b)
    assert "under the data's detection threshold" in acc.report["used"]
    assert "cannot touch" not in acc.report["used"]
    none = userlog.ContactAccounts.of(data, None, t, SetupCfg())
    assert none.report["declared"] is None and np.array_equal(none.used, data)


def test_a_bore_run_is_one_account_and_nothing_is_present(default_episode):
    """The README's first run (a bore, its contacts under the 4 N detection threshold): the set-up
    declares the bore as a zone, the data's free span ends where the tip can touch, and nothing is
    present (was: ft_offset 7 N, the bore's contacts fitted as free space)."""
    from kinadapt_nn.diagnostics.importers import RawLog

    tr = default_episode.trace
    raw = RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], "default run")
    log, setup = ownrun_as_log(raw, load_config(None, ["run.progress=false"]))
    assert (setup.contact.mode, setup.contact.zone, setup.tool.tip_known) == ("exclude", "entrance", False)
    rep = userlog.diagnose(log, setup, hints=False).report
    assert not [e["effect"] for e in rep["ranking"] if e["verdict"] == "present"], rep["summary"]
    acc = rep["contact"]["accounts"]
    assert acc["declared_windows_s"] and not acc["data_windows_s"]
    assert rep["segmentation"]["free_span_s"][1] <= acc["declared_windows_s"][0][0] + 1e-9
    assert "Free space and contact" in rep["summary"]


def test_an_effect_free_excitation_run_needs_no_baseline(tmp_path):
    """No hidden effect, no ``--baseline``: nothing present, and the tool's tip, fitted beside the
    effects ([tool] tip_known = false), covers the true tip (3, -2, 100) mm within 3 of its sd."""
    from kinadapt_nn.diagnostics.importers import RawLog
    from kinadapt_nn.runs.episode import run_episode

    cfg = load_config(REPO / "online" / "excite.toml", ["run.tensorboard=false", "run.figure=false",
                                                        "run.progress=false", "run.seed=3"])
    tr = run_episode(cfg).trace
    log, setup = ownrun_as_log(RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], "excite"), cfg)
    rep = userlog.diagnose(log, setup, hints=False).report
    assert not [e["effect"] for e in rep["ranking"] if e["verdict"] == "present"], rep["summary"]
    tt = rep["effective_setup"]["tool_tip"]
    err = np.asarray(tt["tip_sensor_m"]) - np.asarray(cfg.tool.offset_f_m)
    assert np.all(np.abs(err) <= 3.0 * np.asarray(tt["sd_m"]) + 1e-6), (err, tt["sd_m"])
    assert np.linalg.norm(tt["difference_m"]) > 3e-3  # the nominal guess was 3.6 mm off: found, not assumed
