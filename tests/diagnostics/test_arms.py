"""Any arm (``kinadapt_nn.diagnostics.arms``): the same arm from MJCF, URDF and DH has the same
flange pose; DH against an independent product of DH matrices; the site Jacobian against finite
differences; gravity from ``[world]``; bad arm files and mismatched logs are one line; effects
whose parameters follow the set-up (``params_for``)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from kinadapt_nn.diagnostics import physical as ph
from kinadapt_nn.diagnostics.arms import dh_mjcf, load_arm
from kinadapt_nn.diagnostics import effect  # the public decorator (the diagnosis's default set-up)
from kinadapt_nn.diagnostics.setup import SetupCfg, load_setup, rpy_matrix
from kinadapt_nn.errors import ConfigError, KinadaptError, ModelFileError
from kinadapt_nn.robot import JOINT_LIMITS_RAD

ROOT = Path(__file__).resolve().parents[2]
ARMS = ROOT / "examples" / "arms"
N_Q = 50
TOL = 1e-9
UR5E_D = [0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996]
UR5E_A = [0.0, -0.425, -0.3922, 0.0, 0.0, 0.0]
UR5E_ALPHA = [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]


def _urdf(path: Path, *more: str):
    return load_setup(None, [f'arm.urdf="{path}"', *more])


def _flange_poses(setup, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3) positions and (B, 3, 3) rotations of the flange at each q (B, dof), straight from MuJoCo."""
    arm = load_arm(setup.arm)
    d = mujoco.MjData(arm.model)
    p, R = np.empty((len(q), 3)), np.empty((len(q), 3, 3))
    for i, qi in enumerate(q):
        d.qpos[arm.qpos_adr] = qi
        mujoco.mj_kinematics(arm.model, d)
        p[i], R[i] = d.site_xpos[arm.site], d.site_xmat[arm.site].reshape(3, 3)
    return p, R


def _dh_product(q: np.ndarray, d, a, alpha, convention: str, offset=None, base=np.eye(4), flange=np.eye(4)):
    """The flange transform by the textbook product of DH matrices (written out entry by entry)."""
    offset = np.zeros(len(q)) if offset is None else offset
    T = base.copy()
    for i in range(len(q)):
        th = q[i] + offset[i]
        ct, st = np.cos(th), np.sin(th)
        if convention == "classic":  # Rz(theta) Tz(d) Tx(a) Rx(alpha)
            ca, sa = np.cos(alpha[i]), np.sin(alpha[i])
            A = np.array([[ct, -st * ca, st * sa, a[i] * ct], [st, ct * ca, -ct * sa, a[i] * st],
                          [0.0, sa, ca, d[i]], [0.0, 0.0, 0.0, 1.0]])
        else:  # Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta) Tz(d)
            ca, sa = np.cos(alpha[i]), np.sin(alpha[i])
            A = np.array([[ct, -st, 0.0, a[i]], [st * ca, ct * ca, -sa, -sa * d[i]],
                          [st * sa, ct * sa, ca, ca * d[i]], [0.0, 0.0, 0.0, 1.0]])
        T = T @ A
    return T @ flange


def _pose(xyz, rpy_deg) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rpy_matrix(np.deg2rad(rpy_deg)), xyz
    return T


def _assert_same(a, b):
    np.testing.assert_allclose(a[0], b[0], rtol=0, atol=TOL)
    np.testing.assert_allclose(a[1], b[1], rtol=0, atol=TOL)


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert msg and "\n" not in msg, msg
    return msg


