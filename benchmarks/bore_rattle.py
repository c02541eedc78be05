"""The bore rattle (issue 40): which element of the loop throws the sliding peg off the bore wall.

    python benchmarks/bore_rattle.py [--jobs 1] [--only table,static,creep,bound,seeds,gain,figure] [--png PATH] [--json PATH]

From the paper's setting (``kinadapt_nn.paper.PAPER_SETTING``: composite law, MuJoCo's friction
reference = the normal's), one parameter at a time, each row one insertion; per row, from the
first contact to the seat (or the end):

* ``trans/s``   contact on/off transitions per second of the truth's normal contact force, at the
                physics rate (``runs.evaluate.contact_quality``; the summary's field at 1 kHz)
* ``f [Hz]``    dominant frequency of that force (Hann-windowed FFT, above 5 Hz; "-" when no chatter)
* ``A [N]``     the chatter's amplitude: rms above 20 Hz of the sensed ``F_lat_x`` (closed loop) or
                of the contact force (open-loop replay)
* ``frac``, ``span``  fraction of the time in contact, longest continuous contact [s]; ``seat`` [s]

Probes the config cannot express are done here, in the benchmark only: the joint servo's gains
scaled, several physics steps per control period, and an open-loop replay (the closed loop's servo
set-points, low-passed, drive a fresh simulator with no controller). ``static``: at one sliding
contact state, MuJoCo's constrained normal acceleration of the peg's contact point for several
friction coefficients and the two friction references. ``creep``: what the fix costs where a
contact should stick (a box at rest on an incline, and a wedged peg), with MuJoCo's impratio.
``seeds``: the default run from 6 jittered starts, both contacts. ``gain``: the paper's gain sweep
(``kinadapt reproduce --only gain_sweep``'s bore half: Gamma 100 and 8000, composite and
prediction-only) with the paper's contact and with the rattle-free default. ``bound``: the paper's
sampled-data virtual-mass bound (Remark cp_ceiling, eq. cp_mass) for our admittance
discretisation, with the contact stiffness MuJoCo actually has and with the joint servo's in series.
Outputs of a run: benchmarks/results/bore_rattle.{txt,json}, docs/figures/bore_rattle.png.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from kinadapt_nn.paper import PAPER_SETTING

PAPER = list(PAPER_SETTING)  # the composite law and the paper's contact (friction reference = the normal's)


@dataclass(frozen=True)
class Probe:
    """What a row changes outside the config (benchmark only)."""

    servo_scale: float = 1.0  # kp and kv of every joint servo x this
    substeps: int = 1  # physics steps per control period (the control period is run.dt_s)
    replay_hz: float = 0.0  # > 0: open loop, the closed loop's set-points low-passed at this cutoff [Hz]
    impratio: float = 1.0  # MuJoCo's impratio (elliptic cone: the friction rows' regularisation / this)


#: (group, label, overrides on top of the paper's setting, probe)
ROWS: list[tuple[str, str, list[str], Probe]] = [
    ("paper setting", "composite law, friction reference = normal's", [], Probe()),
    ("law / gate / rate filter", "adaptation.mode=frozen", ["adaptation.mode=frozen"], Probe()),
    ("law / gate / rate filter", "sensing.filter_tau_s=0.002", ["sensing.filter_tau_s=0.002"], Probe()),
    ("law / gate / rate filter", "sensing.filter_tau_s=0.05", ["sensing.filter_tau_s=0.05"], Probe()),
    ("value force on F_lat", "control.compliance_lat_m_per_N=0", ["control.compliance_lat_m_per_N=0"], Probe()),
    ("value force on F_lat", "control.compliance_lat_m_per_N=4e-5", ["control.compliance_lat_m_per_N=4e-5"], Probe()),
    *[("virtual inertia M = tau/g", f"control.tau_trans_s={v:g} (M {v / 2e-4:g} kg)", [f"control.tau_trans_s={v}"],
       Probe()) for v in (0.0005, 0.001, 0.004, 0.02)],
    ("admittance damping", "control.beta_trans=0.5", ["control.beta_trans=0.5"], Probe()),
    ("joint servo", "kp, kv x 0.5", [], Probe(servo_scale=0.5)),
    ("joint servo", "kp, kv x 2", [], Probe(servo_scale=2.0)),
    ("control period (physics 1 ms)", "control 2 ms", ["run.dt_s=0.002"], Probe(substeps=2)),
    ("physics step (control 1 ms)", "physics 0.5 ms", [], Probe(substeps=2)),
    ("physics step (control 1 ms)", "physics 0.25 ms", [], Probe(substeps=4)),
    ("both", "run.dt_s=0.0005", ["run.dt_s=0.0005"], Probe()),
    ("both", "run.dt_s=0.002", ["run.dt_s=0.002"], Probe()),
    *[("contact solref time constant", f"scene.contact_timeconst_s={v:g}", [f"scene.contact_timeconst_s={v}"], Probe())
      for v in (0.005, 0.05, 0.2)],
    *[("friction", f"scene.friction={v:g}", [f"scene.friction={v}"], Probe()) for v in (0.0, 0.1, 0.5)],
    *[("sliding speed (depth force cap)", f"control.depth_force_max_N={v:g}",
       [f"control.depth_force_max_N={v}", "run.duration_s=20"], Probe()) for v in (20, 40, 160)],
    *[("friction reference (the fix)", f"scene.contact_friction_timeconst_s={v:g} (b_f {2 / (0.99 * v):.3g}/s)",
       [f"scene.contact_friction_timeconst_s={v}"], Probe()) for v in (0.2, 1.0, 2.0, 5.0)],
    ("friction reference (the fix)", "... 2 s, impratio 100", ["scene.contact_friction_timeconst_s=2"],
     Probe(impratio=100.0)),
    ("no controller (open loop)", "set-points low-passed at 20 Hz", [], Probe(replay_hz=20.0)),
    ("no controller (open loop)", "... with friction reference 2 s", ["scene.contact_friction_timeconst_s=2"],
     Probe(replay_hz=20.0)),
]


def _probe_world(probe: Probe, record: dict | None = None, stop=None):
    """A scene class for the episode loop (``runs.loop.setup`` builds an episode's scenes with
    ``runs.loop.SceneBatch``; :func:`_plant` puts this one there): one episode (a batch of one, its
    own MjData), its plant changed as ``probe`` says (servo gains, physics steps per control period,
    impratio), recording into ``record`` per control period the servo set-point (``u``) and at the
    physics rate the truth's normal contact force (``t``, ``f``); ``stop(sim)``, if given, is asked
    before each control period's physics and raises :class:`_Reached` when true."""
    from types import SimpleNamespace

    from kinadapt_nn.sim.ft_sensor import SOURCE_FIELDS, RealisedSensor
    from kinadapt_nn.sim.scenes import SceneBatch

    class ProbeWorld(SceneBatch):
        def __init__(self, cfgs, nthread=1, persistent=None):
            super().__init__(cfgs, nthread, persistent)
            if self.physics is not None:
                raise RuntimeError("the plant probe steps one episode on one thread (its own MjData)")
            s = self.sims[0]
            m, d = s.model, s.data
            m.actuator_gainprm[:, 0] *= probe.servo_scale
            m.actuator_biasprm[:, 1:3] *= probe.servo_scale  # -kp, -kv: kv/kp unchanged
            m.opt.timestep = cfgs[0].run.dt_s / probe.substeps
            m.opt.impratio = probe.impratio
            # the F/T reading's realised acceleration over the physics step (not the control period)
            self.ft = s.ft = RealisedSensor(SimpleNamespace(**{f: getattr(d, f)[None] for f in SOURCE_FIELDS}),
                                            s.ft_chain, m.opt.timestep)
            self._contact = np.zeros((1, 3))

        def step(self, t, active, every_one):
            s = self.sims[0]
            if stop is not None and stop(s):
                raise _Reached
            if record is not None:
                record["u"].append(self.ctrl[0].copy())
            h = s.model.opt.timestep
            for i in range(probe.substeps):
                super().step(t + i * h, active, every_one)
                if record is not None:
                    self._contact[:] = 0.0
                    self.contacts_into(slice(None), self._contact)
                    record["t"].append(s.time_s)
                    record["f"].append(float(self._contact[0, 2]))

    return ProbeWorld


