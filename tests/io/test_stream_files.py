"""Stream recordings (dataset format version 3, form "stream"): round trips, a file that
grows while it is read, interrupted writes, and bad files failing with messages that
name the file, the line and the field."""

from __future__ import annotations

import base64
import json
import warnings

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.errors import DatasetFileError, InputError
from spherecal.core.streams import PoseStream, ProfileStream, Recording, SweepInfo
from spherecal.io.dataset import TruncatedFileWarning, read_dataset, read_dataset_header
from spherecal.io.streams import (
    MAX_STAMP_STEP_S,
    POSES_PER_LINE,
    RecordingWriter,
    read_recording,
    recording_kind,
    write_recording,
)

SWEEPS = [SweepInfo("S1", 100.0, (1.0, 0.0, 0.0)), SweepInfo("S1", 50.0, (-0.6, 0.8, 0.0))]
CLOCKS = {"robot": "abb-egm", "sensor": "nxsensor-i"}


def make_recording(n_poses=600, n_profiles=40, joints=True, seq=True, frame=True, sweep=True, seed=0) -> Recording:
    rng = np.random.default_rng(seed)
    t = 1.7e9 + 0.004 * np.arange(n_poses) + rng.uniform(0, 1e-4, n_poses)  # epoch seconds, jittered
    q = rng.normal(size=(n_poses, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    poses = PoseStream.from_quaternions(
        t, rng.uniform(-1500, 1500, (n_poses, 3)), q,
        rng.uniform(-180, 180, (n_poses, 6)) if joints else None,
        np.arange(n_poses) * 2 + 7 if seq else None)
    counts = rng.integers(0, 50, n_profiles)
    counts[0] = 3
    profiles = [np.column_stack([rng.normal(0, 20, k), rng.uniform(-60, 40, k)]) for k in counts]
    ps = ProfileStream.from_profiles(
        12.5 + 0.002 * np.arange(n_profiles) + rng.uniform(0, 1e-5, n_profiles), profiles,
        frame=np.arange(n_profiles) + 1000 if frame else None,
        sweep=rng.integers(-1, 2, n_profiles) if sweep else None)
    return Recording("eye_to_hand", 12.7, poses, ps, list(SWEEPS) if sweep else [],
                     {"cell": "lab-2", "truth": {"offset_s": 0.0123}}, dict(CLOCKS))


def assert_same(a: Recording, b: Recording) -> None:
    """b read back from a's file: stamps, translations, joints, seq, frames exact; points
    exact to float32; rotations to rounding."""
    assert (a.mounting, a.sphere_radius_mm, a.sweeps, a.clocks) == (b.mounting, b.sphere_radius_mm, b.sweeps, b.clocks)
    assert b.provenance == a.provenance
    np.testing.assert_array_equal(b.poses.t_robot_s, a.poses.t_robot_s)
    np.testing.assert_array_equal(b.poses.t_mm, a.poses.t_mm)
    np.testing.assert_allclose(b.poses.R, a.poses.R, rtol=0, atol=2e-15)
    for name in ("joints_deg", "seq"):
        x, y = getattr(a.poses, name), getattr(b.poses, name)
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(y, x)
    np.testing.assert_array_equal(b.profiles.t_sensor_s, a.profiles.t_sensor_s)
    np.testing.assert_array_equal(b.profiles.start, a.profiles.start)
    assert b.profiles.points_yz_mm.dtype == np.float64
    np.testing.assert_array_equal(b.profiles.points_yz_mm, a.profiles.points_yz_mm.astype(np.float32))
    for name in ("frame", "sweep"):
        x, y = getattr(a.profiles, name), getattr(b.profiles, name)
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(y, x)


@pytest.mark.parametrize("optional", [True, False], ids=["all fields", "required only"])
def test_round_trip(tmp_path, optional, parser):
    rec = make_recording(joints=optional, seq=optional, frame=optional, sweep=optional)
    path = tmp_path / "run.stream.jsonl"
    write_recording(path, rec)
    back = read_recording(path)
    assert_same(rec, back)
    lines = path.read_text().splitlines()
    header = json.loads(lines[0])
    assert (header["format"], header["version"], header["form"]) == ("spherecal-dataset", 3, "stream")
    assert header["clocks"] == CLOCKS
    assert sum("poses" in json.loads(x) for x in lines[1:]) == -(-600 // POSES_PER_LINE)
    assert sum("profile" in json.loads(x) for x in lines[1:]) == 40
    assert recording_kind(path) == "stream"


def test_the_file_holds_what_the_format_says(tmp_path):
    """Stamps are float64 JSON numbers that read back exactly; points are little-endian
    float32 (y, z) interleaved; quaternions (w, x, y, z) with w >= 0."""
    rec = make_recording(n_poses=3, n_profiles=1)
    path = tmp_path / "r.jsonl"
    write_recording(path, rec)
    poses, profile = (json.loads(x) for x in path.read_text().splitlines()[1:])
    assert poses["poses"]["t_robot_s"] == rec.poses.t_robot_s.tolist()
    q = np.array(poses["poses"]["quaternion_wxyz"])
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(geo.matrix_from_quat_wxyz(q), rec.poses.R, atol=1e-15)
    raw = base64.b64decode(profile["profile"]["points_yz_mm_f32le"])
    pts = np.frombuffer(raw, "<f4").reshape(-1, 2)
    np.testing.assert_array_equal(pts, rec.profiles.profile(0).astype(np.float32))
    assert profile["profile"]["t_sensor_s"] == rec.profiles.t_sensor_s[0]


def test_writer_appends_lines_that_read_back_while_it_is_open(tmp_path):
    rec = make_recording(n_poses=400, n_profiles=12)
    path = tmp_path / "live.jsonl"
    p, pr = rec.poses, rec.profiles
    with RecordingWriter(path, mounting=rec.mounting, sphere_radius_mm=rec.sphere_radius_mm, clocks=rec.clocks,
                         sweeps=rec.sweeps, provenance=rec.provenance) as out:
        for k in range(4):  # poses and profiles interleaved, as an acquisition writes them
            a, b = 100 * k, 100 * (k + 1)
            out.add_poses(p.t_robot_s[a:b], p.t_mm[a:b], p.quaternion_wxyz[a:b], p.joints_deg[a:b], p.seq[a:b])
            for j in range(3 * k, 3 * k + 3):
                out.add_profile(pr.t_sensor_s[j], pr.profile(j), frame=int(pr.frame[j]), sweep=int(pr.sweep[j]))
            so_far = read_recording(path)  # every call's lines are flushed
            assert so_far.poses.n == b and so_far.profiles.n == 3 * k + 3
        assert (out.n_pose_samples, out.n_profiles) == (400, 12)
    assert_same(rec, read_recording(path))


def test_poses_given_as_columns_of_one_table_write(tmp_path):
    """A driver that keeps one row per sample (seq, stamp, pose, joints) hands the writer
    column slices of that table, arrays that are not contiguous in memory: they are
    written and read back as any others."""
    rec = make_recording(n_poses=300, n_profiles=5)
    p = rec.poses
    table = np.column_stack([p.seq, p.t_robot_s, p.t_mm, p.quaternion_wxyz, p.joints_deg])
    assert not table[:, 2:5].flags.c_contiguous
    path = tmp_path / "columns.jsonl"
    with RecordingWriter(path, mounting=rec.mounting, sphere_radius_mm=rec.sphere_radius_mm, clocks=rec.clocks,
                         sweeps=rec.sweeps, provenance=rec.provenance) as out:
        out.add_poses(table[:, 1], table[:, 2:5], table[:, 5:9], table[:, 9:], table[:, 0].astype(np.int64))
        out.add_profiles(rec.profiles.t_sensor_s, rec.profiles.points_yz_mm, rec.profiles.start,
                         frame=rec.profiles.frame, sweep=rec.profiles.sweep)
    assert_same(rec, read_recording(path))


def test_profiles_without_points(tmp_path):
    """A sensor that sees nothing sends empty profiles: a batch may hold no point at all."""
    path = tmp_path / "empty.jsonl"
    with RecordingWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05) as out:
        out.add_poses([0.0, 1.0], [[0, 0, 0]] * 2, [IDENT] * 2)
        out.add_profiles(np.arange(300) * 0.01, np.zeros((0, 2)), np.zeros(301, int))
        out.add_profile(3.5, [[1.0, -20.0]])
        out.add_profile(3.6, np.zeros((0, 2)))
    rec = read_recording(path)
    assert rec.profiles.n == 302
    np.testing.assert_array_equal(rec.profiles.counts, [0] * 300 + [1, 0])
    np.testing.assert_array_equal(rec.profiles.points_yz_mm, [[1.0, -20.0]])


def test_add_profiles_writes_a_flat_batch(tmp_path):
    rec = make_recording(n_profiles=30)
    pr = rec.profiles
    path = tmp_path / "batch.jsonl"
    with RecordingWriter(path, mounting=rec.mounting, sphere_radius_mm=rec.sphere_radius_mm, clocks=rec.clocks,
                         sweeps=rec.sweeps, provenance=rec.provenance) as out:
        out.add_poses(rec.poses.t_robot_s, rec.poses.t_mm, rec.poses.quaternion_wxyz, rec.poses.joints_deg,
                      rec.poses.seq)
        s = pr.start
        out.add_profiles(pr.t_sensor_s[:10], pr.points_yz_mm[:s[10]], s[:11], frame=pr.frame[:10], sweep=pr.sweep[:10])
        out.add_profiles(pr.t_sensor_s[10:], pr.points_yz_mm[s[10]:], s[10:] - s[10], frame=pr.frame[10:],
                         sweep=pr.sweep[10:])
    assert_same(rec, read_recording(path))


# -------------------------------------------------------------------------------------
# interrupted writes
# -------------------------------------------------------------------------------------


def test_a_killed_acquisition_reads_up_to_its_last_whole_line(tmp_path):
    rec = make_recording(n_poses=300, n_profiles=10)
    path = tmp_path / "killed.jsonl"
    write_recording(path, rec)
    data = path.read_bytes()
    last = data.rstrip(b"\n").rfind(b"\n") + 1  # the last line (a profile) starts here
    path.write_bytes(data[:last + 40])  # cut 40 bytes into it
    with pytest.warns(TruncatedFileWarning, match=rf"line 13 is incomplete.*dropped 40 bytes from byte {last}.*"
                                                 r"loaded the 9 whole profiles and 300 pose samples"):
        back = read_recording(path)
    assert back.profiles.n == 9 and back.poses.n == 300
    np.testing.assert_array_equal(back.profiles.points_yz_mm, rec.profiles.points_yz_mm[:rec.profiles.start[9]]
                                  .astype(np.float32))
    # the newline alone missing: the line is whole and read
    path.write_bytes(data.rstrip(b"\n"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_recording(path).profiles.n == 10
    path.write_bytes(data[:50])
    with pytest.raises(DatasetFileError, match="ends inside its header"):
        read_recording(path)
    path.write_bytes(b"")
    with pytest.raises(DatasetFileError, match="the file is empty"):
        read_recording(path)


def test_a_recording_without_profiles_or_poses_is_refused(tmp_path):
    rec = make_recording(n_poses=300, n_profiles=10)
    path = tmp_path / "r.jsonl"
    with RecordingWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05) as out:
        out.add_poses(rec.poses.t_robot_s, rec.poses.t_mm, rec.poses.quaternion_wxyz)
    with pytest.raises(DatasetFileError, match=r"holds no profiles \(300 pose samples\)"):
        read_recording(path)
    path.unlink()
    with RecordingWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05) as out:
        out.add_profile(1.0, [[0.0, -20.0]])
    with pytest.raises(DatasetFileError, match="holds 0 pose samples; a recording needs at least 2"):
        read_recording(path)


# -------------------------------------------------------------------------------------
# bad files
# -------------------------------------------------------------------------------------

HEADER = {"format": "spherecal-dataset", "version": 3, "form": "stream", "mounting": "eye_in_hand",
          "sphere_radius_mm": 19.05, "clocks": {"robot": "egm", "sensor": "nx"},
          "sweeps": [{"station": "S1", "speed_mm_s": 100.0, "direction": [1.0, 0.0, 0.0]}],
          "provenance": {}, "created": "2026-01-01T00:00:00Z"}
IDENT = [1.0, 0.0, 0.0, 0.0]


def b64(points) -> str:
    return base64.b64encode(np.asarray(points, "<f4").tobytes()).decode()


def poses_line(t, **changes) -> dict:
    n = len(t)
    d = {"t_robot_s": list(t), "translation_mm": [[1.0, 2.0, 3.0]] * n, "quaternion_wxyz": [IDENT] * n}
    d.update(changes)
    return {"poses": {k: v for k, v in d.items() if v is not ...}}


def profile_line(t, points=((1.0, -20.0), (2.0, -21.0)), **changes) -> dict:
    d = {"t_sensor_s": t, "sweep": 0, "points_yz_mm_f32le": b64(points)}
    d.update(changes)
    return {"profile": {k: v for k, v in d.items() if v is not ...}}


def good_lines() -> list[dict]:
    return [poses_line([10.0, 10.004, 10.008]), profile_line(5.0), poses_line([10.012, 10.016]),
            profile_line(5.002), profile_line(5.004)]


def write_file(path, lines, header=None) -> None:
    h = dict(HEADER)
    h.update(header or {})
    h = {k: v for k, v in h.items() if v is not ...}
    path.write_text("\n".join(json.dumps(x) for x in [h, *lines]) + "\n")


def test_the_hand_written_example_reads(tmp_path):
    path = tmp_path / "ok.jsonl"
    write_file(path, good_lines())
    rec = read_recording(path)
    assert rec.poses.n == 5 and rec.profiles.n == 3
    np.testing.assert_array_equal(rec.profiles.points_yz_mm, [[1, -20], [2, -21]] * 3)
    np.testing.assert_array_equal(rec.profiles.sweep, [0, 0, 0])
    assert rec.profiles.frame is None and rec.poses.joints_deg is None
    assert rec.clocks == {"robot": "egm", "sensor": "nx"}


@pytest.mark.parametrize("field", ["format", "version", "form", "mounting", "sphere_radius_mm", "clocks", "sweeps",
                                   "created"])
def test_a_missing_header_field_is_named(tmp_path, field):
    path = tmp_path / "h.jsonl"
    write_file(path, good_lines(), {field: ...})
    expected = {"format": "not a spherecal stream recording: line 1 should be a header with format",
                "version": "a stream recording has version 3 and form 'stream', found version null",
                "form": "found version 3 and form null"}.get(field, rf"line 1 \(header\): {field}: missing \(required\)")
    with pytest.raises(DatasetFileError, match=expected):
        read_recording(path)


@pytest.mark.parametrize("header, message", [
    ({"clocks": {"robot": "egm"}}, r"line 1 \(header\): clocks: needs exactly the keys robot and sensor.*missing sensor"),
    ({"clocks": {"robot": "egm", "sensor": ""}}, r"clocks.sensor: must be a clock's name"),
    ({"sweeps": [{"station": "S1", "speed_mm_s": 100.0, "direction": [1.0, 1.0, 0.0]}]},
     r"sweeps\[0\].direction: must be a unit vector \(base frame\), its norm is 1.41421"),
    ({"sweeps": [{"station": "S1", "speed_mm_s": -1, "direction": [1.0, 0.0, 0.0]}]},
     r"sweeps\[0\].speed_mm_s: must be a speed > 0 in mm/s, got -1"),
    ({"sweeps": [{"station": "S1", "direction": [1.0, 0.0, 0.0]}]}, r"sweeps\[0\].speed_mm_s: missing"),
    ({"sphere_radius_mm": 0.019}, r"line 1 \(header\): sphere_radius_mm: .*metres"),
    ({"created": "2026-01-01T00:00:00"}, r"line 1 \(header\): created: .* has no time zone"),
    ({"clock": "x"}, r"line 1 \(header\): clock: unknown field"),
    ({"version": 4}, r"dataset format version 4 is newer than this spherecal"),
    ({"version": 2}, r"a dataset of observations \(format version 2\), not a stream recording: read it with "
                     r"spherecal.io.dataset.read_dataset"),
])
def test_bad_headers(tmp_path, header, message):
    path = tmp_path / "h.jsonl"
    write_file(path, good_lines(), header)
    with pytest.raises(DatasetFileError, match=message):
        read_recording(path)


def _bad_b64_length():
    return base64.b64encode(np.zeros(3, "<f4").tobytes()).decode()


@pytest.mark.parametrize("edit, message", [
    # stamps going backwards or jumping
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.008, 10.004])),
     r"line 2: poses.t_robot_s: item 2 is 10.004 s, not after 10.008 s \(item 1\): stamps must increase \(robot clock"),
    (lambda L: L.__setitem__(2, poses_line([10.006, 10.016])),
     r"line 4: poses.t_robot_s: item 0 is 10.006 s, not after 10.008 s \(the stream's sample before it\)"),
    (lambda L: L.__setitem__(2, poses_line([10.012, 10.012 + 2 * MAX_STAMP_STEP_S])),
     r"line 4: poses.t_robot_s: item 1 jumps 7200 s .* a clock jump"),
    (lambda L: L.__setitem__(3, profile_line(4.0)),
     r"line 5: profile.t_sensor_s: 4.0 s is not after the previous profile's 5.0 s \(line 3\): stamps must increase "
     r"\(sensor clock\)"),
    (lambda L: L.__setitem__(3, profile_line(5.0 + 4000)),
     r"line 5: profile.t_sensor_s: 4005.0 s jumps 4000 s after the previous profile \(line 3, sensor clock\)"),
    # points
    (lambda L: L.__setitem__(4, profile_line(5.004, [(1.0, -20.0), (np.nan, -1.0)])),
     r"line 6: profile.points_yz_mm_f32le: point 1 is \(y, z\) = \(nan, -1.0\) mm: not a finite number"),
    (lambda L: L.__setitem__(3, profile_line(5.002, [(np.inf, 0.0)])),
     r"line 5: profile.points_yz_mm_f32le: point 0 is \(y, z\) = \(inf, 0.0\) mm"),
    (lambda L: L.__setitem__(1, profile_line(5.0, points_yz_mm_f32le=_bad_b64_length())),
     r"line 3: profile.points_yz_mm_f32le: decodes to 12 bytes, not a multiple of 8: expected pairs of little-endian "
     r"float32 \(y, z\)"),
    (lambda L: L.__setitem__(1, profile_line(5.0, points_yz_mm_f32le="AAAA$AAA")),
     r"line 3: profile.points_yz_mm_f32le: not valid base64"),
    (lambda L: L.__setitem__(1, profile_line(5.0, points_yz_mm_f32le="AAA")),
     r"line 3: profile.points_yz_mm_f32le: not valid base64"),
    (lambda L: L.__setitem__(1, profile_line(5.0, points_yz_mm_f32le=...)),
     r"line 3: profile.points_yz_mm_f32le: missing \(required\)"),
    (lambda L: L.__setitem__(1, profile_line("5.0")), r"line 3: profile.t_sensor_s: must be a finite number"),
    (lambda L: L.__setitem__(1, profile_line(5.0, sweep=1)),
     r"line 3: profile.sweep: must be -1 \(outside a sweep\) or an index into the header's 1 sweeps, got 1"),
    (lambda L: L.__setitem__(3, profile_line(5.002, sweep=...)),
     r"line 5: profile.sweep: missing here, but given on line 3: every profile has a sweep or none does"),
    (lambda L: L.__setitem__(1, profile_line(5.0, exposure_us=10)), r"line 3: profile.exposure_us: unknown field"),
    # pose blocks
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, 10.008], translation_mm=[[1.0, 2.0, 3.0]] * 2)),
     r"line 2: poses.translation_mm: 2 samples, but t_robot_s has 3: every list of a pose line has one entry"),
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, 10.008], quaternion_wxyz=[IDENT] * 4)),
     r"line 2: poses.quaternion_wxyz: 4 samples, but t_robot_s has 3"),
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, 10.008], translation_mm=[[1.0, 2.0]] * 3)),
     r"line 2: poses.translation_mm: expected 3 rows of 3 numbers, got 3 rows of 2 numbers"),
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, 10.008], quaternion_wxyz=[IDENT, IDENT, [1, 0, 0, 0.1]])),
     r"line 2: poses.quaternion_wxyz: item 2 \[1.0, 0.0, 0.0, 0.1\] has norm 1.00499, not 1"),
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, 10.008], translation_mm=[[1.0, True, 3.0]] * 3)),
     r"line 2: poses.translation_mm: must hold only numbers; item \[0\]\[1\] is true"),
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, None])),
     r"line 2: poses.t_robot_s: must hold only numbers; item 2 is null"),
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, 10.008], translation_mm=[[1.0, 2.0, 3e9]] * 3)),
     r"line 2: poses.translation_mm: item \[0\]\[2\] is 3000000000.0: not a finite number of at most 1e\+06"),
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, 10.008], quaternion_wxyz=...)),
     r"line 2: poses.quaternion_wxyz: missing \(required\)"),
    (lambda L: L.__setitem__(2, poses_line([10.012, 10.016], joints_deg=[[0.0] * 6] * 2)),
     r"line 4: poses.joints_deg: given here, but missing on line 2: every pose line has joints or none does"),
    (lambda L: L.__setitem__(2, poses_line([10.012, 10.016], seq=[1, 2])),
     r"line 4: poses.seq: given here, but missing on line 2"),
    (lambda L: L.__setitem__(0, poses_line([10.0, 10.004, 10.008], seq=[1, 2, 2.5])),
     r"line 2: poses.seq: must hold whole numbers"),
    # lines
    (lambda L: L.insert(1, {"pose": {}}), r"line 3: expected an object with one key, \"poses\" or \"profile\""),
    (lambda L: L.insert(1, dict(HEADER)), r"line 3: a second header"),
    (lambda L: L.insert(1, {"poses": [1, 2]}), r"line 3: poses: expected an object, got list"),
])
def test_bad_lines_name_the_file_line_and_field(tmp_path, edit, message):
    lines = good_lines()
    edit(lines)
    path = tmp_path / "bad.jsonl"
    write_file(path, lines)
    with pytest.raises(DatasetFileError, match=rf"{path}.*{message}"):
        read_recording(path)