# ------------------------------------------------------------------------------------ same arm, 3 ways
def test_panda_mjcf_urdf_dh_same_flange_pose():
    q = np.random.default_rng(0).uniform(JOINT_LIMITS_RAD[:, 0], JOINT_LIMITS_RAD[:, 1], size=(N_Q, 7))
    ref = _flange_poses(SetupCfg(), q)  # models/panda.xml, site "flange"
    _assert_same(_flange_poses(load_setup(ARMS / "panda_dh.toml"), q), ref)
    _assert_same(_flange_poses(_urdf(ARMS / "panda.urdf", 'arm.flange_link="panda_link8"'), q), ref)
    # "" = the link of the last joint (panda_link7), the flange given as an offset in it
    _assert_same(_flange_poses(_urdf(ARMS / "panda.urdf", "arm.flange_xyz_m=[0, 0, 0.107]"), q), ref)
    T = np.stack([_dh_product(qi, [0.333, 0, 0.316, 0, 0.384, 0, 0], [0, 0, 0, 0.0825, -0.0825, 0, 0.088],
                              [0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2], "modified",
                              flange=_pose([0, 0, 0.107], [0, 0, 0])) for qi in q])
    _assert_same((T[:, :3, 3], T[:, :3, :3]), ref)


def test_panda_urdf_limits_are_the_mjcf_limits():
    model = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "panda.xml"))
    import xml.etree.ElementTree as ET

    lim = [(float(j.find("limit").get("lower")), float(j.find("limit").get("upper")))
           for j in ET.parse(ARMS / "panda.urdf").getroot().findall("joint") if j.get("type") == "revolute"]
    np.testing.assert_array_equal(np.array(lim), model.jnt_range)


def test_ur5e_dh_and_urdf_same_flange_pose():
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, size=(N_Q, 6))
    dh = load_setup(ARMS / "ur5e_dh.toml")
    assert load_arm(dh.arm).dof == 6 and len(dh.log.q) == 6
    ref = _flange_poses(dh, q)
    _assert_same(_flange_poses(_urdf(ARMS / "ur5e.urdf"), q), ref)  # flange_link "" = wrist_3_link = frame 6
    T = np.stack([_dh_product(qi, UR5E_D, UR5E_A, UR5E_ALPHA, "classic") for qi in q])
    _assert_same((T[:, :3, 3], T[:, :3, :3]), ref)
    # the published zero pose: x = a2 + a3, y = -(d4 + d6), z = d1 - d5
    p0, _ = _flange_poses(dh, np.zeros((1, 6)))
    np.testing.assert_allclose(p0[0], [-0.8172, -0.2329, 0.0628], atol=1e-12)


def test_classic_and_modified_dh_of_the_same_arm_agree():
    """Classic ``prod Rz Tz Tx Rx`` regrouped is modified with (a, alpha) shifted down one row and
    the last ``Tx(a_n) Rx(alpha_n)`` as the flange; offsets, base and flange pose arbitrary."""
    rng = np.random.default_rng(2)
    n = 5
    d, a = rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n)
    alpha, off = rng.uniform(-np.pi, np.pi, n), rng.uniform(-np.pi, np.pi, n)
    base = dict(base_xyz_m=[0.1, -0.2, 0.3], base_rpy_deg=[10.0, -20.0, 30.0])
    classic = {"convention": "classic", "a_m": list(a), "d_m": list(d), "alpha_rad": list(alpha),
               "theta_offset_rad": list(off), **base, "flange_xyz_m": [0.01, 0.02, 0.05], "flange_rpy_deg": [5.0, 6.0, 7.0]}
    # modified flange = Tx(a_n) Rx(alpha_n) * classic flange
    F = _pose([a[-1], 0, 0], [np.rad2deg(alpha[-1]), 0, 0]) @ _pose([0.01, 0.02, 0.05], [5.0, 6.0, 7.0])
    rpy = [np.arctan2(F[2, 1], F[2, 2]), -np.arcsin(F[2, 0]), np.arctan2(F[1, 0], F[0, 0])]
    modified = {"convention": "modified", "a_m": [0.0, *a[:-1]], "d_m": list(d), "alpha_rad": [0.0, *alpha[:-1]],
                "theta_offset_rad": list(off), **base, "flange_xyz_m": list(F[:3, 3]),
                "flange_rpy_deg": list(np.rad2deg(rpy))}
    q = rng.uniform(-np.pi, np.pi, size=(N_Q, n))
    pc = _flange_poses(SetupCfg.model_validate({"log": {"q": [f"j{i}" for i in range(n)]}, "arm": {"dh": classic}}), q)
    pm = _flange_poses(SetupCfg.model_validate({"log": {"q": [f"j{i}" for i in range(n)]}, "arm": {"dh": modified}}), q)
    _assert_same(pc, pm)
    T = np.stack([_dh_product(qi, d, a, alpha, "classic", off, _pose(base["base_xyz_m"], base["base_rpy_deg"]),
                              _pose([0.01, 0.02, 0.05], [5.0, 6.0, 7.0])) for qi in q])
    _assert_same((T[:, :3, 3], T[:, :3, :3]), pc)