@contextmanager
def _plant(world):
    """The episode loop builds its scenes with ``world`` meanwhile (benchmark only; the loop's
    kernels compiled first, outside it, by the caller's :func:`_episode`)."""
    from kinadapt_nn.runs import loop

    before = loop.SceneBatch
    loop.SceneBatch = world
    try:
        yield
    finally:
        loop.SceneBatch = before


def _episode(cfg, probe: Probe, record: dict | None = None, stop=None):
    """``run_episode(cfg)`` on the probed plant (:func:`_probe_world`); a record that stays empty
    means the probe missed the loop's plant: an error, not a row."""
    from kinadapt_nn.runs.batch import compile_loop
    from kinadapt_nn.runs.episode import run_episode

    compile_loop(cfg)  # a cold cache's two-step warm-up episode runs on the plain plant
    with _plant(_probe_world(probe, record, stop)):
        r = run_episode(cfg)
    if record is not None and not record["t"]:
        raise RuntimeError("the plant probe recorded nothing: the episode loop no longer builds its scenes with "
                           "runs.loop.SceneBatch")
    return r


def _spectrum_peak(t: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """(dominant frequency above 5 Hz [Hz], rms above 20 Hz) of x(t), uniformly sampled."""
    from scipy.signal import butter, filtfilt

    dt = float(np.median(np.diff(t)))
    x = x - x.mean()
    X = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    fr = np.fft.rfftfreq(len(x), dt)
    b, a = butter(2, 20.0 / (0.5 / dt), btype="high")
    return float(fr[np.argmax(X * (fr > 5.0))]), float(np.sqrt(np.mean(filtfilt(b, a, x) ** 2)))


def _metrics(t, f, seat, fx=None, t_fx=None) -> dict:
    from kinadapt_nn.runs.evaluate import contact_quality

    q = contact_quality(t, f)
    i0 = int(np.argmax(f > 0))
    i1 = max(i0 + 64, int(np.searchsorted(t, seat if seat else t[-1])))
    freq, amp_f = _spectrum_peak(t[i0:i1], f[i0:i1])
    amp = amp_f
    if fx is not None:
        j0, j1 = np.searchsorted(t_fx, t[i0]), np.searchsorted(t_fx, t[i1 - 1])
        amp = _spectrum_peak(t_fx[j0:j1], fx[j0:j1])[1]
    chatter = q["contact_transitions_per_s"] > 5.0
    return {"transitions_per_s": q["contact_transitions_per_s"], "freq_Hz": freq if chatter else None,
            "chatter_rms_N": amp, "contact_fraction": q["contact_fraction"], "longest_span_s": q["longest_contact_span_s"]}


def run_row(row) -> dict:
    """One row of the table (in a worker process)."""
    from kinadapt_nn.config import load_config

    group, label, over, probe = row
    cfg = load_config(None, ["run.progress=false", "run.figure=false", "run.tensorboard=false", *PAPER, *over])
    rec = {"t": [], "f": [], "u": []}
    r = _episode(cfg, probe, rec)  # benchmark-only probe of the plant
    s = r.summary
    out = {"group": group, "label": label, "seat_time_s": s["seat_time_s"], "max_force_N": s["max_force_N"],
           "max_moment_Nm": s["max_moment_Nm"]}
    if probe.replay_hz > 0.0:
        t, f = _replay(cfg, np.array(rec["u"]), probe.replay_hz)
        return {**out, **_metrics(t, f, s["seat_time_s"]), "seat_time_s": None}
    t, f = np.array(rec["t"]), np.array(rec["f"])
    return {**out, **_metrics(t, f, s["seat_time_s"], r.trace["s"][:, 1], r.trace["t_s"])}


def _replay(cfg, u: np.ndarray, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Drive a fresh simulator with the servo set-points ``u`` (N, n) low-passed (zero phase) at
    ``cutoff_hz``: no controller in the loop. -> (t, normal contact force) per step."""
    from scipy.signal import butter, filtfilt

    from kinadapt_nn.sim.adapter import PegInHoleSim

    b, a = butter(2, cutoff_hz / (0.5 / cfg.run.dt_s))
    us = filtfilt(b, a, u, axis=0)
    sim = PegInHoleSim(cfg)
    t, f = np.zeros(len(us)), np.zeros(len(us))
    for k, uk in enumerate(us):
        sim.data.ctrl[:] = uk
        sim.step()
        t[k], f[k] = sim.time_s, sim.contacts_of(sim._sens_v, sim._own_data)[2]
    return t, f


def print_table(rows: list[dict]) -> None:
    print(f"{'what is varied':34s} {'value':48s} {'trans/s':>8s} {'f [Hz]':>7s} {'A [N]':>6s} {'frac':>5s} "
          f"{'span [s]':>8s} {'seat [s]':>8s} {'max|F|':>7s}")
    for r in rows:
        fz = f"{r['freq_Hz']:.0f}" if r["freq_Hz"] else "-"
        seat = f"{r['seat_time_s']:.3f}" if r["seat_time_s"] else "-"
        print(f"{r['group']:34s} {r['label']:48s} {r['transitions_per_s']:8.1f} {fz:>7s} {r['chatter_rms_N']:6.2f} "
              f"{r['contact_fraction']:5.2f} {r['longest_span_s']:8.3f} {seat:>8s} {r['max_force_N']:7.2f}")


# ---------------------------------------------------------------------------------- static
def _contact_state(t_s: float):
    """The paper setting's simulator at its first contact at or after ``t_s``: (sim, its config)."""
    from kinadapt_nn.config import load_config

    cfg = load_config(None, ["run.progress=false", "run.figure=false", "run.tensorboard=false", *PAPER,
                             f"run.duration_s={t_s + 0.05}"])
    keep: dict = {}

    def reached(sim) -> bool:
        if sim.time_s >= t_s and sim.data.ncon:
            keep["sim"] = sim
            return True
        return False

    try:
        _episode(cfg, Probe(), stop=reached)
    except _Reached:
        pass
    if "sim" not in keep:
        raise RuntimeError(f"the paper setting's episode had no contact at or after {t_s} s")
    return keep["sim"], cfg


class _Reached(Exception):
    """The contact state is reached: stop the episode there."""


def _normal_acceleration(model, data_from, mu: float) -> tuple[float, float, float]:
    """At the state of ``data_from`` in ``model`` with friction ``mu``: (normal acceleration of the peg's
    point at the first contact, + into the wall [m/s^2], sliding speed along the bore axis [m/s],
    total normal force [N])."""
    import mujoco

    m = model
    if m.npair:
        m.pair_friction[:, :2] = mu
    else:
        m.opt.o_friction[:2] = mu
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], d.ctrl[:], d.time = data_from.qpos, data_from.qvel, data_from.ctrl, data_from.time
    mujoco.mj_forward(m, d)
    tool = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")
    jp = np.zeros((3, m.nv))
    mujoco.mj_jac(m, d, jp, None, d.contact.pos[0], tool)
    n = d.contact.frame[0, :3]
    f6, fn = np.zeros(6), 0.0
    for i in range(d.ncon):
        mujoco.mj_contactForce(m, d, i, f6)
        fn += f6[0]
    return float(n @ (jp @ d.qacc)), float(-(jp @ d.qvel)[2]), fn


def static_separation(t_s: float = 2.5) -> list[dict]:
    """MuJoCo's constrained normal acceleration at one sliding contact state of the paper setting,
    the state held, for friction 0 .. 0.5 under both friction references, against mu b_f v_t."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.sim.adapter import PegInHoleSim

    sim, cfg = _contact_state(t_s)
    fixed = PegInHoleSim(load_config(None, [*PAPER, "scene.contact_friction_timeconst_s=2"]))
    rows = []
    for name, model, tc in (("normal's (paper)", sim.model, cfg.scene.contact_timeconst_s), ("2 s (default)", fixed.model, 2.0)):
        b = 2.0 / (0.99 * tc)
        for mu in (0.0, 0.1, 0.3, 0.5):
            a_n, v_t, fn = _normal_acceleration(model, sim.data, mu)
            rows.append({"friction_reference": name, "b_per_s": b, "mu": mu, "a_n_m_s2": a_n, "mu_b_vt_m_s2": mu * b * v_t,
                         "sliding_speed_m_s": v_t, "normal_force_N": fn, "t_s": float(sim.data.time)})
    return rows


# ----------------------------------------------------------------------------------- seeds
def seed_row(seed: int) -> dict:
    """The default run from a jittered start (lateral +- 0.3 mm, tilt +- 0.5 deg, ``run.seed``), with the
    paper's contact and with the default one: transitions per s, seat time, max |F|."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.episode import run_episode

    row = {"seed": seed}
    for name, over in (("paper_contact", ["scene.contact_friction_timeconst_s=0"]), ("default", [])):
        s = run_episode(load_config(None, ["run.progress=false", "run.figure=false", "run.tensorboard=false",
                                           f"run.seed={seed}", "start.lateral_jitter_m=0.0003",
                                           "start.tilt_jitter_deg=0.5", *over])).summary
        row[name] = {k: s[k] for k in ("contact_transitions_per_s", "seat_time_s", "max_force_N")}
    return row


# ----------------------------------------------------------------------------------- creep
def incline_creep(timeconst_s: float, impratio: float, slope_deg: float = 10.0) -> dict:
    """What the fix costs where a contact should stick: a 0.1 kg, 20 mm box (named as the peg) at rest on a
    plane (named as a block geom) tilted ``slope_deg`` (tan 10 deg = 0.18 < mu 0.3), the scene's global
    contact parameters, and ``sim.scene.friction_reference_pairs(timeconst_s)`` with MuJoCo's ``impratio``
    when ``timeconst_s > 0``. -> slide in the first second [m] and the creep speed over 3-4 s [m/s]."""
    import mujoco

    from kinadapt_nn.sim.scene import BLOCK_TOP_GEOMS_PREFIX, PEG_GEOM, friction_reference_pairs

    spec = mujoco.MjSpec()
    o = spec.option
    o.timestep, o.integrator = 1e-3, mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    o.enableflags |= int(mujoco.mjtEnableBit.mjENBL_OVERRIDE)
    o.o_solref, o.o_solimp = [0.02, 1.0], [0.95, 0.99, 0.001, 0.5, 2.0]
    o.o_friction, o.o_margin = [0.3, 0.3, 0.005, 0.0001, 0.0001], 0.0
    q = np.zeros(4)
    mujoco.mju_euler2Quat(q, np.deg2rad([0.0, slope_deg, 0.0]), "xyz")
    spec.worldbody.add_geom(name=f"{BLOCK_TOP_GEOMS_PREFIX}incline", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1],
                            quat=list(q))
    n = np.array([np.sin(np.deg2rad(slope_deg)), 0.0, np.cos(np.deg2rad(slope_deg))])
    box = spec.worldbody.add_body(pos=list(0.00999 * n), quat=list(q))
    box.add_freejoint()
    box.add_geom(name=PEG_GEOM, type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.01] * 3, mass=0.1)
    if timeconst_s > 0.0:
        friction_reference_pairs(spec, timeconst_s)
        o.impratio = impratio
    m = spec.compile()
    d = mujoco.MjData(m)
    x = []
    for k in range(4000):
        mujoco.mj_step(m, d)
        if k % 1000 == 999:
            x.append(d.qpos[:3].copy())
    return {"timeconst_s": timeconst_s, "impratio": impratio, "slide_first_s_m": float(np.linalg.norm(x[0] - 0.00999 * n)),
            "creep_m_s": float(np.linalg.norm(x[3] - x[2]))}


