"""The simulated wrist sensor against an independent Newton-Euler computation (issues 37, 49).

    python benchmarks/sim_sensor_acceleration.py [--steps 3000]

Issue 37 found that MuJoCo's force/torque sensors are evaluated in ``mj_forward`` with its
``qacc``, while ``implicitfast`` integrates the stiff joint servos (kv 450 N m s/rad,
``models/panda.xml``) so that the velocity the encoders see changes by less than ``qacc dt``.
``kinadapt_nn.sim.ft_sensor`` now gives the reading for the acceleration the step realised. This
prints, per joint, the slope of MuJoCo's ``qacc`` against the realised acceleration (why the old
reading was wrong), and then checks the package's reading against a Newton-Euler computation that
shares nothing with it:

* a logged trajectory of the package's own simulator (``PegInHoleSim``: encoders, the reading it
  hands out, and on the truth side the contact forces of each step) -- fast reorientation of the
  wrist in free space, then the peg pressed and slid on the block's top face;
* the rigid tool of the config (mass, centre of mass, a box's inertia), the accelerations as finite
  differences of the logged velocities, the flange's motion from MuJoCo's *bare* arm
  (``models/panda.xml``, no tool: kinematics only), the contact forces from the log.

It prints the inertial part's factor (the slope of the logged wrench minus the static and contact
parts against the one the motion implies: 1 when the sensor reads what a real one would; the old
reading gave -5.9, -5.8 and 1.1 for fx, fy, fz) and the largest difference, per phase.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import NamedTuple

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "models" / "panda.xml"


class SensorLog(NamedTuple):
    """A logged trajectory: row k holds the encoders after step k and the reading handed out with
    them (the state step k started from, with the acceleration it realised)."""

    q: np.ndarray  #: (T, 7) encoder positions [rad]
    qdot: np.ndarray  #: (T, 7) encoder velocities [rad/s]
    wrench: np.ndarray  #: (T, 6) F/T reading [N, N m], flange on tool, about O, frame f
    mujoco_own: np.ndarray  #: (T, 6) MuJoCo's own sensor values of the same step (its ``qacc``)
    contact_f_w: np.ndarray  #: (T, 3) total contact force on the tool, world [N] (the step the reading belongs to)
    contact_m_w: np.ndarray  #: (T, 3) its moment about the world origin [N m]
    in_contact: np.ndarray  #: (T,) bool
    dt_s: float


def record(steps: int = 3000, seed: int = 0) -> tuple[SensorLog, object]:
    """Drive the package's simulator (``online/excite.toml``'s tool, the bore scene): 40 % of the
    steps fast wrist sines in free space, then down onto the block's top face 25 mm beside the bore
    and a slide along it. -> (the log, the config)."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.sim.adapter import PegInHoleSim

    cfg = load_config(None, ["start.lateral_w_m=[0.03,0.0]", "start.tip_height_m=0.02", f"run.seed={seed}"])
    sim = PegInHoleSim(cfg)
    m, d, ids = sim.model, sim.data, sim.ids
    dt = m.opt.timestep
    q_ref = sim.q_start.copy()
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    peg, block = int(ids.peg_geom), set(int(g) for g in ids.block_geoms)
    rows = {k: [] for k in SensorLog._fields if k != "dt_s"}
    f6 = np.zeros(6)
    n_free = int(0.4 * steps)
    fn, touched = 0.0, -1
    for k in range(steps):
        t = k * dt
        qdot_ref = np.zeros(7)
        if k < n_free:  # fast reorientation: wrist sines (rad, rad/s)
            w = np.array([0.0, 0.0, 0.0, 2.0, 3.0, 4.0, 5.0]) * 2 * np.pi
            amp = np.array([0.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.4])
            q_ref = sim.q_start + amp * np.sin(w * t)  # no velocity feed-forward: the servos' damping works
        else:  # resolved rate at the tip: down at 20 mm/s until it touches, then held at ~10 N and slid along +y
            mujoco.mj_jacSite(m, d, jacp, jacr, ids.tip_site)
            J = np.vstack([jacp[:, ids.dof_adr], jacr[:, ids.dof_adr]])
            touched = k if touched < 0 and fn > 0.0 else touched
            vz = -0.02 if touched < 0 else -2e-4 * (10.0 - fn)
            v = np.array([0.0, 0.015 if touched >= 0 and k > touched + 300 else 0.0, vz, 0.0, 0.0, 0.0])
            qdot_ref = np.linalg.lstsq(J, v, rcond=None)[0]
            q_ref = q_ref + dt * qdot_ref
        sim.apply(q_ref, qdot_ref)
        sim.step()
        o = sim.sense()
        fw, mw, touch = np.zeros(3), np.zeros(3), False
        for i in range(d.ncon):  # this step's contacts (the state it started from)
            c = d.contact[i]
            g1, g2 = int(c.geom[0]), int(c.geom[1])
            if peg not in (g1, g2) or not ({g1, g2} & block):
                continue
            mujoco.mj_contactForce(m, d, i, f6)
            f = c.frame.reshape(3, 3).T @ f6[:3]  # on geom2 from geom1, world
            f_on_peg = f if g2 == peg else -f
            fw += f_on_peg
            mw += np.cross(c.pos, f_on_peg)
            touch = True
        fn = float(-fw[2])
        own = np.r_[d.sensordata[ids.force_adr:ids.force_adr + 3], d.sensordata[ids.torque_adr:ids.torque_adr + 3]]
        for key, val in zip(rows, (o.q_rad, o.qdot_rad_s, o.wrench_raw_f, own, fw, mw, touch)):
            rows[key].append(np.copy(val))
    log = SensorLog(*(np.array(v) for v in rows.values()), dt_s=dt)
    return log, cfg


