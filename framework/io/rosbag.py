"""ROS 2 bags in: a rosbag2 recording (MCAP or sqlite3 storage) as a stream recording.

:func:`read_bag` reads the profiles and the flange poses a ROS 2 cell recorded and gives
a :class:`~spherecal.core.streams.Recording` (which
:func:`spherecal.io.streams.write_recording` writes in the stream format, so everything
downstream reads one kind of file). It needs no ROS installation: the ``rosbags``
package reads both storages in pure Python.

What it reads (REP 103: metres, radians, quaternions (x, y, z, w), scalar **last**):

- profiles: ``sensor_msgs/msg/PointCloud2``, one message per profile, x, y, z FLOAT32 (or
  FLOAT64) in metres in the sensor frame. The laser plane is the sensor's x = 0 plane:
  (y, z) becomes the profile's (y, z) in mm and x must be 0. A driver that puts the line
  along x gives ``line_axis="x"``: (x, z) becomes (y, z) and y must be 0; the calibrated
  sensor frame is then not the cloud's frame: ``sensor_from_cloud = Rz(+90 deg)``
  (y_sensor = x_cloud, x_sensor = -y_cloud; :mod:`spherecal.io.bag_frames`). Points
  are decoded with NumPy from ``data``, ``point_step`` and the fields' offsets; the
  message's fixed layout is read with ``struct``, not through a generic deserialiser,
  because ten thousand clouds a minute must convert at tens of millions of points a
  second.
- poses, one of:
  ``geometry_msgs/msg/PoseStamped`` (base_from_flange, position in m, orientation
  (x, y, z, w)); ``tf2_msgs/msg/TFMessage`` with ``base_frame`` and ``flange_frame``
  named (the chain between them composed from the dynamic transforms on the pose topic
  and the static ones on ``/tf_static``); ``sensor_msgs/msg/JointState`` (radians)
  mapped to flange poses by ``joints_to_pose``, a callable the application passes (the
  robot plugin's forward kinematics: joints in degrees (n, J) -> base_from_flange
  rotations (n, 3, 3) and translations (n, 3) mm).
- the stamps: every message's ``header.stamp``, never the bag's log time (when the
  recording computer received it). The profile stamps are the sensor clock's, the pose
  stamps the robot clock's (the time model relates them).

Bad input raises a :class:`BagError` subclass naming the cause (:class:`BagTopicError`,
:class:`BagUnitsError`, :class:`BagCloudError`, :class:`BagStampError`,
:class:`BagTimeSpanError`, :class:`BagCutShortError`); a wrong argument raises
:class:`InputError`. What needs attention but does not stop the conversion is a
:class:`BagWarning`: some profiles outside the pose stream's time span, invalid points
dropped from clouds that say they have some (``is_dense`` false), both streams stamped by
the recording computer's clock (:class:`SameClockWarning`: no drift between them can be
seen).
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import InputError
from spherecal.core.streams import PoseStream, ProfileStream, Recording
from spherecal.io.bag_frames import SENSOR_FROM_CLOUD_TEXT
from spherecal.io.mcap_scan import NotPlain, scan_messages
from spherecal.io.rosbag_cut import cut_short_text
from spherecal.io.stream_fields import _check_mounting_radius

from spherecal.io.rosbag_messages import (
    _check_stamps,
    _seconds,
    PROFILE_TYPE,
    POSE_STAMPED,
    TF_MESSAGE,
    JOINT_STATE,
    POSE_TYPES,
    MAX_FLANGE_DISTANCE_M,
    MAX_OUTSIDE_FRACTION,
    BagError,
    BagCutShortError,
    BagTopicError,
    BagUnitsError,
    BagCloudError,
    BagStampError,
    BagTimeSpanError,
    BagWarning,
    SameClockWarning,
    _CloudParser,
    _parse_pose_stamped,
    _typestore,
    _cloud_from_typestore,
    _CloudDecoder,
)


__all__ = [
    "BagCloudError",
    "BagCutShortError",
    "BagError",
    "BagStampError",
    "BagTimeSpanError",
    "BagTopicError",
    "BagUnitsError",
    "BagWarning",
    "SameClockWarning",
    "read_bag",
    "PROFILE_TYPE",
    "POSE_TYPES",
]

# ---------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------


@dataclass
class _Topic:
    name: str
    msgtype: str
    connections: list = field(default_factory=list)
    count: int = 0


def _open(path: Path, name: str):
    try:
        from rosbags.rosbag2 import Reader
        from rosbags.rosbag2.errors import ReaderError
    except ImportError:  # pragma: no cover - a dependency
        raise InputError("reading ROS 2 bags needs the rosbags package: pip install rosbags") from None
    if not path.exists():
        raise BagError(f"{name}: no such file or folder")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise BagError(f"{name}: a folder without metadata.yaml, not a rosbag2 recording (give the bag's folder, "
                       "or its .mcap or .db3 file)")
    if path.is_file() and path.suffix not in (".mcap", ".db3"):
        raise BagError(f"{name}: not a rosbag2 recording: a bag is a folder with metadata.yaml, or a .mcap or .db3 "
                       "file")
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError, ValueError, KeyError) as exc:
        raise _unreadable(path, name, "cannot read the bag", exc) from None
    return reader


def _unreadable(path: Path, name: str, what: str, exc: Exception) -> BagError:
    """The error for a bag the storage library refuses: a storage file cut short (a
    recording interrupted) says so and names the repair; other damage is the library's word."""
    text = cut_short_text(path, name, str(exc))
    return BagCutShortError(text) if text else BagError(f"{name}: {what} ({exc})")