def jam_row(case: tuple[str, list[str], float]) -> dict:
    """The wedge of tests/runs/test_episode.py (a 3-deg start tilt, 6 s: the paper's contact jams) with
    a friction reference and impratio: failure class, true tip depth at the end, max |F|."""
    from kinadapt_nn.config import load_config

    name, over, impratio = case
    cfg = load_config(None, ["run.progress=false", "run.figure=false", "run.tensorboard=false", "run.duration_s=6.0",
                             "start.tilt_deg=[0.0, 3.0]", *over])
    r = _episode(cfg, Probe(impratio=impratio), {"t": [], "f": [], "u": []})
    return {"case": name, "failure": r.summary["failure"], "true_final_depth_m": r.summary["true_final_depth_m"],
            "max_force_N": r.summary["max_force_N"], "contact_transitions_per_s": r.summary["contact_transitions_per_s"]}


JAM_CASES = [("paper's contact", ["scene.contact_friction_timeconst_s=0"], 1.0), ("default", [], 1.0),
             ("default, impratio 10", [], 10.0), ("default, impratio 100", [], 100.0)]


# ----------------------------------------------------------------------------------- bound
def _stable(m: float, K: float, T: float, D: float, delay: int) -> bool:
    """One translational channel of eq. cp_admittance as the controller discretises it (implicit in the
    damping, docs/method.md) against a contact spring K sampled every T, the force ``delay`` samples old:
    m (v[k+1] - v[k]) / T + D v[k+1] = -K x[k - delay], x[k+1] = x[k] + T v[k+1]. Schur stable?"""
    a, g = m / (m + T * D), T * T * K / (m + T * D)
    c = np.zeros(3 + delay)
    c[:3] = 1.0, -(1.0 + a), a  # x[k+1] - (1+a) x[k] + a x[k-1] + g x[k-delay] = 0
    c[1 + delay] += g
    return bool(np.max(np.abs(np.roots(c))) < 1.0)


