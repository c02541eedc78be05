"""The user's arm as a MuJoCo model for kinematics: from an MJCF, a URDF or a DH table (``[arm]``).

``load_arm(setup.arm) -> Arm``: the compiled model, the flange site and the joints between the
world and that site (``dof`` of them, base to flange; the log's ``[log] q`` columns in that order).
Only the kinematic tree is used: masses and inertias are placeholders, meshes are never read.

* ``mjcf``: the file as it is (``flange_site`` names the flange).
* ``urdf``: links and joints only (``<visual>``, ``<collision>``, ``<inertial>``, ``<limit>``, ``<mimic>``
  and everything outside ``<link>``/``<joint>`` dropped, so meshes need not exist), every link a body
  (static links are not fused), a site ``flange`` on ``flange_link`` at ``flange_xyz_m``/``flange_rpy_deg``.
* ``dh``: generated MJCF (``dh_mjcf``), one body per joint with a hinge about its local z.

Frames and rpy as in ``kinadapt_nn.diagnostics.setup``: ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import NamedTuple

import mujoco
import numpy as np

from kinadapt_nn.diagnostics.setup import ArmDeclCfg, DHCfg, rpy_matrix
from kinadapt_nn.errors import KinadaptError, ModelFileError

FLANGE_SITE = "flange"  #: the site added to a URDF or DH arm
#: placeholder inertial of every generated body [kg], [kg m^2] (kinematics only)
_MASS, _INERTIA = 0.1, 1e-3
URDF_MOVING = ("revolute", "continuous", "prismatic")
URDF_TYPES = (*URDF_MOVING, "fixed")


class Arm(NamedTuple):
    """A compiled arm and the joints that move its flange."""

    model: mujoco.MjModel
    site: int  #: id of the flange site
    dof: int  #: joints between the world and the flange (n)
    qpos_adr: np.ndarray  #: (n,) qpos address of each, base to flange
    dof_adr: np.ndarray  #: (n,) velocity (Jacobian column) address of each
    source: str  #: what it was built from, for messages ("URDF 'ur5e.urdf'")
    joint_ids: np.ndarray  #: (n,) MuJoCo joint id of each


def load_arm(arm: ArmDeclCfg) -> Arm:
    """The arm of ``[arm]``; every failure is a one-line ``ModelFileError``/``KinadaptError``."""
    model, site, source = {"mjcf": _from_mjcf, "urdf": _from_urdf, "dh": _from_dh}[arm.kind](arm)
    return _chain(model, site, source)


# --------------------------------------------------------------------------------------------- MJCF
def _from_mjcf(arm: ArmDeclCfg) -> tuple[mujoco.MjModel, int, str]:
    path = arm.path()
    source = f"arm model '{path}'"
    if not path.is_file():
        raise ModelFileError(f"{source} not found (fix [arm] mjcf in the setup file; \"\" = the shipped Panda)")
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # mujoco raises ValueError with a multi-line message
        raise ModelFileError(f"{source} could not be loaded: {_first_line(exc)} (fix the file or [arm] mjcf)") from None
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, arm.flange_site)
    if site < 0:
        names = [model.site(i).name for i in range(model.nsite)]
        raise KinadaptError(f"{source} has no site '{arm.flange_site}' (fix [arm] flange_site; "
                            f"sites: {', '.join(names) or 'none'})")
    return model, site, source


# --------------------------------------------------------------------------------------------- URDF
class _Tree(NamedTuple):
    links: list[str]
    joints: list[ET.Element]  #: the cleaned joints
    children: dict[str, list[tuple[str, str]]]  #: link -> [(joint type, child link)]
    root: str


def _from_urdf(arm: ArmDeclCfg) -> tuple[mujoco.MjModel, int, str]:
    path = Path(arm.urdf)
    source = f"URDF '{path}'"
    if not path.is_file():
        raise ModelFileError(f"{source} not found (fix [arm] urdf in the setup file)")
    text = path.read_text(errors="replace")
    if "${" in text or "$(" in text:
        raise ModelFileError(f"{source} holds xacro expressions (${{...}}); expand it first "
                             "(xacro FILE.urdf.xacro > FILE.urdf) and give the result as [arm] urdf")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ModelFileError(f"{source} is not valid XML ({exc}); fix the file") from None
    if root.tag != "robot":
        raise ModelFileError(f"{source}: the root element is <{root.tag}>, not <robot> (is it a URDF?)")
    tree = _urdf_tree(root, source)
    flange = arm.flange_link or _last_link(tree, source)
    if flange not in tree.links:
        raise KinadaptError(f"{source} has no link '{flange}' (fix [arm] flange_link; links: {_few(tree.links)})")
    robot = ET.Element("robot", name=root.get("name", "arm"))
    for name in tree.links:
        link = ET.SubElement(robot, "link", name=name)
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "mass", value=repr(_MASS))
        ET.SubElement(inertial, "inertia", ixx=repr(_INERTIA), iyy=repr(_INERTIA), izz=repr(_INERTIA),
                      ixy="0", ixz="0", iyz="0")
    robot.extend(tree.joints)
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(robot, encoding="unicode"))
        spec.compiler.fusestatic = False  # a fixed-joint link (the flange) stays a body
        spec.body(flange).add_site(name=FLANGE_SITE, pos=list(arm.flange_xyz_m), quat=list(_quat(arm.flange_rpy_deg)))
        model = spec.compile()
    except Exception as exc:
        raise ModelFileError(f"{source} could not be loaded: {_first_line(exc)} (fix the file)") from None
    return model, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE), source


def _urdf_tree(root: ET.Element, source: str) -> _Tree:
    """The links and joints of a URDF, checked (one-line errors), the joints stripped to their
    kinematics (origin, parent, child, axis)."""
    links = [ln.get("name", "") for ln in root.findall("link")]
    if not links or not all(links):
        raise ModelFileError(f"{source}: every <link> needs a name and there must be at least one (fix the file)")
    dup = sorted({n for n in links if links.count(n) > 1})
    if dup:
        raise ModelFileError(f"{source}: link '{dup[0]}' is defined twice (fix the file)")
    known, joints, children, child_of = set(links), [], {n: [] for n in links}, {}
    for j in root.findall("joint"):
        name, kind = j.get("name", "?"), j.get("type", "")
        if kind in ("floating", "planar"):
            raise KinadaptError(f"{source}: joint '{name}' is {kind}; the arm's base must be fixed to the world "
                                "(remove it or make it fixed)")
        if kind not in URDF_TYPES:
            raise ModelFileError(f"{source}: joint '{name}' has type '{kind}' (choose from {', '.join(URDF_TYPES)})")
        ends = [(j.find(e).get("link", "") if j.find(e) is not None else "") for e in ("parent", "child")]
        for end, link in zip(("parent", "child"), ends):
            if link not in known:
                raise ModelFileError(f"{source}: joint '{name}' names {end} link '{link}', which is not defined "
                                     "(fix the file)")
        parent, child = ends
        if child in child_of:
            raise ModelFileError(f"{source}: link '{child}' is the child of joints '{child_of[child]}' and '{name}' "
                                 "(a URDF is a tree; fix the file)")
        child_of[child] = name
        children[parent].append((kind, child))
        clean = ET.Element("joint", name=name, type=kind)
        clean.extend(e for e in j if e.tag in ("origin", "parent", "child", "axis"))
        joints.append(clean)
    if not any(t in URDF_MOVING for t in (j.get("type") for j in joints)):
        raise KinadaptError(f"{source} has no revolute, continuous or prismatic joint (an arm needs joints)")
    roots = [n for n in links if n not in child_of]
    if len(roots) != 1:
        raise ModelFileError(f"{source}: the links form {len(roots)} separate trees (roots {_few(roots)}); "
                             "connect them with joints")
    return _Tree(links, joints, children, roots[0])


def _last_link(tree: _Tree, source: str) -> str:
    """The link moved by the last joint of the chain: from the root along the only branch that
    holds moving joints (fixed side branches such as a camera mount are ignored)."""
    def moves(kind: str, link: str) -> bool:
        return kind in URDF_MOVING or any(moves(k, c) for k, c in tree.children[link])

    link, last = tree.root, tree.root
    while True:
        ahead = [(k, c) for k, c in tree.children[link] if moves(k, c)]
        if not ahead:
            return last
        if len(ahead) > 1:
            raise KinadaptError(f"{source} branches at link '{link}' into {_few([c for _, c in ahead])}: name the "
                                "flange's link with [arm] flange_link")
        kind, link = ahead[0]
        if kind in URDF_MOVING:
            last = link


# ----------------------------------------------------------------------------------------------- DH
def dh_mjcf(dh: DHCfg) -> str:
    """MJCF text of a DH arm (``DHCfg``'s docstring): bodies ``link1..linkN``, each with its hinge
    ``joint1..jointN`` about its own z at its origin, in a body ``base``; the site ``flange``.

    Body i's frame is the frame the joint turns about: classic, joint frame i-1 (body i+1 sits at
    ``Rz(off_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` in body i); modified, frame i with ``theta_i = off_i``
    (body i sits at ``Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(off_i) Tz(d_i)`` in body i-1). ``Rz(q)`` and
    ``Tz(d)`` commute, so the hinge's rotation may stand at either place."""
    n, off = dh.n_joints, dh.offsets()
    if dh.convention == "classic":
        link = [_rz(off[i]) @ _trans(0, 0, dh.d_m[i]) @ _trans(dh.a_m[i], 0, 0) @ _rx(dh.alpha_rad[i]) for i in range(n)]
        place = [np.eye(4)] + link[:-1]  # body i in body i-1
        flange_in_last = link[-1]
    else:
        place = [_rx(dh.alpha_rad[i]) @ _trans(dh.a_m[i], 0, 0) @ _rz(off[i]) @ _trans(0, 0, dh.d_m[i]) for i in range(n)]
        flange_in_last = np.eye(4)
    flange_in_last = flange_in_last @ _pose(dh.flange_xyz_m, dh.flange_rpy_deg)
    inertial = f'<inertial pos="0 0 0" mass="{_MASS!r}" diaginertia="{_INERTIA!r} {_INERTIA!r} {_INERTIA!r}"/>'
    lines = ['<mujoco model="dh_arm">', '  <compiler angle="radian" autolimits="true"/>', "  <worldbody>",
             f'    <body name="base" {_attrs(_pose(dh.base_xyz_m, dh.base_rpy_deg))}>', f"      {inertial}"]
    for i in range(n):
        pad = "  " * (i + 4)
        lines += [f'{pad}<body name="link{i + 1}" {_attrs(place[i])}>', f"{pad}  {inertial}",
                  f'{pad}  <joint name="joint{i + 1}" type="hinge" axis="0 0 1"/>']
    lines.append(f'{"  " * (n + 4)}<site name="{FLANGE_SITE}" size="0.005" {_attrs(flange_in_last)}/>')
    lines += [f'{"  " * (i + 4)}</body>' for i in reversed(range(n))]
    lines += ["    </body>", "  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)


def _from_dh(arm: ArmDeclCfg) -> tuple[mujoco.MjModel, int, str]:
    source = f"the DH arm ([arm] dh, {arm.dh.convention})"
    try:
        model = mujoco.MjModel.from_xml_string(dh_mjcf(arm.dh))
    except Exception as exc:  # not expected for validated numbers
        raise ModelFileError(f"{source} could not be built: {_first_line(exc)} (check [arm] dh)") from None
    return model, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE), source


def _rx(a: float) -> np.ndarray:
    T = np.eye(4)
    T[1:3, 1:3] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return T


def _rz(a: float) -> np.ndarray:
    T = np.eye(4)
    T[0:2, 0:2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return T


def _trans(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _pose(xyz_m, rpy_deg) -> np.ndarray:
    T = _trans(*xyz_m)
    T[:3, :3] = rpy_matrix(np.deg2rad(np.asarray(rpy_deg, dtype=float)))
    return T


def _quat(rpy_deg) -> np.ndarray:
    """(w, x, y, z) of ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, rpy_matrix(np.deg2rad(np.asarray(rpy_deg, dtype=float))).ravel())
    return q


def _attrs(T: np.ndarray) -> str:
    """``pos``/``quat`` attributes of a (4, 4) transform, full precision."""
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(T[:3, :3]).ravel())
    return f'pos="{" ".join(repr(float(x)) for x in T[:3, 3])}" quat="{" ".join(repr(float(x)) for x in q)}"'


# ------------------------------------------------------------------------------------------- common
def _chain(model: mujoco.MjModel, site: int, source: str) -> Arm:
    """The hinge and slide joints from the world to the flange site's body, base first."""
    per_body = []
    body = int(model.site_bodyid[site])
    while body > 0:
        adr, num = int(model.body_jntadr[body]), int(model.body_jntnum[body])
        per_body.append(list(range(adr, adr + num)) if adr >= 0 else [])
        body = int(model.body_parentid[body])
    joints = [j for js in reversed(per_body) for j in js]
    moving = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    for j in joints:
        if int(model.jnt_type[j]) not in moving:
            what = "a free joint (a floating base)" if int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE) \
                else "a ball joint"
            raise KinadaptError(f"{source}: joint '{model.joint(j).name}' between the world and the flange is {what}; "
                                "an arm's base is fixed and its joints turn or slide about one axis")
    if not joints:
        raise KinadaptError(f"{source} has no joint between the world and the flange (fix the flange: "
                            "[arm] flange_site / flange_link)")
    idx = np.array(joints, dtype=int)
    return Arm(model, site, len(joints), model.jnt_qposadr[idx].astype(int), model.jnt_dofadr[idx].astype(int), source,
               idx)


def _first_line(exc: Exception) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return lines[0] if lines else type(exc).__name__


def _few(names: list[str], k: int = 8) -> str:
    return ", ".join(names[:k]) + (f" ... ({len(names)} in all)" if len(names) > k else "") if names else "none"


__all__ = ["Arm", "load_arm", "dh_mjcf", "FLANGE_SITE"]
