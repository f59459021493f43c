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
  sensor frame is then the cloud's frame turned by +90 degrees about z
  (``sensor_from_cloud = Rz(90 deg)``: y_sensor = x_cloud, x_sensor = -y_cloud). Points
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
:class:`BagTimeSpanError`); a wrong argument raises :class:`InputError`. What needs
attention but does not stop the conversion is a :class:`BagWarning`: some profiles
outside the pose stream's time span, invalid points dropped from clouds that say they
have some (``is_dense`` false), both streams stamped by the recording computer's clock
(:class:`SameClockWarning`: no drift between them can be seen).
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from struct import unpack_from
from typing import Literal

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DatasetFileError, InputError
from spherecal.core.streams import PoseStream, ProfileStream, Recording
from spherecal.io.streams import MAX_STAMP_STEP_S, PointBuffer, _check_mounting_radius

__all__ = [
    "BagCloudError",
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

PROFILE_TYPE = "sensor_msgs/msg/PointCloud2"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_TYPES = (POSE_STAMPED, TF_MESSAGE, JOINT_STATE)

#: A profile point may lie this far off the laser plane (m): the plane's coordinate of
#: every point must be 0, to rounding of the driver's arithmetic.
MAX_OFF_PLANE_M = 1e-4
#: Profiles whose largest coordinate is typically beyond this (m) are in millimetres: no
#: line profiler measures 5 m away, and a profile in mm spans more than 5 mm.
MAX_PROFILE_EXTENT_M = 5.0
#: Flange positions typically beyond this (m) from the base are in millimetres.
MAX_FLANGE_DISTANCE_M = 100.0
#: More than this fraction of profiles outside the pose stream's time span is refused
#: (the wrong topic or clock); fewer are kept, with a warning.
MAX_OUTSIDE_FRACTION = 0.5

_FLOAT_TYPES = {7: 4, 8: 8}  # PointField datatype -> size: FLOAT32, FLOAT64
_CDR_LE = b"\x00\x01"


class BagError(DatasetFileError):
    """A ROS 2 bag cannot be converted; the message names the bag, the topic and the cause."""


class BagTopicError(BagError):
    """A topic is missing, has the wrong message type, or lacks what the conversion needs
    (a frame of the transform tree, a joint); the message lists what the bag has."""


class BagUnitsError(BagError):
    """Values in the wrong unit or frame: millimetres where ROS requires metres, points off
    the laser plane (the line along x, not y?)."""


class BagCloudError(BagError):
    """A point cloud that is not a profile: no points at all, non-finite points in a cloud
    that says it has none, fields missing or not floating point, a size that does not add up."""


class BagStampError(BagError):
    """Header stamps that go backwards, repeat, jump, or were never set."""


class BagTimeSpanError(BagError):
    """Most profiles lie outside the pose stream's time span."""


class BagWarning(UserWarning):
    """Something in a bag that the conversion kept but that needs a look."""


class SameClockWarning(BagWarning):
    """Both streams were stamped by one clock (the recording computer's): no drift between
    the robot's and the sensor's clocks can be seen."""


# ---------------------------------------------------------------------------------------
# CDR (little-endian, ROS 2's serialisation) of the fixed-layout messages
# ---------------------------------------------------------------------------------------


def _align(p: int, n: int) -> int:
    """Offset ``p`` (from the message start, 4 bytes of encapsulation header first)
    aligned to ``n`` relative to the payload, as CDR aligns."""
    return 4 + ((p - 4 + n - 1) & ~(n - 1))


def _string(raw: bytes, p: int) -> tuple[str, int]:
    (n,) = unpack_from("<I", raw, p)
    p += 4
    return raw[p:p + max(n - 1, 0)].decode("utf-8", "replace"), p + n


@dataclass
class _Cloud:
    """What the conversion needs of one PointCloud2."""

    sec: int
    nanosec: int
    frame_id: str
    height: int
    width: int
    fields: dict[str, tuple[int, int, int]]  # name -> (offset, datatype, count)
    is_bigendian: bool
    point_step: int
    row_step: int
    data_start: int
    data_len: int
    is_dense: bool


class _CloudParser:
    """Reads PointCloud2 messages in little-endian CDR (ValueError or struct.error when a
    message is not one). The block from the field count to ``point_step`` (the fields and
    the byte order) is the same in every message of one driver: a block seen in the
    message before is matched byte for byte instead of parsed again."""

    def __init__(self):
        self._block = b""
        self._parsed: tuple[dict, bool, int] | None = None
        self._frames: dict[bytes, str] = {}

    def __call__(self, raw: bytes) -> _Cloud:
        if raw[:2] != _CDR_LE:
            raise ValueError(f"encapsulation {raw[:2].hex()} is not little-endian CDR")
        sec, nanosec, n = unpack_from("<iII", raw, 4)
        frame = raw[16:16 + max(n - 1, 0)]
        frame_id = self._frames.get(frame)
        if frame_id is None:
            frame_id = self._frames.setdefault(frame, frame.decode("utf-8", "replace"))
        p = _align(16 + n, 4)
        height, width = unpack_from("<II", raw, p)
        q = p + 8
        if self._parsed is not None and raw.startswith(self._block, q):
            fields, is_bigendian, point_step = self._parsed
            r = q + len(self._block)
        else:
            fields, is_bigendian, point_step, r = self._block_at(raw, q)
            self._block, self._parsed = raw[q:r], (fields, is_bigendian, point_step)
        row_step, n_data = unpack_from("<II", raw, r)
        start = r + 8
        if start + n_data + 1 > len(raw):
            raise ValueError(f"data of {n_data} bytes runs past the message's {len(raw)} bytes")
        return _Cloud(sec, nanosec, frame_id, height, width, fields, is_bigendian, point_step, row_step, start, n_data,
                      raw[start + n_data] != 0)

    @staticmethod
    def _block_at(raw: bytes, p: int) -> tuple[dict, bool, int, int]:
        (n_fields,) = unpack_from("<I", raw, p)
        p += 4
        fields = {}
        for _ in range(n_fields):
            name, p = _string(raw, p)
            p = _align(p, 4)
            (offset,) = unpack_from("<I", raw, p)
            datatype = raw[p + 4]
            p = _align(p + 5, 4)
            (count,) = unpack_from("<I", raw, p)
            p += 4
            fields[name] = (offset, datatype, count)
        is_bigendian = bool(raw[p])
        p = _align(p + 1, 4)
        (point_step,) = unpack_from("<I", raw, p)
        return fields, is_bigendian, point_step, p + 4


def _parse_pose_stamped(raw: bytes) -> tuple[int, int, str, tuple[float, ...]]:
    """(sec, nanosec, frame_id, (px, py, pz, qx, qy, qz, qw)) of a PoseStamped, m."""
    if raw[:2] != _CDR_LE:
        raise ValueError(f"encapsulation {raw[:2].hex()} is not little-endian CDR")
    sec, nanosec = unpack_from("<iI", raw, 4)
    frame_id, p = _string(raw, 12)
    p = _align(p, 8)
    return sec, nanosec, frame_id, unpack_from("<7d", raw, p)


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    # the messages read here are the same in every ROS 2 distribution
    return get_typestore(Stores.ROS2_HUMBLE)


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
        raise BagError(f"{name}: cannot read the bag ({exc})") from None
    return reader


def _messages(reader, connections, name: str):
    """The reader's messages; a damaged storage file is a BagError naming the bag."""
    from rosbags.rosbag2.errors import ReaderError

    try:
        yield from reader.messages(connections=connections)
    except (ReaderError, OSError, ValueError, KeyError) as exc:
        raise BagError(f"{name}: cannot read the bag's messages ({exc})") from None


def _topics_text(topics: dict[str, _Topic]) -> str:
    if not topics:
        return "the bag has no topics"
    return "the bag has: " + "; ".join(f"{t.name} ({t.msgtype}, {t.count} messages)" for _, t in sorted(topics.items()))


def _check_stamps(ns: np.ndarray, log_ns: np.ndarray, name: str, topic: str, what: str) -> None:
    """Stamps set, strictly increasing, without a jump (BagStampError naming the message)."""
    zero = np.flatnonzero(ns <= 0)
    if zero.size:
        i = int(zero[0])
        raise BagStampError(f"{name}: {topic}: message {i} (bag log time {log_ns[i] / 1e9:.6f} s) has header stamp "
                            f"{ns[i] / 1e9:g} s: the driver does not stamp its {what}; spherecal needs the time each "
                            "was measured, not when it was received")
    if len(ns) < 2:
        return
    d = np.diff(ns)
    back = np.flatnonzero(d <= 0)
    jump = np.flatnonzero(d > MAX_STAMP_STEP_S * 1e9)
    if back.size and (not jump.size or back[0] < jump[0]):
        k = int(back[0])
        how = "repeats" if d[k] == 0 else "goes backwards from"
        raise BagStampError(f"{name}: {topic}: the header stamp of message {k + 1} {how} message {k}'s "
                            f"({ns[k + 1] / 1e9:.9f} s after {ns[k] / 1e9:.9f} s; bag log times "
                            f"{log_ns[k] / 1e9:.6f} s and {log_ns[k + 1] / 1e9:.6f} s): the {what} must be stamped in "
                            "the order they were measured, each once")
    if jump.size:
        k = int(jump[0])
        raise BagStampError(f"{name}: {topic}: the header stamp jumps {d[k] / 1e9:.6g} s from message {k} to "
                            f"{k + 1} ({ns[k] / 1e9:.6f} s to {ns[k + 1] / 1e9:.6f} s): more than "
                            f"{MAX_STAMP_STEP_S:g} s between two {what} is a clock jump (a reset, or stamps in "
                            "another unit)")


def _seconds(sec: np.ndarray, nanosec: np.ndarray) -> np.ndarray:
    return sec.astype(np.float64) + nanosec.astype(np.float64) * 1e-9


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
    ``joint_names`` picks and orders the joints it takes, by default those of the first
    message; messages without them, from another publisher on the topic, are skipped).
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
        parse_cloud = _CloudParser()
        decoder = _CloudDecoder(name, profile_topic, line_axis, prof.count)
        pose_raw: list[bytes] = []
        pose_log: list[int] = []
        static_raw: list[bytes] = []
        for conn, log_ns, raw in _messages(reader, wanted, name):
            topic = conn.topic
            if topic == profile_topic:
                try:
                    cloud = parse_cloud(raw)
                except Exception as exc:  # noqa: BLE001 - big-endian or unusual (struct.error, ValueError...)
                    cloud, raw = _cloud_from_typestore(raw, exc, name, profile_topic, len(decoder.meta))
                decoder.add(raw, cloud, log_ns)
            elif topic == pose_topic:
                pose_raw.append(raw)
                pose_log.append(log_ns)
            else:
                static_raw.append(raw)
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
        **({"sensor_from_cloud_frame": "Rz(+90 deg): y_sensor = x_cloud, x_sensor = -y_cloud"}
           if line_axis == "x" else {}),
        **cloud_info,
        **pose_info,
        "clock_check": clock_info,
    }
    poses = PoseStream(t_robot, R, t_mm, joints)
    return Recording(mounting=mounting, sphere_radius_mm=float(sphere_radius_mm), poses=poses,
                     profiles=ProfileStream(t_sensor, profiles, start), sweeps=[], provenance=provenance,
                     clocks=clocks)


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