def mass_bound(K: float, T: float, D: float, delay: int) -> tuple[float, float] | None:
    """The stable virtual masses [m_lo, m_hi] (grid 1e-4 .. 1e5 kg) for contact stiffness K, or None."""
    ms = np.logspace(-4, 5, 901)
    ok = np.array([_stable(m, K, T, D, delay) for m in ms])
    return (float(ms[ok].min()), float(ms[ok].max())) if ok.any() else None


def sampled_bound(t_s: float = 2.5) -> dict:
    """The contact stiffness MuJoCo has (statics of its soft constraint, k = K imp / R per row, summed over
    a contact's rows), the joint servo's stiffness along the normal, and the virtual-mass bound with each."""
    from kinadapt_nn.robot import SERVO_KP

    sim, cfg = _contact_state(t_s)
    m, d = sim.model, sim.data
    k_rows = d.efc_KBIP[:d.nefc, 0] * d.efc_KBIP[:d.nefc, 2] / d.efc_R[:d.nefc]
    k_contacts = [float(k_rows[c.efc_address:c.efc_address + 2 * (c.dim - 1)].sum()) for c in d.contact]
    import mujoco

    tool = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")
    jp = np.zeros((3, m.nv))
    mujoco.mj_jac(m, d, jp, None, d.contact.pos[0], tool)
    J, n = jp[:, sim.ids.dof_adr], d.contact.frame[0, :3]
    K_s = SERVO_KP / float(n @ J @ J.T @ n)
    c = cfg.control
    T, M, D = cfg.run.dt_s, c.tau_trans_s / c.gain_trans, (1.0 + c.beta_trans) / c.gain_trans
    K_c = float(sum(k_contacts))
    K_series = 1.0 / (1.0 / K_c + 1.0 / K_s)
    out = {"t_s": float(d.time), "K_c_per_contact_N_m": k_contacts, "K_c_N_m": K_c, "K_servo_N_m": K_s,
           "K_series_N_m": K_series, "M_kg": M, "D_N_s_m": D, "T_s": T}
    for name, K in (("contact", K_c), ("servo_in_series", K_series)):
        for delay in (0, 1):
            out[f"stable_masses_{name}_delay{delay}_kg"] = mass_bound(K, T, D, delay)
    out["M_min_closed_form_contact_delay0_kg"] = max(0.0, K_c * T * T / 4 - T * D / 2)
    Ks = np.logspace(3, 9, 601)
    for delay in (0, 1):  # the stiffest contact the configured M is stable against
        ok = [K for K in Ks if _stable(M, K, T, D, delay)]
        out[f"K_max_stable_at_M_delay{delay}_N_m"] = float(max(ok)) if ok else 0.0
    return out


