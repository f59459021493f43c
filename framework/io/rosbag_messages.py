"""The messages of a ROS 2 bag that :mod:`spherecal.io.rosbag` reads: the message types,
the errors that name what is wrong with a bag, the little-endian CDR of the fixed-layout
messages (PointCloud2, PoseStamped) read with ``struct``, and the clouds decoded into
profiles (y, z) mm with NumPy, a run of messages at a time."""


import functools
import math
import warnings
from dataclasses import dataclass
from struct import unpack_from

import numpy as np

from spherecal.core.errors import DatasetFileError
from spherecal.io.stream_fields import MAX_STAMP_STEP_S, PointBuffer

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


class BagCutShortError(BagError):
    """A storage file that ends too soon (a recording interrupted); the message names the
    file and the tools that repair it."""


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
    return bytes(raw[p:p + max(n - 1, 0)]).decode("utf-8", "replace"), p + n


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
    """Reads PointCloud2 messages in little-endian CDR, given as bytes or a bytes view
    (ValueError or struct.error when a message is not one). The block from the field count to ``point_step`` (the fields and
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
        frame = bytes(raw[16:16 + max(n - 1, 0)])
        frame_id = self._frames.get(frame)
        if frame_id is None:
            frame_id = self._frames.setdefault(frame, frame.decode("utf-8", "replace"))
        p = _align(16 + n, 4)
        height, width = unpack_from("<II", raw, p)
        q = p + 8
        if self._parsed is not None and raw[q:q + len(self._block)] == self._block:
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


@functools.cache
def _typestore():
    from rosbags.typesys import Stores, get_typestore

    # the messages read here are the same in every ROS 2 distribution
    return get_typestore(Stores.ROS2_HUMBLE)



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
            # FLOAT32 clouds stay single precision: float32 metres times 1000, rounded once to
            # float32, is the value the stream file stores (the product is exact in double, so
            # float32 arithmetic rounds it as a detour through float64 would)
            self.points = PointBuffer(self.n_expected * cloud.width * cloud.height,
                                      np.float32 if lay[2].itemsize == 4 else np.float64)
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
            mm = block.dtype.type(1000.0)
            np.multiply(line, mm, out=block[:, 0])  # m -> mm, column by column in one pass each
            np.multiply(rng, mm, out=block[:, 1])
            # sums of squares (BLAS dot products) carry a NaN or an infinity through, and bound the
            # largest off-plane coordinate: the point-by-point look is needed only when one says so
            flat = block.reshape(-1)
            normal_sq = float(np.dot(normal, normal))
            fin = None
            if not math.isfinite(normal_sq + float(np.dot(flat, flat))):
                fin = np.isfinite(normal) & np.isfinite(line) & np.isfinite(rng)
                if fin.all():
                    fin = None  # finite values whose squares overflow: nothing to drop
                else:
                    self._bad_runs.append((base, fin))
            if fin is not None:
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
        info = {"cloud_frame_id": frames[0], "n_clouds": m, "n_empty_clouds": int((~nonempty).sum()),
                "n_invalid_points_dropped": n_dropped}
        return t, out, start, info


def _off_plane(name: str, topic: str, line_axis: str, index: int, t: float, worst_m: float) -> None:
    normal = "x" if line_axis == "y" else "y"
    hint = ("if the driver puts the laser line along x, give line_axis='x'" if line_axis == "y" else
            "if the driver puts the laser line along y, give line_axis='y'")
    raise BagUnitsError(f"{name}: {topic}: message {index} (stamp {t:.6f} s) has points up to {worst_m:.6g} m off the "
                        f"laser plane ({normal} must be 0 to {MAX_OFF_PLANE_M:g} m: the laser light lies in the "
                        f"sensor's {normal} = 0 plane); {hint}")


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
        differ = " (the two messages differ: exact duplicates are dropped)" if d[k] == 0 else ""
        raise BagStampError(f"{name}: {topic}: the header stamp of message {k + 1} {how} message {k}'s "
                            f"({ns[k + 1] / 1e9:.9f} s after {ns[k] / 1e9:.9f} s; bag log times "
                            f"{log_ns[k] / 1e9:.6f} s and {log_ns[k + 1] / 1e9:.6f} s){differ}: the {what} must be "
                            "stamped in the order they were measured, each once")
    if jump.size:
        k = int(jump[0])
        raise BagStampError(f"{name}: {topic}: the header stamp jumps {d[k] / 1e9:.6g} s from message {k} to "
                            f"{k + 1} ({ns[k] / 1e9:.6f} s to {ns[k + 1] / 1e9:.6f} s): more than "
                            f"{MAX_STAMP_STEP_S:g} s between two {what} is a clock jump (a reset, or stamps in "
                            "another unit)")


def _seconds(sec: np.ndarray, nanosec: np.ndarray) -> np.ndarray:
    return sec.astype(np.float64) + nanosec.astype(np.float64) * 1e-9
