"""ROS 2 bags: a folder with ``metadata.yaml``, or a ``.mcap`` / ``.db3`` file (read with ``rosbags``).

``sensor_msgs/msg/JointState`` on ``log.joint_state_topic`` (``log.q`` are joint names; the
``velocity`` field is used when ``log.qdot`` is non-empty and every message has it, else
``qdot_rad_s`` is None) and ``geometry_msgs/msg/WrenchStamped`` on ``log.wrench_topic``. Time is
the header stamp (the bag's record time when a stream's stamps are all zero). Joint-state
messages that do not name all the declared joints (e.g. a gripper's) are skipped. The units
apply as declared (REP 103 says rad, N and N m). The two streams run on their own clocks; each
must be finite, strictly increasing and free of gaps. The wrench stream is the master clock:
its samples are kept as recorded (interpolating them would average neighbouring noisy samples
and understate the sensor noise), the joint states (positions and velocities, smooth signals)
and the ``[log] extra`` ``TOPIC:FIELD`` values are linearly interpolated onto the wrench stamps,
and wrench samples outside the joint-state stream's time span are dropped. A static log's
streams are checked the same way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from kinadapt_nn.diagnostics.readers.base import (GAP_FACTOR, Label, LogReader, UserLog, assemble_columns, clean,
                                                  first_line, layout, list_names, unreadable)
from kinadapt_nn.errors import KinadaptError

if TYPE_CHECKING:
    from kinadapt_nn.diagnostics.setup import LogCfg

_JOINT_STATE = "sensor_msgs/msg/JointState"
_WRENCH = "geometry_msgs/msg/WrenchStamped"
_WRENCH_NAMES = ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")


@dataclass
class _BagMessages:
    """What a bag holds on the setup's topics, message by message, in record order."""

    js_head: list[int] = dc_field(default_factory=list)  # joint states: header stamp [ns]
    js_rec: list[int] = dc_field(default_factory=list)  # record time [ns]
    js_names: list[tuple[str, ...]] = dc_field(default_factory=list)
    js_pos: list[np.ndarray] = dc_field(default_factory=list)
    js_vel: list[np.ndarray] = dc_field(default_factory=list)
    w_head: list[int] = dc_field(default_factory=list)  # wrench: header stamp [ns]
    w_rec: list[int] = dc_field(default_factory=list)  # record time [ns]
    w_val: list[tuple[float, ...]] = dc_field(default_factory=list)  # (fx, fy, fz, tx, ty, tz)
    ex_t: dict[str, list[int]] = dc_field(default_factory=dict)  # [log] extra name -> stamps [ns]
    ex_v: dict[str, list[float]] = dc_field(default_factory=dict)  # [log] extra name -> values


def _stamps(header_ns: list[int], record_ns: list[int]) -> np.ndarray:
    """Header stamps [ns] (int64); the bag's record times when a stream never fills its stamps."""
    return np.asarray(record_ns if header_ns and not any(header_ns) else header_ns, dtype=np.int64)


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _extra_topics(log: LogCfg) -> dict[str, list[tuple[str, list[str]]]]:
    """``[log] extra`` in a bag: topic -> [(the column's name, its dotted field's parts)]."""
    topics: dict[str, list[tuple[str, list[str]]]] = {}
    for name in log.extra:  # "TOPIC:FIELD" (a dotted field of the topic's messages)
        topic, _, fld = name.rpartition(":")
        if not topic or not fld:
            raise KinadaptError(f"[log] extra '{name}': in a ROS 2 bag an extra column is 'TOPIC:FIELD' "
                                "(e.g. '/sensor/temperature:temperature'); fix the setup")
        topics.setdefault(topic, []).append((name, fld.split(".")))
    return topics


def _check_topics(path: Path, have: dict[str, str], want: list[tuple[str, str, str]], extra_topics) -> None:
    listing = ", ".join(f"{clean(t, 60)} [{clean(m, 60)}]" for t, m in sorted(have.items())) or "none"
    for topic in extra_topics:
        if topic not in have:
            raise KinadaptError(f"ROS 2 bag '{path}' has no topic '{topic}' ([log] extra in the setup); its "
                                f"topics: {listing}; fix [log] extra")
    for topic, msgtype, key in want:
        if topic not in have:
            raise KinadaptError(f"ROS 2 bag '{path}' has no topic '{topic}' ({key} in the setup); its topics: "
                                f"{listing}; set {key}")
        if have[topic] != msgtype:
            raise KinadaptError(f"ROS 2 bag '{path}': topic '{topic}' ({key}) carries "
                                f"{clean(have[topic], 60)}, not {msgtype}; set {key} to a {msgtype} "
                                f"topic (its topics: {listing})")