def _messages(reader, connections, name: str, path: Path):
    """The reader's messages; a damaged storage file is a BagError naming the bag."""
    from rosbags.rosbag2.errors import ReaderError

    try:
        yield from reader.messages(connections=connections)
    except (ReaderError, OSError, ValueError, KeyError) as exc:
        raise _unreadable(path, name, "cannot read the bag's messages", exc) from None


def _mcap_files(path: Path) -> list[Path]:
    """The MCAP files of a bag in recording order (``name_0.mcap``, ``name_1.mcap``, ...),
    none for sqlite3 storage."""
    if path.is_file():
        return [path] if path.suffix == ".mcap" else []
    if any(path.glob("*.db3")):
        return []

    def order(p: Path):
        stem, _, index = p.stem.rpartition("_")
        return (stem, int(index)) if index.isdigit() else (p.stem, -1)

    return sorted(path.glob("*.mcap"), key=order)


def _topics_text(topics: dict[str, _Topic]) -> str:
    if not topics:
        return "the bag has no topics"
    return "the bag has: " + "; ".join(f"{t.name} ({t.msgtype}, {t.count} messages)" for _, t in sorted(topics.items()))


def read_bag(
    path: str | os.PathLike,
    *,
    profile_topic: str,
    pose_topic: str,
    mounting: str,
    sphere_radius_mm: float,
    line_axis: Literal["y", "x"] = "y",
    base_frame: str | None = None,
    flange_frame: str | None = None,
    joints_to_pose: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
    joint_names: Sequence[str] | None = None,
    tf_static_topic: str = "/tf_static",
) -> Recording:
    """A rosbag2 recording (a folder with ``metadata.yaml``, or one ``.mcap`` or ``.db3``
    file) as a :class:`Recording` (see the module docstring for what is read and how).

    ``profile_topic``: PointCloud2, one profile per message. ``pose_topic``: PoseStamped,
    TFMessage (give ``base_frame`` and ``flange_frame``; static transforms are read from
    ``tf_static_topic`` when the bag has it) or JointState (give ``joints_to_pose``;
    ``joint_names``, the arm's joints in the order ``joints_to_pose`` takes them, picks
    them out of each message by name, extra joints left out; messages without them, from
    another publisher on the topic, are skipped, and none with them is a
    :class:`BagTopicError` listing both sets of names. Without ``joint_names`` the joints
    are the first message's, in its order, with a :class:`BagWarning` saying so).
    ``base_frame`` and ``flange_frame`` given with other pose types name those frames in
    the provenance (``base_frame_id``, ``flange_frame_id``: the ROS exports' frames) where
    the messages name none; a PoseStamped's ``header.frame_id`` must be ``base_frame``.
    ``mounting`` and ``sphere_radius_mm`` are the calibration's, which a bag does not
    record. The recording's clocks are named after the topics, or both
    ``"recording computer"`` when their stamps show one clock (:class:`SameClockWarning`).
    """
    name = os.fspath(path)
    problem = _check_mounting_radius(mounting, sphere_radius_mm)
    if problem:
        raise InputError(f"{name}: {problem}")
    if line_axis not in ("y", "x"):
        raise InputError(f"line_axis must be 'y' (the laser line along the cloud's y, the default) or 'x', "
                         f"got {line_axis!r}")
    reader = _open(Path(path), name)
    try:
        topics: dict[str, _Topic] = {}
        for c in reader.connections:
            t = topics.setdefault(c.topic, _Topic(c.topic, c.msgtype))
            t.connections.append(c)
            t.count += c.msgcount
        prof = _require_topic(topics, profile_topic, (PROFILE_TYPE,), name, "profile")
        pose = _require_topic(topics, pose_topic, POSE_TYPES, name, "pose")
        if pose.msgtype == TF_MESSAGE and (not base_frame or not flange_frame):
            raise InputError(f"{name}: {pose_topic} holds transforms (tf2_msgs/msg/TFMessage): name the two frames "
                             "of the flange pose, base_frame (e.g. base_link) and flange_frame (e.g. tool0)")
        if pose.msgtype == JOINT_STATE and joints_to_pose is None:
            raise InputError(f"{name}: {pose_topic} holds joint states (sensor_msgs/msg/JointState): they need the "
                             "robot's kinematics to become flange poses (spherecal solve --robot TYPE)")
        static = topics.get(tf_static_topic) if pose.msgtype == TF_MESSAGE else None
        if static is not None and static.msgtype != TF_MESSAGE:
            static = None
        wanted = prof.connections + pose.connections + (static.connections if static else [])
        counts = {t.name: t.count for t in (prof, pose, static) if t is not None}
        try:
            if reader.compression_mode not in (None, "", "none", "storage"):
                raise NotPlain  # each message compressed, or the whole file: rosbags undoes that
            taken = _take(scan_messages(_mcap_files(Path(path)), counts), name, profile_topic, pose_topic, line_axis,
                          prof.count)
        except NotPlain:
            taken = _take(((c.topic, log, raw) for c, log, raw in _messages(reader, wanted, name, Path(path))), name,
                          profile_topic, pose_topic, line_axis, prof.count)
        decoder, pose_raw, pose_log, static_raw = taken
    finally:
        reader.close()

    if not decoder.meta:
        raise BagCloudError(f"{name}: {profile_topic} has no messages")
    t_sensor, profiles, start, cloud_info = decoder.finish()
    log_pose = np.asarray(pose_log, np.int64)
    if pose.msgtype == POSE_STAMPED:
        t_robot, R, t_mm, joints, pose_info, log_pose = _poses_from_pose_stamped(pose_raw, log_pose, name, pose_topic,
                                                                                 base_frame)
    elif pose.msgtype == TF_MESSAGE:
        t_robot, R, t_mm, joints, pose_info, log_pose = _poses_from_tf(pose_raw, log_pose, static_raw, name, pose_topic,
                                                                       tf_static_topic, base_frame, flange_frame)
    else:
        t_robot, R, t_mm, joints, pose_info, log_pose = _poses_from_joints(pose_raw, log_pose, name, pose_topic,
                                                                           joints_to_pose, joint_names)
    if len(t_robot) < 2:
        raise BagTopicError(f"{name}: {pose_topic} gives {len(t_robot)} flange poses; a recording needs at least 2")
    _check_flange_units(t_mm, name, pose_topic)
    clocks, clock_info = _clocks(t_sensor, np.asarray(decoder.log_ns, np.int64), t_robot, log_pose, profile_topic,
                                 pose_topic, name)
    overlap = t_sensor[0] <= t_robot[-1] and t_robot[0] <= t_sensor[-1]
    if clock_info["same_clock"] or overlap:
        # one clock (or one epoch): a profile outside the poses' span has no pose. Spans
        # on two clocks that do not meet say nothing yet (one may count from 1970, the
        # other from power-on): the solve searches the offset and names what stays outside.
        _check_time_spans(t_sensor, t_robot, name, profile_topic, pose_topic)
    provenance = {
        "source": "rosbag2",
        "bag": os.path.abspath(name),
        "profile_topic": profile_topic,
        "profile_type": PROFILE_TYPE,
        "pose_topic": pose_topic,
        "pose_type": pose.msgtype,
        "line_axis": line_axis,
        **({"sensor_from_cloud_frame": SENSOR_FROM_CLOUD_TEXT[line_axis]} if line_axis in SENSOR_FROM_CLOUD_TEXT
           else {}),
        **cloud_info,
        # the frames given for the exports' names where the messages name none (a PoseStamped's
        # flange, a JointState's base and flange)
        **{k: v.lstrip("/") for k, v in (("base_frame_id", base_frame), ("flange_frame_id", flange_frame)) if v},
        **pose_info,
        "clock_check": clock_info,
    }
    poses = PoseStream(t_robot, R, t_mm, joints)
    return Recording(mounting=mounting, sphere_radius_mm=float(sphere_radius_mm), poses=poses,
                     profiles=ProfileStream(t_sensor, profiles, start), sweeps=[], provenance=provenance,
                     clocks=clocks)