class Expected(NamedTuple):
    """The Newton-Euler wrench of the rigid tool for a log's rows 1..T-1, frame f, about O."""

    wrench: np.ndarray  #: (T-1, 6) [N, N m] the whole reading
    inertial: np.ndarray  #: (T-1, 6) its part from the tool's acceleration (without gravity, contact)
    rest: np.ndarray  #: (T-1, 6) gravity and contact


def excite_log(duration_s: float = 7.9) -> tuple[SensorLog, object]:
    """The package's own excitation run (``online/excite.toml``, its free-space reorientations:
    the first 7.9 s), logged as ``kinadapt online`` writes its trace. -> (the log, the config);
    no contact in these rows (the socket engages below the entrance plane, 30 mm further down)."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.episode import run_episode

    cfg = load_config(ROOT / "online" / "excite.toml", [f"run.duration_s={duration_s}", "run.tensorboard=false",
                                                        "run.figure=false", "run.progress=false"])
    tr = run_episode(cfg).trace.arrays
    T = len(tr["t_s"])
    assert not np.any(tr["truth_contact_force_N"]), "the excitation's free space touched something"
    zeros = np.zeros((T, 3))
    log = SensorLog(tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], np.full((T, 6), np.nan), zeros, zeros,
                    np.zeros(T, bool), float(tr["t_s"][1] - tr["t_s"][0]))
    return log, cfg


def newton_euler(log: SensorLog, tool) -> Expected:
    """The reading a real sensor gives for the logged motion: the tool (``ToolCfg``: mass, a box
    of side x side x length ending at the tip, tilted in the grasp) moved by the flange of the bare
    arm. Row k's reading belongs to the state of row k and the acceleration (qdot_{k+1} - qdot_k)/dt
    (the simulator's timing: one instant's encoders and reading); the flange's acceleration is MuJoCo's kinematics of the bare arm
    (gravity off) at that state, the rest is written here."""
    m = mujoco.MjModel.from_xml_path(str(MODEL))
    m.opt.gravity[:] = 0.0
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "flange")
    g_w = np.array([0.0, 0.0, -9.81])
    # the tool in f: its axis tilted by tilt_deg (about x, then y), the centre half a length back from the tip
    ax, ay = np.deg2rad(tool.tilt_deg)
    Rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    Ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    R_f_t = Rx @ Ry
    c_f = np.asarray(tool.offset_f_m) - 0.5 * tool.length_m * R_f_t[:, 2]
    a, b, h = tool.side_m, tool.side_m, tool.length_m
    I_t = tool.mass_kg / 12.0 * np.diag([b * b + h * h, a * a + h * h, a * a + b * b])
    I_f = R_f_t @ I_t @ R_f_t.T  # about the centre of mass, axes of f
    mass = tool.mass_kg
    T = len(log.q)
    out = np.zeros((3, T - 1, 6))
    acc6, vel6 = np.zeros(6), np.zeros(6)
    for k in range(T - 1):
        d.qpos[:7], d.qvel[:7] = log.q[k], log.qdot[k]
        d.qacc[:7] = (log.qdot[k + 1] - log.qdot[k]) / log.dt_s
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        mujoco.mj_rnePostConstraint(m, d)  # the bodies' accelerations for this qacc (gravity off)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, site, vel6, 0)
        mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_SITE, site, acc6, 0)
        R = d.site_xmat[site].reshape(3, 3)  # f in world
        O = d.site_xpos[site]
        w, alpha, a_O = vel6[:3], acc6[:3], acc6[3:]
        r = R @ c_f
        a_c = a_O + np.cross(alpha, r) + np.cross(w, np.cross(w, r))
        I_w = R @ I_f @ R.T
        f_in = mass * a_c
        t_in = I_w @ alpha + np.cross(w, I_w @ w) + np.cross(r, f_in)
        f_g, t_g = -mass * g_w, np.cross(r, -mass * g_w)
        f_c = -log.contact_f_w[k]
        t_c = -(log.contact_m_w[k] - np.cross(O, log.contact_f_w[k]))  # the contacts' moment about O
        out[0, k] = np.r_[R.T @ (f_in + f_g + f_c), R.T @ (t_in + t_g + t_c)]
        out[1, k] = np.r_[R.T @ f_in, R.T @ t_in]
        out[2, k] = np.r_[R.T @ (f_g + f_c), R.T @ (t_g + t_c)]
    return Expected(*out)


def qacc_factors(steps: int = 1500) -> np.ndarray:
    """MuJoCo's ``qacc`` (what its own F/T sensor uses) over the realised acceleration, the bare
    arm's joints 6 and 7 driven with sines through the servos. -> (2,) slopes."""
    m = mujoco.MjModel.from_xml_path(str(MODEL))
    d = mujoco.MjData(m)
    q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
    d.qpos[:7] = q0
    d.ctrl[:] = q0
    mujoco.mj_forward(m, d)
    qacc, dv = [], []
    for k in range(steps):
        t = k * m.opt.timestep
        ref = q0.copy()
        ref[5] += 0.2 * np.sin(2 * np.pi * 0.7 * t)
        ref[6] += 0.3 * np.sin(2 * np.pi * 1.0 * t)
        d.ctrl[:] = ref
        v0 = d.qvel.copy()
        mujoco.mj_step(m, d)
        if k >= 300:
            qacc.append(d.qacc[:7].copy())
            dv.append((d.qvel[:7] - v0) / m.opt.timestep)
    qacc, dv = np.array(qacc), np.array(dv)
    return np.array([np.polyfit(dv[:, j], qacc[:, j], 1)[0] for j in (5, 6)])