def _add_extra(path: Path, m: _BagMessages, msg, topic: str, rec_ns: int, columns) -> None:
    """The ``[log] extra`` values of one message on ``topic``."""
    hdr = getattr(msg, "header", None)
    st = _ns(hdr.stamp) if hdr is not None else 0
    for name, parts in columns:
        v = msg
        for a in parts:
            if not hasattr(v, a):
                raise KinadaptError(f"ROS 2 bag '{path}': messages on '{topic}' have no field "
                                    f"'{'.'.join(parts)}' ([log] extra '{name}'); fix [log] extra")
            v = getattr(v, a)
        try:
            m.ex_v[name].append(float(v))
        except (TypeError, ValueError):
            raise KinadaptError(f"ROS 2 bag '{path}': field '{'.'.join(parts)}' on '{topic}' is "
                                f"not a number ([log] extra '{name}')") from None
        m.ex_t[name].append(st or int(rec_ns))


def _bag_messages(path: Path, log: LogCfg) -> _BagMessages:
    """Every message on the setup's topics (one-line errors for a missing topic or a damaged bag)."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise KinadaptError("reading ROS 2 bags needs the 'rosbags' package (pip install rosbags)") from None

    want = [(log.joint_state_topic, _JOINT_STATE, "log.joint_state_topic"),
            (log.wrench_topic, _WRENCH, "log.wrench_topic")]
    streams = {w[:2] for w in want}
    extra_topics = _extra_topics(log)
    m = _BagMessages(ex_t={n: [] for n in log.extra}, ex_v={n: [] for n in log.extra})
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            have: dict[str, str] = {}
            for c in reader.connections:
                have.setdefault(c.topic, c.msgtype)
            _check_topics(path, have, want, extra_topics)
            conns = [c for c in reader.connections if (c.topic, c.msgtype) in streams or c.topic in extra_topics]
            for conn, rec_ns, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic in extra_topics:
                    _add_extra(path, m, msg, conn.topic, rec_ns, extra_topics[conn.topic])
                if (conn.topic, conn.msgtype) not in streams:
                    continue
                if conn.msgtype == _JOINT_STATE:
                    m.js_head.append(_ns(msg.header.stamp))
                    m.js_rec.append(int(rec_ns))
                    m.js_names.append(tuple(msg.name))
                    m.js_pos.append(np.asarray(msg.position, dtype=np.float64))
                    m.js_vel.append(np.asarray(msg.velocity, dtype=np.float64))
                else:
                    f, t = msg.wrench.force, msg.wrench.torque
                    m.w_head.append(_ns(msg.header.stamp))
                    m.w_rec.append(int(rec_ns))
                    m.w_val.append((f.x, f.y, f.z, t.x, t.y, t.z))
    except KinadaptError:
        raise
    except Exception as exc:  # noqa: BLE001 -- any failure of the bag library on a damaged file is bad input
        raise unreadable(path, "ROS 2 bag", first_line(exc)) from None
    for topic, n_msgs in ((log.joint_state_topic, len(m.js_head)), (log.wrench_topic, len(m.w_head))):
        if n_msgs == 0:
            raise KinadaptError(f"ROS 2 bag '{path}' has no messages on '{topic}'; record that topic")
    return m


class _Stream(NamedTuple):
    """One topic's samples on its own clock."""

    t_ns: np.ndarray  # (M,) int64 [ns] stamps
    values: np.ndarray  # (M, k) float
    src: list[int]  # (M,) the message index on the topic of each sample (for messages)


def _joint_stream(path: Path, log: LogCfg, m: _BagMessages) -> tuple[_Stream, int]:
    """The joint-state messages that name every declared joint -> (stream of q (dof) and, when asked
    for and present in every such message, qdot (dof); n_qdot = 0 or dof)."""
    index: dict[tuple[str, ...], list[int] | None] = {}
    keep, rows, vels = [], [], []
    for i, names in enumerate(m.js_names):
        if names not in index:
            index[names] = [names.index(j) for j in log.q] if all(j in names for j in log.q) else None
        idx = index[names]
        if idx is None or len(m.js_pos[i]) != len(names):
            continue
        keep.append(i)
        rows.append(m.js_pos[i][idx])
        vels.append(m.js_vel[i][idx] if len(m.js_vel[i]) == len(names) else None)
    if not keep:
        seen = list(dict.fromkeys(j for names in index for j in names))
        missing = next((j for j in log.q if j not in seen), log.q[0])
        raise KinadaptError(f"ROS 2 bag '{path}': no message on '{log.joint_state_topic}' has positions for joint "
                            f"'{missing}' (log.q in the setup); its joint names: {list_names(seen)}; set log.q to "
                            "the arm's joints")
    t = _stamps([m.js_head[i] for i in keep], [m.js_rec[i] for i in keep])
    q = np.array(rows)  # (M, dof)
    if log.qdot and all(v is not None for v in vels):
        return _Stream(t, np.hstack([q, np.array(vels)]), keep), q.shape[1]
    return _Stream(t, q, keep), 0


