"""Dataset and result files: round trips, growth one line at a time, interrupted
writes, and bad files failing with messages that name the file, line and field."""

from __future__ import annotations

import json
import math
import warnings
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from spherecal.io.json_files import json_safe
from spherecal.io.dataset import (
    DATASET_VERSION,
    DatasetWriter,
    TruncatedFileWarning,
    read_dataset,
    read_dataset_header,
    read_result,
    write_dataset,
    write_result,
)
from spherecal.core.errors import DatasetFileError, InputError
from spherecal.core.models import (
    CalibrationResult,
    Dataset,
    Observation,
    ObservationFlag,
    Pose,
    Profile,
    ResidualStats,
    ResultDiagnostics,
)
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

T0 = datetime(2026, 3, 4, 5, 6, 7, 123456, tzinfo=timezone.utc)


def small_obs(index: int, n_points: int = 4, seed: int = 0, station: str = "S1", **kw) -> Observation:
    rng = np.random.default_rng(seed + index)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    fields = dict(
        index=index,
        station=station,
        timestamp=T0 + timedelta(seconds=index),
        base_from_flange=Pose(translation_mm=tuple(rng.uniform(-900, 900, 3)), quaternion_wxyz=tuple(q)),
        profile=Profile(y_mm=rng.normal(0, 5, n_points), z_mm=rng.normal(-20, 5, n_points)),
    )
    fields.update(kw)
    return Observation(**fields)


def small_dataset(n: int = 3, n_points: int = 4) -> Dataset:
    return Dataset(
        mounting="eye_in_hand",
        sphere_radius_mm=19.05,
        observations=[small_obs(i, n_points) for i in range(n)],
        provenance={"source": "test", "operator": "Zoë"},
    )


def assert_same_observations(got: list[Observation], expected: list[Observation]) -> None:
    assert len(got) == len(expected)
    for a, b in zip(got, expected):
        assert a.index == b.index
        assert a.station == b.station
        assert a.timestamp == b.timestamp
        assert a.timestamp.utcoffset() == b.timestamp.utcoffset()
        assert a.base_from_flange == b.base_from_flange  # exact: tuples of floats
        assert a.joints_deg == b.joints_deg
        assert np.array_equal(a.profile.y_mm, b.profile.y_mm)
        assert np.array_equal(a.profile.z_mm, b.profile.z_mm)
        assert a.profile.shot_id == b.profile.shot_id


def json_normalised(value):
    return json.loads(json.dumps(value))


# -------------------------------------------------------------------------------------
# round trips
# -------------------------------------------------------------------------------------


def test_a_dataset_into_a_missing_folder_names_the_file_asked_for(tmp_path):
    """The write goes through a temporary file beside the target: a failure names the
    file the caller asked for and why, never the temporary name."""
    from spherecal.core.errors import FileWriteError

    ds = simulate_dataset(standard_cell("eye_in_hand", seed=3, fov=reference_fov()), SweepPlan(profiles_per_station=4))
    target = tmp_path / "missing" / "d.jsonl"
    with pytest.raises(FileWriteError) as info:
        write_dataset(target, ds)
    assert str(info.value) == f"{target}: cannot write (its folder does not exist)"
    assert ".tmp" not in str(info.value) and not (tmp_path / "missing").exists()


def test_simulated_dataset_round_trip_is_exact(tmp_path, mounting, parser):
    ds = simulate_dataset(standard_cell(mounting, seed=3, fov=reference_fov()))
    assert len(ds.observations) > 10
    path = tmp_path / "run.dataset.jsonl"
    write_dataset(path, ds)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_dataset(path)
    assert back.mounting == ds.mounting
    assert back.sphere_radius_mm == ds.sphere_radius_mm
    assert back.provenance == json_normalised(ds.provenance)
    assert back.provenance["true_transform_name"] == ds.provenance["true_transform_name"]
    assert_same_observations(back.observations, ds.observations)
    header = read_dataset_header(path)
    assert (header.format, header.version, header.mounting) == ("spherecal-dataset", DATASET_VERSION, mounting)
    assert DATASET_VERSION == 2
    assert header.created.tzinfo is not None