def test_a_damaged_middle_line_is_not_taken_for_an_interrupted_write(tmp_path):
    path = tmp_path / "d.jsonl"
    write_file(path, good_lines())
    text = path.read_text().splitlines()
    text[2] = text[2][:30]
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(DatasetFileError, match=r"line 3 \(byte \d+\): not valid JSON .* the file is damaged"):
        read_recording(path)


def test_an_unusual_but_valid_layout_reads(tmp_path):
    """Keys in another order, spaces, an escaped slash in the base64: still JSON, still read."""
    pts = [(1.0, -20.0), (2.0, -21.0)]
    text = b64(pts)
    lines = [json.dumps(HEADER), json.dumps(poses_line([1.0, 2.0])),
             '{"profile" : {"points_yz_mm_f32le" :  "' + text.replace("/", "\\/") + '", "t_sensor_s": 3.0, "sweep": 0}}',
             '{ "profile": {"sweep": -1, "t_sensor_s": 4.0, "points_yz_mm_f32le": "' + text + '"}}']
    path = tmp_path / "layout.jsonl"
    path.write_text("\n".join(lines) + "\n")
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.profiles.points_yz_mm, pts * 2)
    np.testing.assert_array_equal(rec.profiles.sweep, [0, -1])


# -------------------------------------------------------------------------------------
# the writer refuses what would make an unreadable file
# -------------------------------------------------------------------------------------


