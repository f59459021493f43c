"""ROS 2 bags in (spherecal.io.rosbag): bags written here with rosbags, in both storages,
read back against the poses, stamps and points they were made from; and each kind of
bad bag failing with an error that names the cause."""

from __future__ import annotations

import re
import shutil
import warnings

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.errors import InputError
from spherecal.io.rosbag import (
    BagCloudError,
    BagCutShortError,
    BagError,
    BagStampError,
    BagTimeSpanError,
    BagTopicError,
    BagUnitsError,
    BagWarning,
    SameClockWarning,
    read_bag,
)
from spherecal.io.streams import read_recording, recording_kind, write_recording

from bag_files import (
    T0_NS,
    cloud,
    joint_state,
    make_truth,
    pose_messages,
    pose_stamped,
    profile_messages,
    q_xyzw,
    tf_message,
    transform,
    write_bag,
)

CLOUD = "sensor_msgs/msg/PointCloud2"
POSE = "geometry_msgs/msg/PoseStamped"
TF = "tf2_msgs/msg/TFMessage"
JOINTS = "sensor_msgs/msg/JointState"


def seconds(ns) -> np.ndarray:
    ns = np.asarray(ns, np.int64)
    return (ns // 1_000_000_000).astype(float) + (ns % 1_000_000_000).astype(float) * 1e-9


def expected_yz_mm(truth, cols=(1, 2)) -> np.ndarray:
    """The points as read: float32 metres times 1000, rounded to float32 (the value the
    stream file stores)."""
    return (np.concatenate(truth.points_m)[:, cols].astype(np.float32).astype(np.float64) * 1000.0).astype(np.float32)


def read(path, allow=(), **kw):
    args = dict(profile_topic="/profiles", pose_topic="/pose", mounting="eye_in_hand", sphere_radius_mm=19.05)
    args.update(kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean bag converts without a warning
        for category in allow:
            warnings.simplefilter("ignore", category)
        return read_bag(path, **args)


@pytest.fixture(params=["mcap", "sqlite3"])
def storage(request):
    return request.param


# -------------------------------------------------------------------------------------
# round trips
# -------------------------------------------------------------------------------------


def test_pose_stamped_bag_round_trip(tmp_path, storage):
    truth = make_truth()
    bag = write_bag(tmp_path / "bag", storage, {"/profiles": (CLOUD, profile_messages(truth)),
                                                "/pose": (POSE, pose_messages(truth)),
                                                "/rosout_like": (POSE, pose_messages(truth)[:3])})
    rec = read(bag)
    np.testing.assert_array_equal(rec.profiles.t_sensor_s, seconds(truth.profile_ns))
    np.testing.assert_array_equal(rec.poses.t_robot_s, seconds(truth.pose_ns))
    np.testing.assert_array_equal(rec.profiles.counts, [len(p) for p in truth.points_m])
    np.testing.assert_array_equal(rec.profiles.points_yz_mm, expected_yz_mm(truth))
    np.testing.assert_allclose(rec.poses.t_mm, truth.t_mm, rtol=0, atol=1e-9)
    np.testing.assert_allclose(rec.poses.R, truth.R, rtol=0, atol=1e-12)
    assert rec.poses.joints_deg is None and rec.profiles.frame is None and rec.profiles.sweep is None
    assert rec.sweeps == [] and rec.mounting == "eye_in_hand" and rec.sphere_radius_mm == 19.05
    assert rec.clocks == {"robot": "header stamps of /pose", "sensor": "header stamps of /profiles"}
    p = rec.provenance
    assert (p["source"], p["profile_topic"], p["pose_type"], p["cloud_frame_id"], p["base_frame_id"]) == \
        ("rosbag2", "/profiles", POSE, "sensor", "base_link")
    assert p["clock_check"]["same_clock"] is False
    assert abs(p["clock_check"]["relative_rate_ppm"] - 50) < 1  # the helper's sensor runs 50 ppm off
    # into the stream format and back: one path downstream
    out = tmp_path / "bag.stream.jsonl"
    write_recording(out, rec)
    back = read_recording(out)
    # the file holds float32 mm, the values read from the bag, bit for bit
    assert rec.profiles.points_yz_mm.dtype == np.float32
    np.testing.assert_array_equal(back.profiles.points_yz_mm, rec.profiles.points_yz_mm)
    np.testing.assert_array_equal(back.poses.t_robot_s, rec.poses.t_robot_s)
    np.testing.assert_allclose(back.poses.R, rec.poses.R, atol=2e-15)
    assert back.clocks == rec.clocks and back.provenance == rec.provenance
    # the storage file alone reads too
    (single,) = [f for f in bag.iterdir() if f.suffix in (".mcap", ".db3")]
    assert recording_kind(bag) == recording_kind(single) == "rosbag"
    np.testing.assert_array_equal(read(single).profiles.points_yz_mm, rec.profiles.points_yz_mm)


@pytest.mark.parametrize("layout", [
    dict(dtype="<f8"), dict(extra_field=True), dict(pad_row=6), dict(height=2, extra_field=True),
], ids=["float64", "intensity field", "padded rows", "organised 2 rows"])
def test_cloud_layouts(tmp_path, layout):
    truth = make_truth(n_profiles=20, k=40)
    truth.points_m = [p[:40] for p in truth.points_m]  # even counts for two rows
    bag = write_bag(tmp_path / "bag", "mcap", {"/profiles": (CLOUD, profile_messages(truth, **layout)),
                                               "/pose": (POSE, pose_messages(truth))})
    rec = read(bag)
    pts = np.concatenate(truth.points_m)[:, 1:]
    expected = pts.astype(np.float64) * 1000 if layout.get("dtype") == "<f8" else expected_yz_mm(truth)
    np.testing.assert_array_equal(rec.profiles.points_yz_mm, expected)


def test_a_driver_with_the_line_along_x(tmp_path):
    truth = make_truth(n_profiles=10)
    along_x = [p[:, [1, 0, 2]] for p in truth.points_m]  # (x, y, z) = (line, 0, range)
    msgs = profile_messages(truth)
    msgs = [(log, cloud(int(ns), p)) for (log, _), ns, p in zip(msgs, truth.profile_ns, along_x)]
    bag = write_bag(tmp_path / "bag", "mcap", {"/profiles": (CLOUD, msgs), "/pose": (POSE, pose_messages(truth))})
    rec = read(bag, line_axis="x")
    np.testing.assert_array_equal(rec.profiles.points_yz_mm, expected_yz_mm(truth))
    assert "Rz(+90 deg)" in rec.provenance["sensor_from_cloud_frame"]
    with pytest.raises(BagUnitsError, match=r"/profiles: message 0 .* up to 0.0[0-9]+ m off the laser plane \(x must "
                                            r"be 0 .*give line_axis='x'"):
        read(bag)
    with pytest.raises(InputError, match="line_axis must be 'y'"):
        read(bag, line_axis="z")


def _tf_bag(tmp_path, truth, storage="mcap", drop_static=False):
    """world -> base_link (static), base_link -> link_1 -> tool0 (moving), world -> camera
    and tool0 -> sensor_mount (static). Returns the bag and the 4x4 transforms."""
    rng = np.random.default_rng(3)
    n = len(truth.pose_ns)

    def rt(rotvec, t):
        M = np.tile(np.eye(4), (len(t), 1, 1))
        M[:, :3, :3] = geo.matrix_from_rotvec(rotvec)
        M[:, :3, 3] = t
        return M

    s = np.linspace(0, 1, n)[:, None]
    M1 = rt(np.hstack([0 * s, 0 * s, 0.8 * s]), np.hstack([0 * s, 0 * s, 0.4 + 0 * s]))  # base_link -> link_1
    M2 = rt(np.hstack([0.3 * s, 0.5 + 0 * s, 0.1 * s]), np.hstack([0.7 + 0.1 * s, 0.1 * s, 0.2 + 0 * s]))
    W_base = rt(rng.normal(0, 0.3, (1, 3)), rng.normal(0, 1, (1, 3)))[0]  # world -> base_link
    W_cam = rt(rng.normal(0, 0.3, (1, 3)), rng.normal(0, 1, (1, 3)))[0]  # world -> camera
    F_mount = rt(rng.normal(0, 0.3, (1, 3)), rng.normal(0, 0.1, (1, 3)))[0]  # tool0 -> sensor_mount

    def tr(ns, parent, child, M):
        return transform(ns, parent, child, M[:3, 3], q_xyzw(M[:3, :3]))

    dyn = [(int(ns) + 1_000_000, tf_message([tr(int(ns), "base_link", "link_1", M1[i]),
                                              tr(int(ns), "link_1", "tool0", M2[i])]))
           for i, ns in enumerate(truth.pose_ns)]
    static = [(T0_NS, tf_message([tr(T0_NS, "world", "base_link", W_base), tr(T0_NS, "world", "camera", W_cam),
                                  tr(T0_NS, "tool0", "sensor_mount", F_mount)]))]
    topics = {"/profiles": (CLOUD, profile_messages(truth)), "/tf": (TF, dyn)}
    if not drop_static:
        topics["/tf_static"] = (TF, static)
    bag = write_bag(tmp_path / "bag", storage, topics)
    return bag, M1, M2, W_base, W_cam, F_mount


def test_tf_chain_composed_from_dynamic_and_static_transforms(tmp_path, storage):
    truth = make_truth()
    bag, M1, M2, W_base, W_cam, F_mount = _tf_bag(tmp_path, truth, storage)
    cases = {
        ("base_link", "tool0"): M1 @ M2,
        ("world", "sensor_mount"): W_base @ M1 @ M2 @ F_mount,
        ("camera", "tool0"): np.linalg.inv(W_cam) @ W_base @ M1 @ M2,  # through their common parent, world
    }
    for (base, flange), M in cases.items():
        rec = read(bag, pose_topic="/tf", base_frame=base, flange_frame=flange)
        np.testing.assert_allclose(rec.poses.R, M[:, :3, :3], atol=1e-12, err_msg=f"{base}->{flange}")
        np.testing.assert_allclose(rec.poses.t_mm, M[:, :3, 3] * 1000, atol=1e-9, err_msg=f"{base}->{flange}")
        np.testing.assert_array_equal(rec.poses.t_robot_s, seconds(truth.pose_ns))
        assert rec.provenance["tf_chain"]["moving"] == ["link_1->tool0", "base_link->link_1"]


def test_tf_errors(tmp_path):
    truth = make_truth(n_profiles=10)
    bag, *_ = _tf_bag(tmp_path, truth)
    with pytest.raises(InputError, match="name the two frames of the flange pose, base_frame .* and flange_frame"):
        read(bag, pose_topic="/tf")
    with pytest.raises(BagTopicError, match=r"flange_frame 'tool_0' is in no transform on /tf or /tf_static; the tree "
                                            r"has: .*link_1->tool0"):
        read(bag, pose_topic="/tf", base_frame="base_link", flange_frame="tool_0")
    with pytest.raises(BagTopicError, match=r"no transform between 'world' and 'camera' moves"):
        read(bag, pose_topic="/tf", base_frame="world", flange_frame="camera")
    shutil.rmtree(bag)
    bag, *_ = _tf_bag(tmp_path, truth, drop_static=True)
    with pytest.raises(BagTopicError, match=r"base_frame 'world' is in no transform"):
        read(bag, pose_topic="/tf", base_frame="world", flange_frame="tool0")


def test_joint_states_through_the_robots_kinematics(tmp_path, storage):
    truth = make_truth(n_profiles=20)
    rng = np.random.default_rng(5)
    q_rad = np.cumsum(rng.normal(0, 0.002, (len(truth.pose_ns), 3)), axis=0) + [0.1, -0.5, 1.2]
    names = ["joint_1", "joint_2", "joint_3"]
    msgs = [(int(ns) + 900_000, joint_state(int(ns), names[::-1], q_rad[i, ::-1]))  # the driver's own order
            for i, ns in enumerate(truth.pose_ns)]
    gripper = [(int(ns) + 950_000, joint_state(int(ns) + 7, ["finger"], [0.01])) for ns in truth.pose_ns[::20]]

    def fk(q_deg):  # a toy arm: Rz(q1) Ry(q2), reach along x scaled by q3
        q = np.radians(q_deg)
        R = geo.matrix_from_rotvec(np.column_stack([0 * q[:, 0], 0 * q[:, 0], q[:, 0]])) @ \
            geo.matrix_from_rotvec(np.column_stack([0 * q[:, 1], q[:, 1], 0 * q[:, 1]]))
        return R, np.einsum("nij,j->ni", R, [800.0, 0, 0]) * q[:, 2:3]

    bag = write_bag(tmp_path / "bag", storage, {"/profiles": (CLOUD, profile_messages(truth)),
                                                "/joint_states": (JOINTS, msgs + gripper)})
    with pytest.warns(BagWarning, match=r"skipped 10 of 210 messages without the joints \['joint_1', 'joint_2', "
                                        r"'joint_3'\]"):
        rec = read_bag(bag, profile_topic="/profiles", pose_topic="/joint_states", mounting="eye_to_hand",
                       sphere_radius_mm=25.0, joints_to_pose=fk, joint_names=names)
    np.testing.assert_allclose(rec.poses.joints_deg, np.degrees(q_rad), atol=1e-12)
    R, t = fk(np.degrees(q_rad))
    np.testing.assert_allclose(rec.poses.R, R, atol=1e-12)
    np.testing.assert_allclose(rec.poses.t_mm, t, atol=1e-9)
    assert rec.provenance["joint_names"] == names
    with pytest.raises(InputError, match="joint states .* need the robot's kinematics"):
        read(bag, pose_topic="/joint_states")
    with pytest.raises(InputError, match=r"joints_to_pose must return finite rotations \(n, 3, 3\)"):
        read(bag, pose_topic="/joint_states", joint_names=names, joints_to_pose=lambda q: (np.eye(3), q[:, :3]),
             allow=[BagWarning])


# -------------------------------------------------------------------------------------
# bad bags
# -------------------------------------------------------------------------------------


def _bag(tmp_path, truth=None, profiles=None, poses=None, name="bag", **kw):
    truth = truth or make_truth(n_profiles=20)
    return write_bag(tmp_path / name, "mcap", {
        "/profiles": (CLOUD, profiles if profiles is not None else profile_messages(truth, **kw)),
        "/pose": (POSE, poses if poses is not None else pose_messages(truth))})


def test_missing_topics_and_wrong_types_list_what_the_bag_has(tmp_path):
    bag = _bag(tmp_path)
    with pytest.raises(BagTopicError, match=r"no topic '/scan' \(the profile topic\); the bag has: /pose "
                                            r"\(geometry_msgs/msg/PoseStamped, 200 messages\); /profiles "
                                            r"\(sensor_msgs/msg/PointCloud2, 20 messages\)"):
        read(bag, profile_topic="/scan")
    with pytest.raises(BagTopicError, match=r"no topic '/tool_pose' \(the pose topic\)"):
        read(bag, pose_topic="/tool_pose")
    with pytest.raises(BagTopicError, match=r"/pose holds geometry_msgs/msg/PoseStamped; the profile topic must hold "
                                            r"sensor_msgs/msg/PointCloud2"):
        read(bag, profile_topic="/pose")
    with pytest.raises(BagTopicError, match=r"/profiles holds sensor_msgs/msg/PointCloud2; the pose topic must hold "
                                            r"geometry_msgs/msg/PoseStamped or tf2_msgs/msg/TFMessage or "
                                            r"sensor_msgs/msg/JointState"):
        read(bag, pose_topic="/profiles")
    with pytest.raises(BagTopicError, match=r"/pose: the poses are in frame 'base_link', not base_frame 'world'"):
        read(bag, base_frame="world")


def test_not_a_bag(tmp_path):
    with pytest.raises(BagError, match="no such file or folder"):
        read(tmp_path / "nothing")
    (tmp_path / "folder").mkdir()
    with pytest.raises(BagError, match="a folder without metadata.yaml"):
        read(tmp_path / "folder")
    (tmp_path / "x.mcap").write_bytes(b"not an mcap file")
    with pytest.raises(BagError, match="cannot read the bag"):
        read(tmp_path / "x.mcap")
    (tmp_path / "x.jsonl").write_text("{}\n")
    with pytest.raises(BagError, match="not a rosbag2 recording"):
        read(tmp_path / "x.jsonl")


@pytest.mark.parametrize("storage, fraction", [("mcap", 0.6), ("mcap", 0.999), ("sqlite3", 0.5)])
def test_a_bag_cut_short_says_so_and_names_the_repair(tmp_path, storage, fraction):
    """A recording interrupted leaves a storage file without its end: the error says the
    bag looks cut short and names the file and the tools that repair it, for the bag
    folder and for the file given alone."""
    truth = make_truth(n_poses=400, n_profiles=150)
    bag = write_bag(tmp_path / "bag", storage, {"/profiles": (CLOUD, profile_messages(truth)),
                                               "/pose": (POSE, pose_messages(truth))})
    (file,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    data = file.read_bytes()
    file.write_bytes(data[:int(len(data) * fraction)])
    alone = tmp_path / f"alone{file.suffix}"
    shutil.copy(file, alone)
    repair = r"`mcap recover .*` \(the mcap CLI\)" if storage == "mcap" else r"`sqlite3 .* \.recover \| sqlite3 "
    with pytest.raises(BagCutShortError, match=rf"bag: the bag looks cut short \(a recording interrupted\): "
                                               rf"{re.escape(str(file))}.*Repair it: {repair}.*"
                                               rf"`ros2 bag reindex {re.escape(str(bag))}`"):
        read(bag)
    with pytest.raises(BagCutShortError, match=rf"the bag looks cut short.*{re.escape(str(alone))}.*Repair it: {repair}") \
            as err:
        read(alone)
    assert "reindex" not in str(err.value)  # a file alone has no metadata.yaml to rewrite
    # a whole file with its own damage keeps the storage library's word
    (tmp_path / "x.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(100) + b"\x89MCAP0\r\n")
    with pytest.raises(BagError, match="cannot read the bag") as err:
        read(tmp_path / "x.mcap")
    assert "cut short" not in str(err.value)


def test_millimetres_where_metres_belong(tmp_path):
    truth = make_truth(n_profiles=20)
    mm = [p * 1000 for p in truth.points_m]
    msgs = [(log, cloud(int(ns), p)) for (log, _), ns, p in zip(profile_messages(truth), truth.profile_ns, mm)]
    with pytest.raises(BagUnitsError, match=r"/profiles: the points look like millimetres, not metres: a typical "
                                            r"profile reaches [0-9.]+ from the sensor, more than 5 if that were metres"):
        read(_bag(tmp_path, truth, profiles=msgs))
    q = q_xyzw(truth.R)
    poses_mm = [(int(ns) + 10, pose_stamped(int(ns), truth.t_mm[i], q[i])) for i, ns in enumerate(truth.pose_ns)]
    with pytest.raises(BagUnitsError, match=r"/pose: the flange positions look like millimetres, not metres"):
        read(_bag(tmp_path, truth, poses=poses_mm, name="bag2"))


def test_empty_and_non_finite_clouds(tmp_path):
    truth = make_truth(n_profiles=20)
    empty = [np.zeros((0, 3))] * 20
    msgs = [(log, cloud(int(ns), p)) for (log, _), ns, p in zip(profile_messages(truth), truth.profile_ns, empty)]
    with pytest.raises(BagCloudError, match=r"/profiles: all 20 clouds are empty \(no finite point\)"):
        read(_bag(tmp_path, truth, profiles=msgs))
    # some empty clouds are profiles with no point
    some = [p if j % 3 else p[:0] for j, p in enumerate(truth.points_m)]
    msgs = [(log, cloud(int(ns), p)) for (log, _), ns, p in zip(profile_messages(truth), truth.profile_ns, some)]
    rec = read(_bag(tmp_path, truth, profiles=msgs, name="some"))
    np.testing.assert_array_equal(rec.profiles.counts, [len(p) for p in some])
    assert rec.provenance["n_empty_clouds"] == 7
    # NaN in a cloud that says it is dense: an error; in one that says it may not be: dropped
    nan = [p.copy() for p in truth.points_m]
    nan[4][3, 2] = np.nan
    nan[9][0, 1] = np.inf
    for dense in (True, False):
        msgs = [(log, cloud(int(ns), p, is_dense=dense)) for (log, _), ns, p in
                zip(profile_messages(truth), truth.profile_ns, nan)]
        bag = _bag(tmp_path, truth, profiles=msgs, name=f"nan{dense}")
        if dense:
            with pytest.raises(BagCloudError, match=r"message 4 \(stamp [0-9.]+ s\) says is_dense \(no invalid "
                                                    r"points\) but point 3 is not finite; 2 such clouds"):
                read(bag)
        else:
            with pytest.warns(BagWarning, match=r"dropped 2 invalid \(NaN or infinite\) points from 2 clouds"):
                rec = read_bag(bag, profile_topic="/profiles", pose_topic="/pose", mounting="eye_in_hand",
                               sphere_radius_mm=19.05)
            keep = [np.delete(p, np.flatnonzero(~np.isfinite(p).all(axis=1)), axis=0) for p in nan]
            np.testing.assert_array_equal(rec.profiles.points_yz_mm,
                                          (np.concatenate(keep)[:, 1:].astype(np.float32).astype(float) * 1000)
                                          .astype(np.float32))
            np.testing.assert_array_equal(rec.profiles.counts, [len(p) for p in keep])


def test_a_cloud_without_x_y_z(tmp_path):
    truth = make_truth(n_profiles=5)
    msgs = profile_messages(truth)
    bad = msgs[2][1]
    bad.fields[0].name = "u"
    with pytest.raises(BagCloudError, match=r"/profiles: message 2 \(stamp [0-9.]+ s\): no field x \(fields: u, y, "
                                            r"z\); a profile is a cloud of x, y, z"):
        read(_bag(tmp_path, truth, profiles=msgs))


@pytest.mark.parametrize("which, change, message", [
    ("profiles", lambda ns: ns.__setitem__(7, ns[6] - 1000), r"/profiles: the header stamp of message 7 goes "
                                                             r"backwards from message 6's"),
    ("profiles", lambda ns: ns.__setitem__(7, ns[6]), r"/profiles: the header stamp of message 7 repeats message 6's"),
    ("profiles", lambda ns: ns.__setitem__(slice(7, None), ns[7:] + 4000 * 10**9),
     r"/profiles: the header stamp jumps 400[0-9.]+ s from message 6 to 7 .* a clock jump"),
    ("profiles", lambda ns: ns.__setitem__(0, 0), r"/profiles: message 0 .* has header stamp 0 s: the driver does not "
                                                  r"stamp its profiles"),
    ("poses", lambda ns: ns.__setitem__(50, ns[49] - 1), r"/pose: the header stamp of message 50 goes backwards"),
])
def test_stamps_going_backwards_repeating_jumping_or_unset(tmp_path, which, change, message):
    truth = make_truth(n_profiles=20)
    change(truth.profile_ns if which == "profiles" else truth.pose_ns)
    # the bag's log times stay in order: only the header stamps are wrong
    profiles = [(T0_NS + 10**9 + j * 10**6, m) for j, (_, m) in enumerate(profile_messages(truth))]
    poses = [(T0_NS + 10**9 + j * 10**6, m) for j, (_, m) in enumerate(pose_messages(truth))]
    with pytest.raises(BagStampError, match=message):
        read(_bag(tmp_path, truth, profiles=profiles, poses=poses))


def test_exact_duplicate_messages_are_dropped_and_counted(tmp_path, storage):
    """A message recorded twice (the same stamp and content, a little later in the log)
    is dropped with a warning that counts them; the bag reads as without them. A
    repeated stamp with other content stays an error (the parametrised test above)."""
    truth = make_truth(n_profiles=30)
    profiles, poses = profile_messages(truth), pose_messages(truth)
    clean = read(write_bag(tmp_path / "clean", storage, {"/profiles": (CLOUD, profiles), "/pose": (POSE, poses)}))
    twice = profiles + [(log + 1000, m) for log, m in profiles[10:13]]
    poses_twice = poses + [(log + 1000, m) for log, m in poses[50:100:10]]
    bag = write_bag(tmp_path / "dup", storage, {"/profiles": (CLOUD, twice), "/pose": (POSE, poses_twice)})
    with pytest.warns(BagWarning) as seen:
        rec = read_bag(bag, profile_topic="/profiles", pose_topic="/pose", mounting="eye_in_hand",
                       sphere_radius_mm=19.05)
    texts = sorted(str(w.message) for w in seen)
    assert len(texts) == 2, texts
    assert re.search(r"/pose: dropped 5 exact duplicate messages .*the first: message 51 of 205", texts[0]), texts
    assert re.search(r"/profiles: dropped 3 exact duplicate messages .*the first: message 11 of 33", texts[1]), texts
    np.testing.assert_array_equal(rec.profiles.points_yz_mm, clean.profiles.points_yz_mm)
    np.testing.assert_array_equal(rec.profiles.t_sensor_s, clean.profiles.t_sensor_s)
    np.testing.assert_array_equal(rec.poses.t_robot_s, clean.poses.t_robot_s)
    np.testing.assert_array_equal(rec.poses.t_mm, clean.poses.t_mm)


def test_profiles_outside_the_pose_streams_span(tmp_path):
    truth = make_truth(n_profiles=20)
    late = truth.profile_ns.copy()
    late[-3:] = truth.pose_ns[-1] + np.arange(1, 4) * 1_000_000
    truth.profile_ns = late
    with pytest.warns(BagWarning, match=r"3 of 20 profiles lie outside the pose stream's time span \(/profiles: "
                                        r"[0-9.]+ to [0-9.]+ s; /pose: [0-9.]+ to [0-9.]+ s, header stamps\)"):
        rec = read_bag(_bag(tmp_path, truth), profile_topic="/profiles", pose_topic="/pose", mounting="eye_in_hand",
                       sphere_radius_mm=19.05)
    assert rec.profiles.n == 20  # kept: the clocks' offset may bring them in
    # on another clock altogether (stamped 10 s off the computer's log times, the poses
    # not): the spans say nothing before the clock offset is known, the solve searches it
    truth.profile_ns = truth.profile_ns + 10 * 10**9
    rec = read(_bag(tmp_path, truth, name="other"))
    assert rec.profiles.n == 20 and rec.clocks["robot"] != rec.clocks["sensor"]


def test_both_streams_stamped_by_the_recording_computer(tmp_path):
    truth = make_truth(n_poses=600, n_profiles=120)
    rng = np.random.default_rng(1)
    # stamped on reception: each log time 0.1 ms after its stamp, 20 us of jitter, no drift
    profiles = [(int(ns) + int(rng.uniform(1e5, 1.2e5)), m) for (_, m), ns in
                zip(profile_messages(truth, drift_ppm=0), truth.profile_ns)]
    poses = [(int(ns) + int(rng.uniform(1e5, 1.2e5)), m) for (_, m), ns in zip(pose_messages(truth), truth.pose_ns)]
    with pytest.warns(SameClockWarning, match=r"/profiles and /pose look stamped by one clock, the recording "
                                              r"computer's.*No drift between the robot's and the sensor's clocks can "
                                              r"be seen"):
        rec = read_bag(_bag(tmp_path, truth, profiles=profiles, poses=poses), profile_topic="/profiles",
                       pose_topic="/pose", mounting="eye_in_hand", sphere_radius_mm=19.05)
    assert rec.clocks["robot"] == rec.clocks["sensor"] == "recording computer"
    assert rec.provenance["clock_check"]["same_clock"] is True


def test_log_times_copied_from_the_stamps_show_no_one_clock(tmp_path):
    """A converter that writes each message's log time = its header stamp makes each topic
    look stamped on reception; stamps 1.77e9 s apart (the sensor's epoch, the robot's
    power-on) are two clocks all the same: no SameClockWarning, no span error, the solve
    searches the offset."""
    truth = make_truth(n_poses=600, n_profiles=120)
    truth.pose_ns = truth.pose_ns - T0_NS + 3_725 * 10**9  # the controller counts from power-on
    profiles = [(int(ns), m) for (_, m), ns in zip(profile_messages(truth, drift_ppm=0), truth.profile_ns)]
    poses = [(int(ns), m) for (_, m), ns in zip(pose_messages(truth), truth.pose_ns)]
    rec = read(_bag(tmp_path, truth, profiles=profiles, poses=poses))  # any warning fails
    assert rec.clocks == {"robot": "header stamps of /pose", "sensor": "header stamps of /profiles"}
    check = rec.provenance["clock_check"]
    assert check["same_clock"] is False and check["stamp_spans_gap_s"] > 1e9
    np.testing.assert_array_equal(rec.poses.t_robot_s, seconds(truth.pose_ns))


def test_pose_stamped_read_at_once_as_one_by_one(tmp_path):
    """A driver's PoseStamped messages, all of one layout, are read in one block; the
    values are those of the message-by-message reading, and messages in two frames or
    with a non-finite value are still named."""
    from spherecal.io.rosbag import _pose_stamped_block, _pose_stamped_one_by_one
    from bag_files import TS

    truth = make_truth(n_poses=30)
    raws = [bytes(TS.serialize_cdr(m, POSE)) for _, m in pose_messages(truth)]
    block = _pose_stamped_block(raws)
    assert block is not None
    for a, b in zip(block, _pose_stamped_one_by_one(raws, "bag", "/pose")):
        if isinstance(a, set):
            assert a == b == {"base_link"}
        else:
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(block[2 + 1][:, :3], truth.t_mm / 1000.0)

    other = [bytes(TS.serialize_cdr(m, POSE)) for _, m in pose_messages(truth, frame="world")]
    assert _pose_stamped_block(raws[:10] + other[10:]) is None  # two frames: read one by one
    msgs = pose_messages(truth)
    msgs = msgs[:10] + pose_messages(truth, frame="world")[10:]
    bag = write_bag(tmp_path / "two", "mcap", {"/profiles": (CLOUD, profile_messages(truth)[:5]), "/pose": (POSE, msgs)})
    with pytest.raises(BagTopicError, match=r"/pose: poses in 2 frames \('base_link', 'world'\)"):
        read(bag)
    bad = pose_messages(truth)
    bad[7][1].pose.position.x = float("nan")
    bag = write_bag(tmp_path / "nan", "mcap", {"/profiles": (CLOUD, profile_messages(truth)[:5]), "/pose": (POSE, bad)})
    with pytest.raises(BagTopicError, match=r"/pose: message 7 has a non-finite pose"):
        read(bag)