# ---------------------------------------------------------------------------------- figure
def _trace(over: list[str]):
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.episode import run_episode

    r = run_episode(load_config(None, ["run.progress=false", "run.figure=false", "run.tensorboard=false", *over]))
    return r.summary, {k: r.trace[k] for k in ("t_s", "s", "truth_contact_force_N")}


def figure(rows: list[dict], png: str, ex) -> None:
    """The default run (``kinadapt online``) before / after the fix: F_lat_x and the contact force over
    0.1 s, the spectrum of F_lat_x; and the table's transitions per second against the friction
    reference's damping."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (s0, a), (s1, b) = ex.map(_trace, [["scene.contact_friction_timeconst_s=0"], []])  # the default run before / after
    fig, ax = plt.subplots(2, 2, figsize=(12, 7), constrained_layout=True)
    for (s, tr), name, col in (((s0, a), "before: friction reference = normal's (the paper's runs)", "C3"),
                               ((s1, b), "after: friction reference 2 s (the default)", "C0")):
        t, fx, fc = tr["t_s"], tr["s"][:, 1], tr["truth_contact_force_N"]
        w = (t >= 2.45) & (t <= 2.55)
        ax[0, 0].plot(t[w], fx[w], color=col, label=f"{name}: {s['contact_transitions_per_s']:.1f} transitions/s")
        ax[1, 0].plot(t[w], fc[w], color=col, drawstyle="steps-post")
        i0, i1 = int(np.argmax(fc > 0)), int(np.searchsorted(t, s["seat_time_s"] or t[-1]))
        x = fx[i0:i1] - fx[i0:i1].mean()
        X = np.abs(np.fft.rfft(x * np.hanning(len(x)))) * 2 / np.hanning(len(x)).sum()
        ax[0, 1].semilogy(np.fft.rfftfreq(len(x), t[1] - t[0]), np.maximum(X, 1e-5), color=col, lw=0.8,
                          label=f"{name}: seat {s['seat_time_s']:.3f} s")
    ax[0, 0].set(xlabel="time [s]", ylabel="sensed F_lat_x [N]", title="F_lat_x, 0.1 s mid-insertion")
    ax[1, 0].set(xlabel="time [s]", ylabel="truth normal contact force [N]", title="contact force (1 kHz samples)")
    ax[0, 1].set(xlabel="frequency [Hz]", ylabel="|F_lat_x| amplitude [N]", title="spectrum of F_lat_x, first contact to seat",
                 xlim=(0, 500))
    fr = [r for r in rows if r["group"] == "paper setting" or "b_f " in r["label"]]
    bf = [101.0 if r["group"] == "paper setting" else float(r["label"].split("b_f ")[1].split("/s")[0]) for r in fr]
    ax[1, 1].loglog(bf, np.maximum([r["transitions_per_s"] for r in fr], 0.1), "o-", color="k")
    ax[1, 1].axhline(5.0, color="0.5", ls=":", label="5 per s")
    ax[1, 1].set(xlabel="friction rows' reference damping b_f = 2/(0.99 t_f) [1/s]", ylabel="contact transitions per s",
                 title="transitions vs the friction reference (the table's rows; 0 drawn at 0.1)")
    for a_ in (ax[0, 0], ax[0, 1], ax[1, 1]):
        a_.legend(fontsize=8)
    fig.suptitle("The bore rattle of the default run (kinadapt online): MuJoCo's friction reference pushes the sliding peg off the wall")
    fig.savefig(png, dpi=110)
    plt.close(fig)


def _part_static(ex) -> list[dict]:
    rows = ex.submit(static_separation).result()
    for r in rows:
        print(f"friction reference {r['friction_reference']:17s} (b {r['b_per_s']:6.1f}/s) mu {r['mu']:.1f}: "
              f"a_n {r['a_n_m_s2']:+.3f} m/s^2 (+ = into the wall), mu b v_t {r['mu_b_vt_m_s2']:.3f}, "
              f"normal force {r['normal_force_N']:.2f} N, sliding {1e3 * r['sliding_speed_m_s']:.1f} mm/s")
    return rows


def _part_seeds(ex) -> list[dict]:
    rows = list(ex.map(seed_row, range(1, 7)))
    for r in rows:
        p, d = r["paper_contact"], r["default"]
        print(f"seed {r['seed']} (jittered start): paper contact {p['contact_transitions_per_s']:6.1f}/s seat "
              f"{p['seat_time_s'] or float('nan'):.3f} s max|F| {p['max_force_N']:.2f} N | default "
              f"{d['contact_transitions_per_s']:5.1f}/s seat {d['seat_time_s'] or float('nan'):.3f} s "
              f"max|F| {d['max_force_N']:.2f} N")
    return rows


def gain_row(job: tuple[float, str, str]) -> dict:
    """One bore episode of the paper's gain sweep (``paper.reproduce.part_gain_sweep``): the paper's
    law setting with ``adaptation.gamma`` = Gamma and ``adaptation.mode`` = law, on the contact named
    (``paper``: MuJoCo's friction reference = the normal's; ``default``: the rattle-free one).
    ``final_V_aug`` = gamma_d V + |theta - theta_true|^2 / (2 Gamma) at the end, as the paper's figure."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.episode import run_episode

    gamma, law, contact = job
    over = [] if contact == "paper" else ["scene.contact_friction_timeconst_s=2.0"]
    cfg = load_config(None, ["run.progress=false", "run.figure=false", "run.tensorboard=false", *PAPER_SETTING,
                             *over, f"adaptation.gamma={gamma}", f"adaptation.mode={law}"])
    r = run_episode(cfg)
    s, tr = r.summary, r.trace
    true = np.asarray(tr.meta["truth_offset_f_m"])
    gd = cfg.adaptation.gamma_d
    v_aug = gd * tr["V"][-1] + 0.5 * float(np.sum((tr["theta"][-1] - true) ** 2)) / gamma
    return {"gamma": gamma, "law": law, "contact": contact, "final_V_aug": float(v_aug),
            **{k: s[k] for k in ("seat_time_s", "contact_transitions_per_s", "max_force_N",
                                 "offset_error_lateral_final_m")}}