def test_writer_refuses_bad_input_and_leaves_the_file_as_it_was(tmp_path):
    path = tmp_path / "w.jsonl"
    out = RecordingWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05, clocks={"robot": "r", "sensor": "s"},
                          sweeps=SWEEPS[:1])
    out.add_poses([1.0, 2.0], [[0, 0, 0]] * 2, [IDENT] * 2, joints_deg=[[0.0] * 6] * 2)
    out.add_profile(0.5, [[1.0, -20.0]], sweep=0)
    size = path.stat().st_size
    cases = [
        (lambda: out.add_poses([1.5], [[0, 0, 0]], [IDENT], joints_deg=[[0.0] * 6]),
         r"poses.t_robot_s: item 0 is 1.5 s, not after 2.0 s"),
        (lambda: out.add_poses([3.0], [[0, 0, 0]], [IDENT]), r"poses.joints_deg: missing here but given on the earlier"),
        (lambda: out.add_poses([3.0], [[0, 0, 0]], [[1, 0, 0, 0.5]], joints_deg=[[0.0] * 6]),
         r"poses.quaternion_wxyz: item 0 .* has norm 1.11803, not 1"),
        (lambda: out.add_poses([3.0, 4.0], [[0, 0, 0]], [IDENT] * 2, joints_deg=[[0.0] * 6] * 2),
         r"poses: 2 stamps, but the other arrays do not have one row per stamp"),
        (lambda: out.add_poses([3.0], [[0, np.nan, 0]], [IDENT], joints_deg=[[0.0] * 6]),
         r"poses.translation_mm: item \[0\]\[1\] is nan"),
        (lambda: out.add_profile(0.4, [[1.0, -20.0]], sweep=0), r"profile.t_sensor_s: item 0 is 0.4 s, not after 0.5 s"),
        (lambda: out.add_profile(0.6, [[1.0, np.inf]], sweep=0), r"point 0 is \[1.0, inf\] mm: not a finite number"),
        (lambda: out.add_profile(0.6, [[1.0, -20.0]], sweep=3), r"profile.sweep: 3 .* not -1 or an index into the 1 "),
        (lambda: out.add_profile(0.6, [[1.0, -20.0]]), r"profile.sweep: missing here but not on the earlier profiles"),
    ]
    for call, message in cases:
        with pytest.raises(InputError, match=message):
            call()
        assert path.stat().st_size == size
    out.close()
    rec = read_recording(path)
    assert rec.poses.n == 2 and rec.profiles.n == 1
    with pytest.raises(DatasetFileError, match="already exists"):
        RecordingWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05)
    with pytest.raises(InputError, match="sphere_radius_mm"):
        RecordingWriter(tmp_path / "m.jsonl", mounting="eye_in_hand", sphere_radius_mm=0.019)
    with pytest.raises(InputError, match=r"clocks: needs exactly the keys robot and sensor"):
        RecordingWriter(tmp_path / "c.jsonl", mounting="eye_in_hand", sphere_radius_mm=19.05, clocks={"pc": "x"})