def _take(messages, name: str, profile_topic: str, pose_topic: str, line_axis: str, n_profiles: int):
    """(cloud decoder, pose messages, their log times, static transform messages) of the
    bag's messages, (topic, log time ns, CDR bytes) in each topic's log-time order."""
    parse_cloud = _CloudParser()
    decoder = _CloudDecoder(name, profile_topic, line_axis, n_profiles)
    pose_raw: list[bytes] = []
    pose_log: list[int] = []
    static_raw: list[bytes] = []
    before = {profile_topic: None, pose_topic: None}  # each topic's message before, as read
    seen = dict.fromkeys(before, 0)
    dropped: dict[str, list[tuple[int, float]]] = {profile_topic: [], pose_topic: []}  # (index, log time s)
    for topic, log_ns, raw in messages:
        if topic in before:
            # a message read twice (a recorder subscribed twice, a replay recorded): the same
            # bytes, stamp and all, as the message before it on its topic; the stamp (bytes
            # 4 to 12 after the CDR header) tells most messages apart without comparing the rest
            last = before[topic]
            k = seen[topic]
            seen[topic] = k + 1
            if last is not None and len(last) == len(raw) and last[4:12] == raw[4:12] and last == raw:
                dropped[topic].append((k, log_ns / 1e9))
                continue
            before[topic] = raw
        if topic == profile_topic:
            try:
                cloud = parse_cloud(raw)
            except Exception as exc:  # noqa: BLE001 - big-endian or unusual (struct.error, ValueError...)
                cloud, raw = _cloud_from_typestore(bytes(raw), exc, name, profile_topic, len(decoder.meta))
            decoder.add(raw, cloud, log_ns)
        elif topic == pose_topic:
            pose_raw.append(bytes(raw))
            pose_log.append(log_ns)
        else:
            static_raw.append(bytes(raw))
    for topic, drops in dropped.items():
        if drops:
            k, log_s = drops[0]
            warnings.warn(f"{name}: {topic}: dropped {len(drops)} exact duplicate messages (each byte for byte the message "
                          f"before it on the topic, header stamp and all; the first: message {k} of "
                          f"{seen[topic]}, bag log time {log_s:.6f} s); later messages are numbered without them",
                          BagWarning, stacklevel=3)
    return decoder, pose_raw, pose_log, static_raw