def test_round_trip_keeps_every_quaternion_bit(tmp_path, parser):
    # Re-normalising a unit quaternion changes the last bit of a few per cent of them;
    # the file must give back exactly what was written.
    rng = np.random.default_rng(7)
    obs = []
    for i in range(300):
        q = rng.normal(size=4)
        pose = Pose(translation_mm=tuple(rng.normal(0, 500, 3)), quaternion_wxyz=tuple(q / np.linalg.norm(q)))
        obs.append(small_obs(i, base_from_flange=pose))
    ds = Dataset(mounting="eye_to_hand", sphere_radius_mm=12.7, observations=obs)
    write_dataset(tmp_path / "q.jsonl", ds)
    back = read_dataset(tmp_path / "q.jsonl")
    assert [o.base_from_flange.quaternion_wxyz for o in back.observations] == [
        o.base_from_flange.quaternion_wxyz for o in obs
    ]
    assert all(o.base_from_flange.quaternion_wxyz[0] >= 0 for o in back.observations)


def test_round_trip_of_joints_only_observations_and_time_zones(tmp_path, parser):
    cet = timezone(timedelta(hours=1))
    obs = [
        small_obs(0, base_from_flange=None, joints_deg=(0.0, 10.5, -20.25, 1e-9, 90.0, -180.0)),
        small_obs(1, station="Öst-2", timestamp=datetime(2026, 5, 1, 12, 0, tzinfo=cet)),
        small_obs(5, joints_deg=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0)),
    ]
    ds = Dataset(mounting="eye_in_hand", sphere_radius_mm=25.0, observations=obs)
    write_dataset(tmp_path / "j.jsonl", ds)
    back = read_dataset(tmp_path / "j.jsonl")
    assert_same_observations(back.observations, obs)
    assert back.observations[1].timestamp.isoformat() == "2026-05-01T12:00:00+01:00"


def test_round_trip_of_shot_ids_and_files_without_them(tmp_path, parser):
    obs = [small_obs(0), small_obs(1, profile=Profile(y_mm=[1.0, 2.0], z_mm=[3.0, 4.0], shot_id="4294967295")),
           small_obs(2, profile=Profile.from_points([[1.0, 2.0]], shot_id="cam-1#0017"))]
    path = tmp_path / "ids.jsonl"
    write_dataset(path, Dataset(mounting="eye_in_hand", sphere_radius_mm=19.1, observations=obs))
    lines = [json.loads(line) for line in path.read_text().splitlines()[1:]]
    assert "shot_id" not in lines[0]["profile"]  # a file from before shot ids looks the same
    assert lines[1]["profile"]["shot_id"] == "4294967295"
    back = read_dataset(path)
    assert [o.profile.shot_id for o in back.observations] == [None, "4294967295", "cam-1#0017"]
    assert_same_observations(back.observations, obs)


def test_file_is_readable_json_lines(tmp_path):
    path = tmp_path / "d.jsonl"
    write_dataset(path, small_dataset(2))
    lines = path.read_text(encoding="utf-8").splitlines()
    assert len(lines) == 3
    header, first = json.loads(lines[0]), json.loads(lines[1])
    assert list(header)[:2] == ["format", "version"]
    assert header["provenance"]["operator"] == "Zoë"  # UTF-8, not \u escapes
    assert "Zoë" in lines[0]
    assert first["kind"] == "observation" and first["index"] == 0
    assert first["timestamp"] == "2026-03-04T05:06:07.123456+00:00"
    assert set(first["base_from_flange"]) == {"translation_mm", "quaternion_wxyz"}
    assert first["joints_deg"] is None
    assert len(first["profile"]["y_mm"]) == 4