def factors(reading: np.ndarray, exp: Expected, rows: np.ndarray) -> np.ndarray:
    """(6,) the slope of a logged reading's (T, 6) inertial part (reading minus gravity and contact)
    against the one the motion implies, per channel, over ``rows`` of ``exp`` (bool (T-1,))."""
    meas = reading[:-1][rows] - exp.rest[rows]
    ref = exp.inertial[rows]
    return np.array([float(ref[:, j] @ meas[:, j] / (ref[:, j] @ ref[:, j])) for j in range(6)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=3000)
    a = ap.parse_args()
    f67 = qacc_factors()
    print(f"MuJoCo's qacc over the realised acceleration (what its own F/T sensor used): joint 6 {f67[0]:.2f}x, "
          f"joint 7 {f67[1]:.2f}x")
    ex_log, ex_cfg = excite_log()
    log, cfg = record(a.steps)
    exp = newton_euler(log, cfg.tool)
    contact = log.in_contact[:-1]
    n_free = int(0.4 * a.steps)
    T = len(ex_log.q)
    phases = {"the package's excite run, free space (online/excite.toml, 7.9 s)": (ex_log, newton_euler(ex_log, ex_cfg.tool),
                                                                                 np.arange(T - 1) >= 500),
              "driven: free space, fast wrist sines": (log, exp, (np.arange(len(contact)) < n_free) & ~contact),
              "driven: in contact (pressed on the block's face, slid)": (log, exp, contact)}
    chans = ("fx", "fy", "fz", "tx", "ty", "tz")
    for name, (log, exp, rows) in phases.items():
        fac = factors(log.wrench, exp, rows)
        old = factors(log.mujoco_own, exp, rows)
        diff = np.abs(log.wrench[:-1][rows] - exp.wrench[rows])
        peak = np.abs(exp.inertial[rows]).max(axis=0)
        print(f"{name}: {int(rows.sum())} rows; the inertial part's factor (logged / Newton-Euler): "
              + ", ".join(f"{c} {v:.4f}" for c, v in zip(chans, fac)))
        print(f"  largest |logged - Newton-Euler|: force {diff[:, :3].max():.2e} N, torque {diff[:, 3:].max():.2e} N m "
              f"(largest inertial part: force {peak[:3].max():.3f} N, torque {peak[3:].max():.4f} N m; "
              f"largest contact force {np.linalg.norm(log.contact_f_w[:-1][rows], axis=1).max():.2f} N)")
        if np.isfinite(old).all():
            print("  MuJoCo's own sensor values (the old reading): " + ", ".join(f"{c} {v:.2f}" for c, v in zip(chans, old)))


if __name__ == "__main__":
    main()