def _part_gain(ex) -> list[dict]:
    jobs = [(g, law, c) for c in ("paper", "default") for g in (100.0, 8000.0) for law in ("composite", "prediction")]
    rows = list(ex.map(gain_row, jobs))
    for r in rows:
        print(f"gain sweep, bore, {r['contact']:7s} contact, Gamma {r['gamma']:6g}, {r['law']:10s}: seat "
              f"{r['seat_time_s'] or float('nan'):.3f} s, {r['contact_transitions_per_s']:6.1f} transitions/s, max|F| "
              f"{r['max_force_N']:.2f} N, lateral offset error {1e3 * r['offset_error_lateral_final_m']:.2f} mm, "
              f"final V_aug {r['final_V_aug']:.3e}")
    return rows


def _part_creep(ex) -> dict:
    creep = [incline_creep(tc, imp) for tc, imp in ((0.0, 1.0), (2.0, 1.0), (2.0, 10.0), (2.0, 100.0))]
    for r in creep:
        ref = "normal's (paper)" if r["timeconst_s"] == 0 else f"{r['timeconst_s']:g} s, impratio {r['impratio']:g}"
        print(f"box at rest on a 10-deg incline, mu 0.3, friction reference {ref:22s}: slid "
              f"{1e3 * r['slide_first_s_m']:.3f} mm in 1 s, creeps {1e3 * r['creep_m_s']:.3f} mm/s")
    jam = list(ex.map(jam_row, JAM_CASES))
    for r in jam:
        print(f"3-deg wedge, {r['case']:22s}: {r['failure']:8s} true tip depth {1e3 * r['true_final_depth_m']:.2f} mm "
              f"(target 45), max|F| {r['max_force_N']:.1f} N, {r['contact_transitions_per_s']:.1f} transitions/s")
    return {"creep": creep, "jam": jam}


def _part_bound(ex) -> dict:
    bound = ex.submit(sampled_bound).result()
    print(json.dumps(bound, indent=1))
    return bound


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--only", default="table,static,creep,bound,seeds,gain,figure")
    ap.add_argument("--png", default="docs/figures/bore_rattle.png")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    parts, res = set(a.only.split(",")), {}
    print(f"machine: {platform.machine()} cpu_count={os.cpu_count()} platform={platform.platform()} "
          f"python={platform.python_version()} (load average {os.getloadavg()[0]:.1f})")
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        if parts & {"table", "figure"}:
            res["rows"] = list(ex.map(run_row, ROWS))
            print_table(res["rows"])
        for name, part in (("static", _part_static), ("seeds", _part_seeds), ("creep", _part_creep),
                           ("bound", _part_bound), ("gain", _part_gain)):
            if name in parts:
                res[name] = part(ex)
        if "figure" in parts:
            figure(res["rows"], a.png, ex)
            print(f"figure: {a.png}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)


if __name__ == "__main__":
    main()