def test_dh_mjcf_is_one_body_per_joint():
    text = dh_mjcf(load_setup(ARMS / "ur5e_dh.toml").arm.dh)
    model = mujoco.MjModel.from_xml_string(text)
    assert model.njnt == 6 and model.nbody == 8 and all(int(t) == int(mujoco.mjtJoint.mjJNT_HINGE) for t in model.jnt_type)


# ------------------------------------------------------------------------------- velocities, gravity
def _ur5e_with_sensor(*more: str):
    return load_setup(ARMS / "ur5e_dh.toml", ["sensor.position_flange_m=[0.02, -0.01, 0.06]",
                                               "sensor.rpy_flange_deg=[15, -30, 45]", *more])


def test_dh_site_jacobian_against_finite_differences():
    """omega from ``series`` (site Jacobian times qdot) against the rotation's central difference
    along qdot; the sensor's acceleration (Jacobian, lever and Savitzky-Golay derivative) against
    the second difference of its position on a smooth motion."""
    setup = _ur5e_with_sensor()
    arm = ph.ArmModel(setup)
    rng = np.random.default_rng(3)
    q, qd = rng.uniform(-np.pi, np.pi, (20, 6)), rng.normal(0.0, 1.0, (20, 6))
    kin = arm.series(q, qd, np.arange(20) * 0.01)
    h = 1e-6
    Rp, Rm = arm.series(q + h * qd, qd, np.arange(20) * 0.01).R_ws, arm.series(q - h * qd, qd, np.arange(20) * 0.01).R_ws
    W = np.einsum("nji,njk->nik", kin.R_ws, (Rp - Rm) / (2 * h))  # R^T dR = [omega_s]x
    omega_fd = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    np.testing.assert_allclose(kin.omega_s, omega_fd, atol=1e-7)

    t = np.arange(3000) * 1e-3
    w, amp, q0 = np.array([1.1, 0.7, 1.3, 0.9, 1.7, 0.5]), rng.uniform(0.2, 0.6, 6), rng.uniform(-1, 1, 6)
    qt = q0 + amp * np.sin(w * t[:, None])
    qdt = amp * w * np.cos(w * t[:, None])
    kin = arm.series(qt, qdt, t)
    dt = t[1] - t[0]
    a_w = (kin.p_ws[2:] - 2 * kin.p_ws[1:-1] + kin.p_ws[:-2]) / dt ** 2
    a_s = np.einsum("nji,nj->ni", kin.R_ws[1:-1], a_w)
    inner = slice(100, -100)  # away from the filter's ends
    err = np.abs(kin.a_s[1:-1][inner] - a_s[inner]).max()
    assert err < 1e-3 * np.abs(a_s[inner]).max(), err


def test_gravity_follows_world_gravity():
    q = np.random.default_rng(4).uniform(-np.pi, np.pi, (10, 6))
    t = np.arange(10) * 0.01
    for g in (9.81, 3.71):
        kin = ph.ArmModel(_ur5e_with_sensor(f"world.gravity_mps2={g}")).series(q, np.zeros_like(q), t)
        np.testing.assert_allclose(np.linalg.norm(kin.g_s, axis=1), g, rtol=1e-12)
        np.testing.assert_allclose(np.einsum("nij,nj->ni", kin.R_ws, kin.g_s), np.tile([0, 0, -g], (10, 1)), atol=1e-12)


