"""The grasp compliance on the excitation run, from both sides (issue 49: the excite table's
``grasp_compliance`` rows came out ~4-6 % low).

    python benchmarks/grasp_compliance_check.py [--stiffness 100] [--armature A] [--no-diagnose] [--set KEY=VALUE]

One ``online/excite.toml`` run with the hidden effect ``grasp_compliance`` (stiffness k), then:

1. **What the simulator realises.** The hinges' turn (MuJoCo's ``grasp_x``, ``grasp_y``, truth) and the
   reading's moment about the sensor origin (the one handed out with the same instant's encoders,
   ``sim.ft_sensor``) over the socket's engagement: the least-squares slope turn / moment, as a multiple
   of the declared 1/k; the shares of the moment that the hinge's damper (``c turn'``, the lag a
   quasi-static model leaves out) and its armature (``a turn''``: MuJoCo's armature has no body, so the
   reading carries its torque as if the hinge bore it) take; and how closely the reading's moment is
   ``k turn + c turn' + a turn''`` (the hinge's own equation, the tool's inertia aside).
2. **The loads that turn with the tool.** The contact's axial force (the preload) over the engagement,
   and ``|tip| F_axial / k_rot``: the share of the socket's angular spring that the preload at the turned
   tip takes back (``effects.builtin.grasp_compliance``).
3. **What the diagnosis estimates** (unless ``--no-diagnose``): ``kinadapt diagnose``'s estimate, as the
   excite table runs it (the nominal tip a first guess) and with the true tip declared known.

``--armature A``: the grasp hinges' armature [kg m^2] for this run (``sim.scene.GRASP_ARMATURE_KG_M2``);
``--before``: the hinges as they were before (the Panda's joint class's 0.1 kg m^2, the damper for the
tool's own inertia; the diagnosis's column is today's). Times on the shared 2-core VM:
about 30 s with the two diagnoses (one run: 28 s measured).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
EXCITE = REPO / "online" / "excite.toml"
QUIET = ["run.tensorboard=false", "run.figure=false", "run.progress=false"]


class Recorder:
    """The hinges' state and the reading of every physics step (one episode): wraps the sensor's
    ``after_step`` (which fills the reading of the state the step started from) and keeps that
    state's hinge angles and rates beside it, and the fixture's wrench on the tool that step."""

    def __init__(self, before: bool = False) -> None:
        from kinadapt_nn.sim import adapter, ft_sensor

        self.rows: list[np.ndarray] = []
        self.sim = None
        rec = self
        self._orig_after, self._orig_init = ft_sensor.RealisedSensor.after_step, adapter.PegInHoleSim.__init__

        def after_step(sensor, rows):
            rec._orig_after(sensor, rows)
            s = rec.sim
            if s is not None and sensor is s.ft:
                rec.rows.append(np.concatenate([sensor.qpos0[0, rec.qa], sensor.qvel0[0, rec.va], sensor.wrench[0],
                                                s.data.xfrc_applied[rec.tb]]))

        def init(sim, cfg):
            rec._orig_init(sim, cfg)
            m = sim.model
            rec.sim = sim
            rec.qa = [int(m.joint(n).qposadr[0]) for n in ("grasp_x", "grasp_y")]
            rec.va = [int(m.joint(n).dofadr[0]) for n in ("grasp_x", "grasp_y")]
            rec.tb = int(m.body("tool").id)
            if before:  # the hinges as they were: the arm's joint class's armature, damped for the tool alone
                t = cfg.tool
                m.dof_armature[rec.va] = 0.1
                m.dof_damping[rec.va] = 2.0 * 0.7 * np.sqrt(m.jnt_stiffness[m.dof_jntid[rec.va]] * (t.mass_kg * t.length_m ** 2 / 3.0 + 1e-5))
            rec.stiffness = np.array([float(m.jnt_stiffness[m.joint(n).id]) for n in ("grasp_x", "grasp_y")])
            rec.damping = np.array([float(m.dof_damping[j]) for j in rec.va])
            rec.armature = np.array([float(m.dof_armature[j]) for j in rec.va])

        ft_sensor.RealisedSensor.after_step = after_step
        adapter.PegInHoleSim.__init__ = init

    def restore(self) -> None:
        from kinadapt_nn.sim import adapter, ft_sensor

        ft_sensor.RealisedSensor.after_step = self._orig_after
        adapter.PegInHoleSim.__init__ = self._orig_init


def slope(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of y on x with an intercept."""
    xc, yc = x - x.mean(), y - y.mean()
    return float(xc @ yc / (xc @ xc))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stiffness", type=float, default=100.0, help="the hinges' stiffness k [N m/rad]")
    ap.add_argument("--armature", type=float, default=None, help="the hinges' armature [kg m^2] (default: the scene's)")
    ap.add_argument("--before", action="store_true",
                    help="the hinges as they were before issue 49's fix: armature 0.1 kg m^2 (the Panda's joint class), "
                         "damper 2 0.7 sqrt(k I_tool)")
    ap.add_argument("--no-diagnose", action="store_true", help="only the simulator's side")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a config override")
    a = ap.parse_args()

    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.episode import run_episode
    from kinadapt_nn.sim import scene

    if a.armature is not None:
        scene.GRASP_ARMATURE_KG_M2 = a.armature
    cfg = load_config(EXCITE, [*QUIET, "effects.grasp_compliance.enabled=true",
                               f"effects.grasp_compliance.stiffness_Nm_per_rad={a.stiffness}", *a.set])
    rec = Recorder(a.before)
    try:
        tr = run_episode(cfg).trace
    finally:
        rec.restore()
    R = np.array(rec.rows)
    turn, rate, w, xfrc = R[:, 0:2], R[:, 2:4], R[:, 4:10], R[:, 10:16]
    dt = cfg.run.dt_s
    acc = np.gradient(rate, dt, axis=0)
    on = np.linalg.norm(xfrc, axis=1) > 0.0  # the socket engaged (its wrench on the tool)
    k, c, arm = rec.stiffness, rec.damping, rec.armature
    M = -w[:, 3:5]  # the moment on the tool about O beyond the flange, s (the reading is the flange's on the tool)
    print(f"grasp hinges: k {k[0]:g} N m/rad (declared compliance {1 / k[0]:.4g} rad/(N m)), damper {c[0]:.4g} "
          f"N m s/rad, armature {arm[0]:.3g} kg m^2; {on.sum() * dt:.1f} s of {len(on) * dt:.1f} s engaged")
    from kinadapt_nn.sim.socket import socket_damping

    t = cfg.tool
    I_tool = t.mass_kg * t.length_m ** 2 / 3.0 + 1e-5  # the scene's inertia of the tool about a hinge
    c_lat, _, c_rot = socket_damping(cfg.scene)
    c_sock = c_lat * float(np.sum(np.square(t.offset_f_m))) + c_rot
    print(f"   free hinge: {np.sqrt(k[0] / (I_tool + arm[0])) / (2 * np.pi):.3g} Hz, damping ratio "
          f"{c[0] / (2 * np.sqrt(k[0] * (I_tool + arm[0]))):.2f} (tool {I_tool:.3g} kg m^2 + armature); the socket's damper on "
          f"the turn {c_sock:.3f} N m s/rad, explicit: dt c / I = {dt * c_sock / I_tool:.2f} with the tool alone, "
          f"{dt * c_sock / (I_tool + arm[0]):.2f} with the armature (stable below 2)")
    print("1. the simulator over the engagement: the turn on the reading's moment, as a multiple of 1/k (1: the "
          "declared compliance); the damper's and the armature's shares of the moment (c turn', a turn'' on it)")
    for i, ax in enumerate("xy"):
        m_ = M[on, i]
        print(f"   about s {ax}: realised {slope(m_, turn[on, i]) * k[i]:.4f} x 1/k;  damper {slope(m_, c[i] * rate[on, i]):+.5f}, "
              f"armature {slope(m_, arm[i] * acc[on, i]):+.5f};  moment rms {m_.std():.3f} N m, armature torque rms "
              f"{(arm[i] * acc[on, i]).std():.1e} N m, rms(moment - k turn - c turn' - a turn'') / rms(moment) "
              f"{np.std(m_ - k[i] * turn[on, i] - c[i] * rate[on, i] - arm[i] * acc[on, i]) / m_.std():.1e}")
    f_ax = w[on, 2]  # the flange's axial force on the tool, s z: the preload the fixture pushes back with
    tip = np.asarray(cfg.tool.offset_f_m, dtype=float)
    mm = (M[on] ** 2).sum(axis=1)
    f_w = float((f_ax * mm).sum() / mm.sum())
    print(f"2. the loads that turn with the tool: axial force over the engagement {f_ax.mean():.2f} N (mean), "
          f"{f_w:.2f} N (weighted by the moment^2);  |tip| F / k_rot = {np.linalg.norm(tip) * f_w / cfg.scene.socket_k_rot_Nm_per_rad:.4f}")
    if a.no_diagnose:
        return
    from kinadapt_nn.diagnostics import ownrun, userlog
    from kinadapt_nn.diagnostics.importers import RawLog
    from kinadapt_nn.sim.effects import truth_config

    raw = RawLog(*(np.asarray(tr[key]) for key in ("t_s", "q_rad", "qdot_rad_s", "wrench_raw_f")), "grasp")
    seen = cfg.model_copy(update={"effects": type(cfg.effects)()})
    true_tip = np.asarray(truth_config(cfg).tool.offset_f_m, dtype=float)
    print("3. the diagnosis's estimate (injected compliance %.4g rad/(N m)):" % (1 / k[0]))
    for label, tip_kw in (("nominal tip a first guess (the excite table)", {}),
                          ("the true tip declared known", {"tip_sensor_m": true_tip})):
        log, setup = ownrun.as_log(raw, seen, **tip_kw)
        rep = userlog.diagnose(log, setup, hints=False).report
        e = next((x for x in rep["ranking"] if x["effect"] == "grasp_compliance"), None)
        present = [x["effect"] for x in rep["ranking"] if x["verdict"] == "present"]
        if e is None or "estimate_params" not in e:
            print(f"   {label}: no estimate; present: {present}")
            continue
        v, sd = e["estimate_params"]["value"][0], e["estimate_params"]["sd"][0]
        print(f"   {label}: {v:.4g} +- {sd:.2g} ({(v * k[0] - 1) * 100:+.1f} %, {(v - 1 / k[0]) / sd:+.1f} sd); "
              f"present: {', '.join(present) or '-'}")


if __name__ == "__main__":
    main()