def test_write_dataset_refuses_to_overwrite_unless_asked(tmp_path):
    path = tmp_path / "d.jsonl"
    write_dataset(path, small_dataset(2))
    with pytest.raises(DatasetFileError, match=r"d\.jsonl already exists; pass overwrite=True"):
        write_dataset(path, small_dataset(3))
    assert len(read_dataset(path).observations) == 2
    write_dataset(path, small_dataset(3), overwrite=True)
    assert len(read_dataset(path).observations) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.jsonl"]  # no temporary left


def test_write_refuses_nan_in_provenance_and_naive_timestamps(tmp_path):
    ds = small_dataset(1)
    ds.provenance["noise_mm"] = float("nan")
    with pytest.raises(InputError, match=r"header\.provenance\.noise_mm is nan"):
        write_dataset(tmp_path / "a.jsonl", ds)
    naive = small_obs(0, timestamp=datetime(2026, 1, 1, 12, 0))
    ds = Dataset(mounting="eye_in_hand", sphere_radius_mm=19.05, observations=[naive])
    with pytest.raises(InputError, match="observation 0: timestamp 2026-01-01T12:00:00 has no time zone"):
        write_dataset(tmp_path / "b.jsonl", ds)
    assert not list(tmp_path.iterdir())


# -------------------------------------------------------------------------------------
# interrupted writes
# -------------------------------------------------------------------------------------


def test_file_cut_anywhere_in_last_line_loads_earlier_observations(tmp_path, parser):
    ds = small_dataset(3, n_points=3)
    full = tmp_path / "full.jsonl"
    write_dataset(full, ds)
    data = full.read_bytes()
    last_start = data.rstrip(b"\n").rfind(b"\n") + 1
    cut = tmp_path / "cut.jsonl"
    for end in range(last_start, len(data) + 1):
        cut.write_bytes(data[:end])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            back = read_dataset(cut)
        n_expected = 3 if end >= len(data) - 1 else 2  # only the newline missing: still whole
        assert [o.index for o in back.observations] == list(range(n_expected)), end
        if last_start < end < len(data) - 1:
            assert len(caught) == 1, end
            assert caught[0].category is TruncatedFileWarning
            msg = str(caught[0].message)
            assert f"cut.jsonl: line 4 is incomplete" in msg
            assert f"dropped {end - last_start} bytes from byte {last_start} on" in msg
            assert "loaded the 2 whole observations" in msg
        else:
            assert caught == [], end
    assert_same_observations(back.observations, ds.observations)


def test_file_cut_inside_header_is_a_clear_error(tmp_path):
    path = tmp_path / "d.jsonl"
    write_dataset(path, small_dataset(1))
    data = path.read_bytes()
    header_len = data.index(b"\n")
    for end in range(1, header_len):
        path.write_bytes(data[:end])
        with pytest.raises(DatasetFileError, match=r"d\.jsonl: the file ends inside its header"):
            read_dataset(path)
    path.write_bytes(data[:header_len])  # whole header, newline missing: no observations yet
    assert read_dataset(path).observations == []
    path.write_bytes(b"")
    with pytest.raises(DatasetFileError, match=r"d\.jsonl: the file is empty"):
        read_dataset(path)


def test_zero_filled_tail_after_a_crash_is_dropped(tmp_path):
    path = tmp_path / "d.jsonl"
    write_dataset(path, small_dataset(2))
    with open(path, "ab") as f:
        f.write(b"\0" * 64)
    with pytest.warns(TruncatedFileWarning, match="dropped 64 bytes"):
        assert len(read_dataset(path).observations) == 2


def test_invalid_json_in_the_middle_is_an_error(tmp_path, parser):
    path = tmp_path / "d.jsonl"
    write_dataset(path, small_dataset(3))
    lines = path.read_bytes().split(b"\n")
    lines[2] = lines[2][:40]
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(DatasetFileError, match=r"d\.jsonl line 3 \(byte \d+\): not valid JSON .* the file is damaged"):
        read_dataset(path)


# -------------------------------------------------------------------------------------
# the writer
# -------------------------------------------------------------------------------------


