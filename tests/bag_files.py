"""Small rosbag2 recordings written with rosbags for the tests: profiles as PointCloud2,
flange poses as PoseStamped, TFMessage or JointState, in MCAP or sqlite3 storage, each
with a known truth (stamps, poses, points)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.typesys import Stores, get_typestore

from spherecal.core import geometry as geo

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
T0_NS = 1_767_600_000_123_456_789  # an epoch stamp, ns


def stamp(ns: int):
    return T["builtin_interfaces/msg/Time"](sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def header(ns: int, frame: str):
    return T["std_msgs/msg/Header"](stamp=stamp(ns), frame_id=frame)


def cloud(ns: int, xyz_m: np.ndarray, frame="sensor", *, dtype="<f4", extra_field=False, is_dense=True,
          pad_row=0, height=1):
    """A PointCloud2 of the points (n, 3) m; ``extra_field`` adds an intensity after z
    (point_step 16), ``pad_row`` bytes after each row, ``height`` rows."""
    PF = T["sensor_msgs/msg/PointField"]
    size = np.dtype(dtype).itemsize
    datatype = 7 if size == 4 else 8
    n = len(xyz_m)
    fields = [PF(name=a, offset=size * i, datatype=datatype, count=1) for i, a in enumerate("xyz")]
    step = 3 * size
    cols = [np.asarray(xyz_m, dtype=dtype)]
    if extra_field:
        fields.append(PF(name="intensity", offset=step, datatype=7, count=1))
        step += 4
    rec = np.zeros(n, dtype=np.dtype({"names": ["xyz", "i"][:1 + extra_field],
                                      "formats": [(dtype, 3), "<f4"][:1 + extra_field],
                                      "itemsize": step}))
    rec["xyz"] = cols[0]
    width = n // height
    rows = rec.view(np.uint8).reshape(height, width * step)
    if pad_row:
        rows = np.hstack([rows, np.full((height, pad_row), 0xEE, np.uint8)])
    return T["sensor_msgs/msg/PointCloud2"](
        header=header(ns, frame), height=height, width=width, fields=fields, is_bigendian=False, point_step=step,
        row_step=width * step + pad_row, data=rows.ravel().copy(), is_dense=is_dense)


def pose_stamped(ns: int, t_m, q_xyzw, frame="base_link"):
    G = T
    return G["geometry_msgs/msg/PoseStamped"](header=header(ns, frame), pose=G["geometry_msgs/msg/Pose"](
        position=G["geometry_msgs/msg/Point"](x=float(t_m[0]), y=float(t_m[1]), z=float(t_m[2])),
        orientation=G["geometry_msgs/msg/Quaternion"](x=float(q_xyzw[0]), y=float(q_xyzw[1]), z=float(q_xyzw[2]),
                                                      w=float(q_xyzw[3]))))


def transform(ns: int, parent: str, child: str, t_m, q_xyzw):
    G = T
    return G["geometry_msgs/msg/TransformStamped"](
        header=header(ns, parent), child_frame_id=child, transform=G["geometry_msgs/msg/Transform"](
            translation=G["geometry_msgs/msg/Vector3"](x=float(t_m[0]), y=float(t_m[1]), z=float(t_m[2])),
            rotation=G["geometry_msgs/msg/Quaternion"](x=float(q_xyzw[0]), y=float(q_xyzw[1]), z=float(q_xyzw[2]),
                                                       w=float(q_xyzw[3]))))


def tf_message(transforms):
    return T["tf2_msgs/msg/TFMessage"](transforms=list(transforms))


def joint_state(ns: int, names, positions_rad):
    return T["sensor_msgs/msg/JointState"](header=header(ns, ""), name=list(names),
                                           position=np.ascontiguousarray(positions_rad, float), velocity=np.zeros(0),
                                           effort=np.zeros(0))


def write_bag(path: Path, storage: str, topics: dict[str, tuple[str, list[tuple[int, object]]]],
              compression: str | None = None, in_log_order: bool = True) -> Path:
    """topics: name -> (message type, [(log time ns, message), ...]); messages are written
    in log-time order across topics, as a recorder does, or (``in_log_order`` False) in
    the order given, topic after topic. ``compression``: None, "storage" (MCAP chunks
    compressed with zstd) or "message" (each message's bytes compressed)."""
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    w = Writer(path, version=9, storage_plugin=plugin)
    if compression is not None:
        w.set_compression(getattr(CompressionMode, compression.upper()), CompressionFormat.ZSTD)
    with w:
        conns = {name: w.add_connection(name, msgtype, typestore=TS) for name, (msgtype, _) in topics.items()}
        allmsgs = [(log, name, msg) for name, (_, msgs) in topics.items() for log, msg in msgs]
        if in_log_order:
            allmsgs.sort(key=lambda x: x[0])
        for log, name, msg in allmsgs:
            w.write(conns[name], log, TS.serialize_cdr(msg, topics[name][0]))
    return path


@dataclass
class Truth:
    """A short recording's truth: pose stamps (ns, robot), base_from_flange (R, t mm),
    profile stamps (ns, sensor) and points (list of (k, 3) m in the cloud frame)."""

    pose_ns: np.ndarray
    R: np.ndarray
    t_mm: np.ndarray
    profile_ns: np.ndarray
    points_m: list = field(default_factory=list)


def make_truth(n_poses=200, n_profiles=60, seed=0, k=40) -> Truth:
    rng = np.random.default_rng(seed)
    pose_ns = T0_NS + np.arange(n_poses, dtype=np.int64) * 4_000_000 + rng.integers(0, 50_000, n_poses)
    s = np.linspace(0, 1, n_poses)
    rotvec = np.column_stack([0.3 * s, -0.2 + 0.4 * s, 3.0 - 0.5 * s])
    R = geo.matrix_from_rotvec(rotvec)
    t_mm = np.column_stack([900 + 100 * s, -150 + 60 * s, 600 - 40 * s ** 2])
    profile_ns = (pose_ns[5] + np.arange(n_profiles, dtype=np.int64) * 12_345_678 + 1_000)
    pts = []
    for j in range(n_profiles):
        kk = k + j % 7
        p = np.zeros((kk, 3))
        p[:, 1] = rng.uniform(-0.02, 0.02, kk)
        p[:, 2] = rng.uniform(-0.06, 0.04, kk)
        pts.append(p)
    return Truth(pose_ns, R, t_mm, profile_ns, pts)


def q_xyzw(R) -> np.ndarray:
    return geo.quat_xyzw_from_wxyz(geo.quat_wxyz_from_matrix(R))


def profile_messages(truth: Truth, latency_ns=2_000_000, drift_ppm=50.0, **kw):
    """The profiles as clouds; their log times run ``drift_ppm`` fast of their stamps (a
    sensor clock of its own), so the bag does not look stamped by one clock."""
    ns0 = int(truth.profile_ns[0])
    return [(int(ns) + latency_ns + int((int(ns) - ns0) * drift_ppm * 1e-6), cloud(int(ns), p, **kw))
            for ns, p in zip(truth.profile_ns, truth.points_m)]


def pose_messages(truth: Truth, latency_ns=1_000_000, frame="base_link"):
    q = q_xyzw(truth.R)
    return [(int(ns) + latency_ns, pose_stamped(int(ns), truth.t_mm[i] / 1000.0, q[i], frame))
            for i, ns in enumerate(truth.pose_ns)]
