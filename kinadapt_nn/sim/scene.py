"""Build the peg-in-hole scene programmatically with ``mujoco.MjSpec``.

The Panda comes from ``models/panda.xml``; the tool (a rigid square peg under a wrist F/T
sensor site) and the bore block are added here from ``ToolCfg`` / ``SceneCfg`` so every
tool of a sweep is the same code path. Nothing is downloaded.

Frames: the tool body's origin is the flange origin O with axes of the flange frame ``f``;
the F/T sensor site ``ft_site`` sits there, so the sensor reports the wrench the flange
exerts on the tool, about O, in ``f``.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import mujoco
import numpy as np

from kinadapt_nn.config import ArmCfg, EffectsCfg, SceneCfg, ToolCfg, arm_mjcf_path, true_bore_entry
from kinadapt_nn.errors import ModelFileError
from kinadapt_nn.geometry import quat_from_matrix, tilt_rotation
from kinadapt_nn.robot import FLANGE_BODY
from kinadapt_nn.sim.truth import apply_arm_errors

FT_SITE = "ft_site"
TIP_SITE = "tip_site"  # truth only: the true tip (never given to the controller)
PEG_GEOM = "peg"
TOOL_BODY = "tool"
FORCE_SENSOR = "ft_force"
TORQUE_SENSOR = "ft_torque"
BLOCK_BODY = "bore_block"
#: truth only: MuJoCo's contact sensor on the peg <-> block contacts (number found, then per slot the
#: normal force (3, contact frame) and the position (3, world)); never given to the controller
TRUTH_CONTACT_SENSOR = "truth_peg_block_contacts"
TRUTH_CONTACT_SLOTS = 24  #: contacts it reports (more are rare: the scan of the contact array then)
BLOCK_TOP_GEOMS_PREFIX = "block_"
#: [kg m^2] the grasp hinges' armature (effect grasp_compliance). Numerical, not a rotor of the grasp:
#: the socket fixture's damper acts on the tool's turn explicitly (``sim.socket``: its wrench is computed
#: on the step's start state), c = c_lat |tip|^2 + c_rot = 1.74 N m s/rad at the excitation's fixture, and
#: one 1 ms step would take dt c / I = 5.07 of the turn rate with the tool's own 3.4e-4 kg m^2 (unstable
#: above 2: with no armature the excitation run blows up); 0.52 with this added. MuJoCo's armature has
#: no body, so the reading (the tool's Newton-Euler force) carries its torque ``a d2(turn)/dt2`` as if the
#: hinge's spring bore it: -0.02 % of the turn / moment slope on the excitation run. Before, the hinges
#: inherited the Panda's joint class's 0.1 kg m^2: -0.63 % there (the realised compliance 1.006 / k seen
#: from the reading) and a damping ratio of 0.04 where 0.7 was meant (benchmarks/grasp_compliance_check.py
#: [--before]; tests/sim/test_grasp_hinge.py)
GRASP_ARMATURE_KG_M2 = 3e-3


class SceneIds(NamedTuple):
    """MuJoCo ids and addresses looked up once."""

    ft_site: int  #: site id of the F/T sensor (flange origin O)
    tip_site: int  #: site id of the true tip (truth side only)
    peg_geom: int  #: geom id of the peg
    block_geoms: np.ndarray  #: (k,) geom ids of the block
    force_adr: int  #: sensordata address of the 3 force values
    torque_adr: int  #: sensordata address of the 3 torque values
    qpos_adr: np.ndarray  #: (n,) qpos addresses of the arm joints
    dof_adr: np.ndarray  #: (n,) dof addresses of the arm joints
    contact_adr: int = -1  #: sensordata address of the truth contact sensor (-1: no block in the scene)


def _box_inertia(mass: float, half: np.ndarray) -> np.ndarray:
    a, b, c = 2 * half
    return mass / 12.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


def _add_tool(spec: mujoco.MjSpec, tool: ToolCfg, effects: EffectsCfg | None = None) -> None:
    link7 = spec.body(FLANGE_BODY)
    flange_site = spec.site("flange")
    gc = effects.grasp_compliance if effects is not None else None
    if gc is not None and gc.enabled:
        # effect grasp_compliance: the F/T sensor sits on a rigid plate at the flange; the tool
        # hangs below it on two damped hinges about f x and f y through O
        plate = link7.add_body(name="ft_plate", pos=list(flange_site.pos))
        plate.explicitinertial = True
        plate.mass = 1e-4
        plate.inertia = [1e-8, 1e-8, 1e-8]
        plate.add_site(name=FT_SITE, pos=[0, 0, 0], size=[0.006, 0, 0], rgba=[0.8, 0.3, 0.3, 1])
        body = plate.add_body(name=TOOL_BODY, pos=[0, 0, 0])
        inertia_O = tool.mass_kg * tool.length_m**2 / 3.0 + 1e-5  # [kg m^2] about a hinge at O
        # the hinges' own inertia (armature) set here, not inherited from the arm's joint class
        # (the Panda's 0.1 kg m^2, 300x the tool's: the sensor does not see an armature's torque)
        damping = 2.0 * 0.7 * np.sqrt(gc.stiffness_Nm_per_rad * (inertia_O + GRASP_ARMATURE_KG_M2))
        for name, axis in (("grasp_x", [1, 0, 0]), ("grasp_y", [0, 1, 0])):
            body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=axis, pos=[0, 0, 0],
                           stiffness=gc.stiffness_Nm_per_rad, damping=damping, armature=GRASP_ARMATURE_KG_M2)
    else:
        body = link7.add_body(name=TOOL_BODY, pos=list(flange_site.pos))
    R_f_t = tilt_rotation(tool.tilt_deg)  # tool axes in f (grasp tilt)
    axis_f = R_f_t[:, 2]
    tip_f = np.asarray(tool.offset_f_m, dtype=float)
    centre_f = tip_f - 0.5 * tool.length_m * axis_f
    half = np.array([tool.side_m / 2, tool.side_m / 2, tool.length_m / 2])
    quat = quat_from_matrix(R_f_t)
    body.add_geom(
        name=PEG_GEOM,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=list(half),
        pos=list(centre_f),
        quat=list(quat),
        contype=1,
        conaffinity=1,
        condim=4 if (effects is not None and effects.contact_friction_couple.enabled) else 3,
        density=0.0,
        rgba=[0.35, 0.47, 0.75, 1.0],
    )
    body.explicitinertial = True
    body.mass = tool.mass_kg
    body.ipos = list(centre_f)
    body.iquat = list(quat)
    body.inertia = list(_box_inertia(tool.mass_kg, half))
    if gc is None or not gc.enabled:
        body.add_site(name=FT_SITE, pos=[0, 0, 0], size=[0.006, 0, 0], rgba=[0.8, 0.3, 0.3, 1])
    body.add_site(name=TIP_SITE, pos=list(tip_f), size=[0.003, 0, 0], rgba=[1, 0.8, 0.2, 1])
    if effects is not None and effects.tool_gravity.enabled:  # effect tool_gravity: a rigid payload
        g = effects.tool_gravity
        pay = body.add_body(name="payload", pos=list(g.com_f_m))
        pay.explicitinertial = True
        pay.mass = g.mass_kg
        pay.ipos = [0.0, 0.0, 0.0]  # the payload body sits at its COM
        r = 0.02  # [m] a small solid sphere's inertia
        pay.inertia = [0.4 * g.mass_kg * r * r] * 3
    if effects is not None and effects.world_force.enabled:  # effect world_force: a massless body where the snag pulls
        snag = body.add_body(name="snag", pos=list(effects.world_force.point_f_m))
        snag.explicitinertial = True
        snag.mass = 0.0
        snag.ipos = [0.0, 0.0, 0.0]  # the force acts at the body's centre of mass (xfrc_applied): the point
        snag.inertia = [0.0, 0.0, 0.0]


def _convex_prism(spec: mujoco.MjSpec, name: str, profile_xz: np.ndarray, y0: float, y1: float) -> None:
    verts = []
    for y in (y0, y1):
        for x, z in profile_xz:
            verts.extend([x, y, z])
    spec.add_mesh(name=name, uservert=verts)


def _add_block(spec: mujoco.MjSpec, scene: SceneCfg) -> None:
    cx, cy, top = true_bore_entry(scene)
    hw, B, depth, c = scene.bore_half_width_m, scene.block_half_size_m, scene.bore_depth_m, scene.chamfer_m
    floor_t = 0.02
    bottom = top - depth - floor_t
    h_wall = (top - bottom) / 2
    block = spec.worldbody.add_body(name=BLOCK_BODY, pos=[cx, cy, 0.0])
    common = dict(contype=1, conaffinity=1, condim=3, rgba=[0.78, 0.8, 0.84, 1.0])
    # four corner blocks (never chamfered)
    half_corner = (B - hw) / 2
    for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
        block.add_geom(
            name=f"{BLOCK_TOP_GEOMS_PREFIX}corner{i}",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[half_corner, half_corner, h_wall],
            pos=[sx * (hw + half_corner), sy * (hw + half_corner), bottom + h_wall],
            **common,
        )
    # four side walls facing the bore; with a chamfer they are convex prisms
    for i, (axis, sign) in enumerate([(0, 1), (0, -1), (1, 1), (1, -1)]):
        name = f"{BLOCK_TOP_GEOMS_PREFIX}wall{i}"
        if c <= 0.0:
            size = [half_corner, hw, h_wall] if axis == 0 else [hw, half_corner, h_wall]
            pos = [sign * (hw + half_corner), 0.0, bottom + h_wall]
            if axis == 1:
                pos = [0.0, sign * (hw + half_corner), bottom + h_wall]
            block.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=size, pos=pos, **common)
            continue
        # profile in (u, z) with u the outward distance from the bore axis
        prof = np.array([[hw, top - c], [hw + c, top], [B, top], [B, bottom], [hw, bottom]])
        mesh_name = f"{name}_mesh"
        _convex_prism(spec, mesh_name, prof, -hw, hw)
        # mesh is built with u along +x and the extrusion along y; rotate into place
        angle = {(0, 1): 0.0, (1, 1): 90.0, (0, -1): 180.0, (1, -1): 270.0}[(axis, sign)]
        q = np.zeros(4)
        mujoco.mju_axisAngle2Quat(q, np.array([0.0, 0.0, 1.0]), np.deg2rad(angle))
        block.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh_name, quat=list(q), **common)
    block.add_geom(
        name=f"{BLOCK_TOP_GEOMS_PREFIX}floor",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[hw, hw, floor_t / 2],
        pos=[0.0, 0.0, bottom + floor_t / 2],
        **common,
    )


def friction_reference_pairs(spec: mujoco.MjSpec, timeconst_s: float) -> None:
    """The peg <-> block contacts as explicit pairs whose friction rows have their own reference
    (``solreffriction = [timeconst_s, 1]``, elliptic cone), everything else as the global override
    set it (normal solref and solimp, friction, margin, condim).

    Why (docs/paper_results.md, "The bore rattle"): in MuJoCo's convex contact model a sliding
    contact's friction rows ask for the reference deceleration ``-b v_t``, ``b = 2 / (0.99 t)``,
    which the friction cone cannot deliver; the solution trades the shortfall against the normal
    row and pushes the bodies apart at about ``mu b v_t`` (MuJoCo's documentation: "the only way to
    initiate slip is to generate some motion in the normal direction"). With the normal's 20 ms
    that is 0.5 m/s^2 for the peg sliding down the bore edge at 15 mm/s: the peg is thrown off the
    wall every few steps (88 Hz, 209 contact transitions per s). A friction reference of 2 s
    (b = 1/s) removes the push; what it costs is a weaker arrest of slip inside the cone (a free
    body that should stick creeps; the docs give the numbers). Pair parameters are not overridden
    only when the override flag is off, so it is cleared and the pairs carry the override's values;
    the peg's own contype is cleared so that no dynamic contact duplicates a pair (the peg and the
    block are the only colliding geoms). ``spec``: the scene with its peg (``PEG_GEOM``) and block
    geoms."""
    o = spec.option
    o.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_OVERRIDE)
    o.cone = mujoco.mjtCone.mjCONE_ELLIPTIC  # solreffriction applies to elliptic friction rows only
    peg = spec.geom(PEG_GEOM)
    for g in spec.geoms:
        if g.name.startswith(BLOCK_TOP_GEOMS_PREFIX):
            spec.add_pair(geomname1=PEG_GEOM, geomname2=g.name, condim=peg.condim, friction=list(o.o_friction),
                          solref=list(o.o_solref), solimp=list(o.o_solimp), margin=o.o_margin,
                          solreffriction=[timeconst_s, 1.0])
    peg.contype, peg.conaffinity = 0, 0


def build_spec(
    tool: ToolCfg, scene: SceneCfg, mjcf_path: Path | None = None, arm: ArmCfg | None = None,
    effects: EffectsCfg | None = None,
) -> mujoco.MjSpec:
    """The full scene spec: Panda + tool + bore block + wrist F/T sensor."""
    mjcf_path = Path(mjcf_path) if mjcf_path is not None else arm_mjcf_path(scene)
    if not mjcf_path.is_file():
        raise ModelFileError(f"model file '{mjcf_path}' not found (reinstall the package or fix the path)")
    try:
        spec = mujoco.MjSpec.from_file(str(mjcf_path))
    except Exception as exc:  # mujoco raises ValueError with a long message
        raise ModelFileError(f"model file '{mjcf_path}' could not be parsed: {str(exc).splitlines()[0]}") from None
    spec.option.o_solref = [scene.contact_timeconst_s, scene.contact_dampratio]
    spec.option.enableflags |= int(mujoco.mjtEnableBit.mjENBL_OVERRIDE)
    torsion = effects.contact_friction_couple.radius_m if effects is not None and effects.contact_friction_couple.enabled else 0.005
    spec.option.o_friction = [scene.friction, scene.friction, torsion, 0.0001, 0.0001]
    spec.option.o_margin = 0.0
    spec.option.o_solimp = [0.95, 0.99, 0.001, 0.5, 2.0]
    if arm is not None:
        apply_arm_errors(spec, arm.link_length_error_m, arm.joint_offset_rad)
    _add_tool(spec, tool, effects)
    if scene.contact_model == "bore":
        _add_block(spec, scene)
        if scene.contact_friction_timeconst_s > 0.0:
            friction_reference_pairs(spec, scene.contact_friction_timeconst_s)
    spec.add_sensor(
        name=FORCE_SENSOR, type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=FT_SITE
    )
    spec.add_sensor(
        name=TORQUE_SENSOR, type=mujoco.mjtSensor.mjSENS_TORQUE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=FT_SITE
    )
    if scene.contact_model == "bore":
        fields = sum(1 << int(f) for f in (mujoco.mjtConDataField.mjCONDATA_FOUND, mujoco.mjtConDataField.mjCONDATA_FORCE,
                                            mujoco.mjtConDataField.mjCONDATA_POS))
        spec.add_sensor(name=TRUTH_CONTACT_SENSOR, type=mujoco.mjtSensor.mjSENS_CONTACT, objtype=mujoco.mjtObj.mjOBJ_GEOM,
                        objname=PEG_GEOM, reftype=mujoco.mjtObj.mjOBJ_BODY, refname=BLOCK_BODY,
                        intprm=[fields, 0, TRUTH_CONTACT_SLOTS])  # reduce 0: every contact, in MuJoCo's order
    spec.worldbody.add_light(pos=[0.4, -0.6, 1.5], dir=[0, 0.5, -1])
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.rgba.haze = [0.55, 0.6, 0.68, 1.0]
    spec.worldbody.add_geom(  # visual floor only (no collisions)
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1.0, 1.0, 0.01], pos=[0, 0, 0],
        contype=0, conaffinity=0, rgba=[0.42, 0.45, 0.5, 1.0],
    )
    if scene.contact_model == "bore":  # pedestal under the block (visual only)
        cx, cy, top = true_bore_entry(scene)
        h = max(top - scene.bore_depth_m - 0.02, 0.0)
        if h > 0:
            spec.worldbody.add_geom(name="pedestal", type=mujoco.mjtGeom.mjGEOM_BOX,
                                    size=[scene.block_half_size_m, scene.block_half_size_m, h / 2],
                                    pos=[cx, cy, h / 2], contype=0, conaffinity=0, rgba=[0.3, 0.32, 0.36, 1])
    spec.worldbody.add_camera(
        name="side", pos=[scene.bore_entry_w_m[0] + 0.0, scene.bore_entry_w_m[1] - 0.55, scene.bore_entry_w_m[2] + 0.18],
        xyaxes=[1, 0, 0, 0, 0.3, 1],
    )
    return spec


def _sensor_adr(model: mujoco.MjModel, name: str) -> int:
    """sensordata address of sensor ``name``, -1 when the model has none."""
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
    return int(model.sensor_adr[i]) if i >= 0 else -1


def build_model(tool: ToolCfg, scene: SceneCfg, mjcf_path: Path | None = None, arm: ArmCfg | None = None,
                effects: EffectsCfg | None = None) -> tuple[mujoco.MjModel, SceneIds]:
    """Compile the scene and look every id/address up once."""
    spec = build_spec(tool, scene, mjcf_path, arm, effects)
    try:
        model = spec.compile()
    except Exception as exc:
        raise ModelFileError(f"scene does not compile: {str(exc).splitlines()[0]}") from None
    block_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, BLOCK_BODY)
    block_geoms = np.flatnonzero(model.geom_bodyid == block_id) if block_id >= 0 else np.zeros(0, int)
    joint_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"joint{i}") for i in range(1, 8)]
    ids = SceneIds(
        ft_site=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FT_SITE),
        tip_site=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, TIP_SITE),
        peg_geom=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, PEG_GEOM),
        block_geoms=block_geoms,
        force_adr=int(model.sensor_adr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, FORCE_SENSOR)]),
        torque_adr=int(model.sensor_adr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, TORQUE_SENSOR)]),
        qpos_adr=np.array([int(model.jnt_qposadr[j]) for j in joint_ids]),
        dof_adr=np.array([int(model.jnt_dofadr[j]) for j in joint_ids]),
        contact_adr=_sensor_adr(model, TRUTH_CONTACT_SENSOR),
    )
    return model, ids