# -------------------------------------------------------------------------------------- one-line errors
def test_log_with_other_joint_count_is_one_line():
    from kinadapt_nn.diagnostics.signals import from_log

    n = 50
    log = SimpleNamespace(t_s=np.arange(n) * 0.01, q_rad=np.zeros((n, 6)), qdot_rad_s=None,
                          wrench_log=np.zeros((n, 6)), extra=None, source="log.csv", static=False)
    setup = load_setup(None, ['log.q=["a", "b", "c", "d", "e", "f"]'])  # the shipped Panda: 7 joints
    with pytest.raises(KinadaptError) as exc:
        from_log(log, setup)
    msg = _one_line(exc)
    assert "6 joint" in msg and "7 joints" in msg


def test_bad_arm_declarations_are_one_line(tmp_path):
    with pytest.raises(ModelFileError) as exc:
        load_arm(_urdf(tmp_path / "absent.urdf").arm)
    assert "absent.urdf" in _one_line(exc) and "[arm] urdf" in str(exc.value)
    with pytest.raises(KinadaptError) as exc:
        load_arm(_urdf(ARMS / "ur5e.urdf", 'arm.flange_link="tool0"').arm)
    assert "tool0" in _one_line(exc) and "wrist_3_link" in str(exc.value)
    with pytest.raises(ConfigError) as exc:
        load_setup(None, ['arm.dh={convention="classic", a_m=[0, 0.4], d_m=[0.1], alpha_rad=[0, 0]}'])
    assert "d_m" in _one_line(exc)
    two_links = "<robot name='x'><link name='a'/><link name='b'/><joint name='j' type='{}'><parent link='a'/>" \
                "<child link='b'/></joint></robot>"
    for name, text, error, words in (("bad", "<robot name='x'><link name='a'></robot>", ModelFileError, "not valid XML"),
                                     ("still", two_links.format("fixed"), KinadaptError, "no revolute"),
                                     ("floating", two_links.format("floating"), KinadaptError, "floating")):
        f = tmp_path / f"{name}.urdf"
        f.write_text(text)
        with pytest.raises(error) as exc:
            load_arm(_urdf(f).arm)
        assert words in _one_line(exc)
    with pytest.raises(KinadaptError) as exc:
        load_arm(load_setup(None, ['arm.flange_site="tcp"']).arm)
    assert "tcp" in _one_line(exc)


def test_branching_urdf_needs_flange_link(tmp_path):
    two = tmp_path / "gripper.urdf"
    joint = "<joint name='{n}' type='prismatic'><parent link='{p}'/><child link='{c}'/><axis xyz='1 0 0'/></joint>"
    two.write_text("<robot name='x'>" + "".join(f"<link name='{n}'/>" for n in ("a", "b", "f1", "f2"))
                   + "<joint name='j' type='revolute'><parent link='a'/><child link='b'/><axis xyz='0 0 1'/></joint>"
                   + joint.format(n="s1", p="b", c="f1") + joint.format(n="s2", p="b", c="f2") + "</robot>")
    with pytest.raises(KinadaptError) as exc:
        load_arm(_urdf(two).arm)
    assert "flange_link" in _one_line(exc)
    arm = load_arm(_urdf(two, 'arm.flange_link="b"').arm)
    assert arm.dof == 1  # the fingers are not between the base and the flange


