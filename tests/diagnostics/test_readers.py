"""Log readers for ``kinadapt diagnose --setup``: every format reads back what was written, and every
validation rule is a one-line ``KinadaptError`` naming the file, row and column."""

from __future__ import annotations

import gzip
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from kinadapt_nn.diagnostics.readers import SUPPORTED, read_log, write_log
from kinadapt_nn.diagnostics.setup import LogCfg, SetupCfg
from kinadapt_nn.errors import KinadaptError

N, RATE = 1000, 500.0  # samples, [Hz]
ARM = tuple(f"panda_joint{i}" for i in range(1, 8))


def synth(n: int = N, rate: float = RATE, dof: int = 7):
    """Smooth sines: t (n,) [s], q, qdot (n, dof) [rad, rad/s], wrench (n, 6) [N, N m]."""
    t = np.arange(n) / rate
    return (t, *joints_at(t, dof), wrench_at(t))


def joints_at(t: np.ndarray, dof: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """(n,) [s] -> q, qdot (n, dof) [rad, rad/s]: smooth sines."""
    k = np.arange(1, dof + 1)
    q = 0.3 * np.sin(2 * np.pi * 0.4 * k * t[:, None] / 7 + k) + 0.1 * k
    qdot = 0.3 * (2 * np.pi * 0.4 * k / 7) * np.cos(2 * np.pi * 0.4 * k * t[:, None] / 7 + k)
    return q, qdot


def wrench_at(t: np.ndarray) -> np.ndarray:
    """(n,) [s] -> (n, 6): a smooth wrench (slow enough for linear interpolation at 1 kHz)."""
    k = np.arange(1, 7)
    return 5.0 * np.sin(2 * np.pi * 0.5 * t[:, None] + k) + k


def setup_of(**log) -> SetupCfg:
    return SetupCfg(log=LogCfg(**log))


DEFAULT = setup_of()
WITH_QDOT = setup_of(qdot=[f"qd{i}" for i in range(1, 8)])
# other names, degrees, time in milliseconds, and velocities
CUSTOM = setup_of(time="stamp_ms", time_scale_s=1e-3, angle_unit="deg", q=[f"pos_{i}" for i in range(7)],
                  qdot=[f"vel_{i}" for i in range(7)], wrench=["Fx", "Fy", "Fz", "Mx", "My", "Mz"])


def err(path: Path, setup: SetupCfg = DEFAULT) -> str:
    """The message of the one-line error that reading ``path`` raises."""
    with pytest.raises(KinadaptError) as info:
        read_log(path, setup)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg
    return msg


# --------------------------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz", ".parquet", ".pq"])
@pytest.mark.parametrize("variant", ["default", "custom", "ns"])
def test_tables_read_back_what_was_written(tmp_path, suffix, variant):
    t, q, qdot, w = synth()
    path = tmp_path / f"log{suffix}"
    if variant == "default":  # seconds with an offset, radians, no velocities
        setup = DEFAULT
        write_log(path, 12.5 + t, q, None, w, setup.log)
    elif variant == "custom":  # milliseconds, degrees, velocities, other column names
        setup = CUSTOM
        write_log(path, 1000.0 * t, np.rad2deg(q), np.rad2deg(qdot), w, setup.log)
    else:  # integer nanosecond stamps: differenced exactly before scaling
        setup = setup_of(time="stamp_ns", time_scale_s=1e-9)
        write_log(path, 1_700_000_000_000_000_000 + np.arange(N, dtype=np.int64) * 2_000_000, q, None, w, setup.log)
    log = read_log(path, setup)
    assert log.source == str(path) and log.t_s.shape == (N,) and log.t_s[0] == 0.0
    np.testing.assert_allclose(log.t_s, t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(log.wrench_log, w)
    if variant == "custom":
        np.testing.assert_allclose(log.q_rad, q, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(log.qdot_rad_s, qdot, rtol=1e-14, atol=1e-15)
    else:
        np.testing.assert_array_equal(log.q_rad, q)
        assert log.qdot_rad_s is None
    if suffix == ".csv.gz":
        with gzip.open(path, "rt") as fh:
            assert setup.log.time in fh.readline()


def test_extra_columns_are_ignored_and_the_delimiter_is_sniffed(tmp_path):
    t, q, qdot, w = synth()
    path = tmp_path / "with_qdot.csv"
    write_log(path, t, q, qdot, w, WITH_QDOT.log)
    log = read_log(path, DEFAULT)  # the qd* columns are extra for this setup
    assert log.qdot_rad_s is None
    np.testing.assert_array_equal(log.q_rad, q)
    # hand-written: semicolons, spaces around names, a text column
    rows = ["time ; note ; " + " ; ".join([*DEFAULT.log.q, *DEFAULT.log.wrench])]
    rows += [f"{float(t[i])!r};ok;" + ";".join(repr(float(v)) for v in [*q[i], *w[i]]) for i in range(N)]
    semi = tmp_path / "semi.csv"
    semi.write_text("\n".join(rows) + "\n")
    log = read_log(semi, setup_of(time="time"))
    np.testing.assert_array_equal(log.q_rad, q)
    np.testing.assert_array_equal(log.wrench_log, w)


def test_declared_extra_columns_are_read_and_checked(tmp_path):
    """``[log] extra``: the named columns reach ``UserLog.extra`` in SI rows; a missing one or a
    non-finite value is the readers' one-line error naming the column."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    t, q, _, w = synth()
    temp = 24.0 + np.sin(t)
    cols = {"t": t, **{f"q{i + 1}": q[:, i] for i in range(7)}, **{n: w[:, k] for k, n in enumerate(DEFAULT.log.wrench)},
            "temp_C": temp}
    path = tmp_path / "extra.parquet"
    pq.write_table(pa.table({k: pa.array(v) for k, v in cols.items()}), path)
    log = read_log(path, setup_of(extra=["temp_C"]))
    np.testing.assert_array_equal(log.extra["temp_C"], temp)
    assert read_log(path, DEFAULT).extra is None
    msg = err(path, setup_of(extra=["temp_K"]))
    assert "temp_K" in msg and "temp_C" in msg
    temp[17] = np.nan
    pq.write_table(pa.table({k: pa.array(v) for k, v in {**cols, "temp_C": temp}.items()}), path)
    msg = err(path, setup_of(extra=["temp_C"]))
    assert "temp_C" in msg and "not finite" in msg and "17" in msg


def test_a_15_s_500_hz_csv_reads_in_well_under_a_second(tmp_path):
    t, q, qdot, w = synth(7500)
    for suffix in (".csv", ".csv.gz"):
        path = tmp_path / f"long{suffix}"
        write_log(path, t, q, qdot, w, WITH_QDOT.log)  # 21 columns
        t0 = time.perf_counter()
        log = read_log(path, WITH_QDOT)
        assert time.perf_counter() - t0 < 0.5
        assert log.q_rad.shape == (7500, 7) and log.qdot_rad_s.shape == (7500, 7)


def test_trace_file_and_run_folder(tmp_path):
    from kinadapt_nn.trace import Trace

    t, q, qdot, w = synth()
    run = tmp_path / "run"
    run.mkdir()
    Trace(arrays={"t_s": t + 0.25, "q_rad": q, "qdot_rad_s": qdot, "wrench_raw_f": w, "V": np.zeros(N)},
          meta={"dt_s": 1 / RATE}).save(run / "trace.npz")
    for path in (run, run / "trace.npz"):
        log = read_log(path, CUSTOM)  # the setup's names and units do not apply to traces
        np.testing.assert_allclose(log.t_s, t, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(log.q_rad, q)
        np.testing.assert_array_equal(log.qdot_rad_s, qdot)
        np.testing.assert_array_equal(log.wrench_log, w)
    t_bad = t.copy()
    t_bad[40] = t_bad[39]
    Trace(arrays={"t_s": t_bad, "q_rad": q, "qdot_rad_s": qdot, "wrench_raw_f": w}).save(tmp_path / "bad.npz")
    assert "sample 40" in err(tmp_path / "bad.npz")


# --------------------------------------------------------------------------------------------- joints, units, static logs


@pytest.mark.parametrize("dof", [1, 6, 12])
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_any_number_of_joints(tmp_path, dof, suffix):
    t, q, qdot, w = synth(dof=dof)
    setup = setup_of(q=[f"j{i}" for i in range(dof)], qdot=[f"jd{i}" for i in range(dof)])
    path = tmp_path / f"log{suffix}"
    write_log(path, t, q, qdot, w, setup.log)
    log = read_log(path, setup)
    assert log.q_rad.shape == (N, dof) and log.qdot_rad_s.shape == (N, dof)
    np.testing.assert_array_equal(log.q_rad, q)
    np.testing.assert_array_equal(log.qdot_rad_s, qdot)
    with pytest.raises(KinadaptError, match=rf"q has shape \({N}, 7\); expected \({N}, {dof}\)"):
        write_log(path, t, synth()[1], qdot, w, setup.log)  # seven joints for a dof-joint log


def test_wrench_units_come_back_in_si(tmp_path):
    """N mm and lbf in / lbf columns are scaled by their exact SI factors; the default N, N m stays bit-exact."""
    t, q, _, w = synth()
    path = tmp_path / "mm.csv"
    mm = setup_of(torque_unit="N mm")
    raw = np.hstack([w[:, :3], 1000.0 * w[:, 3:]])  # [N, N mm]
    write_log(path, t, q, None, raw, mm.log)
    log = read_log(path, mm)
    np.testing.assert_array_equal(log.wrench_log[:, :3], w[:, :3])
    np.testing.assert_array_equal(log.wrench_log[:, 3:], raw[:, 3:] * 1e-3)
    np.testing.assert_allclose(log.wrench_log[:, 3:], w[:, 3:], rtol=1e-15)
    imperial = setup_of(force_unit="lbf", torque_unit="lbf in")
    write_log(path, t, q, None, w, imperial.log)  # the same numbers, read as lbf and lbf in
    log = read_log(path, imperial)
    np.testing.assert_array_equal(log.wrench_log[:, :3], w[:, :3] * 4.4482216152605)  # 1 lbf [N]
    np.testing.assert_array_equal(log.wrench_log[:, 3:], w[:, 3:] * 0.1129848290276167)  # 1 lbf in [N m]


STATIC = setup_of(static=True, time="")


def poses(n: int = 12, dof: int = 7):
    """Random poses at rest: q (n, dof) [rad], wrench (n, 6) [N, N m]."""
    rng = np.random.default_rng(n)
    return rng.uniform(-2.0, 2.0, (n, dof)), rng.normal(0.0, 5.0, (n, 6))


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_static_log_without_a_time_column(tmp_path, suffix):
    q, w = poses()
    path = tmp_path / f"poses{suffix}"
    write_log(path, None, q, None, w, STATIC.log)
    log = read_log(path, STATIC)
    assert log.t_s is None and log.static and log.qdot_rad_s is None
    np.testing.assert_array_equal(log.q_rad, q)
    np.testing.assert_array_equal(log.wrench_log, w)
    if suffix == ".csv":
        assert path.read_text().splitlines()[0].split(",")[0] == '"q1"'  # no time column written
    write_log(path, None, q[:11], None, w[:11], STATIC.log)
    msg = err(path, STATIC)
    assert "only 11" in msg and "12" in msg and "static" in msg
    with pytest.raises(KinadaptError, match="time"):
        write_log(path, None, q, None, w, DEFAULT.log)  # the columns name a time column


def test_static_log_may_leave_the_time_key_out(tmp_path):
    """``static = true`` with no time key and no column 't': no time column (the key's default names
    one only if it is there); a moving log, or a time column named on purpose, still needs it."""
    q, w = poses()
    path = tmp_path / "poses.csv"
    write_log(path, None, q, None, w, STATIC.log)
    log = read_log(path, setup_of(static=True))
    assert log.t_s is None and log.static
    np.testing.assert_array_equal(log.wrench_log, w)
    assert "has no column 't'" in err(path, DEFAULT)
    assert "has no column 'stamp'" in err(path, setup_of(static=True, time="stamp"))


def test_static_log_time_may_be_in_any_order(tmp_path):
    """Rows are poses: repeated, shuffled and far-apart times are read (from the earliest row),
    where a moving log would be refused; a non-finite time is still an error."""
    q, w = poses(60)  # enough rows for a moving log too
    t = np.array([5.0, 3.0, 3.0, 100.0, 4.5, *np.arange(55) * 0.1 + 200.0])
    path = tmp_path / "poses.csv"
    static_t = setup_of(static=True)
    write_log(path, t, q, None, w, static_t.log)
    log = read_log(path, static_t)
    assert log.static
    np.testing.assert_allclose(log.t_s, t - 3.0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(log.q_rad, q)
    assert "line 3" in err(path, DEFAULT) and "does not increase" in err(path, DEFAULT)  # as a moving log
    t[4] = np.nan
    write_log(path, t, q, None, w, static_t.log)
    msg = err(path, static_t)
    assert "line 6" in msg and "'t'" in msg and "not finite" in msg


def test_a_moving_log_needs_its_time_column():
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.errors import ConfigError

    with pytest.raises(ConfigError, match="static"):
        load_setup(None, ['log.time=""'])
    assert load_setup(None, ['log.time=""', "log.static=true"]).log.time == ""


# --------------------------------------------------------------------------------------------- ROS 2 bags

T0_NS = 1_700_000_000_000_000_000
W_OFFSET_NS = 3_300_000  # the wrench stamps are 3.3 ms off the joint states' grid ...
W_RATE = 1000.0  # ... at 1 kHz, from 50 ms before the first joint state to 50 ms after the last


class BagData(NamedTuple):
    """What a test bag holds: two streams on their own clocks."""

    t_j_ns: np.ndarray  # (M,) int64 [ns] joint-state stamps
    q: np.ndarray  # (M, dof) [rad]
    qdot: np.ndarray  # (M, dof) [rad/s]
    t_w_ns: np.ndarray  # (K,) int64 [ns] wrench stamps
    wrench: np.ndarray  # (K, 6) [N, N m]


def default_bag_data() -> BagData:
    """Joint states at 500 Hz (``synth``), the wrench at 1 kHz offset by ``W_OFFSET_NS``, longer."""
    t, q, qdot, _ = synth()
    k = np.arange(-50, int(t[-1] * W_RATE) + 50, dtype=np.int64)  # wrench sample k at k ms + offset
    return BagData(T0_NS + np.arange(N, dtype=np.int64) * 2_000_000, q, qdot, T0_NS + W_OFFSET_NS + k * 1_000_000,
                   wrench_at(k / W_RATE + W_OFFSET_NS * 1e-9))


def write_bag(path: Path, plugin: str, data: BagData | None = None, stamps: bool = True,
              velocity: bool = True) -> None:
    """``data`` (``default_bag_data()``) as a bag, with a gripper's joint states between the arm's
    (every tenth, skipped by the reader); ``stamps=False`` leaves the header stamps zero (only the
    bag's record times), ``velocity=False`` empty."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Vec, Wrench = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Wrench"]

    def header(ns: int):
        ns = ns if stamps else 0
        return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="ft")

    d = data or default_bag_data()
    names = list(ARM[: d.q.shape[1]][::-1])
    msgs = []
    for i, ns in enumerate(int(x) for x in d.t_j_ns):
        # the joints in another order than the setup's, plus a gripper message between (skipped)
        msg = T["sensor_msgs/msg/JointState"](header=header(ns), name=names, position=d.q[i, ::-1].copy(),
                                             velocity=d.qdot[i, ::-1].copy() if velocity else np.zeros(0),
                                             effort=np.zeros(0))
        msgs.append((ns, "/joint_states", msg))
        if i % 10 == 0:
            finger = T["sensor_msgs/msg/JointState"](header=header(ns + 1000), name=["panda_finger_joint1"],
                                                    position=np.zeros(1), velocity=np.zeros(1), effort=np.zeros(0))
            msgs.append((ns + 1000, "/joint_states", finger))
    for ns, w in zip((int(x) for x in d.t_w_ns), d.wrench):
        msg = T["geometry_msgs/msg/WrenchStamped"](header=header(ns), wrench=Wrench(
            force=Vec(x=w[0], y=w[1], z=w[2]), torque=Vec(x=w[3], y=w[4], z=w[5])))
        msgs.append((ns, "/ft_sensor/wrench", msg))
    msgs.sort(key=lambda m: m[0])
    with Writer(path, version=9, storage_plugin=getattr(StoragePlugin, plugin)) as writer:
        conns = {topic: writer.add_connection(topic, msgtype, typestore=store) for topic, msgtype in (
            ("/joint_states", "sensor_msgs/msg/JointState"), ("/ft_sensor/wrench", "geometry_msgs/msg/WrenchStamped"),
            ("/tf", "tf2_msgs/msg/TFMessage"))}
        for ns, topic, msg in msgs:
            writer.write(conns[topic], ns, store.serialize_cdr(msg, msg.__msgtype__))


@pytest.fixture(scope="module", params=["SQLITE3", "MCAP"])
def bag(request, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("bag") / f"bag_{request.param.lower()}"
    write_bag(path, request.param)
    return path


class Expected(NamedTuple):
    """What a bag should read as: the wrench stream is the master clock."""

    t_s: np.ndarray  # (N,) [s] from the first kept wrench sample
    q: np.ndarray  # (N, dof) the joint states linearly interpolated onto the kept wrench stamps
    qdot: np.ndarray  # (N, dof) the same for the velocities
    wrench: np.ndarray  # (N, 6) the wrench samples inside the joint states' span, as recorded
    t_abs_s: np.ndarray  # (N,) [s] the kept wrench stamps from T0_NS
    inside: np.ndarray  # (K,) bool: the wrench samples kept


def expected_from_bag(d: BagData | None = None) -> Expected:
    d = d or default_bag_data()
    tj, tw = (d.t_j_ns - T0_NS) * 1e-9, (d.t_w_ns - T0_NS) * 1e-9
    inside = (d.t_w_ns >= d.t_j_ns[0]) & (d.t_w_ns <= d.t_j_ns[-1])  # wrench outside the joint span is dropped
    at = lambda a: np.stack([np.interp(tw[inside], tj, a[:, k]) for k in range(a.shape[1])], axis=1)  # noqa: E731
    return Expected(tw[inside] - tw[inside][0], at(d.q), at(d.qdot), d.wrench[inside], tw[inside], inside)


def test_bag_keeps_the_wrench_samples_and_interpolates_the_joint_states(bag):
    e = expected_from_bag()
    assert 0 < len(e.t_s) < len(default_bag_data().t_w_ns)
    storage = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    for path in (bag, storage):  # the bag folder, or its storage file alone
        setup = setup_of(q=ARM, qdot=[f"v{i}" for i in range(7)])  # any names: use the velocity field
        log = read_log(path, setup)
        assert log.t_s[0] == 0.0 and not log.static
        np.testing.assert_allclose(log.t_s, e.t_s, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(log.wrench_log, e.wrench)  # the samples as recorded
        np.testing.assert_allclose(log.q_rad, e.q, rtol=0, atol=1e-12)  # the linear interpolation
        np.testing.assert_allclose(log.qdot_rad_s, e.qdot, rtol=0, atol=1e-12)
        q_true, qdot_true = joints_at(e.t_abs_s)
        np.testing.assert_allclose(log.q_rad, q_true, rtol=0, atol=1e-5)  # the true joint angles
        np.testing.assert_allclose(log.qdot_rad_s, qdot_true, rtol=0, atol=1e-4)
    assert read_log(bag, setup_of(q=ARM)).qdot_rad_s is None  # no velocities asked for


def test_bag_reads_any_subset_of_joints_and_the_declared_units(bag):
    """Six of the seven joints, in another order: (N, 6); messages naming all of them are kept. The
    wrench units apply as declared."""
    e = expected_from_bag()
    log = read_log(bag, setup_of(q=ARM[5::-1], force_unit="kN", torque_unit="N mm"))
    assert log.q_rad.shape == (len(e.t_s), 6)
    np.testing.assert_allclose(log.q_rad, e.q[:, 5::-1], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(log.wrench_log[:, :3], e.wrench[:, :3] * 1000.0)
    np.testing.assert_array_equal(log.wrench_log[:, 3:], e.wrench[:, 3:] * 1e-3)
    static = read_log(bag, setup_of(q=ARM, static=True))  # stamps as usual
    assert static.static
    np.testing.assert_array_equal(static.t_s, read_log(bag, setup_of(q=ARM)).t_s)


def test_bag_joint_states_are_validated_on_their_own_clock(tmp_path):
    """A non-finite joint state or a gap in the joint states (the wrench running on) is a one-line
    error naming the message on its topic (the gripper's messages count)."""
    d = default_bag_data()
    q = d.q.copy()
    q[100, 2] = np.nan  # arm message 100 is the 111th on /joint_states (11 gripper messages before)
    write_bag(tmp_path / "nan", "MCAP", d._replace(q=q))
    msg = err(tmp_path / "nan", setup_of(q=ARM))
    assert "joint-state sample 110" in msg and "panda_joint3" in msg and "not finite" in msg
    keep = np.r_[0:400, 421:N]  # 44 ms from the 400th arm message to the next (40 gripper messages before)
    write_bag(tmp_path / "gap", "MCAP", d._replace(t_j_ns=d.t_j_ns[keep], q=d.q[keep], qdot=d.qdot[keep]))
    msg = err(tmp_path / "gap", setup_of(q=ARM))
    assert "joint-state sample 440" in msg and "/joint_states" in msg and "gap of 0.044 s" in msg


def test_bag_and_csv_of_one_noisy_log_give_the_same_wrench_samples_and_noise(tmp_path):
    """A 1 kHz noisy wrench and 250 Hz joint states offset by half a wrench period: the bag reads
    the wrench samples the CSV of the same log holds, so the noise estimate is the same. The old
    reading (the wrench interpolated onto the joint stamps) averaged neighbouring samples and would
    have understated the noise by about 1/sqrt(2)."""
    from kinadapt_nn.diagnostics.userlog import RowCfg, noise_sigma

    rng = np.random.default_rng(7)
    sigma = np.array([0.2, 0.2, 0.2, 0.01, 0.01, 0.01])  # [N, N m]
    tw = np.arange(8000) / 1000.0  # [s] 8 s of wrench at 1 kHz
    w = wrench_at(tw) + sigma * rng.standard_normal((len(tw), 6))
    tj = 0.0005 + np.arange(2000) / 250.0  # [s] joint states at 250 Hz, half a wrench period late
    q_j, qdot_j = joints_at(tj)
    d = BagData(T0_NS + np.round(tj * 1e9).astype(np.int64), q_j, qdot_j,
                T0_NS + np.round(tw * 1e9).astype(np.int64), w)
    write_bag(tmp_path / "bag", "MCAP", d)
    q_w, qdot_w = joints_at(tw)  # the CSV: one row per wrench sample, the joints at its stamp
    write_log(tmp_path / "log.csv", tw, q_w, qdot_w, w, WITH_QDOT.log)
    from_bag = read_log(tmp_path / "bag", setup_of(q=ARM, qdot=ARM))
    from_csv = read_log(tmp_path / "log.csv", WITH_QDOT)
    inside = expected_from_bag(d).inside
    assert 7990 <= inside.sum() < 8000
    np.testing.assert_array_equal(from_bag.wrench_log, from_csv.wrench_log[inside])
    np.testing.assert_allclose(from_bag.t_s, from_csv.t_s[inside] - from_csv.t_s[inside][0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(from_bag.q_rad, from_csv.q_rad[inside], rtol=0, atol=1e-5)
    np.testing.assert_allclose(from_bag.qdot_rad_s, from_csv.qdot_rad_s[inside], rtol=0, atol=1e-4)
    s_bag, s_csv = noise_sigma(from_bag.wrench_log, RowCfg()), noise_sigma(from_csv.wrench_log, RowCfg())
    np.testing.assert_allclose(s_bag, s_csv, rtol=0.05)
    np.testing.assert_allclose(s_csv, sigma, rtol=0.1)  # the estimate itself is right
    old = np.stack([np.interp(tj, tw, w[:, k]) for k in range(6)], axis=1)  # the wrench at the joint stamps
    ratio = noise_sigma(old, RowCfg()) / s_bag  # about 1/sqrt(2): two neighbours averaged
    assert np.all(ratio < 0.85) and ratio.mean() < 0.76


def test_bag_names_what_is_missing(bag):
    msg = err(bag, setup_of(q=ARM, wrench_topic="/ft"))
    assert "'/ft'" in msg and "/ft_sensor/wrench" in msg and "/joint_states" in msg and "log.wrench_topic" in msg
    msg = err(bag, setup_of(q=ARM, joint_state_topic="/ft_sensor/wrench"))
    assert "geometry_msgs/msg/WrenchStamped" in msg and "log.joint_state_topic" in msg
    msg = err(bag, setup_of(q=(*ARM[:6], "panda_joint8")))
    assert "'panda_joint8'" in msg and "'panda_joint1'" in msg and "'panda_finger_joint1'" in msg


# --------------------------------------------------------------------------------------------- validation


def csv_lines(tmp_path: Path, n: int = N) -> tuple[list[str], list[str]]:
    """A valid CSV log's lines (line k of the file is ``lines[k - 1]``) and its header names."""
    t, q, _, w = synth(n)
    path = tmp_path / "src.csv"
    write_log(path, t, q, None, w, DEFAULT.log)
    lines = path.read_text().splitlines()
    return lines, [h.strip('"') for h in lines[0].split(",")]


def put(tmp_path: Path, lines: list[str], name: str = "bad.csv") -> Path:
    path = tmp_path / name
    if name.endswith(".gz"):
        path.write_bytes(gzip.compress(("\n".join(lines) + "\n").encode()))
    else:
        path.write_text("\n".join(lines) + "\n")
    return path


def with_value(lines: list[str], header: list[str], line: int, column: str, value: str) -> list[str]:
    out = list(lines)
    fields = out[line - 1].split(",")
    fields[header.index(column)] = value
    out[line - 1] = ",".join(fields)
    return out


def test_missing_column_is_named_with_the_file_columns(tmp_path):
    lines, header = csv_lines(tmp_path)
    msg = err(put(tmp_path, lines), setup_of(wrench=["fx", "fy", "Fz", "tx", "ty", "tz"]))
    assert "no column 'Fz'" in msg and "log.wrench" in msg and "'fz'" in msg and "'t'" in msg
    msg = err(put(tmp_path, lines), setup_of(time="a", q=list("bcdefgh"), wrench=list("ijklmn")))
    assert SUPPORTED in msg  # nothing matches: perhaps not a header / not a CSV log


@pytest.mark.parametrize("value, words", [("abc", ["'abc', not a number"]), ("", ["empty"]),
                                          ("nan", ["nan", "not finite"]), ("-inf", ["-inf", "not finite"])])
@pytest.mark.parametrize("name", ["bad.csv", "bad.csv.gz"])
def test_bad_values_name_line_and_column(tmp_path, value, words, name):
    lines, header = csv_lines(tmp_path)
    msg = err(put(tmp_path, with_value(lines, header, 101, "q3", value), name))
    assert "line 101" in msg and "'q3'" in msg and all(w in msg for w in words)
    msg = err(put(tmp_path, with_value(lines, header, 7, "t", value), name))
    assert "line 7" in msg and "'t'" in msg


def test_line_numbers_count_blank_lines_and_bad_rows_are_named(tmp_path):
    lines, header = csv_lines(tmp_path)
    bad = with_value(lines, header, 301, "tz", "x")
    bad.insert(10, "")  # a blank line moves every later row down one line
    assert "line 302" in err(put(tmp_path, bad))
    short = list(lines)
    short[6] = ",".join(short[6].split(",")[:-1])
    msg = err(put(tmp_path, short))
    assert "line 7 has 13 fields, the header has 14" in msg and SUPPORTED in msg


def test_time_must_increase(tmp_path):
    lines, header = csv_lines(tmp_path)
    prev = lines[198].split(",")[header.index("t")]
    msg = err(put(tmp_path, with_value(lines, header, 200, "t", prev)))
    assert "line 200" in msg and "does not increase" in msg and "'t'" in msg


def test_a_gap_is_named_with_its_length(tmp_path):
    t, q, _, w = synth()
    t[500:] += 1.0  # a 1.002 s step before row 500 (line 502)
    path = tmp_path / "gap.csv"
    write_log(path, t, q, None, w, DEFAULT.log)
    msg = err(path)
    assert "line 502" in msg and "gap of 1.002 s" in msg and "split" in msg
    pq = tmp_path / "gap.parquet"
    write_log(pq, t, q, None, w, DEFAULT.log)
    assert "sample 500" in err(pq)


def test_too_few_samples_and_empty_files(tmp_path):
    lines, _ = csv_lines(tmp_path)
    msg = err(put(tmp_path, lines[:31]))
    assert "only 30 data rows" in msg and "50" in msg
    assert "empty" in err(put(tmp_path, lines[:1], "header_only.csv"))
    (tmp_path / "nothing.csv").write_text("")
    assert "empty" in err(tmp_path / "nothing.csv")
    (tmp_path / "nothing.csv.gz").write_bytes(gzip.compress(b""))
    assert "empty" in err(tmp_path / "nothing.csv.gz")


def test_parquet_rows_are_samples(tmp_path):
    t, q, _, w = synth()
    q[17, 4] = np.nan
    path = tmp_path / "nan.parquet"
    write_log(path, t, q, None, w, DEFAULT.log)
    msg = err(path)
    assert "sample 17" in msg and "'q5'" in msg and "not finite" in msg


@pytest.mark.parametrize("name", ["junk.csv", "junk.csv.gz", "junk.parquet", "junk.npz", "junk.mcap", "junk.db3",
                                  "junk.txt"])
def test_garbage_and_unknown_formats_list_the_supported_ones(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(np.random.default_rng(0).bytes(4096))
    assert SUPPORTED in err(path)


def test_missing_paths_and_plain_folders(tmp_path):
    assert "not found" in err(tmp_path / "nope.csv")
    (tmp_path / "folder").mkdir()
    msg = err(tmp_path / "folder")
    assert "metadata.yaml" in msg and "trace.npz" in msg and SUPPORTED in msg


def test_bag_without_stamps_or_velocities(tmp_path):
    """Zero header stamps: the record times are used; no velocity field: ``qdot_rad_s`` is None."""
    path = tmp_path / "bag"
    write_bag(path, "MCAP", stamps=False, velocity=False)
    e = expected_from_bag()
    log = read_log(path, setup_of(q=ARM, qdot=[f"v{i}" for i in range(7)]))
    assert log.qdot_rad_s is None
    np.testing.assert_allclose(log.t_s, e.t_s, rtol=0, atol=1e-12)
    np.testing.assert_allclose(log.q_rad, e.q, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(log.wrench_log, e.wrench)


def test_timestamp_time_columns_use_their_own_unit(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    t, q, _, w = synth()
    stamps = (1_700_000_000_000_000_000 + np.arange(N, dtype=np.int64) * 2_000_000).astype("datetime64[ns]")
    data = {"t": pa.array(stamps), **{c: pa.array(q[:, j]) for j, c in enumerate(DEFAULT.log.q)},
            **{c: pa.array(w[:, j]) for j, c in enumerate(DEFAULT.log.wrench)}}
    path = tmp_path / "stamped.parquet"
    pq.write_table(pa.table(data), path)
    np.testing.assert_allclose(read_log(path, DEFAULT).t_s, t, rtol=0, atol=1e-12)
    assert "time_scale_s = 1.0" in err(path, setup_of(time_scale_s=1e-9))