def _require_topic(topics: dict[str, _Topic], topic: str, types: tuple[str, ...], name: str, what: str) -> _Topic:
    t = topics.get(topic)
    if t is None:
        raise BagTopicError(f"{name}: no topic {topic!r} (the {what} topic); {_topics_text(topics)}")
    if t.msgtype not in types:
        expected = " or ".join(types)
        raise BagTopicError(f"{name}: {topic} holds {t.msgtype}; the {what} topic must hold {expected}. "
                            f"{_topics_text(topics)[0].upper()}{_topics_text(topics)[1:]}")
    if t.count == 0:
        raise BagTopicError(f"{name}: {topic} ({t.msgtype}) has no messages")
    return t


def _check_flange_units(t_mm: np.ndarray, name: str, topic: str) -> None:
    typical_m = float(np.median(np.linalg.norm(t_mm, axis=1))) / 1000.0
    if typical_m > MAX_FLANGE_DISTANCE_M:
        raise BagUnitsError(f"{name}: {topic}: the flange positions look like millimetres, not metres: typically "
                            f"{typical_m:.4g} from the base (more than {MAX_FLANGE_DISTANCE_M:g} m). ROS poses are in "
                            "metres (REP 103)")


def _quaternions_wxyz(q_xyzw: np.ndarray, name: str, topic: str) -> np.ndarray:
    """ROS (x, y, z, w) -> our (w, x, y, z), unit to 1e-3 (normalised), w >= 0."""
    norm = np.linalg.norm(q_xyzw, axis=1)
    bad = np.flatnonzero(~(np.abs(norm - 1.0) <= 1e-3))
    if bad.size:
        i = int(bad[0])
        raise BagUnitsError(f"{name}: {topic}: message {i}: orientation (x, y, z, w) {q_xyzw[i].tolist()} is not a "
                            f"unit quaternion (norm {norm[i]:.6g})")
    q = geo.quat_wxyz_from_xyzw(q_xyzw / norm[:, None])
    return np.where(q[:, :1] < 0, -q, q)