def test_write_recording_is_atomic_and_names_the_file(tmp_path):
    rec = make_recording(n_profiles=3)
    path = tmp_path / "r.jsonl"
    write_recording(path, rec)
    with pytest.raises(DatasetFileError, match="already exists; pass overwrite=True"):
        write_recording(path, rec)
    write_recording(path, rec, overwrite=True)
    bad = Recording(rec.mounting, 0.0127, rec.poses, rec.profiles, rec.sweeps, {}, rec.clocks)
    with pytest.raises(InputError, match=rf"{path}.*sphere_radius_mm"):
        write_recording(path, bad, overwrite=True)
    assert_same(rec, read_recording(path))  # the failed write left the file as it was
    assert [p.name for p in tmp_path.iterdir()] == ["r.jsonl"]
    with pytest.raises(DatasetFileError, match=rf"{tmp_path / 'no' / 'r.jsonl'}: cannot write \(its folder does not"):
        write_recording(tmp_path / "no" / "r.jsonl", rec)


# -------------------------------------------------------------------------------------
# the dataset reader and the stream reader tell each other's files apart
# -------------------------------------------------------------------------------------


def test_read_dataset_names_a_stream_file(tmp_path):
    path = tmp_path / "s.jsonl"
    write_recording(path, make_recording(n_profiles=2))
    for read in (read_dataset, read_dataset_header):
        with pytest.raises(DatasetFileError, match=r"a stream recording \(dataset format version 3, form 'stream'.*"
                                                   r"read it with spherecal.io.streams.read_recording"):
            read(path)