def test_writer_appends_one_observation_at_a_time(tmp_path, parser):
    path = tmp_path / "acq.jsonl"
    obs = [small_obs(i, n_points=50) for i in range(5)]
    with DatasetWriter(path, mounting="eye_to_hand", sphere_radius_mm=19.05, provenance={"cell": "A"}) as out:
        assert read_dataset(path).observations == []  # the header is on disk at once
        for k, o in enumerate(obs):
            assert out.next_index == k
            out.append(o)
            # readable mid-acquisition, without closing the writer
            assert_same_observations(read_dataset(path).observations, obs[: k + 1])
        assert out.n_observations == 5
    assert out.closed
    back = read_dataset(path)
    assert (back.mounting, back.sphere_radius_mm, back.provenance) == ("eye_to_hand", 19.05, {"cell": "A"})
    assert_same_observations(back.observations, obs)
    with pytest.raises(DatasetFileError, match="the writer is closed"):
        out.append(small_obs(5))


def test_writer_refuses_existing_file_and_duplicate_index(tmp_path):
    path = tmp_path / "acq.jsonl"
    with DatasetWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05, fsync=True) as out:
        out.append(small_obs(0))
        with pytest.raises(InputError, match=r"observation index 0 is already in the file \(line 2\).*next free: 1"):
            out.append(small_obs(0))
        with pytest.raises(InputError, match="expected an Observation, got dict"):
            out.append({"index": 1})
    with pytest.raises(DatasetFileError, match=r"acq\.jsonl already exists; pass resume=True"):
        DatasetWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05)
    with pytest.raises(InputError, match="looks like metres"):
        DatasetWriter(tmp_path / "m.jsonl", mounting="eye_in_hand", sphere_radius_mm=0.01905)
    assert len(read_dataset(path).observations) == 1


def test_resume_after_truncation_cuts_the_partial_line_first(tmp_path, parser):
    path = tmp_path / "acq.jsonl"
    kw = dict(mounting="eye_in_hand", sphere_radius_mm=19.05)
    with DatasetWriter(path, provenance={"session": 1}, **kw) as out:
        for i in range(3):
            out.append(small_obs(i))
    data = path.read_bytes()
    last_start = data.rstrip(b"\n").rfind(b"\n") + 1
    path.write_bytes(data[: last_start + 25])  # power cut while writing observation 2
    with pytest.warns(TruncatedFileWarning, match=r"line 4 is incomplete.*dropped 25 bytes.*cut off before appending"):
        out = DatasetWriter(path, provenance={"session": 2}, resume=True, fsync=True, **kw)
    with out:
        assert (out.n_observations, out.next_index) == (2, 2)
        assert path.stat().st_size == last_start
        out.append(small_obs(2, seed=100))
        out.append(small_obs(3, seed=100))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_dataset(path)
    assert back.provenance == {"session": 1}  # the file keeps its own header
    assert_same_observations(back.observations, [small_obs(0), small_obs(1), small_obs(2, seed=100), small_obs(3, seed=100)])


def test_resume_adds_a_missing_final_newline_and_creates_missing_files(tmp_path):
    path = tmp_path / "acq.jsonl"
    kw = dict(mounting="eye_in_hand", sphere_radius_mm=19.05)
    with DatasetWriter(path, resume=True, **kw) as out:  # missing: created
        out.append(small_obs(0))
    path.write_bytes(path.read_bytes().rstrip(b"\n"))
    with DatasetWriter(path, resume=True, **kw) as out:
        out.append(small_obs(1))
    assert path.read_bytes().count(b"\n") == 3
    assert [o.index for o in read_dataset(path).observations] == [0, 1]
    empty = tmp_path / "empty.jsonl"
    empty.write_bytes(b"")  # crash between creating the file and writing its header
    with DatasetWriter(empty, resume=True, **kw) as out:
        out.append(small_obs(0))
    assert len(read_dataset(empty).observations) == 1