def _cloud_from_typestore(raw: bytes, exc: Exception, name: str, topic: str, index: int) -> tuple[_Cloud, bytes]:
    """A cloud the generic deserialiser reads (a big-endian message), and its data."""
    try:
        msg = _typestore().deserialize_cdr(raw, PROFILE_TYPE)
    except Exception as exc2:  # noqa: BLE001 - any failure is a broken message
        raise BagCloudError(f"{name}: {topic}: message {index} is not a readable PointCloud2 ({exc}; {exc2})") from None
    data = np.asarray(msg.data, dtype=np.uint8).tobytes()
    c = _Cloud(int(msg.header.stamp.sec), int(msg.header.stamp.nanosec), msg.header.frame_id, int(msg.height),
               int(msg.width), {f.name: (int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields},
               bool(msg.is_bigendian), int(msg.point_step), int(msg.row_step), 0, len(data), bool(msg.is_dense))
    return c, data


def _layout(c: _Cloud, axes: tuple[str, str, str], name: str, topic: str, index: int, t: float) -> tuple:
    """(point_step, offsets of the normal, line and range coordinates, dtype) of a cloud,
    after checking that its size adds up."""
    where = f"{name}: {topic}: message {index} (stamp {t:.6f} s)"
    missing = [a for a in axes if a not in c.fields]
    if missing:
        raise BagCloudError(f"{where}: no field {', '.join(missing)} (fields: {', '.join(c.fields) or 'none'}); a "
                            "profile is a cloud of x, y, z")
    types = {c.fields[a][1] for a in axes}
    if len(types) != 1 or next(iter(types)) not in _FLOAT_TYPES or any(c.fields[a][2] != 1 for a in axes):
        desc = ", ".join(f"{a}: datatype {c.fields[a][1]} count {c.fields[a][2]}" for a in axes)
        raise BagCloudError(f"{where}: x, y, z must be one FLOAT32 (datatype 7) or FLOAT64 (8) each, all alike; "
                            f"found {desc}")
    size = _FLOAT_TYPES[next(iter(types))]
    offsets = tuple(c.fields[a][0] for a in axes)
    n = c.width * c.height
    if n and (any(o + size > c.point_step for o in offsets) or c.width * c.point_step > c.row_step
              or c.data_len != c.row_step * c.height):
        raise BagCloudError(f"{where}: sizes do not add up: {c.height} x {c.width} points, point_step "
                            f"{c.point_step}, row_step {c.row_step}, fields at {offsets}, {c.data_len} bytes of data")
    dtype = np.dtype(("<" if not c.is_bigendian else ">") + ("f4" if size == 4 else "f8"))
    return c.point_step, offsets, dtype, c.row_step == c.width * c.point_step


#: Clouds are decoded in runs of about this many bytes (a run's passes stay in the cache,
#: and the messages' memory is reused by the next run's).
_RUN_BYTES = 1 << 20


class _CloudDecoder:
    """Profiles (y, z) mm from PointCloud2 messages, decoded as they are read: runs of
    consecutive clouds of one layout at once (one join, strided views of the three
    coordinates), each message's bytes let go once its run is decoded."""

    def __init__(self, name: str, topic: str, line_axis: str, n_expected: int):
        self.name, self.topic, self.line_axis = name, topic, line_axis
        self.axes = ("x", "y", "z") if line_axis == "y" else ("y", "x", "z")  # (normal, line, range)
        self.n_expected = n_expected
        self.points: PointBuffer | None = None
        self.meta: list[_Cloud] = []
        self.log_ns: list[int] = []
        self._layouts: dict[tuple, tuple] = {}
        self._run: list[tuple[bytes, _Cloud]] = []
        self._run_layout: tuple | None = None
        self._run_bytes = 0
        self._bad_runs: list[tuple[int, np.ndarray]] = []  # (first point, finite mask) of runs with invalid points
        self._extent_mm: dict[int, float] = {}  # a sample of profiles: the largest |coordinate| of the finite points

    def add(self, raw: bytes, cloud: _Cloud, log_ns: int) -> None:
        i = len(self.meta)
        key = (id(cloud.fields), cloud.point_step, cloud.row_step, cloud.width, cloud.height, cloud.data_len,
               cloud.is_bigendian)
        lay = self._layouts.get(key)
        if lay is None:
            lay = self._layouts[key] = _layout(cloud, self.axes, self.name, self.topic, i,
                                               cloud.sec + cloud.nanosec * 1e-9)
        if self.points is None:
            self.points = PointBuffer(self.n_expected * cloud.width * cloud.height)
        if self._run and (lay != self._run_layout or self._run_bytes >= _RUN_BYTES):
            self._decode_run()
        self._run.append((raw, cloud))
        self._run_layout = lay
        self._run_bytes += cloud.data_len
        self.meta.append(cloud)
        self.log_ns.append(log_ns)

    def _decode_run(self) -> None:
        run, (step, offsets, dtype, packed) = self._run, self._run_layout
        first_msg = len(self.meta) - len(run)
        if packed:
            buf = b"".join(memoryview(raw)[c.data_start:c.data_start + c.data_len] for raw, c in run)
        else:  # rows padded beyond width * point_step: keep each row's points only
            buf = b"".join(np.frombuffer(raw, np.uint8, c.data_len, c.data_start).reshape(c.height, c.row_step)
                           [:, :c.width * step].tobytes() for raw, c in run)
        counts = [c.width * c.height for _, c in run]
        self._run, self._run_bytes = [], 0
        n = sum(counts)
        points = self.points
        base = points.n
        block = points.reserve(n)
        if n:
            normal, line, rng = (np.ndarray((n,), dtype, buf, o, (step,)) for o in offsets)
            block[:, 0] = line  # column by column: NumPy's fastest strided cast
            block[:, 1] = rng
            block *= 1000.0  # m -> mm, in double precision
            # sums of squares (strided BLAS dot products) carry a NaN or an infinity through, and bound the
            # largest off-plane coordinate: the point-by-point look is needed only when one says so
            normal_sq = float(np.dot(normal, normal))
            fin = None
            if not math.isfinite(normal_sq + float(np.dot(line, line)) + float(np.dot(rng, rng))):
                fin = np.isfinite(normal) & np.isfinite(line) & np.isfinite(rng)
                self._bad_runs.append((base, fin))
                normal_max = float(np.abs(normal[fin]).max(initial=0.0))
            elif normal_sq > MAX_OFF_PLANE_M ** 2:
                normal_max = max(float(normal.max()), -float(normal.min()))
            else:
                normal_max = 0.0
            local = np.zeros(len(counts) + 1, np.int64)
            np.cumsum(counts, out=local[1:])
            nz = np.flatnonzero(np.diff(local))
            if normal_max > MAX_OFF_PLANE_M:
                absn = np.abs(normal) if fin is None else np.where(fin, np.abs(normal), 0.0)
                off = np.maximum.reduceat(absn, local[nz])
                i = first_msg + int(nz[np.argmax(off > MAX_OFF_PLANE_M)])
                c = self.meta[i]
                _off_plane(self.name, self.topic, self.line_axis, i, c.sec + c.nanosec * 1e-9, float(off.max()))
            # the units check needs a typical profile's reach: the run's first non-empty profile stands for it
            if nz.size:
                lo, hi = int(local[nz[0]]), int(local[nz[0] + 1])
                reach = np.abs(block[lo:hi]) if fin is None else np.abs(block[lo:hi][fin[lo:hi]])
                self._extent_mm[first_msg + int(nz[0])] = float(reach.max(initial=0.0))
        for k in counts:
            points.added(k)

    def finish(self):
        """(stamps s, points (N, 2) mm, starts, what the conversion saw), after the checks
        that need every profile."""
        if self._run:
            self._decode_run()
        name, topic, meta = self.name, self.topic, self.meta
        m = len(meta)
        sec = np.fromiter((c.sec for c in meta), np.int64, m)
        nsec = np.fromiter((c.nanosec for c in meta), np.int64, m)
        _check_stamps(sec * 1_000_000_000 + nsec, np.asarray(self.log_ns, np.int64), name, topic, "profiles")
        t = _seconds(sec, nsec)
        frames = sorted({c.frame_id for c in meta})
        if len(frames) > 1:
            raise BagCloudError(f"{name}: {topic}: clouds in {len(frames)} frames "
                                f"({', '.join(map(repr, frames[:5]))}): one sensor's profiles come in one frame")
        out = self.points.array()
        start = np.asarray(self.points.starts, np.int64)
        counts = np.diff(start)
        # non-finite points: an error in a cloud that says it has none, dropped otherwise
        n_dropped = 0
        if self._bad_runs:
            finite = np.ones(len(out), bool)
            for base, fin in self._bad_runs:
                finite[base:base + len(fin)] = fin
            dense = np.fromiter((c.is_dense for c in meta), bool, m)
            bad_msg = np.unique(np.searchsorted(start, np.flatnonzero(~finite), side="right") - 1)
            dense_bad = bad_msg[dense[bad_msg]]
            if dense_bad.size:
                i = int(dense_bad[0])
                k = int(np.flatnonzero(~finite[start[i]:start[i + 1]])[0])
                raise BagCloudError(f"{name}: {topic}: message {i} (stamp {t[i]:.6f} s) says is_dense (no invalid "
                                    f"points) but point {k} is not finite; {dense_bad.size} such clouds")
            n_dropped = int((~finite).sum())
            owner = np.repeat(np.arange(m), counts)  # each point's message
            out = out[finite]
            counts = np.bincount(owner[finite], minlength=m).astype(np.int64)
            start = np.zeros(m + 1, np.int64)
            np.cumsum(counts, out=start[1:])
            warnings.warn(f"{name}: {topic}: dropped {n_dropped} invalid (NaN or infinite) points from "
                          f"{bad_msg.size} clouds that say they may hold some (is_dense false)", BagWarning,
                          stacklevel=3)
        nonempty = counts > 0
        if not nonempty.any():
            raise BagCloudError(f"{name}: {topic}: all {m} clouds are empty (no finite point): the sensor saw "
                                "nothing, or the topic is not the profiles")
        sample = [v for i, v in self._extent_mm.items() if nonempty[i]]
        typical = float(np.median(sample)) / 1000.0 if sample else 0.0
        if typical > MAX_PROFILE_EXTENT_M:
            raise BagUnitsError(f"{name}: {topic}: the points look like millimetres, not metres: a typical profile "
                                f"reaches {typical:.4g} from the sensor, more than {MAX_PROFILE_EXTENT_M:g} if that "
                                "were metres. ROS clouds are in metres (REP 103); have the driver publish metres")
        info = {"sensor_frame_id": frames[0], "n_clouds": m, "n_empty_clouds": int((~nonempty).sum()),
                "n_invalid_points_dropped": n_dropped}
        return t, out, start, info


def _off_plane(name: str, topic: str, line_axis: str, index: int, t: float, worst_m: float) -> None:
    normal = "x" if line_axis == "y" else "y"
    hint = ("if the driver puts the laser line along x, give line_axis='x'" if line_axis == "y" else
            "if the driver puts the laser line along y, give line_axis='y'")
    raise BagUnitsError(f"{name}: {topic}: message {index} (stamp {t:.6f} s) has points up to {worst_m:.6g} m off the "
                        f"laser plane ({normal} must be 0 to {MAX_OFF_PLANE_M:g} m: the laser light lies in the "
                        f"sensor's {normal} = 0 plane); {hint}")


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


def _poses_from_pose_stamped(raws, log_ns, name, topic, base_frame):
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
    ts = _typestore()
    rows = []
    stamps = []
    logs = []
    names = list(joint_names) if joint_names is not None else None
    skipped = 0
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
            skipped += 1  # another publisher on the topic (a gripper): not the arm
            continue
        rows.append(pos[[index[n_] for n_ in names]])
        stamps.append(int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec))
        logs.append(log_ns[i])
    if not rows:
        raise BagTopicError(f"{name}: {topic}: no message has the joints {names}")
    if skipped:
        warnings.warn(f"{name}: {topic}: skipped {skipped} of {len(raws)} messages without the joints {names} "
                      "(another publisher on the topic?)", BagWarning, stacklevel=3)
    q_deg = np.degrees(np.asarray(rows))
    if not np.all(np.isfinite(q_deg)):
        i = int(np.flatnonzero(~np.isfinite(q_deg).all(axis=1))[0])
        raise BagTopicError(f"{name}: {topic}: message {i} has a non-finite joint position")
    ns = np.asarray(stamps, np.int64)
    logs_a = np.asarray(logs, np.int64)
    _check_stamps(ns, logs_a, name, topic, "joint states")
    try:
        R, t = joints_to_pose(q_deg)
        R = np.asarray(R, dtype=float)
        t = np.asarray(t, dtype=float)
    except (ValueError, TypeError) as exc:
        raise InputError(f"{name}: {topic}: the robot's kinematics refused the joints ({exc})") from None
    n = len(q_deg)
    if R.shape != (n, 3, 3) or t.shape != (n, 3) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise InputError(f"joints_to_pose must return finite rotations (n, 3, 3) and translations (n, 3) mm for "
                         f"n = {n} joint rows; got {R.shape} and {t.shape}")
    sec, nsec = np.divmod(ns, 1_000_000_000)
    return _seconds(sec, nsec), R, t, q_deg, {"joint_names": names, "n_joint_messages_skipped": skipped}, logs_a


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
    computer's (each header stamp a little before its log time, and no drift between the
    two streams' delays)."""
    clocks = {"robot": f"header stamps of {pose_topic}", "sensor": f"header stamps of {profile_topic}"}
    med_s, slope_s, se_s = _delay_trend(t_sensor, log_sensor)
    med_r, slope_r, se_r = _delay_trend(t_robot, log_robot)
    rel, se = slope_s - slope_r, math.hypot(se_s, se_r)
    near = -0.005 <= med_s <= 1.0 and -0.005 <= med_r <= 1.0
    same = near and math.isfinite(se) and abs(rel) <= 2e-6 + 3.0 * se and se < 5e-6
    info = {"sensor_delay_median_s": med_s, "robot_delay_median_s": med_r, "relative_rate_ppm": rel * 1e6,
            "relative_rate_std_ppm": se * 1e6 if math.isfinite(se) else None, "same_clock": bool(same)}
    if same:
        clocks = {"robot": "recording computer", "sensor": "recording computer"}
        warnings.warn(
            f"{name}: {profile_topic} and {pose_topic} look stamped by one clock, the recording computer's: each "
            f"header stamp is a little before its log time (median {med_s * 1e3:.3g} ms and {med_r * 1e3:.3g} ms) and "
            f"the two delays do not drift apart ({rel * 1e6:.3g} +- {se * 1e6:.2g} ppm). No drift between the robot's "
            "and the sensor's clocks can be seen, and the offset is the difference of the drivers' latencies; stamp "
            "with the devices' own clocks (hardware stamps) to estimate both", SameClockWarning, stacklevel=3)
    return clocks, info