def _pose_stamped_block(raws):
    """(sec, nanosec, frame ids, (n, 7) values) of PoseStamped messages that all share one
    layout (little-endian CDR, one frame id, one length), read at once; None otherwise."""
    n = len(raws)
    if not n or len({len(r) for r in raws}) != 1:
        return None
    try:
        _, _, frame, _ = _parse_pose_stamped(raws[0])
    except Exception:  # noqa: BLE001 - the message by message reading says what is wrong
        return None
    size = len(raws[0])
    at = _align_8(12 + 4 + len(frame.encode("utf-8")) + 1)
    if at + 56 != size:
        return None
    a = np.frombuffer(b"".join(raws), np.uint8).reshape(n, size)
    if not (a[:, 0:4] == a[0, 0:4]).all() or not (a[:, 12:at] == a[0, 12:at]).all() or bytes(a[0, :2]) != b"\x00\x01":
        return None
    sec = a[:, 4:8].copy().view("<i4")[:, 0].astype(np.int64)
    nsec = a[:, 8:12].copy().view("<u4")[:, 0].astype(np.int64)
    vals = a[:, at:at + 56].copy().view("<f8").astype(np.float64)
    return sec, nsec, {frame}, vals


def _align_8(p: int) -> int:
    """A message offset (4 bytes of encapsulation header first) aligned to 8 in the payload."""
    return 4 + ((p - 4 + 7) & ~7)


def _poses_from_pose_stamped(raws, log_ns, name, topic, base_frame):
    block = _pose_stamped_block(raws)
    if block is not None:  # one driver's messages, all alike: read at once
        sec, nsec, frames, vals = block
    else:
        sec, nsec, frames, vals = _pose_stamped_one_by_one(raws, name, topic)
    if not np.all(np.isfinite(vals)):
        i = int(np.flatnonzero(~np.isfinite(vals).all(axis=1))[0])
        raise BagTopicError(f"{name}: {topic}: message {i} has a non-finite pose {vals[i].tolist()}")
    if len(frames) > 1:
        raise BagTopicError(f"{name}: {topic}: poses in {len(frames)} frames ({', '.join(sorted(map(repr, frames)))}); "
                            "the flange poses must all be in the robot's base frame")
    frame = next(iter(frames))
    if base_frame and frame != base_frame:
        raise BagTopicError(f"{name}: {topic}: the poses are in frame {frame!r}, not base_frame {base_frame!r}")
    ns = sec * 1_000_000_000 + nsec
    _check_stamps(ns, log_ns, name, topic, "poses")
    q = _quaternions_wxyz(vals[:, 3:], name, topic)
    return (_seconds(sec, nsec), geo.matrix_from_quat_wxyz(q), vals[:, :3] * 1000.0, None,
            {"base_frame_id": frame}, log_ns)


def _pose_stamped_one_by_one(raws, name, topic):
    n = len(raws)
    vals = np.empty((n, 7))
    sec = np.empty(n, np.int64)
    nsec = np.empty(n, np.int64)
    frames = set()
    ts = None
    for i, raw in enumerate(raws):
        try:
            s, ns_, frame, v = _parse_pose_stamped(raw)
        except Exception:  # noqa: BLE001 - big-endian or damaged: the generic deserialiser says which
            ts = ts or _typestore()
            try:
                msg = ts.deserialize_cdr(raw, POSE_STAMPED)
            except Exception as exc:  # noqa: BLE001
                raise BagTopicError(f"{name}: {topic}: message {i} is not a readable PoseStamped ({exc})") from None
            p, o = msg.pose.position, msg.pose.orientation
            s, ns_, frame, v = msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id, \
                (p.x, p.y, p.z, o.x, o.y, o.z, o.w)
        sec[i], nsec[i] = s, ns_
        vals[i] = v
        frames.add(frame)
    return sec, nsec, frames, vals