def test_resume_checks_the_header_matches(tmp_path):
    path = tmp_path / "acq.jsonl"
    DatasetWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05).close()
    with pytest.raises(
        DatasetFileError,
        match=r"acq\.jsonl holds a dataset for mounting=eye_in_hand, sphere_radius_mm=19\.05; "
        r"this acquisition is mounting=eye_to_hand.*new file",
    ):
        DatasetWriter(path, mounting="eye_to_hand", sphere_radius_mm=19.05, resume=True)
    with pytest.raises(DatasetFileError, match=r"sphere_radius_mm=12\.7\. Write to a new file"):
        DatasetWriter(path, mounting="eye_in_hand", sphere_radius_mm=12.7, resume=True)
    path.write_bytes(path.read_bytes()[:30])
    with pytest.raises(DatasetFileError, match="ends inside its header.*delete the file"):
        DatasetWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05, resume=True)


# -------------------------------------------------------------------------------------
# bad files
# -------------------------------------------------------------------------------------


def write_lines(path, header: dict | None = None, observations: list[dict] = ()) -> None:
    h = {
        "format": "spherecal-dataset",
        "version": 1,
        "mounting": "eye_in_hand",
        "sphere_radius_mm": 19.05,
        "provenance": {},
        "created": "2026-01-01T00:00:00Z",
    }
    h.update(header or {})
    lines = [json.dumps(h)] + [json.dumps(o) for o in observations]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def obs_dict(index: int, /, **changes) -> dict:
    d = {
        "kind": "observation",
        "index": index,
        "station": "S1",
        "timestamp": "2026-01-01T00:00:01Z",
        "base_from_flange": {"translation_mm": [1.0, 2.0, 3.0], "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0]},
        "joints_deg": None,
        "profile": {"y_mm": [1.0, 2.0, 3.0], "z_mm": [-20.0, -21.0, -22.0]},
    }
    for key, value in changes.items():
        target = d
        *parents, leaf = key.split("__")
        for p in parents:
            target = target[p]
        if value is ...:
            del target[leaf]
        else:
            target[leaf] = value
    return d


@pytest.mark.parametrize(
    "header, message",
    [
        ({"format": "spherecal-result"}, r'line 1 has format "spherecal-result".*not a dataset: give a dataset'),
        ({"format": "laser-scans"}, r'not a spherecal dataset: line 1 has format "laser-scans", expected \'spherecal-dataset\''),
        ({"version": 3}, r"dataset format version 3 is newer than this spherecal .* \(versions 1 to 2\); upgrade spherecal"),
        ({"version": "1"}, r'line 1 \(header\): version must be a whole number >= 1, found "1"'),
        ({"mounting": "eye_on_hand"}, r"line 1 \(header\): mounting: Input should be 'eye_in_hand' or 'eye_to_hand'"),
        ({"sphere_radius_mm": 0.019}, r"line 1 \(header\): sphere_radius_mm: .*looks like metres"),
        ({"created": "2026-01-01T00:00:00"}, r"line 1 \(header\): created: .* has no time zone"),
        ({"sphere_radius": 19.05}, r"line 1 \(header\): sphere_radius: unknown key \(allowed here: .*did you mean 'sphere_radius_mm'\?\)"),
    ],
)
def test_bad_headers(tmp_path, header, message, parser):
    path = tmp_path / "bad.jsonl"
    write_lines(path, header, [obs_dict(0)])
    with pytest.raises(DatasetFileError, match=r"bad\.jsonl.*" + message):
        read_dataset(path)


def test_a_file_that_is_not_a_dataset(tmp_path):
    path = tmp_path / "scan.csv"
    path.write_text("y,z\n1.0,2.0\n")
    with pytest.raises(DatasetFileError, match=r"scan\.csv: not a spherecal dataset: line 1 is not valid JSON"):
        read_dataset(path)
    path.write_text('{"y": 1}\n')
    with pytest.raises(DatasetFileError, match="an object without 'format'"):
        read_dataset(path)
    with pytest.raises(DatasetFileError, match=r"nothere\.jsonl: no such file"):
        read_dataset(tmp_path / "nothere.jsonl")


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"profile__y_mm": [1.0, float("nan"), 3.0]}, r"profile\.y_mm: contains NaN or infinite values \(first at index 1: nan\)"),
        ({"profile__z_mm": [1.0, 2.0, float("inf")]}, r"profile\.z_mm: contains NaN or infinite values \(first at index 2: inf\)"),
        ({"profile__y_mm": [[1.0, 2.0], [3.0, 4.0]]}, r"profile\.y_mm: expected a flat list of numbers, got shape \(2, 2\)"),
        ({"profile__y_mm": [[1.0], [2.0, 3.0]]}, r"profile\.y_mm: expected a flat list of numbers, got nested lists"),
        ({"profile__y_mm": [1.0, 2.0]}, r"profile: y_mm has 2 values but z_mm has 3"),
        ({"profile__y_mm": [], "profile__z_mm": []}, r"profile: profile is empty"),
        ({"profile__y_mm": [1.0, "2.0", 3.0]}, r'profile\.y_mm: must hold only numbers; item 1 is "2\.0" \(str\)'),
        ({"profile__y_mm": [1.0, 2.0, True]}, r"profile\.y_mm: must hold only numbers; item 2 is true \(bool\)"),
        ({"profile__z_mm": [1.0, None, 3.0]}, r"profile\.z_mm: must hold only numbers; item 1 is null"),
        ({"profile__y_mm": "1.0 2.0 3.0"}, r"profile\.y_mm: expected a list of numbers, got str"),
        ({"base_from_flange__translation_mm": [1.0, "2", 3.0]}, r'base_from_flange\.translation_mm: must hold only numbers; item 1 is "2"'),
        ({"base_from_flange__quaternion_wxyz": [1.0, 0.0, 0.0]}, r"base_from_flange\.quaternion_wxyz: needs 4 numbers \(w, x, y, z\), got 3"),
        ({"base_from_flange__translation_mm": [1.0, 2.0, 3.0, 4.0]}, r"base_from_flange\.translation_mm: needs 3 numbers \(x, y, z\), got 4"),
        ({"base_from_flange__quaternion_wxyz": [0.5, 0.5, 0.5, 0.0]}, r"base_from_flange\.quaternion_wxyz: .*has norm 0\.866025; expected a unit quaternion"),
        ({"base_from_flange": None}, r"needs base_from_flange or joints_deg"),
        ({"joints_deg": [0.0, 1.0, 2.0, 3.0, 4.0, True]}, r"joints_deg: must hold only numbers; item 5 is true"),
        ({"timestamp": "2026-01-01T00:00:01"}, r"timestamp: '2026-01-01T00:00:01' has no time zone"),
        ({"timestamp": ...}, r"timestamp: missing \(required in files"),
        ({"station": ""}, r"station: String should have at least 1 character"),
        ({"index": -1}, r"index: Input should be greater than or equal to 0"),
        ({"index": 1.0}, r"index: Input should be a valid integer"),
        ({"kind": "event"}, r'kind: expected \'observation\', got "event"'),
        ({"exposure_us": 120}, r"exposure_us: unknown key"),
        ({"profile__shot_id": 17}, r"profile\.shot_id: Input should be a valid string"),
        ({"profile__shot_id": "frame 17"}, r"profile\.shot_id: String should match pattern"),
        ({"profile__shot_id": "7" * 65}, r"profile\.shot_id: String should have at most 64 characters"),
    ],
)
def test_bad_observation_lines_name_file_line_observation_and_field(tmp_path, changes, message, parser):
    path = tmp_path / "run.jsonl"
    write_lines(path, None, [obs_dict(0), obs_dict(1, **changes), obs_dict(2)])
    where = r"run\.jsonl line 3.*" if "index" in changes else r"run\.jsonl line 3 \(observation 1\): "
    with pytest.raises(DatasetFileError, match=where + message):
        read_dataset(path)


