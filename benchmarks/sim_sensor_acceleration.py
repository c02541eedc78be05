"""The simulated wrist sensor's acceleration against the encoders' (issue 37, a finding).

    python benchmarks/sim_sensor_acceleration.py

MuJoCo's force/torque sensors are evaluated in ``mj_forward``, with its ``qacc``; ``implicitfast``
then integrates the stiff joint servos (kv 450 N m s/rad, ``models/panda.xml``) implicitly, so the
velocity the encoders see changes by less than ``qacc dt``. This drives the bare arm's wrist joints
with sines through the position servos and prints, per joint, the slope of ``qacc`` against the
integrated acceleration ``(qvel_{k+1} - qvel_k) / dt``: the factor by which the simulated sensor's
inertial wrench exceeds the one the encoders' motion implies.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

MODEL = Path(__file__).resolve().parents[1] / "models" / "panda.xml"


def main() -> None:
    import mujoco

    m = mujoco.MjModel.from_xml_path(str(MODEL))
    d = mujoco.MjData(m)
    q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
    d.qpos[:7] = q0
    d.ctrl[:] = q0
    mujoco.mj_forward(m, d)
    qacc, dv = [], []
    for k in range(1500):
        t = k * m.opt.timestep
        ref = q0.copy()
        ref[5] += 0.2 * np.sin(2 * np.pi * 0.7 * t)  # joint 6
        ref[6] += 0.3 * np.sin(2 * np.pi * 1.0 * t)  # joint 7
        d.ctrl[:] = ref
        v0 = d.qvel.copy()
        mujoco.mj_step(m, d)
        if k >= 300:  # after the start transient
            qacc.append(d.qacc[:7].copy())
            dv.append((d.qvel[:7] - v0) / m.opt.timestep)
    qacc, dv = np.array(qacc), np.array(dv)
    print(f"integrator {m.opt.integrator} (implicitfast = {int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)}), "
          f"timestep {m.opt.timestep} s")
    for j in (5, 6):
        print(f"joint {j + 1}: qacc of mj_forward (what the F/T sensor uses) = "
              f"{np.polyfit(dv[:, j], qacc[:, j], 1)[0]:.2f} x the integrated acceleration")


if __name__ == "__main__":
    main()