def _poses_from_tf(raws, log_ns, static_raws, name, topic, static_topic, base_frame, flange_frame):
    """base_from_flange from the transform tree: the dynamic transforms on ``topic``, the
    static ones on ``static_topic``, composed along the chain between the two frames."""
    ts = _typestore()
    dynamic: dict[tuple[str, str], list[tuple[int, int, tuple[float, ...]]]] = {}
    static: dict[tuple[str, str], tuple[float, ...]] = {}
    parent_of: dict[str, str] = {}

    def edges(raw_list, label, into_static, logs):
        for i, raw in enumerate(raw_list):
            try:
                msg = ts.deserialize_cdr(raw, TF_MESSAGE)
            except Exception as exc:  # noqa: BLE001
                raise BagTopicError(f"{name}: {label}: message {i} is not a readable TFMessage ({exc})") from None
            for tr in msg.transforms:
                parent, child = tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/")
                if parent_of.setdefault(child, parent) != parent:
                    raise BagTopicError(f"{name}: {label}: frame {child!r} has two parents, {parent_of[child]!r} and "
                                        f"{parent!r}: not a tree")
                x, r = tr.transform.translation, tr.transform.rotation
                v = (x.x, x.y, x.z, r.x, r.y, r.z, r.w)
                if into_static:
                    static[(parent, child)] = v
                else:
                    ns = int(tr.header.stamp.sec) * 1_000_000_000 + int(tr.header.stamp.nanosec)
                    dynamic.setdefault((parent, child), []).append((ns, logs[i], v))

    edges(static_raws, static_topic, True, None)
    edges(raws, topic, False, log_ns)
    base, flange = base_frame.lstrip("/"), flange_frame.lstrip("/")
    known = set(parent_of) | set(parent_of.values())
    for f, label in ((base, "base_frame"), (flange, "flange_frame")):
        if f not in known:
            listed = ", ".join(f"{p}->{c}" for c, p in sorted(parent_of.items(), key=lambda e: e[1]))
            raise BagTopicError(f"{name}: {label} {f!r} is in no transform on {topic} or {static_topic}; the tree "
                                f"has: {listed or 'nothing'}")

    def up(f):
        chain = [f]
        while chain[-1] in parent_of:
            chain.append(parent_of[chain[-1]])
            if len(chain) > 1000:
                raise BagTopicError(f"{name}: the transform tree has a loop through {f!r}")
        return chain

    cb, cf = up(base), up(flange)
    common = next((x for x in cf if x in cb), None)
    if common is None:
        raise BagTopicError(f"{name}: frames {base!r} and {flange!r} are in two unconnected transform trees (roots "
                            f"{cb[-1]!r} and {cf[-1]!r}); is {static_topic} recorded?")
    path_b = [(parent_of[c], c) for c in cb[:cb.index(common)]]  # common ... base, child-up order
    path_f = [(parent_of[c], c) for c in cf[:cf.index(common)]]
    moving = [e for e in path_b + path_f if e in dynamic]
    if not moving:
        raise BagTopicError(f"{name}: no transform between {base!r} and {flange!r} moves on {topic} (the chain is "
                            "all static): the flange pose must come from the robot's state")
    # the stamps of the moving links: one set, the robot state publisher's
    series = {}
    for e in moving:
        s = dynamic[e]
        ns = np.fromiter((x[0] for x in s), np.int64, len(s))
        order = np.argsort(ns, kind="stable")
        logs = np.fromiter((x[1] for x in s), np.int64, len(s))[order]
        vals = np.array([s[i][2] for i in order], dtype=float)
        ns = ns[order]
        dup = np.flatnonzero(np.diff(ns) == 0)  # the same transform published twice
        if dup.size:
            same = np.all(vals[dup] == vals[dup + 1], axis=1)
            if not same.all():
                i = int(dup[~same][0])
                raise BagStampError(f"{name}: {topic}: two different transforms {e[0]}->{e[1]} with the same stamp "
                                    f"{ns[i] / 1e9:.9f} s")
            keep = np.ones(len(ns), bool)
            keep[dup + 1] = False
            ns, vals, logs = ns[keep], vals[keep], logs[keep]
        series[e] = (ns, vals, logs)
    first = moving[0]
    ns0 = series[first][0]
    for e in moving[1:]:
        if not np.array_equal(series[e][0], ns0):
            raise BagTopicError(f"{name}: {topic}: the moving transforms {first[0]}->{first[1]} "
                                f"({len(ns0)} stamps) and {e[0]}->{e[1]} ({len(series[e][0])} stamps) are published "
                                "at different stamps; spherecal composes a chain only from transforms of one stamp")
    _check_stamps(ns0, series[first][2], name, f"{topic} ({first[0]}->{first[1]})", "poses")
    n = len(ns0)

    def rt(e):
        if e in series:
            v = series[e][1]
        else:
            v = np.tile(np.asarray(static[e], float), (n, 1))
        if not np.all(np.isfinite(v)):
            raise BagTopicError(f"{name}: transform {e[0]}->{e[1]} has a non-finite value")
        q = _quaternions_wxyz(v[:, 3:], name, f"{topic} ({e[0]}->{e[1]})")
        return geo.matrix_from_quat_wxyz(q), v[:, :3] * 1000.0

    def compose(path):  # common_from_frame: parent_from_child products from the common frame down
        R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        t = np.zeros((n, 3))
        for e in reversed(path):
            Re, te = rt(e)
            t = t + np.einsum("nij,nj->ni", R, te)
            R = R @ Re
        return R, t

    Rb, tb = compose(path_b)
    Rf, tf = compose(path_f)
    Rbt = np.swapaxes(Rb, 1, 2)
    R = Rbt @ Rf
    t = np.einsum("nij,nj->ni", Rbt, tf - tb)
    sec, nsec = np.divmod(ns0, 1_000_000_000)
    info = {"base_frame_id": base, "flange_frame_id": flange,
            "tf_chain": {"up_from_base": [f"{c}<-{p}" for p, c in path_b],
                         "down_to_flange": [f"{p}->{c}" for p, c in reversed(path_f)],
                         "moving": [f"{p}->{c}" for p, c in moving]}}
    return _seconds(sec, nsec), R, t, None, info, series[first][2]