def test_recording_kind(tmp_path):
    ds = tmp_path / "d.jsonl"
    v2_header = {k: v for k, v in HEADER.items() if k not in ("form", "clocks", "sweeps")} | {"version": 2}
    ds.write_text(json.dumps(v2_header) + "\n")
    assert recording_kind(ds) == "dataset"
    st = tmp_path / "s.jsonl"
    write_recording(st, make_recording(n_profiles=2))
    assert recording_kind(st) == "stream"
    bag = tmp_path / "bag"
    bag.mkdir()
    with pytest.raises(DatasetFileError, match="a folder without metadata.yaml: not a rosbag2 recording"):
        recording_kind(bag)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    assert recording_kind(bag) == "rosbag"
    assert recording_kind(tmp_path / "x.mcap") == "rosbag"
    assert recording_kind(tmp_path / "x.db3") == "rosbag"
    assert recording_kind(tmp_path / "missing.jsonl") == "dataset"


def test_the_example_in_the_docs_reads(tmp_path):
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "file-formats.md").read_text()
    block = text[text.index("## Stream recordings"):].split("```json\n", 1)[1].split("```", 1)[0]
    lines: list[str] = []
    for row in block.splitlines():  # a row starting with a space continues the line above
        if row.startswith(" "):
            lines[-1] += " " + row.strip()
        else:
            lines.append(row)
    path = tmp_path / "example.stream.jsonl"
    path.write_text("\n".join(lines) + "\n")
    rec = read_recording(path)
    assert (rec.poses.n, rec.profiles.n, rec.clocks["robot"]) == (6, 2, "abb-egm")
    np.testing.assert_array_equal(rec.profiles.profile(0), [[-3.5, -21.25], [-3.0, -20.5], [-2.5, -20.125]])