def _check_stream(path: Path, s: _Stream, names: Sequence[str], topic: str, what: str) -> None:
    """A bag stream on its own clock: at least two samples, finite, strictly increasing, no gaps."""
    at = lambda k: f"ROS 2 bag '{path}', {what} sample {s.src[k]} on '{topic}'"  # noqa: E731
    if len(s.t_ns) < 2:
        raise KinadaptError(f"ROS 2 bag '{path}' has only {len(s.t_ns)} {what} message on '{topic}'; "
                            "record it during the whole log")
    bad = np.flatnonzero(~np.isfinite(s.values).all(axis=1))
    if bad.size:
        r = int(bad[0])
        j = int(np.flatnonzero(~np.isfinite(s.values[r]))[0])
        raise KinadaptError(f"{at(r)}: {names[j]} is {s.values[r, j]} (not finite); filter the bag")
    dt = np.diff(s.t_ns)
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise KinadaptError(f"{at(k)}: the header stamp does not increase; the {what} stamps must be strictly "
                            "increasing")
    med = float(np.median(dt))
    if np.any(dt > GAP_FACTOR * med):
        k = int(np.flatnonzero(dt > GAP_FACTOR * med)[0]) + 1
        raise KinadaptError(f"{at(k)}: a gap of {dt[k - 1] * 1e-9:.4g} s (the median step is {med * 1e-9:.4g} s); "
                            "split the log at the gap")


def _onto(t_new: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of (M, k) ``values`` at (M,) times ``t`` onto (N,) ``t_new`` -> (N, k)."""
    return np.stack([np.interp(t_new, t, values[:, k]) for k in range(values.shape[1])], axis=1)


def _extra_onto(path: Path, log: LogCfg, m: _BagMessages, origin: int, tw_ns: np.ndarray) -> list[np.ndarray]:
    """Each ``[log] extra`` value interpolated onto the wrench stamps -> [(N, 1)]."""
    out = []
    for name in log.extra:
        te, ve = np.asarray(m.ex_t[name], dtype=np.int64), np.asarray(m.ex_v[name], dtype=np.float64)
        if len(te) < 2:
            raise KinadaptError(f"ROS 2 bag '{path}' has {len(te)} message(s) for [log] extra '{name}'; "
                                "record it during the whole log")
        order = np.argsort(te, kind="stable")
        out.append(np.interp(tw_ns, (te[order] - origin).astype(np.float64), ve[order])[:, None])
    return out


def read(path: Path, log: LogCfg) -> UserLog:
    """A ROS 2 bag (module docstring) -> ``UserLog``: both streams validated on their own clocks, the
    wrench stamps the master clock; one-line ``KinadaptError`` otherwise."""
    m = _bag_messages(path, log)
    joints, n_qdot = _joint_stream(path, log, m)
    j_names = [*log.q, *(f"{j} velocity" for j in log.q[: n_qdot])]
    _check_stream(path, joints, j_names, log.joint_state_topic, "joint-state")
    wrench = _Stream(_stamps(m.w_head, m.w_rec), np.array(m.w_val, dtype=np.float64), list(range(len(m.w_head))))
    _check_stream(path, wrench, _WRENCH_NAMES, log.wrench_topic, "wrench")
    t_j, t_w = joints.t_ns, wrench.t_ns
    inside = np.flatnonzero((t_w >= t_j[0]) & (t_w <= t_j[-1]))  # wrench samples the joint states span
    if inside.size == 0:
        o = min(int(t_j[0]), int(t_w[0]))
        raise KinadaptError(
            f"ROS 2 bag '{path}': the joint states ({(t_j[0] - o) * 1e-9:.3f} to {(t_j[-1] - o) * 1e-9:.3f} s) and "
            f"the wrench ({(t_w[0] - o) * 1e-9:.3f} to {(t_w[-1] - o) * 1e-9:.3f} s) do not overlap in time; "
            "check both topics' header stamps")
    origin = int(t_w[inside[0]])
    tw_ns = (t_w[inside] - origin).astype(np.float64)  # (N,) [ns] the master clock
    joints_at = _onto(tw_ns, (t_j - origin).astype(np.float64), joints.values)  # (N, dof + n_qdot)
    cols = np.hstack([joints_at, wrench.values[inside], *_extra_onto(path, log, m, origin, tw_ns)])
    names = [*j_names, *_WRENCH_NAMES, *log.extra]
    label: Label = lambda i: f"wrench sample {inside[i]}"  # noqa: E731
    return assemble_columns(path, t_w[inside], 1e-9, cols, layout(log, names, n_qdot), label, "header stamp")



READER = LogReader("bag", "a ROS 2 bag (a folder with metadata.yaml, .mcap, .db3)", "a ROS 2 bag", read,
                   suffixes=(".mcap", ".db3"), folder_files=("metadata.yaml",))