def test_mixed_files_are_refused(tmp_path, parser):
    path = tmp_path / "joined.jsonl"
    write_lines(path, None, [obs_dict(0), obs_dict(1)])
    text = path.read_text()
    path.write_text(text + text)  # two acquisitions pasted into one file
    with pytest.raises(DatasetFileError, match=r"joined\.jsonl line 4: a second header .* two files were joined"):
        read_dataset(path)
    write_lines(path, None, [obs_dict(0), obs_dict(1), obs_dict(1)])
    with pytest.raises(DatasetFileError, match=r"line 4 \(observation 1\): index 1 was already used on line 3"):
        read_dataset(path)
    write_lines(path, None, [obs_dict(0), [1.0, 2.0]])
    with pytest.raises(DatasetFileError, match=r"line 3: expected a JSON object, got list"):
        read_dataset(path)


def test_integers_and_blank_lines_are_accepted(tmp_path, parser):
    path = tmp_path / "hand.jsonl"
    write_lines(path, None, [obs_dict(0, profile__y_mm=[1, 2, 3], base_from_flange__translation_mm=[1, 2, 3])])
    path.write_text(path.read_text() + "\n  \n")
    (o,) = read_dataset(path).observations
    assert o.profile.y_mm.dtype == float and o.profile.y_mm.tolist() == [1.0, 2.0, 3.0]
    assert o.base_from_flange.translation_mm == (1.0, 2.0, 3.0)
    write_lines(path, None, [obs_dict(0, profile__y_mm=[1.0, 0.0, 1.0])])  # real 1.0 and 0.0 are numbers
    assert read_dataset(path).observations[0].profile.y_mm.tolist() == [1.0, 0.0, 1.0]