def _poses_from_joints(raws, log_ns, name, topic, joints_to_pose, joint_names):
    """Flange poses from joint states: each message's positions picked by the arm's joint
    names (``joint_names``: extra joints in a message, a gripper's, left out; a message
    without them, from another publisher, skipped), or without names in the order of the
    first message's, all of them (said: nothing checks that it is the arm's order)."""
    ts = _typestore()
    rows = []
    stamps = []
    logs = []
    by_name = joint_names is not None
    names = list(joint_names) if by_name else None
    others: dict[tuple[str, ...], int] = {}  # the name lists of the messages skipped, and how many
    for i, raw in enumerate(raws):
        try:
            msg = ts.deserialize_cdr(raw, JOINT_STATE)
        except Exception as exc:  # noqa: BLE001
            raise BagTopicError(f"{name}: {topic}: message {i} is not a readable JointState ({exc})") from None
        msg_names = list(msg.name)
        if names is None:
            names = msg_names
        pos = np.asarray(msg.position, dtype=float)
        if len(pos) != len(msg_names):
            raise BagTopicError(f"{name}: {topic}: message {i} has {len(msg_names)} names but {len(pos)} positions")
        index = {n_: k for k, n_ in enumerate(msg_names)}
        if any(n_ not in index for n_ in names):
            others[tuple(msg_names)] = others.get(tuple(msg_names), 0) + 1
            continue
        rows.append(pos[[index[n_] for n_ in names]])
        stamps.append(int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec))
        logs.append(log_ns[i])
    skipped = sum(others.values())
    seen = "; ".join(f"{list(k)} ({v} messages)" for k, v in sorted(others.items(), key=lambda e: -e[1])[:3])
    if not rows:
        if by_name:
            raise BagTopicError(f"{name}: {topic}: no message names the arm's joints {names}, the names the robot's "
                                f"kinematics takes them by; the messages name {seen}. The joint names do not match: "
                                "record the arm's own /joint_states, or describe the arm with the names its driver "
                                "publishes")
        raise BagTopicError(f"{name}: {topic}: no message has the joints {names}")
    if skipped:
        warnings.warn(f"{name}: {topic}: skipped {skipped} of {len(raws)} messages without the joints {names} "
                      f"(another publisher on the topic?); they name {seen}", BagWarning, stacklevel=3)
    if not by_name:
        warnings.warn(f"{name}: {topic}: the robot's kinematics names no joints: the joints are taken in the order "
                      f"of the first message's names, {names}, all of them; check that this is the arm's order, base "
                      "to flange", BagWarning, stacklevel=3)
    q_deg = np.degrees(np.asarray(rows))
    if not np.all(np.isfinite(q_deg)):
        i = int(np.flatnonzero(~np.isfinite(q_deg).all(axis=1))[0])
        raise BagTopicError(f"{name}: {topic}: message {i} has a non-finite joint position")
    ns = np.asarray(stamps, np.int64)
    logs_a = np.asarray(logs, np.int64)
    _check_stamps(ns, logs_a, name, topic, "joint states")
    taken = (f"the joints {names}, matched by name" if by_name else
             f"the joints {names} in the first message's order (the kinematics names none to match them by)")
    try:
        R, t = joints_to_pose(q_deg)
        R = np.asarray(R, dtype=float)
        t = np.asarray(t, dtype=float)
    except (ValueError, TypeError) as exc:
        raise InputError(f"{name}: {topic}: the robot's kinematics refused the joints ({exc}); {taken}") from None
    n = len(q_deg)
    if R.shape != (n, 3, 3) or t.shape != (n, 3) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise InputError(f"joints_to_pose must return finite rotations (n, 3, 3) and translations (n, 3) mm for "
                         f"n = {n} joint rows; got {R.shape} and {t.shape}")
    sec, nsec = np.divmod(ns, 1_000_000_000)
    info = {"joint_names": names, "joints_matched_by_name": by_name, "n_joint_messages_skipped": skipped}
    return _seconds(sec, nsec), R, t, q_deg, info, logs_a


