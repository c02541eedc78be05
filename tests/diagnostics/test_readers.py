"""Log readers for ``kinadapt diagnose --setup``: every format reads back what was written, and every
validation rule is a one-line ``KinadaptError`` naming the file, row and column."""

from __future__ import annotations

import gzip
import time
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.diagnostics.readers import SUPPORTED, read_log, write_log
from kinadapt_nn.diagnostics.setup import LogCfg, SetupCfg
from kinadapt_nn.errors import KinadaptError

N, RATE = 1000, 500.0  # samples, [Hz]
ARM = tuple(f"panda_joint{i}" for i in range(1, 8))


def synth(n: int = N, rate: float = RATE):
    """Smooth sines: t (n,) [s], q, qdot (n, 7) [rad, rad/s], wrench (n, 6) [N, N m]."""
    t = np.arange(n) / rate
    k = np.arange(1, 8)
    q = 0.3 * np.sin(2 * np.pi * 0.4 * k * t[:, None] / 7 + k) + 0.1 * k
    qdot = 0.3 * (2 * np.pi * 0.4 * k / 7) * np.cos(2 * np.pi * 0.4 * k * t[:, None] / 7 + k)
    wrench = wrench_at(t)
    return t, q, qdot, wrench


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


# --------------------------------------------------------------------------------------------- ROS 2 bags

T0_NS = 1_700_000_000_000_000_000
W_OFFSET_NS = 3_300_000  # the wrench starts 3.3 ms after the first joint state ...
W_RATE = 1000.0  # ... at 1 kHz, and ends 0.2 s before the last joint state


def write_bag(path: Path, plugin: str, stamps: bool = True, velocity: bool = True) -> None:
    """Joint states at 500 Hz (and a gripper's), the wrench at 1 kHz, offset; ``stamps=False``
    leaves the header stamps zero (only the bag's record times), ``velocity=False`` empty."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Vec, Wrench = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Wrench"]

    def header(ns: int):
        ns = ns if stamps else 0
        return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="ft")

    t, q, qdot, _ = synth()
    tw = np.arange(int((t[-1] - 0.2) * W_RATE)) / W_RATE + W_OFFSET_NS * 1e-9
    w = wrench_at(tw)
    msgs = []
    for i in range(N):
        ns = T0_NS + i * 2_000_000
        # the joints in another order than the setup's, plus a gripper message between (skipped)
        msg = T["sensor_msgs/msg/JointState"](header=header(ns), name=list(ARM[::-1]), position=q[i, ::-1].copy(),
                                             velocity=qdot[i, ::-1].copy() if velocity else np.zeros(0),
                                             effort=np.zeros(0))
        msgs.append((ns, "/joint_states", msg))
        if i % 10 == 0:
            finger = T["sensor_msgs/msg/JointState"](header=header(ns + 1000), name=["panda_finger_joint1"],
                                                    position=np.zeros(1), velocity=np.zeros(1), effort=np.zeros(0))
            msgs.append((ns + 1000, "/joint_states", finger))
    for i, s in enumerate(tw):
        ns = T0_NS + W_OFFSET_NS + i * 1_000_000
        msg = T["geometry_msgs/msg/WrenchStamped"](header=header(ns), wrench=Wrench(
            force=Vec(x=w[i, 0], y=w[i, 1], z=w[i, 2]), torque=Vec(x=w[i, 3], y=w[i, 4], z=w[i, 5])))
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


def expected_from_bag():
    """(times [s] from the first kept sample, q, qdot, wrench, times [s] of the synthetic log) the bag
    fixture should read as."""
    t, q, qdot, _ = synth()
    t_w = np.arange(int((t[-1] - 0.2) * W_RATE)) / W_RATE + W_OFFSET_NS * 1e-9
    inside = (t >= t_w[0]) & (t <= t_w[-1])  # joint states outside the wrench span are dropped
    w = np.stack([np.interp(t[inside], t_w, wrench_at(t_w)[:, k]) for k in range(6)], axis=1)
    return t[inside] - t[inside][0], q[inside], qdot[inside], w, t[inside]


def test_bag_reads_joint_states_and_the_interpolated_wrench(bag):
    t, q, qdot, w, t_synth = expected_from_bag()
    assert 0 < len(t) < N
    storage = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    for path in (bag, storage):  # the bag folder, or its storage file alone
        setup = setup_of(q=ARM, qdot=[f"v{i}" for i in range(7)])  # any names: use the velocity field
        log = read_log(path, setup)
        assert log.t_s[0] == 0.0
        np.testing.assert_allclose(log.t_s, t, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(log.q_rad, q)
        np.testing.assert_array_equal(log.qdot_rad_s, qdot)
        np.testing.assert_allclose(log.wrench_log, w, rtol=0, atol=1e-9)  # the linear interpolation
        np.testing.assert_allclose(log.wrench_log, wrench_at(t_synth), rtol=0, atol=1e-3)  # the true wrench
    assert read_log(bag, setup_of(q=ARM)).qdot_rad_s is None  # no velocities asked for


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
    t, q, _, w, _ = expected_from_bag()
    log = read_log(path, setup_of(q=ARM, qdot=[f"v{i}" for i in range(7)]))
    assert log.qdot_rad_s is None
    np.testing.assert_allclose(log.t_s, t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(log.q_rad, q)
    np.testing.assert_allclose(log.wrench_log, w, rtol=0, atol=1e-9)


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