# -------------------------------------------------------------------------------------
# results
# -------------------------------------------------------------------------------------


def hand_made_result(rng=None) -> CalibrationResult:
    rng = rng or np.random.default_rng(11)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    cov = rng.normal(size=(9, 9))
    cov = (cov @ cov.T * 1e-6).tolist()
    return CalibrationResult(
        mounting="eye_in_hand",
        transform_name="flange_from_sensor",
        transform=Pose(translation_mm=(42.51234567890123, -18.3, 163.7), quaternion_wxyz=tuple(q)),
        std_rotation_deg=(0.011, 0.009, 0.02),
        std_translation_mm=(0.031, 0.028, 0.045),
        sphere_centre_frame="base",
        sphere_centre_mm=(1100.0123, 150.004, 399.998),
        std_sphere_centre_mm=(0.02, 0.02, 0.03),
        sphere_radius_mm=19.05,
        radius_fitted=False,
        covariance=cov,
        variance_factor=1.07,
        residuals=ResidualStats(
            rms_mm=0.0102,
            max_abs_mm=0.041,
            p95_abs_mm=0.02,
            n_points_used=11873,
            n_points_rejected=12,
            n_profiles_used=39,
            per_station_rms_mm={"S1": 0.0101, "S2": 0.0099},
        ),
        flagged=[ObservationFlag(index=17, station="S2", reason="pose/profile mismatch (5.2 sigma)")],
        method="two-step circle/sphere fit, then joint least squares",
        two_step_transform=Pose(translation_mm=(42.6, -18.2, 163.5), quaternion_wxyz=tuple(q)),
        diagnostics={"iterations": 6, "condition_number": 3.4e4, "history": np.array([1.5, 0.2, 0.01])},
        provenance={"dataset": "run.dataset.jsonl", "spherecal": "0.1.0"},
    )


def test_result_round_trip(tmp_path):
    result = hand_made_result()
    path = tmp_path / "cal.result.json"
    write_result(path, result)
    back = read_result(path)
    expected = result.model_copy(update={"diagnostics": result.diagnostics.model_copy(update={"history": [1.5, 0.2, 0.01]})})
    assert back == expected
    text = path.read_text(encoding="utf-8")
    assert text.startswith('{\n  "format": "spherecal-result",\n  "version": 3,\n')
    cov_rows = [line for line in text.splitlines() if line.startswith("    [")]
    assert len(cov_rows) == 9  # one covariance row per line
    assert '"quaternion_wxyz": [' in text and '"translation_mm": [42.51234567890123, -18.3, 163.7]' in text