def _check_time_spans(t_sensor, t_robot, name, profile_topic, pose_topic) -> None:
    lo, hi = float(t_robot[0]), float(t_robot[-1])
    outside = (t_sensor < lo) | (t_sensor > hi)
    k = int(outside.sum())
    if not k:
        return
    m = len(t_sensor)
    text = (f"{k} of {m} profiles lie outside the pose stream's time span ({profile_topic}: {t_sensor[0]:.6f} to "
            f"{t_sensor[-1]:.6f} s; {pose_topic}: {lo:.6f} to {hi:.6f} s, header stamps)")
    if k > MAX_OUTSIDE_FRACTION * m:
        raise BagTimeSpanError(f"{name}: {text}: the pose topic does not cover the recording (the wrong topic, or "
                               "stamps on another clock or epoch?)")
    warnings.warn(f"{name}: {text}; they have no measured pose unless the clocks' offset brings them in, and are left "
                  "out of the fit otherwise", BagWarning, stacklevel=3)


#: The two streams' header stamp spans (first to last stamp) may lie this far apart (s)
#: and still be one clock's: the largest delay a stamp may have before its log time.
SAME_CLOCK_MAX_GAP_S = 1.0


def _delay_trend(t_s: np.ndarray, log_ns: np.ndarray) -> tuple[float, float, float]:
    """(median, slope, slope's standard error) of the delay log time - header stamp (s)."""
    d = log_ns / 1e9 - t_s
    x = t_s - t_s.mean()
    sxx = float(x @ x)
    if len(d) < 3 or sxx <= 0:
        return float(np.median(d)), 0.0, math.inf
    slope = float(x @ (d - d.mean())) / sxx
    res = d - d.mean() - slope * x
    se = math.sqrt(float(res @ res) / (len(d) - 2) / sxx)
    return float(np.median(d)), slope, se


def _clocks(t_sensor, log_sensor, t_robot, log_robot, profile_topic, pose_topic, name):
    """Both streams' clock names, and whether their stamps show one clock: the recording
    computer's (each header stamp a little before its log time, no drift between the two
    streams' delays, and the two streams' stamps in one stretch of time)."""
    clocks = {"robot": f"header stamps of {pose_topic}", "sensor": f"header stamps of {profile_topic}"}
    med_s, slope_s, se_s = _delay_trend(t_sensor, log_sensor)
    med_r, slope_r, se_r = _delay_trend(t_robot, log_robot)
    rel, se = slope_s - slope_r, math.hypot(se_s, se_r)
    near = -0.005 <= med_s <= 1.0 and -0.005 <= med_r <= 1.0
    # Each topic is compared only with its own log times above; a converter that writes
    # each message's log time = its header stamp makes every topic look "stamped on
    # reception" whatever clock stamped it. Stamps of one clock, recorded together, lie
    # in one stretch of time: spans apart by more than a delay cannot be one clock.
    gap_s = max(float(t_sensor[0]), float(t_robot[0])) - min(float(t_sensor[-1]), float(t_robot[-1]))
    together = gap_s <= SAME_CLOCK_MAX_GAP_S
    same = near and together and math.isfinite(se) and abs(rel) <= 2e-6 + 3.0 * se and se < 5e-6
    info = {"sensor_delay_median_s": med_s, "robot_delay_median_s": med_r, "relative_rate_ppm": rel * 1e6,
            "relative_rate_std_ppm": se * 1e6 if math.isfinite(se) else None,
            "stamp_spans_gap_s": max(gap_s, 0.0), "same_clock": bool(same)}
    if same:
        clocks = {"robot": "recording computer", "sensor": "recording computer"}
        warnings.warn(
            f"{name}: {profile_topic} and {pose_topic} look stamped by one clock, the recording computer's: each "
            f"header stamp is a little before its log time (median {med_s * 1e3:.3g} ms and {med_r * 1e3:.3g} ms) and "
            f"the two delays do not drift apart ({rel * 1e6:.3g} +- {se * 1e6:.2g} ppm). No drift between the robot's "
            "and the sensor's clocks can be seen, and the offset is the difference of the drivers' latencies; stamp "
            "with the devices' own clocks (hardware stamps) to estimate both", SameClockWarning, stacklevel=3)
    return clocks, info