def test_urdf_with_absent_meshes_and_ros_extras_loads(tmp_path):
    urdf = tmp_path / "sub" / "arm.urdf"
    urdf.parent.mkdir()
    mesh = ("<visual><origin xyz='0 0 0'/><geometry><mesh filename='package://nowhere/meshes/{0}.stl' scale='1 1 1'/>"
            "</geometry><material name='grey'><texture filename='meshes/grey.png'/></material></visual>"
            "<collision><geometry><mesh filename='../meshes/{0}.dae'/></geometry></collision>")
    urdf.write_text(
        "<?xml version='1.0'?><robot name='two'>"
        "<material name='grey'><color rgba='0.5 0.5 0.5 1'/></material>"
        "<link name='world'/>"
        f"<link name='base'>{mesh.format('base')}<inertial><mass value='0'/>"
        "<inertia ixx='0' iyy='0' izz='0' ixy='0' ixz='0' iyz='0'/></inertial></link>"
        f"<link name='upper'>{mesh.format('upper')}</link><link name='lower'>{mesh.format('lower')}</link>"
        "<link name='tool0'/>"
        "<joint name='fix' type='fixed'><parent link='world'/><child link='base'/><origin xyz='0 0 0.5'/></joint>"
        "<joint name='j1' type='continuous'><parent link='base'/><child link='upper'/><axis xyz='0 1 0'/>"
        "<dynamics damping='0.1'/></joint>"
        "<joint name='j2' type='revolute'><parent link='upper'/><child link='lower'/><origin xyz='0 0 0.3'/>"
        "<axis xyz='0 1 0'/><limit lower='-2' upper='2' effort='10' velocity='1'/><safety_controller k_velocity='1'/>"
        "</joint>"
        "<joint name='t' type='fixed'><parent link='lower'/><child link='tool0'/><origin xyz='0 0 0.2'/></joint>"
        "<transmission name='tr'><type>transmission_interface/SimpleTransmission</type></transmission>"
        "<gazebo reference='base'><material>Gazebo/Grey</material></gazebo>"
        "</robot>")
    arm = load_arm(_urdf(urdf, 'arm.flange_link="tool0"').arm)
    assert arm.dof == 2
    # two links in a plane (y axes): flange at base + 0.3 (rotated by q1) + 0.2 (by q1 + q2)
    q = np.array([[0.3, -0.5]])
    p, _ = _flange_poses(_urdf(urdf, 'arm.flange_link="tool0"'), q)
    s1, c1, s12, c12 = np.sin(0.3), np.cos(0.3), np.sin(-0.2), np.cos(-0.2)
    np.testing.assert_allclose(p[0], [0.3 * s1 + 0.2 * s12, 0.0, 0.5 + 0.3 * c1 + 0.2 * c12], atol=1e-12)


# --------------------------------------------------------------------------- effects that follow the set-up
def test_encoder_offset_has_one_parameter_per_joint():
    from kinadapt_nn.diagnostics.signals import from_log
    from kinadapt_nn.diagnostics.userlog import library

    setup = _ur5e_with_sensor("tool.mass_kg=1.5", "tool.com_sensor_m=[0.01, 0.02, 0.08]")
    enc = library(setup)["encoder_offset"]
    assert enc.params == tuple(f"offset_joint{j}" for j in range(1, 7)) and len(enc.relevant) == 6
    assert library(SetupCfg())["encoder_offset"].k == 7
    n = 60
    t = np.arange(n) * 0.01
    q = np.random.default_rng(5).uniform(-1, 1, 6) + 0.3 * np.sin(t[:, None] * np.arange(1, 7))
    log = SimpleNamespace(t_s=t, q_rad=q, qdot_rad_s=None, wrench_log=np.zeros((n, 6)), extra=None, source="x",
                          static=False)
    s = from_log(log, setup)
    C = enc.evaluate(s)
    assert C.shape == (n, 6, 6)
    # joint 1 turns the whole motion about the vertical: nothing changes in the sensor frame
    assert np.abs(C[:, :, 1:]).max() > 1.0 and np.abs(C[:, :, 0]).max() < 1e-6 * np.abs(C[:, :, 1:]).max()
    rep = enc.user_report(np.deg2rad(np.arange(1.0, 7.0)), np.full(6, 0.01), setup)
    assert list(rep) == list(enc.params) and rep["offset_joint6"]["value"] == pytest.approx(6.0)
    assert enc.why_impossible(np.deg2rad([0, 0, 0, 0, 0, 20.0]), setup)


def test_params_for_in_the_public_form():
    @effect(params_for=lambda setup: ({f"k{j}": "N" for j in range(len(setup.log.q))}, [0.1] * len(setup.log.q)),
            doc="per joint")
    def per_joint(s):
        return np.zeros((s.n, 6, s.q.shape[1]))

    assert per_joint.params == tuple(f"k{j}" for j in range(7))  # the default set-up
    assert per_joint.for_setup(load_setup(ARMS / "ur5e_dh.toml")).k == 6
    assert per_joint.for_setup(SetupCfg()) == per_joint