def test_result_quaternions_come_back_bit_for_bit(tmp_path):
    rng = np.random.default_rng(5)
    for i in range(60):
        result = hand_made_result(rng)
        write_result(tmp_path / "r.json", result, overwrite=True)
        back = read_result(tmp_path / "r.json")
        assert back.transform.quaternion_wxyz == result.transform.quaternion_wxyz
        assert back.two_step_transform.quaternion_wxyz == result.two_step_transform.quaternion_wxyz


def test_bad_result_files(tmp_path):
    path = tmp_path / "r.json"
    write_result(path, hand_made_result())
    with pytest.raises(DatasetFileError, match=r"r\.json already exists; pass overwrite=True"):
        write_result(path, hand_made_result())
    doc = json.loads(path.read_text())

    def check(change, message):
        d = json.loads(json.dumps(doc))
        change(d)
        path.write_text(json.dumps(d, indent=2))
        with pytest.raises(DatasetFileError, match=r"r\.json: " + message):
            read_result(path)

    check(lambda d: d.update(version=4), r"result format version 4 is newer than this spherecal .* upgrade spherecal")
    check(lambda d: d.update(format="spherecal-dataset"), r"not a spherecal result: .*give a result\.json or a run folder")
    check(lambda d: d["transform"].update(quaternion_wxyz=[1.0, 0.0, 0.0]), r"transform\.quaternion_wxyz")
    check(lambda d: d.update(variance_factor="1.07"), r"variance_factor: Input should be a valid number")
    check(lambda d: d["residuals"].pop("rms_mm"), r"residuals\.rms_mm: missing")
    check(lambda d: d.update(tool="x"), r"tool: unknown key")
    path.write_text(path.read_text()[:200])
    with pytest.raises(DatasetFileError, match=r"r\.json: not valid JSON"):
        read_result(path)
    dataset = tmp_path / "d.jsonl"
    write_dataset(dataset, small_dataset(1))
    with pytest.raises(DatasetFileError, match=r"d\.jsonl: not a spherecal result: it is a dataset .*give a result\.json"):
        read_result(dataset)
    write_result(path, hand_made_result(), overwrite=True)
    with pytest.raises(DatasetFileError, match=r"r\.json: not a spherecal dataset: it is a calibration result .*give a dataset"):
        read_dataset(path)


def test_result_with_nan_is_refused_with_its_field(tmp_path):
    bad = hand_made_result().model_copy(update={"variance_factor": math.nan})
    with pytest.raises(InputError, match=r"variance_factor is nan: a file cannot hold NaN or infinity"):
        write_result(tmp_path / "r.json", bad)
    bad = hand_made_result().model_copy(update={"diagnostics": ResultDiagnostics.model_validate({"steps": [1.0, math.inf]})})
    with pytest.raises(InputError, match=r"diagnostics\.steps\[1\] is inf"):
        write_result(tmp_path / "r.json", bad)
    assert not list(tmp_path.iterdir())


def test_real_result_round_trip(tmp_path):
    from spherecal import estimation
    ds = simulate_dataset(standard_cell("eye_in_hand", seed=2, fov=reference_fov()))
    write_dataset(tmp_path / "d.jsonl", ds)
    result = estimation.calibrate(read_dataset(tmp_path / "d.jsonl"))
    write_result(tmp_path / "r.json", result)
    back = read_result(tmp_path / "r.json")
    assert back.transform == result.transform
    assert back.covariance == result.covariance
    assert back.residuals == result.residuals
    assert back.model_dump(mode="json") == json_normalised(
        json_safe(result.model_dump(mode="python"), "")
    )