def test_params_for_errors_are_one_line():
    with pytest.raises(KinadaptError) as exc:
        @effect(params_for=lambda setup: ({"a": "N"}, [0.1, 0.2]), doc="wrong")
        def broken(s):
            return np.zeros((s.n, 6, 1))
    assert "broken" in _one_line(exc) and "relevant" in str(exc.value)
    with pytest.raises(KinadaptError) as exc:
        @effect(params_for=lambda setup: 1 / 0, doc="raises")
        def raises(s):
            return np.zeros((s.n, 6, 1))
    assert "ZeroDivisionError" in _one_line(exc)
    with pytest.raises(KinadaptError) as exc:
        @effect(doc="no params")
        def nothing(s):
            return np.zeros((s.n, 6, 1))
    assert "params" in _one_line(exc)
    from kinadapt_nn.effects.contract import effect as layer_effect  # below the diagnosis: no set-up type

    with pytest.raises(KinadaptError) as exc:
        @layer_effect(params_for=lambda setup: ({"a": "N"}, [0.1]), doc="no default set-up")
        def no_default(s):
            return np.zeros((s.n, 6, 1))
    assert "besides params_for" in _one_line(exc) and "kinadapt_nn.diagnostics.effect" in str(exc.value)


def test_batched_kinematics_equal_mujocos_per_sample_site_jacobian(tmp_path):
    """``ArmModel._frames`` (MuJoCo's batched kinematics, the Jacobian from the joints' axes and
    anchors) equals a per-sample ``mj_kinematics`` + ``mj_comPos`` + ``mj_jacSite`` to rounding on
    every kind of arm -- the Panda's MJCF, the UR5e's URDF and DH, a URDF with a slide joint -- over
    more samples than one batch holds."""
    slide = tmp_path / "slide.urdf"
    slide.write_text(
        "<robot name='s'>" + "".join(f"<link name='{n}'/>" for n in ("base", "l1", "l2", "l3"))
        + "<joint name='j1' type='revolute'><parent link='base'/><child link='l1'/><origin xyz='0 0 0.3'/>"
          "<axis xyz='0 0 1'/><limit lower='-3' upper='3' effort='1' velocity='1'/></joint>"
        + "<joint name='j2' type='prismatic'><parent link='l1'/><child link='l2'/><origin xyz='0.1 0 0' rpy='0.3 0 0'/>"
          "<axis xyz='1 0 0'/><limit lower='-3' upper='3' effort='1' velocity='1'/></joint>"
        + "<joint name='j3' type='revolute'><parent link='l2'/><child link='l3'/><origin xyz='0 0.2 0.05'/>"
          "<axis xyz='0 1 0'/><limit lower='-3' upper='3' effort='1' velocity='1'/></joint></robot>")
    rng = np.random.default_rng(11)
    for setup in (load_setup(None), _urdf(ARMS / "ur5e.urdf"), load_setup(ARMS / "ur5e_dh.toml"),
                  _urdf(slide, 'log.q=["a", "b", "c"]')):
        arm = ph.ArmModel(setup)
        q = rng.uniform(-2.5, 2.5, (ph.FRAMES_BATCH + 500, arm.dof))
        R, x, Jp, Jr = arm._frames(q)
        m, d = arm.model, mujoco.MjData(arm.model)
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        for i in range(0, len(q), 37):
            d.qpos[arm._qpos] = q[i]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, jp, jr, arm.site)
            np.testing.assert_allclose(x[i], d.site_xpos[arm.site], atol=1e-12)
            np.testing.assert_allclose(R[i], d.site_xmat[arm.site].reshape(3, 3), atol=1e-12)
            np.testing.assert_allclose(Jp[i], jp[:, arm._cols], atol=1e-12)
            np.testing.assert_allclose(Jr[i], jr[:, arm._cols], atol=1e-12)
        assert not arm._hinge.all() or setup.arm.urdf != str(slide)
